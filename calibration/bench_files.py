"""The bench's files: calibration patterns written as PNGs with ``patterns.json``,
camera captures read and checked against them, the virtual bench's captures and power-meter table
written, and the closed loop over a dataset and its bench export.

Driver module: the calibration fits, the virtual bench and the closed-loop measurement (modules of
this package) compute on arrays; here their inputs are read and their outputs written with
:mod:`skynav.datasets.frame_files` (PNG, atomic writes), the formats' one home.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from skynav.datasets.frame_files import PNG_SCALING, read_png, write_png
from skynav.datasets.hil_export import export_dataset
from skynav.datasets.lock import dataset_lock
from skynav.datasets.reader import open_dataset
from skynav.datasets.recipes import preset_recipe
from skynav.datasets.runner import generate
from skynav.infra.atomic_files import atomic_write_bytes
from skynav.renderer.detector import Sensor
from skynav.scenes.camera import Camera
from skynav.scenes.facility import Facility

from .closed_loop import ClosedLoopResult, LoopRows, angle_arcsec, measure_pair, select_sources
from .errors import CalibrationInputError, CaptureMismatchError
from .geometric import GeometricResult, fit_geometric
from .patterns import SCHEMA, Pattern, design, draw, read_patterns  # noqa: F401
from .virtual_bench import MAX_FRAMES, VirtualBench, scenario

__all__ = ["write_patterns", "read_captures", "calibrate_geometric", "simulate", "closed_loop_dataset",
           "run_closed_loop"]


def write_patterns(facility: Facility, directory, **kw) -> list[Pattern]:
    """Design the calibration patterns (:func:`skynav.calibration.patterns.design`, ``kw``) and
    write them to ``directory``: one PNG per pattern at the screen's bit depth and ``patterns.json``.

    The PNGs hold the screen's DN scaled to the PNG's full range with an ``sBIT`` chunk
    (:func:`~skynav.datasets.frame_files.write_png`), so a viewer shows the dots;
    ``patterns.json`` says so (``png_scaling``, ``significant_bits``). :func:`read_captures` and
    :func:`simulate` read these and the unscaled PNGs of skynav <= 0.3.0 alike
    (:func:`~skynav.datasets.frame_files.read_png`)."""
    d = Path(directory)
    sc = facility.screen
    pats = design(facility, **kw)  # the bad-input checks, before anything is written
    d.mkdir(parents=True, exist_ok=True)
    with dataset_lock(d, what="pattern folder"):
        # patterns.json goes last and names only this set: a killed run leaves no manifest (or the
        # previous one, of files rewritten with the same bytes)
        for p in pats:
            write_png(d / p.file, draw(p, sc.width_px, sc.height_px, sc.bit_depth), bit_depth=sc.bit_depth)
        doc = {"schema": SCHEMA, "screen": {"width_px": sc.width_px, "height_px": sc.height_px, "bit_depth": sc.bit_depth},
               "png_scaling": PNG_SCALING, "significant_bits": int(sc.bit_depth),
               "patterns": [p.to_json() for p in pats]}
        atomic_write_bytes(d / "patterns.json", json.dumps(doc, indent=1).encode())
    return pats


def check_patterns_screen(facility: Facility, screen: dict, patterns_dir) -> None:
    """Refuse patterns made for another screen than the facility's (one line)."""
    sc = facility.screen
    if (screen.get("width_px"), screen.get("height_px"), screen.get("bit_depth")) != (sc.width_px, sc.height_px, sc.bit_depth):
        raise CaptureMismatchError(f"{patterns_dir}: patterns for a {screen.get('width_px')}x{screen.get('height_px')} "
                                   f"{screen.get('bit_depth')}-bit screen, but the facility's screen is {sc.width_px}x{sc.height_px} "
                                   f"{sc.bit_depth}-bit; make patterns for this facility (skynav calibrate patterns)")


def read_pattern_image(patterns_dir, pattern: Pattern, screen: dict) -> np.ndarray:
    """A pattern's PNG, checked: readable, the screen's size, DN within the screen's bit depth."""
    path = Path(patterns_dir) / pattern.file
    if not path.is_file():
        raise CalibrationInputError(f"{path}: pattern image missing (listed in patterns.json); write the patterns again")
    try:
        img = read_png(path)
    except Exception as exc:  # noqa: BLE001 - any unreadable file is a bad input
        raise CalibrationInputError(f"{path}: not a readable greyscale PNG ({exc.__class__.__name__})") from None
    w, h, bd = screen["width_px"], screen["height_px"], screen["bit_depth"]
    if img.ndim != 2 or img.shape != (h, w):
        raise CalibrationInputError(f"{path}: pattern image is {'x'.join(map(str, img.shape[::-1]))} px; the screen is {w}x{h}")
    if int(img.max(initial=0)) > (1 << bd) - 1:
        raise CalibrationInputError(f"{path}: pattern image holds DN {int(img.max())}; the screen is {bd}-bit")
    return img


def read_captures(facility: Facility, patterns_dir, captures_dir):
    """(patterns, {file: image}) after checking that the captures match the patterns."""
    screen, pats = read_patterns(patterns_dir)
    check_patterns_screen(facility, screen, patterns_dir)
    cap = Path(captures_dir)
    if not cap.is_dir():
        raise CaptureMismatchError(f"{captures_dir}: no such captures folder")
    missing = [p.file for p in pats if not (cap / p.file).is_file()]
    if missing:
        raise CaptureMismatchError(f"{captures_dir}: {len(missing)} of {len(pats)} pattern captures missing "
                                   f"(first: {missing[0]}); captures must carry the patterns' file names")
    cam = facility.camera
    want = np.uint8 if cam.sensor.bit_depth <= 8 else np.uint16
    images = {}
    for p in pats:
        try:
            img = read_png(cap / p.file)
        except Exception as exc:  # noqa: BLE001 - any unreadable file is a bad input
            raise CaptureMismatchError(f"{cap / p.file}: not a readable greyscale PNG ({exc.__class__.__name__})") from None
        if img.ndim != 2 or img.shape != (cam.height, cam.width):
            raise CaptureMismatchError(f"{cap / p.file}: capture is {img.shape[1]}x{img.shape[0]} px; the camera is {cam.width}x{cam.height}")
        if img.dtype != want or int(img.max()) > cam.sensor.max_dn:
            raise CaptureMismatchError(f"{cap / p.file}: capture is {img.dtype} with max {int(img.max())}; the camera is "
                                       f"{cam.sensor.bit_depth}-bit ({np.dtype(want).name}, <= {cam.sensor.max_dn})")
        images[p.file] = img
    return pats, images


def calibrate_geometric(facility: Facility, patterns_dir, captures_dir, *, holdout: float = 0.2,
                        seed: int = 0) -> GeometricResult:
    """:func:`~skynav.calibration.geometric.fit_geometric` on the captures of ``captures_dir`` of
    the patterns of ``patterns_dir`` (:func:`read_captures`)."""
    t0 = time.perf_counter()
    pats, images = read_captures(facility, patterns_dir, captures_dir)
    return fit_geometric(facility, pats, images, holdout=holdout, seed=seed, t0=t0, source=(patterns_dir, captures_dir))


def simulate(facility: Facility, patterns_dir, out_dir, *, scenario_name: str = "realistic", seed: int = 0,
             frames: int = 16, progress=None) -> dict:
    """Capture every pattern of ``patterns_dir`` on the virtual bench into ``out_dir`` (same file
    names) and write ``out_dir/power_meter.csv``. Returns a summary dict.

    The folder is locked for the run (a second run on it is refused, as for ``dataset generate``);
    every file is written atomically and the whole set again by a re-run with the same seed, so
    a run killed part-way and run again gives the bytes of one uninterrupted run. Every pattern is
    read and checked (``patterns.json``, the screen, each PNG) before the first capture.

    Raises
    ------
    CalibrationInputError
        Bad patterns, patterns of another screen, ``frames`` outside 1..:data:`MAX_FRAMES`.
    skynav.datasets.lock.DatasetLockedError
        Another run writes into ``out_dir``.
    """
    if isinstance(frames, bool) or not isinstance(frames, int) or not 1 <= frames <= MAX_FRAMES:
        raise CalibrationInputError(f"frames = {frames!r}: expected an integer in 1..{MAX_FRAMES} (exposures averaged per "
                                    "capture; each is a full camera frame of noise)")
    screen, pats = read_patterns(patterns_dir)
    check_patterns_screen(facility, screen, patterns_dir)
    for p in pats:  # all checked before the first write (then read again one at a time: memory)
        read_pattern_image(patterns_dir, p, screen)
    bench = VirtualBench(facility, scenario(scenario_name, facility))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with dataset_lock(out, what="capture folder"):
        return _simulate(facility, bench, pats, lambda p: read_pattern_image(patterns_dir, p, screen), out, scenario_name,
                         seed, frames, progress)


def _simulate(facility, bench, pats, image_of, out, scenario_name, seed, frames, progress):
    rng = np.random.default_rng(seed)
    bd = facility.camera.sensor.bit_depth
    # the lab sets the exposure so that the brightest dots reach ~75 % of full well
    scale = 1.0
    first = next((p for p in pats if p.kind == "dots"), None)
    if first is not None:
        peak = float(bench.expected_electrons(image_of(first).astype(float)).max())
        scale = float(np.clip(0.75 * facility.camera.sensor.full_well_e / max(peak, 1e-9), 0.1, 10.0))
    for i, p in enumerate(pats):
        img = image_of(p)
        write_png(out / p.file, bench.capture(img.astype(float), rng, frames=frames, exposure_scale=scale), bit_depth=bd)
        if progress:
            progress(i + 1, len(pats))
    rows = bench.power_meter(rng=rng)
    text = "digital_count,lit_pixels,irradiance_w_m2\n" + "".join(f"{d},{n},{e:.6e}\n" for d, n, e in rows)
    atomic_write_bytes(out / "power_meter.csv", text.encode())
    return {"captures": len(pats), "measurements": len(rows), "scenario": scenario_name, "exposure_scale": scale}


def closed_loop_dataset(bench, dataset_dir, export_dir, *, seed: int = 0, v_max: float = 6.0, frames=None,
                        progress=None) -> ClosedLoopResult:
    """Capture every exported screen frame of ``export_dir`` (written from ``dataset_dir`` with the
    calibrated facility) on ``bench`` (a :class:`~skynav.calibration.virtual_bench.VirtualBench`)
    and compare with the dataset's software frames (see the module docstring). Frame k's camera
    noise draws from ``SeedSequence([seed, k])``."""
    ds = open_dataset(dataset_dir)
    todo = range(len(ds)) if frames is None else range(min(int(frames), len(ds)))
    cols = {k: [] for k in ("frame", "kind", "name", "v_mag")}
    err = {"noisy": [], "noise_free": []}
    sw_err = {"noisy": [], "noise_free": []}
    pc_err = {"noisy": [], "noise_free": []}
    clipped = []
    dmag = {"noisy": [], "noise_free": []}
    skipped: dict = {}
    sensor = None
    for n_done, k in enumerate(todo):
        rec = ds[k]
        truth = rec.truth
        cam = Camera.from_dict(truth["camera"])
        if cam != bench.facility.camera:
            raise CalibrationInputError(f"{dataset_dir}: frame {k}'s camera differs from the bench's; export a dataset made with the facility's camera")
        src = select_sources(truth, cam, v_max, skipped)
        screen_png = Path(export_dir) / "frames" / f"{k:06d}.png"
        hil = json.loads((Path(export_dir) / "frames" / f"{k:06d}.json").read_text())
        if hil["source"]["frame"] != k:
            raise CalibrationInputError(f"{screen_png}: exported from frame {hil['source']['frame']}, not {k}")
        if not src:
            continue
        sp = cam.sensor
        if sensor is None:
            sensor = Sensor(sp, (cam.height, cam.width))
        cap_e = bench.expected_electrons(read_png(screen_png).astype(float))
        rng = np.random.default_rng(np.random.SeedSequence([seed, k]))
        cap_dn = sensor.expose(cap_e, cam.exposure_s, rng, backend="numpy")
        sw_e = np.asarray(rec.electrons, dtype=float)
        to_e = lambda dn: (dn.astype(float) - sp.offset_dn) / sp.gain_dn_per_e  # noqa: E731
        full = sp.full_well_e
        images = {"cap_noisy": (to_e(cap_dn), cap_dn >= sp.max_dn), "sw_noisy": (to_e(rec.dn), rec.dn >= sp.max_dn),
                  "cap_noise_free": (np.minimum(cap_e, full), cap_e >= full), "sw_noise_free": (np.minimum(sw_e, full), sw_e >= full)}
        xy = np.array([s[4] for s in src])
        v_cam = np.array([s[3] for s in src])
        meas = measure_pair(cam, images, xy)
        ref = meas["sw_noise_free"].xy_px
        ref_cam = cam.line_of_sight(np.where(np.isfinite(ref), ref, 0.0))
        ref_cam[~np.all(np.isfinite(ref), axis=1)] = np.nan
        maxdn = (1 << int(hil["facility"]["screen"]["bit_depth"])) - 1
        peaks = {s["hip"]: s["peak_dn"] for s in hil["stars"]} | {b["name"]: b["peak_dn"] for b in hil["bodies"]}
        clipped += [peaks.get(int(s[1]) if s[0] == "star" else s[1], 0) >= maxdn for s in src]
        for label in ("noisy", "noise_free"):
            c, s = meas[f"cap_{label}"], meas[f"sw_{label}"]
            err[label].append(angle_arcsec(cam, c.xy_px, v_cam))
            pc_err[label].append(angle_arcsec(cam, c.xy_px, ref_cam))
            sw_err[label].append(angle_arcsec(cam, s.xy_px, v_cam))
            phot = c.ok & s.ok & ~c.saturated & ~s.saturated & (c.flux_e > 0) & (s.flux_e > 0)
            with np.errstate(invalid="ignore", divide="ignore"):
                dmag[label].append(np.where(phot, -2.5 * np.log10(c.flux_e / s.flux_e), np.nan))
        cols["frame"] += [k] * len(src)
        cols["kind"] += [s[0] for s in src]
        cols["name"] += [s[1] for s in src]
        cols["v_mag"] += [s[2] for s in src]
        if progress:
            progress(n_done + 1, len(todo))
    cat = lambda parts: np.concatenate(parts) if parts else np.zeros(0)  # noqa: E731
    rows = LoopRows(frame=np.array(cols["frame"], dtype=int), kind=np.array(cols["kind"], dtype=str),
                    name=np.array(cols["name"], dtype=str), v_mag=np.array(cols["v_mag"], dtype=float),
                    err_arcsec={k: cat(v) for k, v in err.items()}, sw_err_arcsec={k: cat(v) for k, v in sw_err.items()},
                    photocentre_err_arcsec={k: cat(v) for k, v in pc_err.items()}, dmag={k: cat(v) for k, v in dmag.items()},
                    screen_clipped=np.array(clipped, dtype=bool), skipped=skipped)
    return ClosedLoopResult(rows=rows, frames=len(todo), v_max=v_max)


def run_closed_loop(facility, calibrated, work_dir, *, scenario_name: str = "realistic", frames: int = 100,
                    dataset_seed: int = 20260101, seed: int = 0, v_max: float = 6.0, progress=False) -> ClosedLoopResult:
    """The whole loop in ``work_dir``: a ``montecarlo`` dataset of ``frames`` frames made with the
    facility's camera (as ``skynav dataset generate montecarlo --count N --seed S``), exported for
    the bench with the ``calibrated`` facility (as ``skynav hil export``), captured on the
    virtual bench ``scenario_name`` of the nominal ``facility`` and measured
    (:func:`closed_loop_dataset`). Both folders resume if already there."""
    work = Path(work_dir)
    recipe = preset_recipe("montecarlo")
    recipe.update(frames=int(frames), seed=int(dataset_seed), camera=facility.camera.to_dict())
    generate(recipe, work / "dataset", workers=1, progress=progress)
    export_dataset(calibrated, work / "dataset", work / "screen", workers=1)
    bench = VirtualBench(facility, scenario(scenario_name, facility))
    return closed_loop_dataset(bench, work / "dataset", work / "screen", seed=seed, v_max=v_max)
