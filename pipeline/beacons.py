"""Beacon (planet) prediction and identification (paper 000 section III.B, Eq. 13-24).

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

import numpy as np

__all__ = ["dcm_from_quat", "quat_from_dcm", "project_beacon", "projection_jacobian", "predict_beacons",
           "CHI2_2DOF_3SIGMA", "BEACON_BODIES"]

CHI2_2DOF_3SIGMA = 11.8292
from skynav.scenes.constants import AU_KM as _AU_KM, C_KM_S  # noqa: E402
from skynav.scenes.photometry import PHASE_RANGE_DEG as _PHASE_RANGE_DEG  # noqa: E402
BEACON_BODIES = ("mercury", "venus", "earth", "moon", "mars", "jupiter", "saturn", "uranus", "neptune")
_LAW_BODIES = frozenset(BEACON_BODIES)
_STATE_BODIES = ("sun",) + BEACON_BODIES
_MOON_V10 = float(-12.73 - 5.0 * np.log10(384400.0 / _AU_KM))  # photometry._moon's v10 (numpy's log10)


def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def dcm_from_quat(q) -> np.ndarray:
    """Paper 000 Eq. 14, scalar first: ``A = (q0^2 - qv.qv) I + 2 qv qv^T - 2 q0 [qv x]``."""
    q0, qv = float(q[0]), np.asarray(q[1:], dtype=float)
    return (q0 * q0 - qv @ qv) * np.eye(3) + 2.0 * np.outer(qv, qv) - 2.0 * q0 * _skew(qv)


def quat_from_dcm(A) -> np.ndarray:
    """Scalar-first quaternion of Eq. 14 (q0 >= 0), inverse of :func:`dcm_from_quat`."""
    A = np.asarray(A, dtype=float)
    tr = np.trace(A)
    cands = np.array([1 + tr, 1 + 2 * A[0, 0] - tr, 1 + 2 * A[1, 1] - tr, 1 + 2 * A[2, 2] - tr])
    k = int(np.argmax(cands))
    q = np.empty(4)
    if k == 0:
        q[0] = 0.5 * np.sqrt(cands[0])
        q[1] = (A[1, 2] - A[2, 1]) / (4 * q[0])
        q[2] = (A[2, 0] - A[0, 2]) / (4 * q[0])
        q[3] = (A[0, 1] - A[1, 0]) / (4 * q[0])
    else:
        i = k - 1
        j, l = (i + 1) % 3, (i + 2) % 3
        q[1 + i] = 0.5 * np.sqrt(cands[k])
        q[0] = (A[j, l] - A[l, j]) / (4 * q[1 + i])
        q[1 + j] = (A[i, j] + A[j, i]) / (4 * q[1 + i])
        q[1 + l] = (A[i, l] + A[l, i]) / (4 * q[1 + i])
    return q if q[0] >= 0 else -q


def project_beacon(q, r_km, r_bc_km, K) -> np.ndarray:
    """Pixel position (2,) of the beacon at ``r_bc_km`` seen from ``r_km`` (Eq. 4-5, pinhole)."""
    v = dcm_from_quat(q) @ (np.asarray(r_bc_km, float) - np.asarray(r_km, float))
    return np.array([K[0][0] * v[0] / v[2] + K[0][2], K[1][1] * v[1] / v[2] + K[1][2]])


def projection_jacobian(q, r_km, r_bc_km, K) -> np.ndarray:
    """``F`` (2, 10) of Eq. 16-20: d(pixel) / d(q0, qv, r, r_bc)."""
    q0, qv = float(q[0]), np.asarray(q[1:], dtype=float)
    rho = np.asarray(r_bc_km, float) - np.asarray(r_km, float)
    A = dcm_from_quat(q)
    v = A @ rho
    fx, fy = K[0][0], K[1][1]
    dproj = np.array([[fx / v[2], 0.0, -fx * v[0] / v[2] ** 2], [0.0, fy / v[2], -fy * v[1] / v[2] ** 2]])
    d_q0 = 2.0 * q0 * rho - 2.0 * (_skew(qv) @ rho)  # Eq. 17
    d_qv = -2.0 * np.outer(rho, qv) + 2.0 * (qv @ rho) * np.eye(3) + 2.0 * np.outer(qv, rho) + 2.0 * q0 * _skew(rho)  # Eq. 18
    d_r = -A  # Eq. 19
    d_rbc = A  # Eq. 20
    return dproj @ np.hstack([d_q0[:, None], d_qv, d_r, d_rbc])


def apparent_direction(r_km, v_km_s, body_pos_km, body_vel_km_s):
    """First-order light-time and aberration: apparent unit vector (3,), ICRS, and the retarded
    body position used (3,). (Norms as :func:`numpy.linalg.norm` computes a vector's: the
    square root of its dot product with itself.)"""
    rho = body_pos_km - r_km
    tau = math.sqrt(rho.dot(rho)) / C_KM_S
    p = body_pos_km - body_vel_km_s * tau
    d = p - r_km
    u = d / math.sqrt(d.dot(d))
    beta = np.asarray(v_km_s, float) / C_KM_S
    u2 = u + beta - (u @ beta) * u
    return u2 / math.sqrt(u2.dot(u2)), p


def predict_beacons(epoch_tdb_s, predicted_state, R_cam_icrs, camera, *, attitude_cov_rad2=None,
                    mode="improved", sigma_qv=1e-4, sigma_rbc_km=0.0, bodies=BEACON_BODIES, ephemeris=None,
                    margin_px=0.0):
    """Predicted pixel position, covariance and V magnitude of every beacon in (or near) the field.

    Returns a list of dicts ``name, xy_px (2,), cov_px2 (2, 2), v_mag, distance_km``.
    """
    if ephemeris is None:
        from skynav.scenes.ephemeris_jpl import default_ephemeris

        ephemeris = default_ephemeris()
    eph = _CachedEphemeris.wrap(ephemeris, epoch_tdb_s)
    r = np.asarray(predicted_state.position_km, float)
    v = np.asarray(predicted_state.velocity_km_s, float)
    Pr = np.asarray(predicted_state.position_cov_km2, float)
    A = np.asarray(R_cam_icrs, float)
    K = camera.K if mode == "paper" else None
    fx, fy, cos_reach = _camera_constants(camera)  # K[0, 0], K[1, 1], half_diagonal_fov_rad
    out = []
    boresight = A[2]
    (p00, _, _), (_, p11, _), (_, _, p22) = Pr.tolist()
    sig_r = math.sqrt(max(p00 + p11 + p22, 0.0))  # numpy.trace's sum (in order), its square root
    # cheap rejection first, all bodies at once: the geometric direction far outside the field
    # (plus 3 sigma of the position error seen from the body's distance, plus light-time and
    # aberration slack); a body kept here is decided by the exact tests below
    bodies = tuple(bodies)
    pos_all = eph.positions(bodies, epoch_tdb_s)
    rho_all = pos_all - r
    dist0 = np.sqrt(np.einsum("ij,ij->i", rho_all, rho_all))
    slack = 3.0 * sig_r / dist0 + 1e-3
    near = ~(rho_all @ boresight < dist0 * np.cos(np.minimum(cos_reach + slack, np.pi)))
    kept = []
    rl, vl = r.tolist(), v.tolist()
    for name in (b for b, ok in zip(bodies, near.tolist()) if ok):
        pos, vel = eph.position_velocity(name, epoch_tdb_s)
        ul, pl, dist = _apparent_one(rl, vl, pos.tolist(), vel.tolist())
        u = np.array(ul)
        vc = A @ u
        if vc[2] <= 0:
            continue
        xy = _project_one(camera, vc)
        if not (math.isfinite(xy[0]) and math.isfinite(xy[1])) or not _in_image(camera, xy, max(margin_px, camera.width)):
            continue
        kept.append((name, u, ul, pl, dist, xy))
    if not kept:
        return out
    sun = eph.position("sun", epoch_tdb_s).tolist()
    q = quat_from_dcm(A) if mode == "paper" else None
    A_q = dcm_from_quat(q) if mode == "paper" else _dcm_of_dcm(A)  # the Jacobian's attitude (Eq. 14 of q)
    minus_A_q = -A_q
    for name, u, ul, pl, dist, xy in kept:
        alpha = _phase_angle_one(pl, sun, rl)
        # Jacobian at the apparent point: put the body along u at its distance (dist: |p - r|,
        # numpy.linalg.norm's operations)
        rel = np.array([(rk + uk * dist) - rk for rk, uk in zip(rl, ul)])  # pb - r, pb = r + u dist
        if mode == "paper":
            pb = r + u * dist
            F = projection_jacobian(q, r, pb, K)
            sr2 = float(np.trace(Pr) / 3.0)
            S = np.diag([0.0] + [sigma_qv**2] * 3 + [sr2] * 3 + [sigma_rbc_km**2] * 3)
            P = F @ S @ F.T
        else:
            # position: F[:, 4:7] of Eq. 19, d(pixel)/d(r) = -dproj A(q); full covariance
            w0, w1, w2 = (A_q @ rel).tolist()
            Fr = np.array([[fx / w2, 0.0, -fx * w0 / w2 ** 2], [0.0, fy / w2, -fy * w1 / w2 ** 2]]) @ minus_A_q
            P = Fr @ Pr @ Fr.T
            # attitude: small rotation phi (camera frame) -> pixel
            # d(pixel)/d(phi) for A' = (I - [phi x]) A: d v_cam = -phi x v_cam = [v_cam x] phi
            c0, c1, c2 = (A @ rel).tolist()
            dproj = np.array([[fx / c2, 0.0, -fx * c0 / c2 ** 2], [0.0, fy / c2, -fy * c1 / c2 ** 2]])
            Fa = dproj @ np.array([[0.0, -c2, c1], [c2, 0.0, -c0], [-c1, c0, 0.0]])  # dproj [v_cam x]
            if attitude_cov_rad2 is not None:
                P = P + Fa @ attitude_cov_rad2 @ Fa.T
            P = P + _FLOOR_PX2  # centroid and first-order model error floor, px^2
        try:
            d0, d1, d2 = pl[0] - sun[0], pl[1] - sun[1], pl[2] - sun[2]
            vm = _v_mag(name, math.sqrt(d0 * d0 + d1 * d1 + d2 * d2), dist, alpha)
        except Exception:  # noqa: BLE001 - a magnitude law outside its range: no brightness prior
            vm = float("nan")
        # in the field, or its 3-sigma ellipse reaches into it (Eq. 23 semi-major axis)
        reach = math.sqrt(CHI2_2DOF_3SIGMA * max(_max_eig_2x2(P), 0.0))
        if not _in_image(camera, xy, margin_px + (reach if mode == "improved" else 0.0)):
            continue
        out.append({"name": name, "xy_px": xy, "cov_px2": P, "v_mag": vm, "distance_km": dist,
                    "attitude_jacobian_px_rad": Fa if mode != "paper" else None})
    return out


_LAST_CAMERA = [None]


def _camera_constants(camera):
    """``(fx_px, fy_px, half_diagonal_fov_rad)`` of a camera, as floats; kept for the last
    camera object (a frozen dataclass: the same object, the same values; one tuple swapped in
    whole, so threads never see one camera's object with another's values), so that tracking
    frames of one camera do not recompute the field's half-diagonal (atan, hypot) every time."""
    hit = _LAST_CAMERA[0]
    if hit is None or hit[0] is not camera:
        hit = (camera, (float(camera.fx_px), float(camera.fy_px), float(camera.half_diagonal_fov_rad)))
        _LAST_CAMERA[0] = hit
    return hit[1]


def _apparent_one(r, v, pos, vel):
    """:func:`apparent_direction` on lists of 3 Python floats: ``(u, p, |p - r|)`` as lists and a
    float, the same element-wise operations in the same order (the dot products as numpy's
    for 3-vectors, ``(x0 y0 + x1 y1) + x2 y2``). Tested against it within 4 ulps
    (tests/pipeline/test_beacon_scalar_helpers.py), not for identical bits."""
    r0, r1, r2 = r
    a0, a1, a2 = pos[0] - r0, pos[1] - r1, pos[2] - r2
    tau = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2) / C_KM_S
    p = [pos[0] - vel[0] * tau, pos[1] - vel[1] * tau, pos[2] - vel[2] * tau]
    d0, d1, d2 = p[0] - r0, p[1] - r1, p[2] - r2
    nd = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    u0, u1, u2 = d0 / nd, d1 / nd, d2 / nd
    b0, b1, b2 = v[0] / C_KM_S, v[1] / C_KM_S, v[2] / C_KM_S
    ub = u0 * b0 + u1 * b1 + u2 * b2
    e0, e1, e2 = (u0 + b0) - ub * u0, (u1 + b1) - ub * u1, (u2 + b2) - ub * u2
    ne = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    return [e0 / ne, e1 / ne, e2 / ne], p, nd


def _phase_angle_one(p, sun, r) -> float:
    """:func:`_phase_angles` of one body, lists of 3 Python floats in (the same operations;
    ``math.atan2`` and ``math.sqrt`` are libm's; numpy's ``arctan2`` may take a SIMD loop that
    differs from libm's in the last bit, so the two agree within a few ulps, as tested)."""
    a0, a1, a2 = sun[0] - p[0], sun[1] - p[1], sun[2] - p[2]
    b0, b1, b2 = r[0] - p[0], r[1] - p[1], r[2] - p[2]
    c0 = a1 * b2 - a2 * b1
    c1 = a2 * b0 - a0 * b2
    c2 = a0 * b1 - a1 * b0
    return math.atan2(math.sqrt(c0 * c0 + c1 * c1 + c2 * c2), a0 * b0 + a1 * b1 + a2 * b2)


_FLOOR_PX2 = np.eye(2) * 0.25**2


def _project_one(camera, v):
    """``camera.project(v[None])[0]`` for one camera-frame vector (3,): the pinhole arithmetic of
    :meth:`~skynav.scenes.camera.Camera.project` without its array overhead when the lens has
    no distortion (the same operations in the same order), else ``camera.project`` itself."""
    if not camera.distortion.is_identity:
        return camera.project(v[None])[0]
    z = float(v[2])
    if not z > 0:
        return np.array([np.nan, np.nan])
    return np.array([camera.fx_px * (float(v[0]) / z) + camera.cx, camera.fy_px * (float(v[1]) / z) + camera.cy])


def _in_image(camera, xy, margin_px) -> bool:
    """``camera.in_image(xy[None], margin_px)[0]`` for one point, in Python floats."""
    x, y = float(xy[0]), float(xy[1])
    return (x >= -0.5 - margin_px) and (x < camera.width - 0.5 + margin_px) and (y >= -0.5 - margin_px) \
        and (y < camera.height - 0.5 + margin_px)


def _dcm_of_dcm(A) -> np.ndarray:
    """``dcm_from_quat(quat_from_dcm(A))`` (Eq. 14 of A's quaternion: A re-orthogonalised to
    rounding) in Python floats, for the improved mode's Jacobian: the same formulas, without
    numpy's per-call overhead on 3 x 3 and 4-vectors (tested within 4 ulps of 1, element-wise)."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = np.asarray(A, dtype=float).tolist()
    tr = a00 + a11 + a22
    cands = (1 + tr, 1 + 2 * a00 - tr, 1 + 2 * a11 - tr, 1 + 2 * a22 - tr)
    k = max(range(4), key=cands.__getitem__)
    M = ((a00, a01, a02), (a10, a11, a12), (a20, a21, a22))
    q = [0.0, 0.0, 0.0, 0.0]
    if k == 0:
        q[0] = 0.5 * math.sqrt(cands[0])
        q[1] = (a12 - a21) / (4 * q[0])
        q[2] = (a20 - a02) / (4 * q[0])
        q[3] = (a01 - a10) / (4 * q[0])
    else:
        i = k - 1
        j, l = (i + 1) % 3, (i + 2) % 3
        q[1 + i] = 0.5 * math.sqrt(cands[k])
        q[0] = (M[j][l] - M[l][j]) / (4 * q[1 + i])
        q[1 + j] = (M[i][j] + M[j][i]) / (4 * q[1 + i])
        q[1 + l] = (M[i][l] + M[l][i]) / (4 * q[1 + i])
    if not q[0] >= 0:
        q = [-x for x in q]
    q0, q1, q2, q3 = q
    s = q0 * q0 - (q1 * q1 + q2 * q2 + q3 * q3)
    t = 2.0 * q0
    return np.array([[s + 2.0 * (q1 * q1), 2.0 * (q1 * q2) - t * -q3, 2.0 * (q1 * q3) - t * q2],
                     [2.0 * (q2 * q1) - t * q3, s + 2.0 * (q2 * q2), 2.0 * (q2 * q3) - t * -q1],
                     [2.0 * (q3 * q1) - t * -q2, 2.0 * (q3 * q2) - t * q1, s + 2.0 * (q3 * q3)]])


def _phase_angles(p, sun, r):
    """Sun-body-observer angles (n,) of the bodies at ``p`` (n, 3):
    :func:`skynav.scenes.photometry.phase_angle_rad` with the cross product written out (the
    same products and differences as :func:`numpy.cross`, the same sums as its norm and dot)."""
    a = np.asarray(sun, float)[None] - p
    b = np.asarray(r, float)[None] - p
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
    c0 = a1 * b2 - a2 * b1
    c1 = a2 * b0 - a0 * b2
    c2 = a0 * b1 - a1 * b0
    return np.arctan2(np.sqrt(c0 * c0 + c1 * c1 + c2 * c2), a0 * b0 + a1 * b1 + a2 * b2)


def _log10(x: float) -> float:
    """:func:`numpy.log10` of one float under ``errstate(divide/invalid="ignore")``: ``-inf`` at
    0, NaN below 0 and at NaN (libm's log10 above 0; numpy's float64 loop is libm's on some CPUs
    and a SIMD loop that may differ in the last bit on others, e.g. AVX-512)."""
    if x > 0.0:
        return math.log10(x)
    return -math.inf if x == 0.0 else math.nan


def _horner(a: float, coeffs) -> float:
    """:func:`skynav.scenes.photometry._poly` for one float (from 0.0: the same products and sums)."""
    out = 0.0
    for c in reversed(coeffs):
        out = out * a + c
    return out


def _phase_law(key: str, a: float) -> float:
    """The phase law ``V(1, alpha)`` of :func:`skynav.scenes.photometry.planet_v_mag` with its
    default options (no Saturn ring tilt, Uranus sub-latitude 0, Neptune after 2000) at one
    phase angle ``a`` (deg): the branch its ``numpy.where`` keeps, in Python floats (the same
    IEEE operations in the same order; its ``log10`` is libm's, see :func:`_log10`)."""
    if key == "mercury":
        return _horner(a, (-0.613, 6.3280e-02, -1.6336e-03, 3.3644e-05, -3.4265e-07, 1.6893e-09, -3.0334e-12))
    if key == "venus":
        if a <= 163.7:
            return _horner(a, (-4.384, -1.044e-03, 3.687e-04, -2.814e-06, 8.938e-09))
        return _horner(a, (236.05828, -2.81914, 8.39034e-03))
    if key == "earth":
        return _horner(a, (-3.99, -1.060e-03, 2.054e-04))
    if key == "mars":
        if a <= 50.0:
            return _horner(a, (-1.601, 2.267e-02, -1.302e-04))
        return _horner(a, (-0.367, -0.02573, 3.445e-04))
    if key == "jupiter":
        if a <= 12.0:
            return _horner(a, (-9.395, -3.7e-04, 6.16e-04))
        return -9.428 - 2.5 * _log10(_horner(a / 180.0, (1.0, -1.507, -0.363, -0.062, 2.809, -1.876)))
    if key == "saturn":
        if a <= 6.0:
            return _horner(a, (-8.95, -3.7e-04, 6.16e-04))
        return _horner(a, (-8.94, 2.446e-04, 2.672e-04, -1.505e-06, 4.767e-09))
    if key == "uranus":
        return (-7.110 - 8.4e-04 * 0.0) + (_horner(a, (0.0, 6.587e-03, 1.045e-04)) if a > 3.1 else 0.0)
    if key == "neptune":
        return -7.00 + (_horner(a, (0.0, 7.944e-03, 9.617e-05)) if a > 1.9 else 0.0)
    return (_MOON_V10 + 0.026 * a) + 4e-9 * a**4  # moon


def _v_mag(name: str, sun_distance_km: float, observer_distance_km: float, phase_angle_rad: float) -> float:
    """``float(planet_v_mag(name, r, delta, alpha))`` for one body, in Python floats: the same
    operations in the same order without numpy's per-call overhead (~50 us there, ~2 us here;
    :func:`math.degrees` is numpy's ``rad2deg``, ``x * (180 / pi)``). Bodies outside
    :data:`BEACON_BODIES` go to ``planet_v_mag`` itself. Not bit-for-bit on every CPU (libm's
    ``log10`` against numpy's SIMD one): tests/pipeline/test_beacon_scalar_helpers.py holds the
    two within a few ulps of each ``log10`` (~1e-13 mag), NaN where the reference is NaN."""
    key = name.lower() if isinstance(name, str) else name
    if key not in _LAW_BODIES:
        from skynav.scenes.photometry import planet_v_mag

        return float(planet_v_mag(name, sun_distance_km, observer_distance_km, phase_angle_rad))
    r_au = float(sun_distance_km) / _AU_KM
    d_au = float(observer_distance_km) / _AU_KM
    a = math.degrees(float(phase_angle_rad))
    lo, hi = _PHASE_RANGE_DEG[key]
    law = _phase_law(key, a) if (a >= lo and a <= hi) else math.nan
    return 5.0 * _log10(r_au * d_au) + law


def _max_eig_2x2(P) -> float:
    """Largest eigenvalue of a symmetric 2 x 2 matrix (:func:`numpy.linalg.eigvalsh`'s last, which
    reads the lower triangle): ``(a + c) / 2 + hypot((a - c) / 2, b)``, within a few ulp of
    LAPACK's (tested against it)."""
    a, c, b = float(P[0, 0]), float(P[1, 1]), float(P[1, 0])
    return 0.5 * (a + c) + math.hypot(0.5 * (a - c), b)


class _CachedEphemeris:
    """Body states at one epoch, computed once: tracking predicts the beacons twice per frame
    (windows from the previous attitude, then the identification), and the states do not change
    within a frame. An ephemeris with ``epoch_states`` (skynav's DE421 adapter) gives every
    body's position in one vectorised evaluation and each velocity when asked (only the bodies
    near the field need one); one with ``states_at`` every body's state in one call; any other
    object with ``position`` / ``position_velocity`` is asked body by body. The last epoch of
    the last ephemeris object is kept (module level; the default ephemeris is one object per
    process)."""

    _last = None

    def __init__(self, eph, epoch):
        self.eph, self.epoch, self._pv, self._st = eph, float(epoch), {}, None
        if hasattr(eph, "epoch_states"):
            self._st = eph.epoch_states(self.epoch, _STATE_BODIES)
        elif hasattr(eph, "states_at"):
            self._pv = {k: (np.asarray(r), np.asarray(v)) for k, (r, v) in
                        eph.states_at(self.epoch, _STATE_BODIES).items()}

    @classmethod
    def wrap(cls, eph, epoch):
        last = cls._last
        if last is None or last.eph is not eph or last.epoch != float(epoch):
            last = cls._last = cls(eph, epoch)
        return last

    def position(self, name, t):
        if self._st is not None and float(t) == self.epoch and name in self._st._col:
            return self._st.position(name)
        return self.position_velocity(name, t)[0]

    def positions(self, names, t):
        """Positions (n, 3) of several bodies at ``t`` (one array; cached per tuple of names)."""
        if self._st is not None and names == BEACON_BODIES and float(t) == self.epoch:
            return self._st.positions[1:]  # _STATE_BODIES[1:]
        key = ("__stack__", names)
        if float(t) == self.epoch and key in self._pv:
            return self._pv[key]
        out = np.array([self.position(n, t) for n in names]).reshape(-1, 3)
        if float(t) == self.epoch:
            self._pv[key] = out
        return out

    def position_velocity(self, name, t):
        if float(t) != self.epoch:
            return self.eph.position_velocity(name, t)
        if name not in self._pv:
            if self._st is not None and name in self._st._col:
                self._pv[name] = (self._st.position(name), self._st.velocity(name))
            else:
                p, v = self.eph.position_velocity(name, t)
                self._pv[name] = (np.array(p), np.array(v))
        return self._pv[name]


def select_spot(pred, spots_xy, candidate_mask, *, mode, spot_mag=None, mag_sigma=1.0):
    """Index of the spot identified as the beacon, or None (Eq. 23-24).

    paper: the closest candidate spot inside the 3-sigma ellipse. improved: the candidate inside
    the ellipse minimising Mahalanobis^2 + ((m_spot - m_pred) / mag_sigma)^2.
    """
    if len(spots_xy) == 0:
        return None
    d = spots_xy - pred["xy_px"][None]
    try:
        Pinv = np.linalg.inv(pred["cov_px2"])
    except np.linalg.LinAlgError:
        return None
    m2 = np.einsum("ni,ij,nj->n", d, Pinv, d)
    inside = candidate_mask & (m2 <= CHI2_2DOF_3SIGMA)
    if not inside.any():
        return None
    idx = np.flatnonzero(inside)
    if mode == "paper" or spot_mag is None or not np.isfinite(pred["v_mag"]):
        cost = np.hypot(d[idx, 0], d[idx, 1])
    else:
        dm = spot_mag[idx] - pred["v_mag"]
        dm = np.where(np.isfinite(dm), dm, 0.0)
        cost = m2[idx] + (dm / mag_sigma) ** 2
    return int(idx[np.argmin(cost)])
