"""SPICE kernels in: the observer's state from SPKs (any type CSPICE reads) and the camera's
attitude from a frame (a CK with its SCLK and FK), through spiceypy (the ``spice`` extra:
``pip install 'skynav[spice]'``).

Scene files: ``observer: {spice: {kernels: [FILE, ...], body: NAME_OR_ID}}`` gives the body's
barycentric state at the scene's epoch (``spkezr`` in ``J2000``, which SPICE aligns with the
ICRF, no aberration correction: the geometric state, as every observer of skynav);
``attitude: {spice: {kernels: [...], frame: NAME}}`` gives ``R_cam_icrs`` and the angular
velocity from ``sxform('J2000', frame)``; the frame must be skynav's camera frame (``+z``
boresight, ``+x`` along columns, docs/conventions.md). A meta-kernel may stand for the list.
The scene's epoch is TDB, which is SPICE's ephemeris time (seconds past J2000 TDB), so no
leapseconds kernel is needed.

The kernel pool
---------------
CSPICE keeps one kernel pool per process. :func:`kernel_pool` holds a process-wide lock, clears
the pool, loads exactly the scene's kernels, and clears the pool again on the way out, so two
scenes (or two threads of a service) never see each other's kernels; worker processes each have
their own pool. CSPICE errors become one line naming the kernels and CSPICE's own short and
long messages (never its multi-line dump).
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Mapping, Sequence

import numpy as np

from skynav.infra.errors import ConfigValueError

from . import frames
from .errors import SceneFileError

__all__ = ["kernel_pool", "spice_state", "spice_attitude", "spice_source"]

_POOL_LOCK = threading.Lock()


def _spice():
    try:
        import spiceypy  # the optional spice extra (CSPICE), only for SPICE kernels
    except ImportError:
        raise SceneFileError("SPICE kernels need the spice extra: pip install 'skynav[spice]'") from None
    return spiceypy


def _names(paths) -> str:
    return ", ".join(str(p) for p in paths)


def _one_line(exc, paths) -> SceneFileError:
    short = getattr(exc, "short", "") or exc.__class__.__name__
    long = " ".join(str(getattr(exc, "long", "") or "").split())
    return SceneFileError(f"{_names(paths)}: {short}{': ' + long if long else ''}"[:600])


@contextlib.contextmanager
def kernel_pool(paths: Sequence):
    """CSPICE with exactly ``paths`` loaded, for this block only (this module's docstring)."""
    sp = _spice()
    for p in paths:
        if not isinstance(p, str) or not p:
            raise SceneFileError(f"{p!r}: a SPICE kernel must be a file path")
        if not os.path.isfile(p):
            raise SceneFileError(f"{p}: no such SPICE kernel")
    with _POOL_LOCK:
        sp.kclear()
        try:
            for p in paths:
                try:
                    sp.furnsh(str(p))
                except Exception as exc:  # CSPICE's error, one line
                    raise _one_line(exc, [p]) from None
            yield sp
        finally:
            sp.kclear()


def spice_state(paths, body, t_tdb_s: float):
    """(position km, velocity km/s) of ``body`` (name or NAIF id) about the solar-system
    barycentre, ICRF (SPICE ``J2000``), at ``t_tdb_s`` (TDB seconds past J2000 = SPICE ET)."""
    with kernel_pool(paths) as sp:
        try:
            s, _ = sp.spkezr(str(body), float(t_tdb_s), "J2000", "NONE", "SOLAR SYSTEM BARYCENTER")
        except Exception as exc:
            raise _one_line(exc, paths) from None
    s = np.asarray(s, dtype=float)
    return s[:3], s[3:]


def spice_attitude(paths, frame: str, t_tdb_s: float):
    """(``R_cam_icrs``, angular velocity rad/s in the camera frame) of SPICE frame ``frame``
    at ``t_tdb_s``: ``sxform('J2000', frame)`` split by ``xf2rav``."""
    with kernel_pool(paths) as sp:
        try:
            xf = sp.sxform("J2000", str(frame), float(t_tdb_s))
            R, av = sp.xf2rav(xf)
        except Exception as exc:
            raise _one_line(exc, paths) from None
    R = np.asarray(R, dtype=float)
    # xf2rav's av: the frame's angular velocity relative to J2000, in J2000 coordinates
    return R, R @ np.asarray(av, dtype=float)


def spice_source(section: str, spec, t_tdb_s: float) -> dict:
    """The scene-file section a ``{spice: {...}}`` source stands for at ``t_tdb_s``:
    ``position_km``/``velocity_km_s`` or ``q_cam_icrs``/``angular_velocity_deg_s``."""
    want = "body" if section == "observer" else "frame"
    if not isinstance(spec, Mapping) or set(spec) != {"kernels", want}:
        raise ConfigValueError(f"{section}.spice", spec, f"a mapping of kernels (a list of files) and {want}")
    paths = [str(p) for p in spec["kernels"]]
    if section == "observer":
        r, v = spice_state(paths, spec[want], t_tdb_s)
        return {"position_km": [float(x) for x in r], "velocity_km_s": [float(x) for x in v]}
    R, w = spice_attitude(paths, spec[want], t_tdb_s)
    return {"q_cam_icrs": [float(x) for x in frames.dcm_to_quat(R)],
            "angular_velocity_deg_s": [float(x) for x in np.degrees(w)]}
