"""A navigation filter of one's own: a plain-numpy unscented Kalman filter on planet lines of sight.

Fly it through the benchmark by its file (or module) path, beside skynav's EKF:

    skynav bench nav DATASET --filter docs/examples/ukf_filter.py:make_filter \
        --filter skynav.pipeline.flight:skynav_ekf

It fulfils skynav's navigation-filter protocol (``skynav.pipeline.protocols.NavigationFilter``):
``initialise``, ``propagate``, ``update``, ``state``, for N Monte Carlo runs at once. State: position
(km) and velocity (km/s), barycentric ICRS. Dynamics: the force model the benchmark hands over
(``setup.dynamics``: the Sun, the planets and the Moon as point masses, solar radiation pressure),
integrated with fixed-step RK4, and a white-noise acceleration. Measurement: the planet's
observed line of sight (``BeaconMeasurement.line_of_sight_icrs`` and its covariance) against the
predicted one, first-order light-time and aberration, in the tangent plane of the measurement.
The model aims at the planet's centre of light (``m.photocentre``: the Lambert law, or the lit
area's centroid for a saturated disc; skynav's laws), the centre with ``--no-phase-offset``.
"""

import numpy as np

from skynav.pipeline.measurement import PHOTOCENTRE_LAWS   # offset of the centre of light, in radii

C_KM_S = 299792.458
STEP_S = 6 * 3600.0          # RK4 step, s
Q_KM2_S3 = 3.5e-16           # white acceleration PSD, km^2/s^3 (two 1e-11 km/s^2 processes, 10-day correlation)
GATE_NIS = 16.0              # reject a measurement whose normalised innovation squared exceeds 4^2


class UnscentedFilter:
    def __init__(self, setup):
        day = 86400.0
        self.dyn = setup.dynamics.bind(setup.ephemeris, setup.t_start_tdb_s - day, setup.t_end_tdb_s + day)

    def initialise(self, t_tdb_s, x0, P0):
        self.t = float(t_tdb_s)
        self.x = np.array(x0[:, :6], dtype=float)
        self.P = np.broadcast_to(np.asarray(P0)[:6, :6], (len(self.x), 6, 6)).copy()

    def state(self):
        return self.x, self.P

    def _sigma_points(self):
        """(N, 13, 6) points and weights of the unscented transform (kappa = 0: no negative weight)."""
        n = 6
        L = np.linalg.cholesky(n * self.P)                          # columns: the points' offsets
        d = np.concatenate([np.swapaxes(L, 1, 2), -np.swapaxes(L, 1, 2)], 1)
        pts = np.concatenate([self.x[:, None], self.x[:, None] + d], 1)
        w = np.full(2 * n + 1, 1.0 / (2 * n))
        w[0] = 0.0
        return pts, w

    def _derivative(self, t, y):
        return np.concatenate([y[:, 3:], self.dyn.acceleration(t, y[:, :3])], 1)

    def propagate(self, t_tdb_s):
        dt_total = float(t_tdb_s) - self.t
        if dt_total == 0.0:
            return
        pts, w = self._sigma_points()
        y = pts.reshape(-1, 6)
        t, steps = self.t, int(np.ceil(abs(dt_total) / STEP_S))
        h = dt_total / steps
        for _ in range(steps):
            k1 = self._derivative(t, y)
            k2 = self._derivative(t + h / 2, y + h / 2 * k1)
            k3 = self._derivative(t + h / 2, y + h / 2 * k2)
            k4 = self._derivative(t + h, y + h * k3)
            y, t = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4), t + h
        pts = y.reshape(pts.shape)
        self.x = np.einsum("k,nki->ni", w, pts)
        d = pts - self.x[:, None]
        dt = abs(dt_total)
        Q = Q_KM2_S3 * np.block([[dt**3 / 3 * np.eye(3), dt**2 / 2 * np.eye(3)], [dt**2 / 2 * np.eye(3), dt * np.eye(3)]])
        self.P = np.einsum("k,nki,nkj->nij", w, d, d) + Q
        self.t = float(t_tdb_s)

    def update(self, m):
        u = m.line_of_sight_icrs
        E = np.linalg.svd(np.eye(3) - np.outer(u, u))[0][:, :2]    # tangent-plane basis at the measurement
        R = E.T @ m.line_of_sight_cov_rad2 @ E
        pts, w = self._sigma_points()
        r, v = pts[..., :3], pts[..., 3:]
        rho = m.body_position_km - r
        lt = np.linalg.norm(rho, axis=-1, keepdims=True) / C_KM_S
        geo = rho - m.body_velocity_km_s * lt                       # the planet one light-time earlier
        if m.body_radius_km > 0:                                    # its centre of light, towards the Sun
            lhat = geo / np.linalg.norm(geo, axis=-1, keepdims=True)
            to_sun = m.sun_position_km - (r + geo)
            to_sun /= np.linalg.norm(to_sun, axis=-1, keepdims=True)
            phase = np.arccos(np.clip(-np.sum(lhat * to_sun, -1), -1.0, 1.0))
            across = to_sun - np.sum(to_sun * lhat, -1, keepdims=True) * lhat
            across /= np.linalg.norm(across, axis=-1, keepdims=True)
            geo = geo + (PHOTOCENTRE_LAWS[m.photocentre](phase) * m.body_radius_km)[..., None] * across
        app = geo / np.linalg.norm(geo, axis=-1, keepdims=True) + v / C_KM_S    # first-order aberration
        app /= np.linalg.norm(app, axis=-1, keepdims=True)
        zs = app @ E                                                # (N, 13, 2); the measurement is (0, 0)
        zm = np.einsum("k,nki->ni", w, zs)
        dz, dx = zs - zm[:, None], pts - self.x[:, None]
        S = np.einsum("k,nki,nkj->nij", w, dz, dz) + R
        C = np.einsum("k,nki,nkj->nij", w, dx, dz)
        nu = -zm
        nis = np.einsum("ni,ni->n", nu, np.linalg.solve(S, nu[..., None])[..., 0])
        accepted = nis <= GATE_NIS
        K = C @ np.linalg.inv(S)
        x_new = self.x + np.einsum("nij,nj->ni", K, nu)
        P_new = self.P - K @ S @ np.swapaxes(K, 1, 2)
        self.x[accepted] = x_new[accepted]
        self.P[accepted] = 0.5 * (P_new + np.swapaxes(P_new, 1, 2))[accepted]
        return _Update(accepted)


class _Update:
    def __init__(self, accepted):
        self.accepted = accepted
        self.residual_px = None     # this filter's innovations are angles, not pixels


def make_filter(setup):
    """The factory ``--filter docs/examples/ukf_filter.py:make_filter`` names."""
    return UnscentedFilter(setup)
