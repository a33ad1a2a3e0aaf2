"""Beacon (planet) prediction and identification (Andreis et al. (2023a), Sec. III.B, Eq. 13-24).

Core functions plus the ephemeris call. The predicted line of sight uses first-order light-time
(``r_p(t - tau) ~ r_p(t) - v_p tau`` with ``tau = |r_p(t) - r| / c``) and first-order aberration
(``u' = u + beta - (u . beta) u``, normalised), the models of the pipeline (the renderer's exact
ones are the truth).

Covariance: ``P = F S F^T`` (Eq. 13) with ``F`` the 2 x 10 Jacobian of the projection with respect
to ``(q0, qv, r, r_bc)`` (Eq. 15-20; quaternion scalar first, ``A`` of Eq. 14), and
``S = diag(sigma_q0^2, sigma_qv^2 I, sigma_r^2 I, sigma_rbc^2 I)`` (Eq. 22) in paper mode; the
improved mode puts the full position covariance and the attitude covariance in ``S``. The 3-sigma
ellipse is ``d^T P^-1 d <= 11.8292`` (Eq. 23, chi-square 2 dof at 0.9973).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skynav.scenes.constants import C_KM_S
from skynav.scenes.ephemeris_jpl import default_ephemeris
from skynav.scenes.frames import dcm_to_quat, quat_to_dcm, skew
from skynav.scenes.photometry import phase_angle_rad, planet_v_mag

__all__ = ["BeaconPrediction", "BodyStates", "project_beacon", "projection_jacobian", "predict_beacons",
           "apparent_direction", "max_eig_2x2", "CHI2_2DOF_3SIGMA", "BEACON_BODIES"]

CHI2_2DOF_3SIGMA = 11.8292  # chi-square, 2 degrees of freedom, P = 0.9973 (Eq. 23)
BEACON_BODIES = ("mercury", "venus", "earth", "moon", "mars", "jupiter", "saturn", "uranus", "neptune")
_STATE_BODIES = ("sun",) + BEACON_BODIES
# improved mode: centroid and first-order model error floor added to every predicted covariance
FLOOR_PX2 = np.eye(2) * 0.25**2


@dataclass(frozen=True, kw_only=True, eq=False)
class BeaconPrediction:
    """One beacon predicted in (or near) the field.

    ``xy_px`` (2,) pixel position; ``cov_px2`` (2, 2) its covariance (Eq. 13); ``v_mag`` the
    predicted V magnitude (NaN outside the magnitude law's phase range); ``distance_km`` from the
    observer; ``attitude_jacobian_px_rad`` (2, 3) d(pixel)/d(small camera-frame rotation), None in
    paper mode.
    """

    name: str
    xy_px: np.ndarray
    cov_px2: np.ndarray
    v_mag: float
    distance_km: float
    attitude_jacobian_px_rad: np.ndarray | None = None


def project_beacon(q, r_km, r_bc_km, K) -> np.ndarray:
    """Pixel position (2,) of the beacon at ``r_bc_km`` seen from ``r_km`` (Eq. 4-5, pinhole)."""
    v = quat_to_dcm(q) @ (np.asarray(r_bc_km, float) - np.asarray(r_km, float))
    return np.array([K[0][0] * v[0] / v[2] + K[0][2], K[1][1] * v[1] / v[2] + K[1][2]])


def projection_jacobian(q, r_km, r_bc_km, K) -> np.ndarray:
    """``F`` (2, 10) of Eq. 16-20: d(pixel) / d(q0, qv, r, r_bc)."""
    q0, qv = float(q[0]), np.asarray(q[1:], dtype=float)
    rho = np.asarray(r_bc_km, float) - np.asarray(r_km, float)
    A = quat_to_dcm(q)
    v = A @ rho
    fx, fy = K[0][0], K[1][1]
    dproj = np.array([[fx / v[2], 0.0, -fx * v[0] / v[2] ** 2], [0.0, fy / v[2], -fy * v[1] / v[2] ** 2]])
    d_q0 = 2.0 * q0 * rho - 2.0 * (skew(qv) @ rho)  # Eq. 17
    d_qv = -2.0 * np.outer(rho, qv) + 2.0 * (qv @ rho) * np.eye(3) + 2.0 * np.outer(qv, rho) + 2.0 * q0 * skew(rho)  # Eq. 18
    d_r = -A  # Eq. 19
    d_rbc = A  # Eq. 20
    return dproj @ np.hstack([d_q0[:, None], d_qv, d_r, d_rbc])


def apparent_direction(r_km, v_km_s, body_pos_km, body_vel_km_s):
    """First-order light-time and aberration: ``(u, p, |p - r|)``, the apparent unit vector (3,)
    in ICRS, the retarded body position (3,) and its distance from the observer (km)."""
    r_km = np.asarray(r_km, float)
    rho = body_pos_km - r_km
    tau = math.sqrt(rho.dot(rho)) / C_KM_S  # light-time, s
    p = body_pos_km - body_vel_km_s * tau
    d = p - r_km
    dist = math.sqrt(d.dot(d))
    u = d / dist
    beta = np.asarray(v_km_s, float) / C_KM_S
    u2 = u + beta - (u @ beta) * u  # stellar aberration, first order in v / c
    return u2 / math.sqrt(u2.dot(u2)), p, dist


def max_eig_2x2(P) -> float:
    """Largest eigenvalue of a symmetric 2 x 2 matrix (the last of :func:`numpy.linalg.eigvalsh`,
    which reads the lower triangle): ``(a + c) / 2 + hypot((a - c) / 2, b)``."""
    a, c, b = float(P[0, 0]), float(P[1, 1]), float(P[1, 0])
    return 0.5 * (a + c) + math.hypot(0.5 * (a - c), b)


class BodyStates:
    """The ephemeris's body states at one epoch, computed once and owned by the caller.

    Tracking predicts the beacons twice per frame (windows from the previous attitude, then the
    identification) and the states do not change within a frame: :func:`process_frame` makes one
    object per frame and passes it to both. An ephemeris with ``epoch_states`` (skynav's DE421
    adapter) gives every body's position in one vectorised evaluation and each velocity when
    asked (only the bodies near the field need one); one with ``states_at`` every body's state in
    one call; any other object with ``position`` / ``position_velocity`` is asked body by body.
    """

    def __init__(self, ephemeris, epoch_tdb_s: float):
        self.ephemeris, self.epoch = ephemeris, float(epoch_tdb_s)
        self._pv, self._st = {}, None
        if hasattr(ephemeris, "epoch_states"):
            self._st = ephemeris.epoch_states(self.epoch, _STATE_BODIES)
        elif hasattr(ephemeris, "states_at"):
            self._pv = {k: (np.asarray(r), np.asarray(v)) for k, (r, v) in
                        ephemeris.states_at(self.epoch, _STATE_BODIES).items()}

    def position(self, name) -> np.ndarray:
        if self._st is not None and name in self._st.bodies:
            return self._st.position(name)
        return self.position_velocity(name)[0]

    def positions(self, names) -> np.ndarray:
        """Positions (n, 3) of several bodies (one array)."""
        if self._st is not None and tuple(names) == BEACON_BODIES:
            return self._st.positions[1:]  # _STATE_BODIES[1:]
        return np.array([self.position(n) for n in names]).reshape(-1, 3)

    def position_velocity(self, name):
        if name not in self._pv:
            if self._st is not None and name in self._st.bodies:
                self._pv[name] = (self._st.position(name), self._st.velocity(name))
            else:
                p, v = self.ephemeris.position_velocity(name, self.epoch)
                self._pv[name] = (np.array(p), np.array(v))
        return self._pv[name]


def predict_beacons(epoch_tdb_s, predicted_state, R_cam_icrs, camera, *, attitude_cov_rad2=None,
                    mode="improved", sigma_qv=1e-4, sigma_rbc_km=0.0, bodies=BEACON_BODIES, ephemeris=None,
                    body_states=None, margin_px=0.0):
    """Predicted pixel position, covariance and V magnitude of every beacon in (or near) the field.

    ``body_states``: a :class:`BodyStates` at ``epoch_tdb_s`` to reuse (else one is made from
    ``ephemeris``, default DE421). Returns a list of :class:`BeaconPrediction`.
    """
    if body_states is None or body_states.epoch != float(epoch_tdb_s):
        body_states = BodyStates(default_ephemeris() if ephemeris is None else ephemeris, epoch_tdb_s)
    eph = body_states
    r = np.asarray(predicted_state.position_km, float)
    v = np.asarray(predicted_state.velocity_km_s, float)
    Pr = np.asarray(predicted_state.position_cov_km2, float)
    A = np.asarray(R_cam_icrs, float)
    K = camera.K if mode == "paper" else None
    fx, fy = float(camera.fx_px), float(camera.fy_px)
    out = []
    boresight = A[2]
    sig_r = math.sqrt(max(float(np.trace(Pr)), 0.0))
    # cheap rejection first, all bodies at once: the geometric direction far outside the field
    # (plus 3 sigma of the position error seen from the body's distance, plus light-time and
    # aberration slack); a body kept here is decided by the exact tests below
    bodies = tuple(bodies)
    rho_all = eph.positions(bodies) - r
    dist0 = np.sqrt(np.einsum("ij,ij->i", rho_all, rho_all))
    slack = 3.0 * sig_r / dist0 + 1e-3
    near = ~(rho_all @ boresight < dist0 * np.cos(np.minimum(camera.half_diagonal_fov_rad + slack, np.pi)))
    kept = []
    for name in (b for b, ok in zip(bodies, near.tolist()) if ok):
        pos, vel = eph.position_velocity(name)
        u, p, dist = apparent_direction(r, v, pos, vel)
        vc = A @ u
        if vc[2] <= 0:
            continue
        xy = camera.project(vc[None])[0]
        if not np.all(np.isfinite(xy)) or not camera.in_image(xy, max(margin_px, camera.width)):
            continue
        kept.append((name, u, p, dist, xy))
    if not kept:
        return out
    sun = eph.position("sun")
    q = dcm_to_quat(A) if mode == "paper" else None
    for name, u, p, dist, xy in kept:
        alpha = float(phase_angle_rad(p, sun, r))
        # Jacobian at the apparent point: the body along u at its distance
        rel = u * dist
        if mode == "paper":
            F = projection_jacobian(q, r, r + rel, K)
            sr2 = float(np.trace(Pr) / 3.0)
            S = np.diag([0.0] + [sigma_qv**2] * 3 + [sr2] * 3 + [sigma_rbc_km**2] * 3)  # Eq. 22
            P = F @ S @ F.T
            Fa = None
        else:
            # position: F[:, 4:7] of Eq. 19, d(pixel)/d(r) = -dproj A (A from Wahba's SVD: a
            # rotation to rounding, the A(q) of Eq. 14 of its own quaternion); full covariance
            c = A @ rel
            dproj = np.array([[fx / c[2], 0.0, -fx * c[0] / c[2] ** 2], [0.0, fy / c[2], -fy * c[1] / c[2] ** 2]])
            Fr = dproj @ -A
            P = Fr @ Pr @ Fr.T
            # attitude: small rotation phi (camera frame) -> pixel;
            # A' = (I - [phi x]) A gives d v_cam = -phi x v_cam = [v_cam x] phi
            Fa = dproj @ skew(c)
            if attitude_cov_rad2 is not None:
                P = P + Fa @ attitude_cov_rad2 @ Fa.T
            P = P + FLOOR_PX2
        try:
            # Mallama & Hilton (2018) through scenes.photometry (NaN outside a law's phase range)
            vm = float(planet_v_mag(name, float(np.linalg.norm(p - sun)), dist, alpha))
        except Exception:  # noqa: BLE001 - no magnitude law for this body: no brightness prior
            vm = float("nan")
        # in the field, or its 3-sigma ellipse reaches into it (Eq. 23 semi-major axis)
        reach = math.sqrt(CHI2_2DOF_3SIGMA * max(max_eig_2x2(P), 0.0))
        if not camera.in_image(xy, margin_px + (reach if mode == "improved" else 0.0)):
            continue
        out.append(BeaconPrediction(name=name, xy_px=xy, cov_px2=P, v_mag=vm, distance_km=dist,
                                    attitude_jacobian_px_rad=Fa))
    return out


def select_spot(pred, spots_xy, candidate_mask, *, mode, spot_mag=None, mag_sigma=1.0):
    """Index of the spot identified as the beacon, or None (Eq. 23-24).

    paper: the closest candidate spot inside the 3-sigma ellipse. improved: the candidate inside
    the ellipse minimising Mahalanobis^2 + ((m_spot - m_pred) / mag_sigma)^2.
    """
    if len(spots_xy) == 0:
        return None
    d = spots_xy - pred.xy_px[None]
    try:
        Pinv = np.linalg.inv(pred.cov_px2)
    except np.linalg.LinAlgError:
        return None
    m2 = np.einsum("ni,ij,nj->n", d, Pinv, d)
    inside = candidate_mask & (m2 <= CHI2_2DOF_3SIGMA)
    if not inside.any():
        return None
    idx = np.flatnonzero(inside)
    if mode == "paper" or spot_mag is None or not np.isfinite(pred.v_mag):
        cost = np.hypot(d[idx, 0], d[idx, 1])
    else:
        dm = spot_mag[idx] - pred.v_mag
        dm = np.where(np.isfinite(dm), dm, 0.0)
        cost = m2[idx] + (dm / mag_sigma) ** 2
    return int(idx[np.argmin(cost)])
