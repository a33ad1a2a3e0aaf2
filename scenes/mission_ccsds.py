"""CCSDS Orbit and Attitude Ephemeris Messages (OEM, AEM) in and out, in KVN, through the
``ccsds-ndm-py`` library (the ``ccsds`` extra: ``pip install 'skynav[ccsds]'``).

What skynav writes and reads
----------------------------
- OEM (CCSDS 502.0-B-3): ``REF_FRAME = ICRF``, ``CENTER_NAME = SOLAR SYSTEM BARYCENTER``,
  ``TIME_SYSTEM = TDB``, states in km and km/s: the observer of docs/conventions.md.
- AEM (CCSDS 504.0-B-2): ``REF_FRAME_A = ICRF``, ``REF_FRAME_B`` the camera frame,
  ``ATTITUDE_TYPE = QUATERNION/ANGVEL``: ``Q1 Q2 Q3 QC`` (scalar last) is skynav's
  ``q_cam_icrs`` (scalar first, the attitude matrix ``A = (q0^2 - qv.qv) I + 2 qv qv^T - 2 q0
  [qv x]`` of docs/conventions.md, which maps frame A's coordinates to frame B's) reordered,
  and the angular velocity in the camera frame in deg/s (the standard's unit).

Files by other programs are read too: OEM with ``TIME_SYSTEM`` TDB, TT, TAI or UTC
(astropy converts), AEM of type ``QUATERNION`` or ``QUATERNION/ANGVEL`` from ICRF (EME2000
is refused: its frame bias, ~0.02", is not a rounding). Between samples the
OEM is interpolated by cubic Hermite on the two bracketing states (position and velocity), the
AEM by spherical linear interpolation (slerp) of the quaternions; an epoch outside the file's
samples is refused, never extrapolated.
"""

from __future__ import annotations

import importlib.util
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import frames

from .constants import J2000_JD, SECONDS_PER_DAY
from .errors import SceneFileError
from .timescales import time_from_tdb_seconds, to_time

__all__ = ["ccsds_available", "OemTable", "AemTable", "oem_kvn", "aem_kvn", "oem_xml", "aem_xml", "read_oem", "read_aem",
           "oem_state", "aem_attitude"]

#: Name of skynav's camera frame in AEM files (``REF_FRAME_B``).
CAMERA_FRAME = "SKYNAV_CAMERA"
_SSB = ("SOLAR SYSTEM BARYCENTER", "SSB", "SOLAR SYSTEM BARYCENTRE")
_TIME_SYSTEMS = {"TDB": "tdb", "TT": "tt", "TAI": "tai", "UTC": "utc"}


def ccsds_available() -> bool:
    """Whether the ``ccsds`` extra (``ccsds-ndm-py``) is installed."""
    return importlib.util.find_spec("ccsds_ndm") is not None


def _ndm():
    try:
        import ccsds_ndm  # the optional ccsds extra, only for OEM/AEM files
    except ImportError:
        raise SceneFileError("CCSDS OEM/AEM files need the ccsds extra: pip install 'skynav[ccsds]'") from None
    return ccsds_ndm


def _iso(t_tdb_s) -> list[str]:
    t = time_from_tdb_seconds(np.asarray(t_tdb_s, dtype=float)).tdb
    t.precision = 6
    return list(np.atleast_1d(t.isot))


def _creation(t_tdb_s) -> str:
    # deterministic bytes: the creation date is the first epoch's, not the clock's
    return _iso([t_tdb_s])[0]


def _oem(t_tdb_s, position_km, velocity_km_s, object_name: str):
    C = _ndm()
    t = np.atleast_1d(np.asarray(t_tdb_s, dtype=float))
    sv = np.hstack([np.atleast_2d(position_km), np.atleast_2d(velocity_km_s)]).astype(float)
    ep = _iso(t)
    md = C.OemMetadata(object_name=object_name, object_id="UNKNOWN", start_time=ep[0], stop_time=ep[-1],
                       center_name="SOLAR SYSTEM BARYCENTER", ref_frame="ICRF", time_system="TDB",
                       interpolation="HERMITE", interpolation_degree=3)
    return C.Oem(C.OdmHeader(creation_date=ep[0], originator="skynav"),
                 [C.OemSegment(md, C.OemData.from_numpy(ep, sv))])


def oem_kvn(t_tdb_s, position_km, velocity_km_s, *, object_name: str = "SKYNAV") -> str:
    """An OEM (KVN text) of barycentric ICRS states at TDB seconds past J2000 (km, km/s)."""
    return _oem(t_tdb_s, position_km, velocity_km_s, object_name).to_str("kvn")


def oem_xml(t_tdb_s, position_km, velocity_km_s, *, object_name: str = "SKYNAV") -> str:
    """The same OEM as :func:`oem_kvn`, in the standard's XML (NDM/XML)."""
    return _oem(t_tdb_s, position_km, velocity_km_s, object_name).to_str("xml")


def _aem(t_tdb_s, q_cam_icrs, angular_velocity_rad_s, object_name: str):
    C = _ndm()
    t = np.atleast_1d(np.asarray(t_tdb_s, dtype=float))
    q = np.atleast_2d(np.asarray(q_cam_icrs, dtype=float))
    w = np.degrees(np.atleast_2d(np.asarray(angular_velocity_rad_s, dtype=float)))
    rows = np.hstack([q[:, 1:4], q[:, :1], w])
    ep = _iso(t)
    md = C.AemMetadata(object_name=object_name, object_id="UNKNOWN", ref_frame_a="ICRF", ref_frame_b=CAMERA_FRAME,
                       start_time=ep[0], stop_time=ep[-1], time_system="TDB", attitude_type="QUATERNION/ANGVEL",
                       angvel_frame=CAMERA_FRAME, interpolation_method="LINEAR", interpolation_degree=1)
    return C.Aem(C.AdmHeader(creation_date=ep[0], originator="skynav"),
                 [C.AemSegment(md, C.AemData.from_numpy(ep, rows, attitude_type="QUATERNION/ANGVEL"))])


def aem_kvn(t_tdb_s, q_cam_icrs, angular_velocity_rad_s, *, object_name: str = "SKYNAV") -> str:
    """An AEM (KVN text) of camera attitudes: ``q_cam_icrs`` scalar first (skynav's), the angular
    velocity in the camera frame, rad/s (written in deg/s)."""
    return _aem(t_tdb_s, q_cam_icrs, angular_velocity_rad_s, object_name).to_str("kvn")


def aem_xml(t_tdb_s, q_cam_icrs, angular_velocity_rad_s, *, object_name: str = "SKYNAV") -> str:
    """The same AEM as :func:`aem_kvn`, in the standard's XML (NDM/XML)."""
    return _aem(t_tdb_s, q_cam_icrs, angular_velocity_rad_s, object_name).to_str("xml")


@dataclass(frozen=True, eq=False)
class OemTable:
    """An OEM's states: TDB seconds past J2000, barycentric ICRS km and km/s."""

    path: str
    t_tdb_s: np.ndarray
    position_km: np.ndarray
    velocity_km_s: np.ndarray
    segment: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class AemTable:
    """An AEM's attitudes: TDB seconds, ``q_cam_icrs`` scalar first, angular velocity rad/s in
    the camera frame (``None`` when the file has none)."""

    path: str
    t_tdb_s: np.ndarray
    q_cam_icrs: np.ndarray
    angular_velocity_rad_s: np.ndarray | None
    segment: np.ndarray | None = None


def _parse(path, kind: str):
    C = _ndm()
    p = Path(path)
    if not p.is_file():
        raise SceneFileError(f"{p}: no such {kind} file")
    try:
        head = p.read_bytes()[:4096].decode("ascii", "replace")
    except OSError as exc:
        raise SceneFileError(f"{p}: cannot read the {kind} ({exc.strerror or exc.__class__.__name__})") from None
    for line in head.splitlines()[:3]:
        key, _, value = line.partition("=")
        if key.strip() == f"CCSDS_{kind}_VERS" and kind == "AEM" and not value.strip().startswith("2"):
            raise SceneFileError(f"{p}: AEM version {value.strip()}: skynav reads version 2.0 (CCSDS 504.0-B-2)")
    try:
        return (C.Oem if kind == "OEM" else C.Aem).from_file(str(p), "kvn" if p.suffix.lower() != ".xml" else "xml")
    except Exception as exc:  # the library's message, on one line
        why = " ".join(str(exc).split()) or exc.__class__.__name__
        raise SceneFileError(f"{p}: not a readable CCSDS {kind}: {why[:300]}") from None


def _tdb_seconds(path, epochs, time_system) -> np.ndarray:
    scale = _TIME_SYSTEMS.get(str(time_system or "").upper())
    if scale is None:
        raise SceneFileError(f"{path}: TIME_SYSTEM {time_system}: skynav reads TDB, TT, TAI or UTC")
    from astropy.time import Time  # heavy (~0.3 s): only when an OEM/AEM is read

    t = Time(list(epochs), scale=scale, format="isot").tdb
    return ((t.jd1 - J2000_JD) + t.jd2) * SECONDS_PER_DAY


def _segments(path, ts) -> tuple[np.ndarray, np.ndarray]:
    """(epochs, segment index of each) of the segments' epochs: strictly increasing inside a
    segment; a segment may start at the epoch where the one before stops (a manoeuvre's
    boundary: the later segment's state holds from there), never before it."""
    if not ts or not any(len(t) for t in ts):
        raise SceneFileError(f"{path}: no data lines")
    for k, t in enumerate(ts):
        if np.any(np.diff(t) <= 0):
            raise SceneFileError(f"{path}: epochs of segment {k + 1} are not strictly increasing")
        if k and len(t) and len(ts[k - 1]) and t[0] < ts[k - 1][-1]:
            raise SceneFileError(f"{path}: segment {k + 1} starts before segment {k} stops")
    return np.concatenate(ts), np.concatenate([np.full(len(t), k) for k, t in enumerate(ts)])


def read_oem(path) -> OemTable:
    """Read an OEM (KVN or XML): every segment, in order; ICRF about the solar-system barycentre."""
    oem = _parse(path, "OEM")
    ts, rs, vs = [], [], []
    for seg in oem.segments:
        md = seg.metadata
        if str(md.ref_frame).upper() != "ICRF":
            raise SceneFileError(f"{path}: REF_FRAME {md.ref_frame}: skynav reads ICRF (barycentric ICRS)")
        if str(md.center_name).upper() not in _SSB:
            raise SceneFileError(f"{path}: CENTER_NAME {md.center_name}: skynav reads SOLAR SYSTEM BARYCENTER")
        sv = np.asarray(seg.data.state_vector_numpy, dtype=float)
        if sv.ndim != 2 or sv.shape[1] < 6 or not np.all(np.isfinite(sv[:, :6])):
            raise SceneFileError(f"{path}: state lines need 6 finite numbers (km, km/s)")
        ts.append(_tdb_seconds(path, seg.data.state_vector_epochs, md.time_system))
        rs.append(sv[:, :3])
        vs.append(sv[:, 3:6])
    t, seg = _segments(path, ts)
    return OemTable(str(path), t, np.vstack(rs), np.vstack(vs), seg)


def read_aem(path) -> AemTable:
    """Read an AEM (KVN or XML) of quaternions from ICRF to the camera frame."""
    aem = _parse(path, "AEM")
    ts, qs, ws = [], [], []
    for seg in aem.segments:
        md = seg.metadata
        kind = str(md.attitude_type).upper()
        if kind not in ("QUATERNION", "QUATERNION/ANGVEL"):
            raise SceneFileError(f"{path}: ATTITUDE_TYPE {md.attitude_type}: skynav reads QUATERNION or QUATERNION/ANGVEL")
        if str(md.ref_frame_a).upper() != "ICRF":
            raise SceneFileError(f"{path}: REF_FRAME_A {md.ref_frame_a}: skynav reads attitudes from ICRF to the camera")
        rows = np.asarray(seg.data.attitude_states_numpy, dtype=float)
        if rows.ndim != 2 or rows.shape[1] < 4 or not np.all(np.isfinite(rows)):
            raise SceneFileError(f"{path}: attitude lines need Q1 Q2 Q3 QC (finite)")
        q = np.hstack([rows[:, 3:4], rows[:, :3]])
        n = np.linalg.norm(q, axis=1)
        if np.any(np.abs(n - 1.0) > 1e-6):
            raise SceneFileError(f"{path}: a quaternion of norm {n[np.argmax(np.abs(n - 1))]:.9g}; expected 1 (within 1e-6)")
        ts.append(_tdb_seconds(path, seg.data.attitude_states_epochs, md.time_system))
        qs.append(q / n[:, None])
        if kind == "QUATERNION/ANGVEL":
            if str(md.angvel_frame or "").upper() != str(md.ref_frame_b).upper():
                raise SceneFileError(f"{path}: ANGVEL_FRAME {md.angvel_frame}: skynav reads the angular velocity "
                                     f"in REF_FRAME_B ({md.ref_frame_b})")
            ws.append(np.radians(rows[:, 4:7]))
        else:
            ws.append(None)
    t, seg = _segments(path, ts)
    w = None if any(x is None for x in ws) else np.vstack(ws)
    return AemTable(str(path), t, np.vstack(qs), w, seg)


def _bracket(path, t_all, t: float, segment=None) -> int:
    """Index ``i`` of the samples ``i, i + 1`` around ``t``, both of one segment (or ``t`` is
    sample ``i`` itself); an epoch outside the file or between two segments is refused."""
    if not t_all[0] <= t <= t_all[-1]:
        raise SceneFileError(f"{path}: epoch {to_time(float(t)).tdb.isot} TDB is outside the file's "
                             f"{to_time(float(t_all[0])).tdb.isot} to {to_time(float(t_all[-1])).tdb.isot}")
    i = int(min(np.searchsorted(t_all, t, side="right") - 1, len(t_all) - 2))
    if segment is not None and segment[i] != segment[i + 1] and t != t_all[i]:
        raise SceneFileError(f"{path}: epoch {to_time(float(t)).tdb.isot} TDB falls between segments "
                             f"{segment[i] + 1} and {segment[i + 1] + 1} (no data there)")
    return i


def oem_state(table: OemTable, t_tdb_s: float):
    """(position km, velocity km/s) at ``t_tdb_s``: a sample as it is, or cubic Hermite between
    the two bracketing samples (positions and velocities)."""
    t_all = table.t_tdb_s
    if len(t_all) == 1:
        if t_tdb_s != t_all[0]:
            _bracket(table.path, np.array([t_all[0], t_all[0]]), t_tdb_s)
        return table.position_km[0].copy(), table.velocity_km_s[0].copy()
    i = _bracket(table.path, t_all, t_tdb_s, table.segment)
    h = t_all[i + 1] - t_all[i]
    s = (t_tdb_s - t_all[i]) / h
    if h <= 0.0 or s == 0.0:  # a sample itself (also the last of a segment)
        return table.position_km[i].copy(), table.velocity_km_s[i].copy()
    p0, p1 = table.position_km[i], table.position_km[i + 1]
    m0, m1 = table.velocity_km_s[i] * h, table.velocity_km_s[i + 1] * h
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    d00, d10, d01, d11 = 6 * s**2 - 6 * s, 3 * s**2 - 4 * s + 1, -6 * s**2 + 6 * s, 3 * s**2 - 2 * s
    r = h00 * p0 + h10 * m0 + h01 * p1 + h11 * m1
    v = (d00 * p0 + d10 * m0 + d01 * p1 + d11 * m1) / h
    return r, v


def aem_attitude(table: AemTable, t_tdb_s: float):
    """(``q_cam_icrs`` scalar first, angular velocity rad/s camera frame) at ``t_tdb_s``: a
    sample as it is, else slerp between the bracketing samples; the angular velocity linear
    between the file's, or the slerp's constant rate when the file has none."""
    t_all = table.t_tdb_s
    if len(t_all) == 1:
        if t_tdb_s != t_all[0]:
            _bracket(table.path, np.array([t_all[0], t_all[0]]), t_tdb_s)
        w = table.angular_velocity_rad_s
        return table.q_cam_icrs[0].copy(), (np.zeros(3) if w is None else w[0].copy())
    i = _bracket(table.path, t_all, t_tdb_s, table.segment)
    h = t_all[i + 1] - t_all[i]
    s = (t_tdb_s - t_all[i]) / h
    seg = table.segment
    if h <= 0.0 or (seg is not None and seg[i] != seg[i + 1]):  # the last sample of a segment
        w = table.angular_velocity_rad_s
        return table.q_cam_icrs[i].copy(), (np.zeros(3) if w is None else w[i].copy())
    R0, R1 = frames.quat_to_dcm(table.q_cam_icrs[i]), frames.quat_to_dcm(table.q_cam_icrs[i + 1])
    # R1 = exp([phi x]) R0; at a constant body rate w (camera frame) R(t) = exp(-[w x] t) R0
    # (frames.propagate_attitude), so the slerp's rate is w = -phi / h
    phi = _rotation_vector(R1 @ R0.T)
    R = frames.rotation_vector_to_dcm(s * phi) @ R0
    q = frames.dcm_to_quat(R)
    if s == 0.0:
        q = table.q_cam_icrs[i].copy()
    w_tab = table.angular_velocity_rad_s
    w = -phi / h if w_tab is None else (1 - s) * w_tab[i] + s * w_tab[i + 1]
    return np.asarray(q, dtype=float), np.asarray(w, dtype=float)


def _rotation_vector(R_delta) -> np.ndarray:
    """The rotation vector ``phi`` of :func:`frames.rotation_vector_to_dcm` (its inverse)."""
    from scipy.spatial.transform import Rotation  # heavy: only when an AEM is interpolated

    phi = Rotation.from_matrix(R_delta).as_rotvec()
    # rotation_vector_to_dcm's sign convention, checked on the result
    if not np.allclose(frames.rotation_vector_to_dcm(phi), R_delta, atol=1e-9):
        phi = -phi
    return phi


def rate_deg_s(w_rad_s) -> list[float]:
    """An angular velocity in deg/s, as a scene file gives it."""
    return [math.degrees(float(x)) for x in w_rad_s]
