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
CSPICE keeps one kernel pool per process. Every use goes through :func:`kernel_pool`, which holds
a process-wide lock for the whole use and, inside it, makes the pool hold exactly the kernels
asked for: when the set differs from the one loaded last (by name, modification time and size),
or the pool is not what skynav left in it (code of yours called ``kclear`` or ``furnsh``), it
clears the pool and loads the set. So two scenes, two threads of a service or two recipes never
see each other's kernels, and a scene that asks for the set already loaded pays nothing to
reload it; worker processes each have their own pool. :func:`release_kernels` empties the pool
(for code of yours that shares the process's CSPICE). CSPICE errors become one line naming the
kernels as given and CSPICE's own short and long messages (never its multi-line dump).

Names, paths and digests
------------------------
A kernel named in a scene file or a recipe is read beside that file; the names as given are what
the truth and the manifest record, with each file's SHA-256 (:func:`kernel_records`), never a
path. A mapping from elsewhere (a service request) names kernels only through
:data:`KERNEL_RESOLVER`, which the service sets to its ``--data-dir`` rule.
"""

from __future__ import annotations

import contextlib
import contextvars
import hashlib
import os
import threading
from collections.abc import Mapping, Sequence

import numpy as np

from skynav.infra.errors import ConfigValueError

from . import frames
from .ephemeris_jpl import BODIES, BODY_NAIF_IDS, EpochStates
from .errors import SceneFileError, UnknownBodyError

__all__ = ["KERNEL_RESOLVER", "KernelName", "kernel_pool", "spice_states", "spice_attitudes", "spice_coverage", "release_kernels", "kernel_records", "given_name", "spice_state",
           "spice_attitude", "spice_source"]

_POOL_LOCK = threading.Lock()
#: What the pool holds, as skynav left it: (the set's key, CSPICE's list of loaded files).
_LOADED: list = [None, None]
_SHA256: dict = {}

#: How a kernel named by a mapping that is not a file (a service request) is found:
#: ``resolve(name, key)`` gives the file's path or raises a one-line error naming ``key``;
#: None (the default) refuses every such name.
KERNEL_RESOLVER: contextvars.ContextVar = contextvars.ContextVar("KERNEL_RESOLVER", default=None)


class KernelName(str):
    """A kernel's name as written in a recipe (the string: what the manifest records) and the
    file it names (``path``, absolute: beside the recipe file, or the current folder)."""

    def __new__(cls, name, path=None):
        self = super().__new__(cls, name)
        self.path = os.path.abspath(str(name)) if path is None else str(path)
        self.given = str(name)
        return self


def given_name(path) -> str:
    """The name a kernel was given by (``.given`` of a path named in a file), else the path."""
    return str(getattr(path, "given", path))


def _spice():
    try:
        import spiceypy  # the optional spice extra (CSPICE), only for SPICE kernels
    except ImportError:
        raise SceneFileError("SPICE kernels need the spice extra: pip install 'skynav[spice]'") from None
    return spiceypy


def _names(paths) -> str:
    return ", ".join(given_name(p) for p in paths)


def _one_line(exc, paths) -> SceneFileError:
    short = getattr(exc, "short", "") or exc.__class__.__name__
    long = " ".join(str(getattr(exc, "long", "") or "").split())
    for p in paths:  # CSPICE names files by path: say the names as given
        long = long.replace(str(p), given_name(p))
    return SceneFileError(f"{_names(paths)}: {short}{': ' + long if long else ''}"[:600])


def _loaded_files(sp) -> tuple:
    return tuple(sp.kdata(i, "ALL")[0] for i in range(sp.ktotal("ALL")))


def _set_key(paths) -> tuple:
    out = []
    for p in paths:
        if not isinstance(p, str) or not p:
            raise SceneFileError(f"{p!r}: a SPICE kernel must be a file path")
        try:
            st = os.stat(p)
        except OSError:
            st = None
        if st is None or not os.path.isfile(p):
            raise SceneFileError(f"{given_name(p)}: no such SPICE kernel")
        out.append((str(p), st.st_mtime_ns, st.st_size))
    return tuple(out)


@contextlib.contextmanager
def kernel_pool(paths: Sequence):
    """CSPICE holding exactly the kernels ``paths``, to this block alone (this module's docstring)."""
    sp = _spice()
    key = _set_key(paths)
    with _POOL_LOCK:
        if _LOADED[0] != key or _loaded_files(sp) != _LOADED[1]:
            _LOADED[0] = None
            sp.kclear()
            for p in paths:
                try:
                    meta = meta_kernel_entries(sp, p)
                    for q in meta if meta is not None else [p]:
                        sp.furnsh(str(q))
                except SceneFileError:
                    sp.kclear()
                    raise
                except Exception as exc:  # CSPICE's error, one line
                    sp.kclear()
                    raise _one_line(exc, [p]) from None
            _LOADED[0], _LOADED[1] = key, _loaded_files(sp)
        yield sp


def _is_meta_kernel(path) -> bool:
    try:
        with open(path, "rb") as f:
            head = f.read(65536)
    except OSError:
        return False
    return head.startswith(b"KPL/") and b"KERNELS_TO_LOAD" in head


def _pool_strings(sp, name: str) -> list:
    try:
        return list(sp.gcpool(name, 0, 10000))
    except sp.exceptions.NotFoundError:  # no such character variable (expool is for numbers)
        return []


def meta_kernel_entries(sp, path):
    """The kernels a meta-kernel lists (``KERNELS_TO_LOAD``, its ``PATH_SYMBOLS`` substituted and
    ``+`` continuations joined), relative ones read beside the meta-kernel as every file is in
    skynav (CSPICE would read them from the current folder); each a path whose ``given`` is the
    entry as written. None when ``path`` is not a meta-kernel. Its other variables are loaded
    (``ldpool``); call with the pool lock held."""
    if not _is_meta_kernel(path):
        return None
    sp.ldpool(str(path))
    entries, joined = [], ""
    for e in _pool_strings(sp, "KERNELS_TO_LOAD"):
        joined += e[:-1] if e.endswith("+") else e
        if not e.endswith("+"):
            entries.append(joined)
            joined = ""
    symbols = dict(zip(_pool_strings(sp, "PATH_SYMBOLS"), _pool_strings(sp, "PATH_VALUES")))
    folder = os.path.dirname(os.path.abspath(str(path)))
    out = []
    for e in entries:
        name = e
        for sym in sorted(symbols, key=len, reverse=True):
            name = name.replace(f"${sym}", symbols[sym])
        full = name if os.path.isabs(name) else os.path.join(folder, name)
        if not os.path.isfile(full):
            raise SceneFileError(f"{given_name(path)}: KERNELS_TO_LOAD names {e}, no such file beside it")
        out.append(_Given(full, e))
    return out


class _Given(str):
    def __new__(cls, path, given):
        self = super().__new__(cls, path)
        self.given = given
        return self


def release_kernels() -> None:
    """Empty the process's kernel pool (``kclear``), for code that shares CSPICE with skynav."""
    sp = _spice()
    with _POOL_LOCK:
        sp.kclear()
        _LOADED[0] = _LOADED[1] = None


def _sha256(path: str) -> str:
    st = os.stat(path)
    key = (str(path), st.st_mtime_ns, st.st_size)
    if key not in _SHA256:
        h = hashlib.sha256()
        with open(path, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
        _SHA256[key] = h.hexdigest()
    return _SHA256[key]


def kernel_records(paths) -> list:
    """``[{"name": as given, "sha256": of the file}]`` of kernels, for the truth and the manifest;
    a meta-kernel's own kernels follow it, named as it writes them, with ``"via"``: its name."""
    out = []
    for p in paths:
        out.append({"name": given_name(p), "sha256": _sha256(str(p))})
        if _is_meta_kernel(str(p)):
            with _POOL_LOCK:
                sp = _spice()
                _LOADED[0] = None  # ldpool adds to the pool: the next use reloads its set
                try:
                    listed = meta_kernel_entries(sp, str(p))
                except SceneFileError:
                    raise
                except Exception as exc:
                    raise _one_line(exc, [p]) from None
            out += [{"name": given_name(q), "sha256": _sha256(str(q)), "via": given_name(p)} for q in listed]
    return out


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


def _body_id(sp, body) -> int:
    text = str(body).strip()
    try:
        return int(text)
    except ValueError:
        code = sp.bods2c(text)  # raises on a name the pool does not know
        return int(code)


def spice_coverage(paths, body) -> tuple:
    """(start, end), TDB s past J2000, of the first interval the SPKs among ``paths`` (a
    meta-kernel's included) cover ``body`` over; None where none does."""
    with kernel_pool(paths) as sp:
        try:
            code = _body_id(sp, body)
            cover = sp.stypes.SPICEDOUBLE_CELL(20000)
            for i in range(sp.ktotal("SPK")):
                sp.spkcov(sp.kdata(i, "SPK")[0], code, cover)
        except Exception as exc:
            raise _one_line(exc, paths) from None
        if sp.wncard(cover) == 0:
            return None
        return tuple(float(x) for x in sp.wnfetd(cover, 0))


def spice_states(paths, body, t_tdb_s):
    """:func:`spice_state` at many epochs, one pool: (positions (N, 3) km, velocities (N, 3) km/s)."""
    t = np.atleast_1d(np.asarray(t_tdb_s, dtype=float))
    out = np.empty((t.size, 6))
    with kernel_pool(paths) as sp:
        try:
            for i, ti in enumerate(t.tolist()):
                out[i] = sp.spkezr(str(body), ti, "J2000", "NONE", "SOLAR SYSTEM BARYCENTER")[0]
        except Exception as exc:
            raise _one_line(exc, paths) from None
    return out[:, :3], out[:, 3:]


def spice_attitudes(paths, frame: str, t_tdb_s):
    """:func:`spice_attitude` at many epochs, one pool: (``R_cam_icrs`` (N, 3, 3), angular
    velocities (N, 3) rad/s, camera frame)."""
    t = np.atleast_1d(np.asarray(t_tdb_s, dtype=float))
    R, w = np.empty((t.size, 3, 3)), np.empty((t.size, 3))
    with kernel_pool(paths) as sp:
        try:
            for i, ti in enumerate(t.tolist()):
                Ri, av = sp.xf2rav(sp.sxform("J2000", str(frame), ti))
                R[i] = Ri
                w[i] = R[i] @ np.asarray(av, dtype=float)
        except Exception as exc:
            raise _one_line(exc, paths) from None
    return R, w


def spice_source(section: str, spec, t_tdb_s: float) -> dict:
    """The scene-file section a ``{spice: {...}}`` source stands for at ``t_tdb_s``:
    ``position_km``/``velocity_km_s`` or ``q_cam_icrs``/``angular_velocity_deg_s``."""
    want = "body" if section == "observer" else "frame"
    if not isinstance(spec, Mapping) or set(spec) != {"kernels", want}:
        raise ConfigValueError(f"{section}.spice", spec, f"a mapping of kernels (a list of files) and {want}")
    paths = list(spec["kernels"])
    if section == "observer":
        r, v = spice_state(paths, spec[want], t_tdb_s)
        return {"position_km": [float(x) for x in r], "velocity_km_s": [float(x) for x in v]}
    R, w = spice_attitude(paths, spec[want], t_tdb_s)
    return {"q_cam_icrs": [float(x) for x in frames.dcm_to_quat(R)],
            "angular_velocity_deg_s": [float(x) for x in np.degrees(w)]}


class SpiceEphemeris:
    """Barycentric ICRS states of :data:`~skynav.scenes.ephemeris_jpl.BODIES` from a planetary
    SPK of any type CSPICE reads (DE440, a mission's moons), in place of DE421: a scene file's
    ``ephemeris: {spk: FILE}``.

    The same NAIF ids as the DE421 path (:data:`~skynav.scenes.ephemeris_jpl.BODY_NAIF_IDS`:
    the system barycentres of the giant planets), geometric states (``spkgeo`` in ``J2000``
    about the solar-system barycentre, no correction), epochs in TDB seconds past J2000
    (SPICE's ET). Each call evaluates inside :func:`kernel_pool` with this one file loaded. The
    interface is :class:`~skynav.scenes.ephemeris_jpl.Ephemeris`'s; ``offset_s`` is added to
    the epoch in float64 (2e-7 s of rounding near 2030, 6 mm at 30 km/s).
    """

    def __init__(self, path):
        self.paths = [path]
        self.path = str(path)

    def __repr__(self) -> str:
        return f"SpiceEphemeris({given_name(self.paths[0])!r})"

    def __eq__(self, other):
        return isinstance(other, SpiceEphemeris) and self.path == other.path

    def __hash__(self):
        return hash((SpiceEphemeris, self.path))

    def _states(self, body, t_tdb_s, offset_s, velocity: bool):
        key = body.lower() if isinstance(body, str) else body
        if key not in BODY_NAIF_IDS:
            raise UnknownBodyError(body, BODIES)
        t = np.asarray(t_tdb_s, dtype=float) + np.asarray(offset_s, dtype=float)
        flat = np.atleast_1d(t).ravel()
        out = np.empty((flat.size, 6))
        with kernel_pool(self.paths) as sp:
            try:
                for i, ti in enumerate(flat.tolist()):
                    out[i] = sp.spkgeo(BODY_NAIF_IDS[key], ti, "J2000", 0)[0]
            except Exception as exc:
                raise _one_line(exc, self.paths) from None
        out = out.reshape(t.shape + (6,)) if t.ndim else out[0]
        return (out[..., :3], out[..., 3:]) if velocity else out[..., :3]

    def position_velocity(self, body: str, t_tdb_s, *, offset_s=0.0):
        """Position (km) and velocity (km/s) of ``body`` at ``t_tdb_s`` (+ ``offset_s``)."""
        return self._states(body, t_tdb_s, offset_s, True)

    def position(self, body: str, t_tdb_s, *, offset_s=0.0):
        """Position (km) of ``body`` at ``t_tdb_s`` (+ ``offset_s``)."""
        return self._states(body, t_tdb_s, offset_s, False)

    def states_at(self, t_tdb_s: float, bodies=None) -> dict:
        """``{body: (r, v)}`` at one epoch."""
        return {b: self.position_velocity(b, float(t_tdb_s)) for b in (bodies or BODIES)}

    def epoch_states(self, t_tdb_s: float, bodies=None):
        """The states of several bodies at one epoch, as an ``EpochStates``."""
        bodies = tuple(bodies or BODIES)
        states = [self.position_velocity(b, float(t_tdb_s)) for b in bodies]
        return EpochStates(bodies, np.array([r for r, _ in states]).reshape(-1, 3),
                           np.array([v for _, v in states]).reshape(-1, 3))

    def positions_at(self, t_tdb_s, bodies=None) -> np.ndarray:
        """Positions (N, bodies, 3) of several bodies at several epochs, km."""
        bodies = tuple(bodies or BODIES)
        t = np.atleast_1d(np.asarray(t_tdb_s, dtype=float))
        return np.stack([self.position(b, t) for b in bodies], axis=1).reshape(t.size, len(bodies), 3)
