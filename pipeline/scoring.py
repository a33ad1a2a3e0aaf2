"""Scoring the image processing against the ground truth: ``skynav bench ip``'s engine.

Scoring module (the only pipeline modules that read truth: ``tests/test_architecture.py``). It
opens a skynav dataset (:func:`skynav.datasets.open_dataset`, typed truth ``ds.truth(k)``) or any
folder of frames in the frame schema (``frames/NNNNNN.png`` + ``.json``, or the pairs directly in
the folder), read by the datasets reader (:func:`skynav.datasets.reader.read_frame_pair`: the
camera, pixel pitch included, and the epoch from the JSON) and scored from the JSON's
``observer.*``, ``attitude.R_cam_icrs`` and ``bodies[]`` (``name``, ``xy``, ``in_fov``,
``visible``). The pipeline gets only the observation and a
predicted state drawn here from the truth with the given sigma per axis (Andreis et al. (2023a), Sec. V).
"""

from __future__ import annotations

import functools
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tqdm.auto import tqdm

from skynav.datasets import open_dataset
from skynav.datasets.errors import DatasetError
from skynav.datasets.reader import read_frame_pair
from skynav.scenes.constants import ARCSEC_RAD

from .attitude import rotation_angle_rad
from .catalog import OnboardCatalog
from .errors import BenchInputError
from .plugins import BUILTIN, PluginError, SkynavProcessor, call_processor, load_image_processor
from .results import PredictedState

__all__ = ["FrameTruthLite", "BeaconScore", "FrameScore", "open_frames", "predicted_state", "score_frame",
           "run_benchmark", "summarise", "summarise_peers", "WRONG_ATTITUDE_ARCSEC", "BEACON_WRONG_PX", "DEFAULT_SIGMAS_KM",
           "DEFAULT_FRAME_TIMEOUT_S"]

WRONG_ATTITUDE_ARCSEC = 500.0    # wrong = error > 500 arcsec
BEACON_WRONG_PX = 5.0            # Andreis et al. (2023a), Sec. V: a beacon error > 5 px is a failure
DEFAULT_SIGMAS_KM = (1e4, 1e5, 1e6, 1e7)
VELOCITY_SIGMA_KM_S = 0.1        # predicted-velocity error per axis (aberration only)
#: the default per-frame time limit of a processor, s: generous (skynav's pipeline takes ~0.1 s a
#: frame); a plug-in stuck on a frame fails that frame, not the benchmark
DEFAULT_FRAME_TIMEOUT_S = 60.0


@dataclass(frozen=True, kw_only=True, eq=False)
class FrameTruthLite:
    """The keys of the truth the benchmark uses."""

    R_cam_icrs: np.ndarray
    position_km: np.ndarray
    velocity_km_s: np.ndarray
    bodies: tuple  # (name, xy (2,), in_fov, visible)


@dataclass(frozen=True, kw_only=True)
class BeaconScore:
    """One beacon's outcome in one run: an expected beacon (in the field and visible) found within
    :data:`BEACON_WRONG_PX` (``"correct"``), farther (``"wrong"``) or not at all (``"none"``), or a
    body the mission rule calls invisible found away from where it is (``"wrong"``)."""

    name: str
    outcome: str
    #: distance from the true position (px); nan when not found or not scored
    error_px: float
    #: found minus true position (dx, dy) px of an expected beacon found; None otherwise
    offset_px: tuple | None


@dataclass(frozen=True, kw_only=True)
class FrameScore:
    """One run of the pipeline (one frame at one predicted-position sigma) scored against the truth;
    a row of ``results.csv`` per beacon (one row when it has none)."""

    frame: int
    sigma_km: float
    #: the pipeline's status (``ok``, ``too_few_stars``, ...)
    status: str
    #: ``"correct"`` (error <= :data:`WRONG_ATTITUDE_ARCSEC`), ``"wrong"`` or ``"none"``
    attitude: str
    #: angle between the estimated and the true attitude (arcsec); nan without an attitude
    error_arcsec: float
    #: the pipeline's own 1-sigma estimate of that error (arcsec)
    error_estimate_arcsec: float
    n_stars: int
    n_spots: int
    #: how the stars were identified (``lost_in_space``, ``tracking``, ...)
    method: str
    time_ms: float
    beacons: tuple
    #: the image processor's name (``skynav-improved``, ``tetra3rs``, a plug-in's spec)
    pipeline: str = ""
    #: why the processor failed on the frame (``"exception: ValueError: ..."``); "" when it did not
    fault: str = ""


class _SkynavSource:
    def __init__(self, ds):
        self.ds = ds
        self.root = ds.root

    def __len__(self):
        return len(self.ds)

    def observation(self, k):
        return self.ds.observation(k)

    def truth(self, k):
        t = self.ds.truth(k, validate=False)
        bodies = tuple((b.name, np.asarray(b.xy, float), bool(b.in_fov), bool(b.visible)) for b in t.bodies)
        return FrameTruthLite(R_cam_icrs=np.asarray(t.R_cam_icrs, float), position_km=np.asarray(t.position_km, float),
                              velocity_km_s=np.asarray(t.velocity_km_s, float), bodies=bodies)


def _need(d, path, where):
    cur = d
    for key in path.split("."):
        if not isinstance(cur, dict) or key not in cur:
            raise BenchInputError(f"{where}: frame JSON has no '{path}' (the benchmark needs epoch.tdb_iso, "
                                  "camera.width, height, focal_length_mm, pixel_pitch_um, exposure_s, bit_depth, "
                                  "observer.*, attitude.R_cam_icrs, bodies[])")
        cur = cur[key]
    return cur


class _FolderSource:
    """Any folder of ``NNNNNN.png`` + ``NNNNNN.json`` pairs (in ``frames/`` or at the top)."""

    def __init__(self, root: Path, pairs):
        self.root = root
        self.pairs = pairs

    def __len__(self):
        return len(self.pairs)

    def _json(self, k):
        png, js = self.pairs[k]
        try:
            d = json.loads(js.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise BenchInputError(f"{js}: not a readable frame JSON ({exc.__class__.__name__})") from None
        for key in ("epoch.tdb_iso", "camera.width", "camera.height", "camera.focal_length_mm", "camera.pixel_pitch_um",
                    "camera.exposure_s", "camera.bit_depth",
                    "observer.position_km", "observer.velocity_km_s", "attitude.R_cam_icrs", "bodies"):
            _need(d, key, js)
        return d

    def observation(self, k):
        png, js = self.pairs[k]
        self._json(k)  # the keys the benchmark needs, checked first (one line naming the key)
        try:
            return read_frame_pair(png, js, index=k)[0]
        except DatasetError as exc:
            raise BenchInputError(str(exc)) from None

    def truth(self, k):
        d = self._json(k)
        bodies = []
        for b in d["bodies"]:
            xy = np.array([np.nan if v is None else v for v in (b.get("xy") or [None, None])], float)
            bodies.append((str(b.get("name", "")), xy, bool(b.get("in_fov", False)), bool(b.get("visible", False))))
        return FrameTruthLite(R_cam_icrs=np.asarray(d["attitude"]["R_cam_icrs"], float),
                              position_km=np.asarray(d["observer"]["position_km"], float),
                              velocity_km_s=np.asarray(d["observer"]["velocity_km_s"], float), bodies=tuple(bodies))


def open_frames(path):
    """A frame source for ``path``: a skynav dataset, or a folder of PNG + JSON frames.

    Raises
    ------
    BenchInputError
        Not a folder, or no frames in it.
    """
    root = Path(path)
    if not root.is_dir():
        raise BenchInputError(f"{root}: no such folder (give a skynav dataset or a folder of NNNNNN.png + .json frames)")
    if (root / "manifest.json").exists():
        try:
            return _SkynavSource(open_dataset(root))
        except DatasetError as exc:
            raise BenchInputError(str(exc)) from None
    for folder in (root / "frames", root):
        if folder.is_dir():
            pngs, jsons = sorted(folder.glob("*.png")), sorted(folder.glob("*.json"))
            pairs = [(p, p.with_suffix(".json")) for p in pngs if p.with_suffix(".json").exists()]
            if pairs:
                lone = [p for p in pngs if not p.with_suffix(".json").exists()] + \
                    [j for j in jsons if not j.with_suffix(".png").exists() and j.name != "manifest.json"]
                if lone:  # scoring the rest would silently drop frames
                    other = ".json" if lone[0].suffix == ".png" else ".png"
                    raise BenchInputError(f"{lone[0]}: has no {lone[0].with_suffix(other).name} beside it ({len(lone)} "
                                          "unpaired file(s)); every frame needs its PNG and its JSON")
                return _FolderSource(root, pairs)
    raise BenchInputError(f"{root} is not a dataset: no manifest.json and no PNG + JSON frame pairs in it or in frames/")


def predicted_state(truth, sigma_km, rng):
    """The benchmark's predicted state: the true position plus N(0, sigma_km^2) per axis, the true
    velocity plus N(0, 0.1^2) km/s per axis (Andreis et al. (2023a), Sec. V), drawn from ``rng``."""
    pos = truth.position_km + rng.normal(0.0, sigma_km, 3)
    vel = truth.velocity_km_s + rng.normal(0.0, VELOCITY_SIGMA_KM_S, 3)
    return PredictedState(position_km=pos, velocity_km_s=vel, position_cov_km2=np.eye(3) * sigma_km**2)


def score_frame(result, truth, *, frame, sigma_km, fault=None, time_ms=None, pipeline="") -> FrameScore:
    """The score of one processed frame: its attitude outcome and its beacons' outcomes.

    ``result``: an :class:`~skynav.pipeline.protocols.ImageResult` (or None with ``fault``, the
    reason the processor failed on the frame: the attitude is ``"none"``, the status ``"fault"``).
    ``time_ms``: the call's wall time (default: the result's own ``timings_ms["total"]``).
    """
    if result is None:
        return FrameScore(frame=int(frame), sigma_km=float(sigma_km), status="fault", attitude="none",
                          error_arcsec=float("nan"), error_estimate_arcsec=float("nan"), n_stars=0, n_spots=0, method="",
                          time_ms=float("nan") if time_ms is None else float(time_ms), beacons=(), pipeline=pipeline,
                          fault="" if fault is None else str(fault))
    err = float("nan")
    if result.R_cam_icrs is not None:
        err = rotation_angle_rad(result.R_cam_icrs, truth.R_cam_icrs) / ARCSEC_RAD
        outcome = "correct" if err <= WRONG_ATTITUDE_ARCSEC else "wrong"
    else:
        outcome = "none"
    if time_ms is None:
        time_ms = result.timings_ms.get("total", float("nan"))
    return FrameScore(frame=int(frame), sigma_km=float(sigma_km), status=result.status, attitude=outcome, error_arcsec=err,
                      error_estimate_arcsec=float(result.error_estimate_arcsec), n_stars=result.n_stars,
                      n_spots=len(result.centroids_xy_px), method=result.method, time_ms=float(time_ms),
                      beacons=_score_beacons(result.beacons if result.R_cam_icrs is not None else (), truth),
                      pipeline=pipeline)


def _score_beacons(found_beacons, truth):
    found = {b.name: b for b in found_beacons}
    beacons = []
    expected = {name for name, xy, in_fov, vis in truth.bodies if in_fov and vis}
    for name, xy, in_fov, vis in truth.bodies:
        b = found.get(name)
        if name in expected:
            if b is None or b.xy_px is None:
                beacons.append(BeaconScore(name=name, outcome="none", error_px=float("nan"), offset_px=None))
            else:
                e = float(np.hypot(*(b.xy_px - xy)))
                d = b.xy_px - xy
                beacons.append(BeaconScore(name=name, outcome="correct" if e <= BEACON_WRONG_PX else "wrong", error_px=e,
                                           offset_px=(float(d[0]), float(d[1]))))
        elif b is not None and b.xy_px is not None:
            # a body the mission rule calls invisible (V > limit, inside the Sun exclusion) but
            # rendered in the field: found where it is, it is not scored; found elsewhere, wrong
            e = float(np.hypot(*(b.xy_px - xy))) if in_fov and np.all(np.isfinite(xy)) else float("inf")
            if not e <= BEACON_WRONG_PX:
                beacons.append(BeaconScore(name=name, outcome="wrong", error_px=float("nan"), offset_px=None))
    return tuple(beacons)


def run_benchmark(path, *, sigmas_km=DEFAULT_SIGMAS_KM, mode="improved", seed=0, progress=True, limit=None,
                  catalog=None, peers=False, options=None, pipelines=None, frame_timeout_s=DEFAULT_FRAME_TIMEOUT_S):
    """Process every frame at every sigma with every image processor: ``(scores, info)``.

    ``pipelines``: the processors, each a ``"MODULE:FACTORY"`` spec (or a short name of
    :data:`skynav.pipeline.plugins.BUILTIN`) or a ``(name, factory)`` pair, ``factory(camera)``
    called once with the first frame's calibrated camera. Default: skynav's pipeline in ``mode``
    with ``options`` (a :class:`~skynav.pipeline.process.ProcessOptions`) and ``catalog``;
    ``peers`` adds tetra3rs and cedar-solve (one that cannot run is noted, not raised).

    Every processor sees the same frames and the same predicted states: each (frame, sigma) draws
    its predicted state from ``SeedSequence([seed, frame, i_sigma])``. A processor's fault on a
    frame (:func:`~skynav.pipeline.plugins.call_processor`, ``frame_timeout_s``) is a failed frame
    with its reason.

    Returns
    -------
    scores : list of FrameScore
        The first processor's (a :class:`FrameScore` per frame and sigma).
    info : dict
        ``frames``, ``wall_s``, ``catalog``, ``kvector_build_s``, ``pipelines`` (name -> its
        scores), ``notes`` (name -> why it did not run), ``peer_rows`` and ``peer_notes`` (the same
        for every processor but the first).
    """
    src = open_frames(path)
    n = len(src) if limit is None else min(limit, len(src))
    if n == 0:
        raise BenchInputError(f"{path}: no frames")
    first = src.observation(0)
    if pipelines is None:
        cat = catalog if catalog is not None else OnboardCatalog.load(camera=first.camera)
        pipelines = [(f"skynav-{mode}", functools.partial(SkynavProcessor, mode=mode, options=options, catalog=cat))]
        pipelines += [BUILTIN["tetra3rs"], BUILTIN["cedar-solve"]] if peers else []
    procs, notes = _make_processors(pipelines, first.camera, optional={BUILTIN["tetra3rs"], BUILTIN["cedar-solve"]}
                                    if peers else set())
    rows = {name: [] for name in procs}
    bar = tqdm(total=n, unit="frame", desc=f"bench ip ({', '.join(procs)})") if progress else None
    t0 = time.perf_counter()
    for k in range(n):
        obs = first if k == 0 else src.observation(k)
        if obs.dn.shape != first.dn.shape:
            raise BenchInputError(f"{path}: frame {k} is {obs.dn.shape[1]}x{obs.dn.shape[0]} px, frame 0 "
                                  f"{first.dn.shape[1]}x{first.dn.shape[0]}; a benchmark's frames share one camera")
        truth = src.truth(k)
        for i, s in enumerate(sigmas_km):
            ps = predicted_state(truth, float(s), np.random.default_rng(np.random.SeedSequence([int(seed), k, i])))
            for name, proc in procs.items():
                res, fault, ms = call_processor(proc, obs, ps, timeout_s=frame_timeout_s)
                rows[name].append(score_frame(res, truth, frame=k, sigma_km=float(s), fault=fault, time_ms=ms,
                                              pipeline=name))
        if bar is not None:
            bar.update(1)  # one frame, at every sigma
    if bar is not None:
        bar.close()
    names = list(procs)
    cat = getattr(procs[names[0]], "catalog", None)
    return rows[names[0]], {"frames": n, "wall_s": time.perf_counter() - t0, "catalog": repr(cat),
                            "kvector_build_s": getattr(cat, "build_time_s", float("nan")), "pipelines": rows,
                            "notes": notes, "peer_rows": {m: rows[m] for m in names[1:]}, "peer_notes": notes}


def _make_processors(pipelines, camera, *, optional):
    """``({name: processor}, {name: why not})``: every processor built for ``camera``; one in
    ``optional`` that cannot be built is noted, any other raises its :class:`PluginError`."""
    procs, notes = {}, {}
    for p in pipelines:
        if isinstance(p, str):
            name = next((short for short, spec in BUILTIN.items() if spec == p), p)
            if ".py:" in name:  # a file's plug-in by its file name, not its whole path
                name = name.replace("\\", "/").rsplit("/", 1)[-1]
            try:
                proc = load_image_processor(p, camera)
            except PluginError as exc:
                if p not in optional:
                    raise
                notes[name] = str(exc).split(": ", 1)[-1]
                continue
        else:
            name, factory = p
            proc = factory(camera)
        while name in procs:  # the same processor twice: both run, told apart
            name += "'"
        procs[name] = proc
    return procs, notes


def summarise_peers(peer_rows, our_rows, sigma0):
    """``peers.<name>.{solved_rate, wrong_rate, error_arcsec_median, time_ms_median}`` of other
    processors' scores at ``sigma0``, plus our numbers on the frames both solve (side by side)."""
    out = {}
    ours = {r.frame: r for r in our_rows if r.sigma_km == float(sigma0)}
    for name, all_rows in peer_rows.items():
        rows = [r for r in all_rows if r.sigma_km == float(sigma0)]
        n = len(rows)
        e = np.array([r.error_arcsec for r in rows if r.attitude != "none"])
        out[name] = {"solved_rate": _rate(len(e), n),
                     "wrong_rate": _rate(int(np.sum(e > WRONG_ATTITUDE_ARCSEC)), n),
                     "error_arcsec_median": float(np.median(e)) if len(e) else float("nan"),
                     "time_ms_median": float(np.median([r.time_ms for r in rows])) if n else float("nan")}
        both = [(r.error_arcsec, ours[r.frame].error_arcsec) for r in rows
                if r.attitude != "none" and r.frame in ours and ours[r.frame].attitude == "correct"]
        if both:
            b = np.array(both)
            out[name]["both_solved_frames"] = len(b)
            out[name]["both_solved_error_arcsec_median"] = {"peer": float(np.median(b[:, 0])), "ours": float(np.median(b[:, 1]))}
    return out


def _rate(x, n):
    return float(x) / n if n else float("nan")


def summarise(rows, *, frames, sigmas_km):
    """``summary.json`` (its fixed keys, which readers rely on, plus details)."""
    s0 = [r for r in rows if r.sigma_km == float(sigmas_km[0])]
    n = len(s0)
    errs = np.array([r.error_arcsec for r in s0 if r.attitude == "correct"])
    times = np.array([r.time_ms for r in rows])
    out = {
        "frames": int(frames),
        "attitude": {
            "correct_rate": _rate(sum(r.attitude == "correct" for r in s0), n),
            "wrong_rate": _rate(sum(r.attitude == "wrong" for r in s0), n),
            "none_rate": _rate(sum(r.attitude == "none" for r in s0), n),
            "error_arcsec_median": float(np.median(errs)) if len(errs) else float("nan"),
            "error_arcsec_p90": float(np.percentile(errs, 90)) if len(errs) else float("nan"),
            # the 68.27th percentile of the error angle (a "1 sigma" that is robust to outliers)
            "error_arcsec_1sigma": float(np.percentile(errs, 68.27)) if len(errs) else float("nan"),
        },
        "beacon": {},
        "time_ms": {"median": float(np.median(times)), "p90": float(np.percentile(times, 90))},
        "status_counts": {},
    }
    for r in s0:
        out["status_counts"][r.status] = out["status_counts"].get(r.status, 0) + 1
    faults = {}
    for r in rows:  # every sigma: a fault is the processor's, whatever the prediction
        if r.fault:
            faults[r.fault] = faults.get(r.fault, 0) + 1
    out["faults"] = dict(sorted(faults.items(), key=lambda kv: -kv[1]))
    for s in sigmas_km:
        rs = [r for r in rows if r.sigma_km == float(s)]
        b = [bb for r in rs for bb in r.beacons]
        nb = len(b)
        e = [bb.error_px for bb in b if bb.outcome == "correct"]
        d = np.array([bb.offset_px for bb in b if bb.outcome == "correct"]).reshape(-1, 2)
        with_att = [bb for r in rs if r.attitude != "none" for bb in r.beacons]
        with_right = [bb for r in rs if r.attitude == "correct" for bb in r.beacons]
        frames_with = [r for r in rs if r.beacons]
        out["beacon"][_key(s)] = {
            "correct_rate": _rate(sum(bb.outcome == "correct" for bb in b), nb),
            "wrong_rate": _rate(sum(bb.outcome == "wrong" for bb in b), nb),
            "none_rate": _rate(sum(bb.outcome == "none" for bb in b), nb),
            "error_px_mean": float(np.mean(e)) if e else float("nan"),
            "beacons": nb,
            "frames_with_beacon": len(frames_with),
            # Andreis et al. (2023a), Table 3 columns 5 and 6: failures (wrong or none) among beacons of frames
            # with an attitude, and of frames with the right attitude
            "failure_rate_with_attitude": _rate(sum(bb.outcome != "correct" for bb in with_att), len(with_att)),
            "failure_rate_with_right_attitude": _rate(sum(bb.outcome != "correct" for bb in with_right), len(with_right)),
            "error_mean_px": d.mean(axis=0).tolist() if len(d) else [float("nan")] * 2,
            "error_cov_px2": np.cov(d.T).tolist() if len(d) > 2 else None,
        }
        ra = [r for r in rs if r.attitude != "none"]
        out["beacon"][_key(s)]["attitude_wrong_rate"] = _rate(sum(r.attitude == "wrong" for r in rs), len(rs))
        del ra
    return out


def _key(s):
    return f"{float(s):g}"
