"""Frames, rotations and attitude: the glossary and the converters.

Glossary (docs/conventions.md)
-------------------------
ICRS
    Inertial frame, origin at the solar-system barycentre. ``position_km`` and ``velocity_km_s``
    are barycentric ICRS unless the name says otherwise (``sun_to_sc_km``).
camera frame
    +z along the boresight, +x along image columns (right), +y along image rows (down).
``R_cam_icrs``
    Passive attitude matrix, ``v_cam = R_cam_icrs @ v_icrs``; shape (3, 3) or (N, 3, 3).
quaternion
    Scalar first ``(q0, q1, q2, q3)``, attitude matrix of Andreis et al. (2023a), Eq. 14:
    ``A = (q0^2 - qv.qv) I + 2 qv qv^T - 2 q0 [qv x]``. ``q`` and ``-q`` are the same attitude;
    :func:`dcm_to_quat` returns ``q0 >= 0``.
RA / Dec / twist
    ``R_cam_icrs = R3(twist) R2(pi/2 - dec) R3(ra)`` with passive elementary rotations, so the
    boresight points at (ra, dec). Sign of twist: the camera axes (rows of ``R_cam_icrs``)
    turn as ``x_cam(twist) = cos(twist) x_cam(0) + sin(twist) y_cam(0)``; at twist = 0,
    ``x_cam`` points towards decreasing declination (south) and ``y_cam`` towards increasing
    right ascension (east); ``tests/scenes/test_frames.py`` pins both statements.
``angular_velocity_rad_s``
    Angular velocity of the camera with respect to ICRS, in the camera frame. Kinematics:
    ``dR/dt = -[w x] R``.

Arrays use a trailing coordinate axis: vectors (N, 3), rotations (N, 3, 3).
"""

from __future__ import annotations

import numpy as np


def cross(a, b):
    """Cross product of (..., 3) vectors: ``numpy.cross``'s products and differences
    (``a1 b2 - a2 b1``, ...) without its axis handling, which dominates on a single vector."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack((a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0), axis=-1)


def rot1(angle_rad):
    """Passive elementary rotation about x: ``v' = R1(a) v``."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


def rot2(angle_rad):
    """Passive elementary rotation about y."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def rot3(angle_rad):
    """Passive elementary rotation about z."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def skew(v):
    """Cross-product matrix ``[v x]`` so that ``skew(a) @ b == cross(a, b)``; v shape (..., 3)."""
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def radec_to_unit(ra_rad, dec_rad):
    """Unit vectors of right ascension and declination.

    Parameters
    ----------
    ra_rad, dec_rad : float or array_like, shape (...)
        Right ascension and declination, rad (broadcast together).

    Returns
    -------
    numpy.ndarray, shape (..., 3)
        Unit vectors in the frame of the angles (ICRS for ICRS coordinates).

    Examples
    --------
    >>> from skynav.scenes import radec_to_unit
    >>> radec_to_unit(np.pi / 2, 0.0).round(12) + 0.0
    array([0., 1., 0.])
    >>> radec_to_unit([0.0, 0.1], [0.0, 0.2]).shape
    (2, 3)
    """
    ra_rad = np.asarray(ra_rad, dtype=float)
    dec_rad = np.asarray(dec_rad, dtype=float)
    cd = np.cos(dec_rad)
    return np.stack([cd * np.cos(ra_rad), cd * np.sin(ra_rad), np.sin(dec_rad)], -1)


def unit_to_radec(u):
    """Right ascension and declination of direction vectors (inverse of :func:`radec_to_unit`).

    Parameters
    ----------
    u : array_like, shape (..., 3)
        Direction vectors, any length (not normalised first: only their direction counts).

    Returns
    -------
    ra_rad : numpy.ndarray or float, shape (...)
        Right ascension in [0, 2 pi), rad.
    dec_rad : numpy.ndarray or float, shape (...)
        Declination in [-pi/2, pi/2], rad.

    Examples
    --------
    >>> from skynav.scenes import unit_to_radec
    >>> ra, dec = unit_to_radec([0.0, -2.0, 2.0])
    >>> float(np.degrees(ra)), float(np.degrees(dec))
    (270.0, 45.0)
    """
    u = np.asarray(u, dtype=float)
    ra = np.arctan2(u[..., 1], u[..., 0]) % (2.0 * np.pi)
    dec = np.arctan2(u[..., 2], np.hypot(u[..., 0], u[..., 1]))
    return ra, dec


def normalize(v):
    """Vectors of shape (..., 3) scaled to unit length."""
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def radec_twist_to_dcm(ra_rad, dec_rad, twist_rad):
    """Attitude matrix of a boresight direction and a twist: ``R3(twist) R2(pi/2 - dec) R3(ra)``.

    Passive elementary rotations, so the camera's +z (the boresight) points at (ra, dec); the sign
    of twist is in the module's glossary and docs/conventions.md "Choices made in the code".

    Parameters
    ----------
    ra_rad, dec_rad : float
        Right ascension and declination of the boresight, ICRS, rad.
    twist_rad : float
        Rotation of the camera about its boresight, rad.

    Returns
    -------
    numpy.ndarray, shape (3, 3)
        ``R_cam_icrs``, with ``v_cam = R_cam_icrs @ v_icrs``; its third row is the boresight.

    Examples
    --------
    >>> from skynav.scenes import radec_to_unit, radec_twist_to_dcm
    >>> R = radec_twist_to_dcm(0.3, -0.2, 1.0)
    >>> bool(np.allclose(R[2], radec_to_unit(0.3, -0.2)))
    True
    """
    return rot3(twist_rad) @ rot2(0.5 * np.pi - dec_rad) @ rot3(ra_rad)


def dcm_to_radec_twist(R_cam_icrs):
    """Boresight right ascension, declination and twist of an attitude matrix.

    Inverse of :func:`radec_twist_to_dcm`. At the poles (dec = +-pi/2) ra and twist are
    degenerate; ra is then returned as 0.

    Parameters
    ----------
    R_cam_icrs : array_like, shape (3, 3)
        Passive attitude matrix, ``v_cam = R_cam_icrs @ v_icrs``.

    Returns
    -------
    ra_rad : float
        Right ascension of the boresight in [0, 2 pi), rad.
    dec_rad : float
        Declination of the boresight, rad.
    twist_rad : float
        Twist in [0, 2 pi), rad.

    Examples
    --------
    >>> from skynav.scenes import dcm_to_radec_twist, radec_twist_to_dcm
    >>> np.round(dcm_to_radec_twist(radec_twist_to_dcm(0.3, -0.2, 1.0)), 12)
    array([ 0.3, -0.2,  1. ])
    """
    R = np.asarray(R_cam_icrs, dtype=float)
    boresight = R[2]  # third row = camera +z in ICRS
    ra, dec = unit_to_radec(boresight)
    # R3(twist) = R @ (R2(pi/2-dec) R3(ra))^T
    Rt = R @ (rot2(0.5 * np.pi - dec) @ rot3(ra)).T
    twist = np.arctan2(Rt[0, 1], Rt[0, 0]) % (2.0 * np.pi)
    return float(ra), float(dec), float(twist)


def quat_to_dcm(q):
    """Attitude matrix of a scalar-first quaternion.

    ``A = (q0^2 - qv.qv) I + 2 qv qv^T - 2 q0 [qv x]``; the quaternion is normalised first.

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Scalar-first quaternions ``(q0, q1, q2, q3)``, any non-zero length.

    Returns
    -------
    numpy.ndarray, shape (..., 3, 3)
        Passive attitude matrices (``R_cam_icrs`` for a camera attitude).

    References
    ----------
    Andreis et al. (2023a), Eq. 14 (the attitude matrix of a quaternion).

    Examples
    --------
    A rotation of the frame by 90 deg about z:

    >>> from skynav.scenes import quat_to_dcm
    >>> s = np.sqrt(0.5)
    >>> quat_to_dcm([s, 0.0, 0.0, s]).round(12) + 0.0
    array([[ 0.,  1.,  0.],
           [-1.,  0.,  0.],
           [ 0.,  0.,  1.]])
    """
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q0 = q[..., 0]
    qv = q[..., 1:]
    eye = np.broadcast_to(np.eye(3), q.shape[:-1] + (3, 3))
    return (
        (q0**2 - np.sum(qv * qv, -1))[..., None, None] * eye
        + 2.0 * qv[..., :, None] * qv[..., None, :]
        - 2.0 * q0[..., None, None] * skew(qv)
    )


def dcm_to_quat(R):
    """Scalar-first quaternion (q0 >= 0) of an attitude matrix, by Shepperd's method.

    Inverse of :func:`quat_to_dcm`; ``q`` and ``-q`` are the same attitude, the one with
    ``q0 >= 0`` is returned.

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
        Passive attitude matrices (rotation matrices).

    Returns
    -------
    numpy.ndarray, shape (..., 4)
        Unit quaternions ``(q0, q1, q2, q3)``, ``q0 >= 0``.

    References
    ----------
    Andreis et al. (2023a), Eq. 14 (the quaternion convention). Shepperd, S. W. (1978),
    "Quaternion from rotation matrix", Journal of Guidance and Control 1(3), 223-224.

    Examples
    --------
    >>> from skynav.scenes import dcm_to_quat, quat_to_dcm
    >>> q = np.array([0.5, -0.5, 0.5, 0.5])
    >>> bool(np.allclose(dcm_to_quat(quat_to_dcm(q)), q))
    True
    """
    R = np.asarray(R, dtype=float)
    flat = R.reshape(-1, 3, 3)
    out = np.empty((flat.shape[0], 4))
    for n, A in enumerate(flat):
        tr = np.trace(A)
        cands = np.array([tr, A[0, 0], A[1, 1], A[2, 2]])
        k = int(np.argmax(cands))
        if k == 0:
            q0 = 0.5 * np.sqrt(1.0 + tr)
            q = [q0, (A[1, 2] - A[2, 1]) / (4 * q0), (A[2, 0] - A[0, 2]) / (4 * q0), (A[0, 1] - A[1, 0]) / (4 * q0)]
        elif k == 1:
            q1 = 0.5 * np.sqrt(1.0 + 2 * A[0, 0] - tr)
            q = [(A[1, 2] - A[2, 1]) / (4 * q1), q1, (A[0, 1] + A[1, 0]) / (4 * q1), (A[0, 2] + A[2, 0]) / (4 * q1)]
        elif k == 2:
            q2 = 0.5 * np.sqrt(1.0 + 2 * A[1, 1] - tr)
            q = [(A[2, 0] - A[0, 2]) / (4 * q2), (A[0, 1] + A[1, 0]) / (4 * q2), q2, (A[1, 2] + A[2, 1]) / (4 * q2)]
        else:
            q3 = 0.5 * np.sqrt(1.0 + 2 * A[2, 2] - tr)
            q = [(A[0, 1] - A[1, 0]) / (4 * q3), (A[0, 2] + A[2, 0]) / (4 * q3), (A[1, 2] + A[2, 1]) / (4 * q3), q3]
        q = np.asarray(q)
        q /= np.linalg.norm(q)
        out[n] = q if q[0] >= 0 else -q
    return out.reshape(R.shape[:-2] + (4,))


def rotation_vector_to_dcm(phi_rad):
    """Active rotation matrix ``exp([phi x])`` (Rodrigues) for a rotation vector (3,)."""
    phi = np.asarray(phi_rad, dtype=float)
    theta = float(np.linalg.norm(phi))
    K = skew(phi)
    if theta < 1e-8:
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + np.sin(theta) / theta * K + (1 - np.cos(theta)) / theta**2 * K @ K


def rotation_vectors_to_dcm(phi_rad):
    """:func:`rotation_vector_to_dcm` of many rotation vectors at once: ``phi_rad`` (..., 3)
    gives (..., 3, 3), each matrix by the same formula (the second-order series below 1e-8 rad)."""
    phi = np.asarray(phi_rad, dtype=float)
    theta = np.sqrt(np.sum(phi * phi, axis=-1))[..., None, None]
    K = skew(phi)
    KK = K @ K
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0, np.sin(safe) / safe)
    b = np.where(small, 0.5, (1 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * K + b * KK


def propagate_attitude(R_cam_icrs, angular_velocity_rad_s, dt_s):
    """Attitude after ``dt_s`` seconds at constant body rate: ``R(t) = exp(-[w x] dt) R0``.

    ``angular_velocity_rad_s`` is in the camera frame (shape (3,)); ``dt_s`` may be an array
    of shape (T,), giving rotations of shape (T, 3, 3).
    """
    w = np.asarray(angular_velocity_rad_s, dtype=float)
    dt = np.asarray(dt_s, dtype=float)
    if dt.ndim == 0:
        return rotation_vector_to_dcm(-w * dt) @ R_cam_icrs
    return np.stack([rotation_vector_to_dcm(-w * d) @ R_cam_icrs for d in dt])


def point_boresight(target_u_icrs, twist_rad=0.0):
    """Attitude matrix that puts the boresight on a direction, with a given twist.

    Parameters
    ----------
    target_u_icrs : array_like, shape (3,)
        Direction to look at, ICRS (any length).
    twist_rad : float
        Twist about the boresight, rad (:func:`radec_twist_to_dcm`).

    Returns
    -------
    numpy.ndarray, shape (3, 3)
        ``R_cam_icrs``; ``R_cam_icrs @ target`` points along the camera's +z.

    Examples
    --------
    >>> from skynav.scenes import point_boresight
    >>> R = point_boresight([1.0, 1.0, 0.0])
    >>> (R @ [1.0, 1.0, 0.0] / np.sqrt(2)).round(12) + 0.0
    array([0., 0., 1.])
    """
    ra, dec = unit_to_radec(normalize(target_u_icrs))
    return radec_twist_to_dcm(float(ra), float(dec), twist_rad)
