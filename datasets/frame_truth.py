"""Typed ground truth of one frame: :class:`FrameTruth`, built from the ``skynav.frame/2`` JSON.

Core module (no files: :func:`read_frame_truth` is the one reader). The JSON dict stays the
exchange format (``ds[k].truth``); this is the same content as read-only numpy arrays with the
units of the code: angles in rad (the file's ``*_deg`` become ``*_rad``),
epochs as TDB seconds past J2000. Keys beyond the fixed ones of docs/conventions.md stay reachable in
:attr:`FrameTruth.raw`.

Only scoring code opens the truth; the navigation pipeline reads frames through
:class:`skynav.datasets.observation.Observation`, which carries none of it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skynav.scenes.timescales import tdb_seconds

from .errors import TruthSchemaError
from .truth_schema import FRAME_SCHEMA, read_truth_json, schema_problems

__all__ = ["StarsTruth", "BodyTruth", "CosmicRaysTruth", "FrameTruth", "read_frame_truth", "epoch_tdb_seconds"]


def _nan(v):
    """JSON value with ``null`` (NaN on writing) back to NaN, recursively."""
    if v is None:
        return math.nan
    if isinstance(v, list):
        return [_nan(x) for x in v]
    return v


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def _column(records, key: str, tail: tuple, dtype=float) -> np.ndarray:
    """Read-only array, shape (N, *tail), of ``record[key]`` over the records."""
    values = [r[key] if dtype is not float else _nan(r[key]) for r in records]
    values = [np.full(tail, math.nan) if tail and not isinstance(v, list) else v for v in values]  # whole null
    return _frozen(np.array(values, dtype=dtype).reshape((len(values), *tail)))


def _vec(v, *shape) -> np.ndarray:
    """Read-only float array of one JSON vector or matrix (``null`` -> NaN)."""
    return _frozen(np.full(shape, math.nan) if v is None else np.array(_nan(v), dtype=float).reshape(shape))


def _num(v) -> float:
    return math.nan if v is None else float(v)


def epoch_tdb_seconds(epoch: dict) -> float:
    """TDB seconds past J2000 of a truth ``epoch`` record.

    ``tdb_seconds_past_j2000`` when the file has it (exact, written since 0.2.0), else the ISO
    string ``tdb_iso`` (millisecond precision), read with astropy in the TDB scale.
    """
    s = epoch.get("tdb_seconds_past_j2000")
    if s is not None:
        return float(s)

    return float(tdb_seconds(epoch["tdb_iso"]))


@dataclass(frozen=True, kw_only=True, eq=False)
class StarsTruth:
    """The stars in the field of view, one row per star (N stars).

    Attributes
    ----------
    hip : ndarray, shape (N,), int64
        Hipparcos numbers.
    v_mag : ndarray, shape (N,)
        V magnitudes.
    u_icrs : ndarray, shape (N, 3)
        Apparent unit vectors, ICRS (alias ``u_apparent``).
    xy : ndarray, shape (N, 2), px
        Apparent pixel positions at mid-exposure (x = column, y = row).
    electrons : ndarray, shape (N,), e-
        Expected charge over the exposure.
    """

    hip: np.ndarray
    v_mag: np.ndarray
    u_icrs: np.ndarray
    xy: np.ndarray
    electrons: np.ndarray

    def __len__(self) -> int:
        return len(self.hip)

    @property
    def u_apparent(self) -> np.ndarray:
        """Alias of ``u_icrs``, the apparent direction (docs/conventions.md "One name per
        quantity"; ``BodyDirections.u_apparent`` of scenes was the other name)."""
        return self.u_icrs

    @classmethod
    def from_records(cls, records) -> "StarsTruth":
        return cls(hip=_column(records, "hip", (), dtype=np.int64), v_mag=_column(records, "v_mag", ()),
                   u_icrs=_column(records, "u_icrs", (3,)), xy=_column(records, "xy", (2,)),
                   electrons=_column(records, "electrons", ()))


@dataclass(frozen=True, kw_only=True, eq=False)
class BodyTruth:
    """One solar-system body of the frame (docs/conventions.md ``bodies`` record).

    Attributes
    ----------
    name : str
        Body name (``mars``, ``moon``, ...).
    xy, xy_geometric : ndarray, shape (2,)
        Apparent (light-time + aberration) and geometric pixel positions at mid-exposure, px;
        NaN where undefined.
    u_icrs : ndarray, shape (3,)
        Apparent unit vector, ICRS (alias ``u_apparent``).
    light_time_s : float
        Light travel time from the body, s.
    distance_km : float
        Observer (at reception) to body (at emission), km.
    v_mag : float
        Apparent V magnitude (NaN outside the phase law's range).
    phase_angle_rad : float
        Sun-body-observer angle, rad (the file's ``phase_angle_deg``).
    angular_diameter_px : float
        Apparent diameter, px.
    in_fov, visible, resolved : bool
        In the image; visible by the mission's rule (``VisibilityCriteria``); drawn as a
        resolved disc (ray-traced) rather than a point.
    electrons : float
        Expected charge over the exposure, e-.

    Examples
    --------
    >>> import tempfile
    >>> from skynav.datasets import generate, preset_recipe
    >>> from skynav.renderer import RenderOptions
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=2, camera={"preset": "paper", "width": 64, "height": 64, "fov_deg": 20})
    >>> tmp = tempfile.TemporaryDirectory()
    >>> summary = generate(recipe, tmp.name + "/ds", workers=1, progress=False,
    ...                    render_options=RenderOptions(backend="numpy"))
    >>> from skynav.datasets import open
    >>> truth = open(tmp.name + "/ds").truth(0)
    >>> mars = truth.body("mars")
    >>> mars.name, mars.xy.shape, bool(mars.distance_km > 0), mars.u_apparent is mars.u_icrs
    ('mars', (2,), True, True)
    >>> tmp.cleanup()
    """

    name: str
    xy: np.ndarray
    xy_geometric: np.ndarray
    u_icrs: np.ndarray
    light_time_s: float
    distance_km: float
    v_mag: float
    phase_angle_rad: float
    angular_diameter_px: float
    in_fov: bool
    visible: bool
    resolved: bool
    electrons: float

    @property
    def u_apparent(self) -> np.ndarray:
        """Alias of ``u_icrs``, the apparent direction (docs/conventions.md "One name per
        quantity"; ``BodyDirections.u_apparent`` of scenes was the other name)."""
        return self.u_icrs

    @classmethod
    def from_record(cls, r: dict) -> "BodyTruth":
        """The body of one ``bodies[]`` record of the truth JSON (degrees converted to radians)."""
        return cls(name=str(r["name"]), xy=_vec(r["xy"], 2), xy_geometric=_vec(r["xy_geometric"], 2),
                   u_icrs=_vec(r["u_icrs"], 3), light_time_s=_num(r["light_time_s"]),
                   distance_km=_num(r["distance_km"]), v_mag=_num(r["v_mag"]),
                   phase_angle_rad=math.radians(_num(r["phase_angle_deg"])),
                   angular_diameter_px=_num(r["angular_diameter_px"]), in_fov=bool(r["in_fov"]),
                   visible=bool(r["visible"]), resolved=bool(r["resolved"]), electrons=_num(r["electrons"]))


@dataclass(frozen=True, kw_only=True, eq=False)
class CosmicRaysTruth:
    """Cosmic-ray hits of the frame (M hits).

    Attributes
    ----------
    xy : ndarray, shape (M, 2), px
        Hit positions.
    electrons : ndarray, shape (M,), e-
        Deposited charge.
    """

    xy: np.ndarray
    electrons: np.ndarray

    def __len__(self) -> int:
        return len(self.electrons)

    @classmethod
    def from_records(cls, records) -> "CosmicRaysTruth":
        return cls(xy=_column(records, "xy", (2,)), electrons=_column(records, "electrons", ()))


@dataclass(frozen=True, kw_only=True, eq=False)
class FrameTruth:
    """Ground truth of one frame, typed (schema ``skynav.frame/2``).

    Attributes
    ----------
    epoch_tdb_s : float
        Mid-exposure epoch, TDB seconds past J2000 (see :func:`epoch_tdb_seconds`).
    epoch_tdb_iso : str
        The same epoch as the file's ISO string, TDB.
    position_km, velocity_km_s : ndarray, shape (3,)
        Observer, barycentric ICRS, km and km/s.
    R_cam_icrs : ndarray, shape (3, 3)
        Attitude, passive: ``v_cam = R_cam_icrs @ v_icrs``.
    q_cam_icrs : ndarray, shape (4,)
        The same attitude as a scalar-first quaternion (Andreis et al. (2023a), Eq. 14).
    angular_velocity_rad_s : ndarray, shape (3,)
        Camera frame, rad/s.
    camera : dict
        The camera record (``Camera.to_dict()``); ``Camera.from_dict(truth.camera)`` rebuilds it.
    stars : StarsTruth
    bodies : tuple of BodyTruth
    cosmic_rays : CosmicRaysTruth
    seeds : dict
        Every seed used.
    raw : dict
        The whole JSON dict (keys beyond the fixed ones: ``render``, ``sun``, ``dataset``...).

    Examples
    --------
    >>> import tempfile
    >>> from skynav.datasets import generate, preset_recipe
    >>> from skynav.renderer import RenderOptions
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=2, camera={"preset": "paper", "width": 64, "height": 64, "fov_deg": 20})
    >>> tmp = tempfile.TemporaryDirectory()
    >>> summary = generate(recipe, tmp.name + "/ds", workers=1, progress=False,
    ...                    render_options=RenderOptions(backend="numpy"))
    >>> from skynav.datasets import open
    >>> truth = open(tmp.name + "/ds").truth(0)
    >>> truth.R_cam_icrs.shape, truth.q_cam_icrs.shape, truth.stars.xy.shape[1]
    ((3, 3), (4,), 2)
    >>> bool(np.allclose(truth.R_cam_icrs @ truth.R_cam_icrs.T, np.eye(3)))
    True
    >>> tmp.cleanup()
    """

    epoch_tdb_s: float
    epoch_tdb_iso: str
    position_km: np.ndarray
    velocity_km_s: np.ndarray
    R_cam_icrs: np.ndarray
    q_cam_icrs: np.ndarray
    angular_velocity_rad_s: np.ndarray
    camera: dict
    stars: StarsTruth
    bodies: tuple
    cosmic_rays: CosmicRaysTruth
    seeds: dict
    raw: dict

    @classmethod
    def from_dict(cls, truth: dict, *, validate: bool = True, source: str = "truth") -> "FrameTruth":
        """Typed truth from the JSON dict.

        Parameters
        ----------
        truth : dict
            What :func:`skynav.datasets.truth_schema.read_truth_json` returns (plain JSON; for an
            in-memory dict with numpy values, pass it through ``truth_to_jsonable`` first).
        validate : bool
            Check it against ``frame.schema.json`` first.
        source : str
            Name used in error messages (the file).

        Returns
        -------
        FrameTruth
            The typed truth (angles in radians; ``raw`` keeps the dict).

        Raises
        ------
        TruthSchemaError
            The dict violates the schema (one line: the source and the first JSON path).
        """
        if validate:
            problems = schema_problems(truth, FRAME_SCHEMA)
            if problems:
                more = f" (+{len(problems) - 1} more)" if len(problems) > 1 else ""
                raise TruthSchemaError(f"{source}: does not follow skynav.frame/2: {problems[0]}{more}", problems)
        att, obs = truth["attitude"], truth["observer"]
        return cls(epoch_tdb_s=epoch_tdb_seconds(truth["epoch"]), epoch_tdb_iso=str(truth["epoch"]["tdb_iso"]),
                   position_km=_vec(obs["position_km"], 3), velocity_km_s=_vec(obs["velocity_km_s"], 3),
                   R_cam_icrs=_vec(att["R_cam_icrs"], 3, 3), q_cam_icrs=_vec(att["q_cam_icrs"], 4),
                   angular_velocity_rad_s=_vec(att["angular_velocity_rad_s"], 3),
                   camera=dict(truth["camera"]), stars=StarsTruth.from_records(truth["stars"]),
                   bodies=tuple(BodyTruth.from_record(b) for b in truth["bodies"]),
                   cosmic_rays=CosmicRaysTruth.from_records(truth["cosmic_rays"]),
                   seeds=dict(truth["seeds"]), raw=truth)

    def body(self, name: str) -> BodyTruth:
        """The body called ``name``.

        Parameters
        ----------
        name : str
            Body name (``mars``, ``moon``, ...).

        Returns
        -------
        BodyTruth
            Its record.

        Raises
        ------
        KeyError
            No such body in the frame (the message names the bodies there are).
        """
        for b in self.bodies:
            if b.name == name:
                return b
        raise KeyError(f"no body {name!r} in this frame; bodies: {', '.join(b.name for b in self.bodies)}")

    def __repr__(self) -> str:
        return (f"FrameTruth(epoch_tdb_iso={self.epoch_tdb_iso!r}, stars={len(self.stars)}, "
                f"bodies={[b.name for b in self.bodies]}, cosmic_rays={len(self.cosmic_rays)})")


def read_frame_truth(source, *, validate: bool = True) -> FrameTruth:
    """:class:`FrameTruth` of a frame's JSON file (path or binary file object)."""
    return FrameTruth.from_dict(read_truth_json(source), validate=validate, source=str(getattr(source, "name", source)))
