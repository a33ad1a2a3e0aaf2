"""Export frames as bench screen frames: ``DIR/frames/NNNNNN.png`` (screen resolution and bit
depth) + ``NNNNNN.json`` (``schema: skynav.hil_frame/2``: the source frame, where each source was
placed on the screen, its intended electrons and peak DN, what was clipped, how the PNG stores
the screen's DN).

The PNG holds the screen's DN scaled to the PNG's full range with an ``sBIT`` chunk naming the
screen's bit depth (:func:`skynav.datasets.frame_files.scale_dn_to_png`; a 10-bit screen's 1023 is
stored as 65535), so any viewer shows the stars; ``png_scaling: "sbit"`` and ``significant_bits``
in the frame JSON and in ``export.json`` say so. Version 1 (skynav <= 0.3.0) stored the DN
unscaled; :func:`skynav.datasets.frame_files.read_png` returns the screen DN of both.

Run like ``dataset generate`` (:mod:`skynav.datasets.runner`), with the same pieces:

- crash-safe and resumable: each file is written atomically, then the frame's checksum record
  ``frames/NNNNNN.sha256`` (:mod:`skynav.datasets.journal`); a re-run keeps a frame only when its
  record exists, both files match it and decode, and makes every other frame again;
- one export per folder: ``DIR/export.json`` names the source dataset (its manifest's SHA-256),
  the facility (the SHA-256 of its canonical mapping) and the skynav version; a re-run with
  another dataset or facility is refused with one line, as is a second process on the same
  folder (the dataset lock);
- in this process, in spawned local processes (threads sized ``cores // workers``), or as Dask
  tasks (``dask_scheduler``); a screen frame depends on its source frame and the facility alone
  (seed = frame index), so the bytes are the same whatever the executor.

The scene of each source frame is rebuilt from its ground truth (epoch, observer, attitude,
camera, visibility, catalogue limit) and drawn by :func:`skynav.renderer.display.screen_frame`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from pathlib import Path

import numpy as np

from skynav.infra.atomic_files import atomic_write_bytes, sha256_file
from skynav.infra.errors import SkynavError
from skynav.infra.pool import process_pool_map
from skynav.renderer.display import screen_frame
from skynav.scenes.scene import build_scene
from skynav.scenes.visibility import VisibilityCriteria

from . import open_dataset
from .data_keys import camera_from_record, note_unknown_keys
from .errors import DatasetError, DatasetMismatchError, OutputFormatError, OutputPathError, TruthSchemaError
from .frame_files import PNG_SCALING, png_bytes
from .frame_truth import epoch_tdb_seconds
from .journal import frame_problem, write_record
from .layout import MANIFEST_NAME, clean_stale_temp_files, frame_relpaths, package_version
from .lock import dataset_lock
from .runner import connect_dask
from .truth_schema import FRAME_SCHEMA, read_truth_json, schema_problems

SCHEMA = "skynav.hil_frame/2"


def scene_from_truth(truth: dict):
    kw = {}
    if "visibility" in truth:
        kw["visibility"] = VisibilityCriteria.from_dict(truth["visibility"])
    if "catalog_limiting_v_mag" in truth:
        kw["catalog_limiting_v_mag"] = float(truth["catalog_limiting_v_mag"])
    return build_scene(epoch_tdb_seconds(truth["epoch"]), position_km=np.array(truth["observer"]["position_km"]),
                       velocity_km_s=np.array(truth["observer"]["velocity_km_s"]), R_cam_icrs=np.array(truth["attitude"]["R_cam_icrs"]),
                       camera=camera_from_record(truth["camera"])[0],
                       angular_velocity_rad_s=truth["attitude"]["angular_velocity_rad_s"], **kw)


def write_screen_frame(facility, scene, out_dir, name: str, *, source: dict, seed: int = 0, options=None,
                       subfolder: str = "frames") -> dict:
    """Render and write one screen frame, ``out_dir/subfolder/name.png`` and ``.json`` (an export's
    layout; ``skynav render --hil`` passes ``subfolder=""``: its one frame beside nothing else, as
    ``render`` writes a camera frame); returns its JSON record."""
    png, rec = screen_frame_bytes(facility, scene, source=source, seed=seed, options=options)
    frames = Path(out_dir) / subfolder
    frames.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(frames / f"{name}.png", png)
    atomic_write_bytes(frames / f"{name}.json", json.dumps(rec, indent=1).encode())
    return rec


def screen_frame_bytes(facility, scene, *, source: dict, seed: int = 0, options=None):
    """Render one screen frame in memory: ``(PNG bytes, JSON record)``, what :func:`write_screen_frame` writes."""
    sf = screen_frame(scene, facility, rng=np.random.default_rng(seed), options=options)
    sc = facility.screen
    on = facility.projection.in_screen(sf.stars_xy) if len(sf.stars_xy) else np.zeros(0, bool)
    rec = {
        "schema": SCHEMA,
        "source": source,
        "facility": {"name": facility.name, "screen": {"width_px": sc.width_px, "height_px": sc.height_px, "bit_depth": sc.bit_depth},
                     "geometric_fit": (facility.calibrated_geometric or {}).get("fit"),
                     "radiometric_fit": (facility.calibrated_radiometric or {}).get("fit")},
        "pixel_convention": "screen px: x = column, y = row, centre of the top-left pixel at (0, 0)",
        "png_scaling": PNG_SCALING, "significant_bits": int(sc.bit_depth),
        "stars": [{"hip": int(h), "v_mag": float(v), "screen_xy": [float(x), float(y)], "electrons": float(e), "peak_dn": int(d),
                   "on_screen": bool(o)}
                  for h, v, (x, y), e, d, o in zip(scene.stars.hip, scene.stars.v_mag, sf.stars_xy, sf.stars_electrons, sf.stars_peak_dn, on)],
        "bodies": sf.bodies,
        "clipped": {"too_bright_px": sf.clipped_bright_px, "too_faint_sources": sf.clipped_faint_sources},
        "black_pedestal_e_per_camera_px": sf.black_pedestal_e_per_camera_px,
    }
    return png_bytes(sf.dn, bit_depth=sc.bit_depth, compress_level=SCREEN_PNG_LEVEL), rec


#: zlib level of the screen PNGs (datasets.frame_files.write_png): screen frames hold ~2.5 times a
#: camera frame's pixels, nearly all black; level 1 writes them in a third of level 6's time.
SCREEN_PNG_LEVEL = 1

EXPORT_MANIFEST = "export.json"
EXPORT_SCHEMA = "skynav.hil_export/2"
FORMATS = ("png", "json")


def _export_one(job):
    """Make screen frame k (files, then the checksum record); returns ``(k, {relpath: sha256})``."""
    facility, root, out, k = job

    truth = read_checked_truth(Path(root), k)
    scene = scene_from_truth(truth)
    name = f"{k:06d}"
    write_screen_frame(facility, scene, out, name, source={"dataset": str(root), "frame": int(k)}, seed=k)
    files = {rel: sha256_file(Path(out) / rel) for rel in frame_relpaths(k, FORMATS).values()}
    # the checksum record is the frame's commit point (the frame JSON holds no timing, so a
    # frame's bytes depend on the source frame and the facility alone)
    return k, {**files, **write_record(out, k, files)}


#: the frame truth's lists of records, which a screen frame does not read
_RECORD_LISTS = ("stars", "bodies", "cosmic_rays")


def read_checked_truth(root: Path, k: int) -> dict:
    """Frame ``k``'s ground truth, checked against ``frame.schema.json`` (types included): an
    export consumes only frames that follow the published contract. One line naming the file and
    the first JSON path at fault.

    A screen frame is rebuilt from the scene sections (epoch, observer, attitude, camera,
    visibility), which are checked whole; of the record lists (stars, bodies, cosmic rays), which
    it does not read, the type and the first record are checked (validating a thousand stars
    would cost a sizeable part of a small screen frame); ``skynav dataset verify`` checks every
    record."""
    where = root / frame_relpaths(k, ("json",))["json"]
    try:
        truth = read_truth_json(where)
    except (OSError, ValueError) as exc:  # a file changed since the check before the run
        if isinstance(exc, SkynavError):
            raise DatasetError(f"{where}: {exc}") from None
        raise DatasetError(f"{where}: frame {k}'s truth is not readable ({exc.__class__.__name__}); "
                           "run skynav dataset verify") from None
    heads = {key: v[:1] for key in _RECORD_LISTS if type(v := truth.get(key)) is list}
    problems = schema_problems(dict(truth, **heads), FRAME_SCHEMA)
    if problems:
        more = f" (+{len(problems) - 1} more)" if len(problems) > 1 else ""
        raise TruthSchemaError(f"{where}: frame {k}'s truth does not follow {FRAME_SCHEMA}: {problems[0]}{more}; "
                               "run skynav dataset verify", problems)
    return truth


def _export_dask(k, *, facility, root, out):
    if "SKYNAV_THREADS" not in os.environ:
        # dask.distributed (the optional 'dask' extra) only with a Dask scheduler
        from distributed import get_worker

        os.environ["SKYNAV_THREADS"] = str(max(1, int(get_worker().state.nthreads)))
    return _export_one((facility, root, out, k))


#: the frame-truth keys a screen frame is rebuilt from
_SCENE_KEYS = ("epoch", "observer", "attitude", "camera")


def _check_scene_sections(truth: dict, where, k: int) -> None:
    """The truth sections a screen frame is rebuilt from, read as :func:`scene_from_truth` reads
    them (without the schema validator: a few microseconds a frame): one line naming the key."""
    def vector(section, key, shape):
        try:
            a = np.asarray(truth[section][key], dtype=float)
            ok = a.shape == shape and bool(np.all(np.isfinite(a)))
        except (KeyError, TypeError, ValueError):
            ok = False
        if not ok:
            raise TruthSchemaError(f"{where}: frame {k}'s truth: {section}.{key} is not {' x '.join(map(str, shape))} finite "
                                   "numbers (run skynav dataset verify)", [])

    try:
        t = epoch_tdb_seconds(truth["epoch"])
        ok = math.isfinite(t)
    except (SkynavError, KeyError, TypeError, ValueError, AttributeError):
        ok = False
    if not ok:
        raise TruthSchemaError(f"{where}: frame {k}'s truth: epoch is not readable (tdb_seconds_past_j2000 or tdb_iso; "
                               "run skynav dataset verify)", [])
    vector("observer", "position_km", (3,))
    vector("observer", "velocity_km_s", (3,))
    vector("attitude", "R_cam_icrs", (3, 3))
    vector("attitude", "angular_velocity_rad_s", (3,))
    if "visibility" in truth:
        try:
            VisibilityCriteria.from_dict(truth["visibility"])
        except (SkynavError, KeyError, TypeError, ValueError, AttributeError):
            raise TruthSchemaError(f"{where}: frame {k}'s truth: visibility is not readable (run skynav dataset verify)",
                                   []) from None
    v = truth.get("catalog_limiting_v_mag", 0.0)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise TruthSchemaError(f"{where}: frame {k}'s truth: catalog_limiting_v_mag = {v!r} is not a finite number", [])


def check_dataset_cameras(ds, facility, dataset_path) -> None:
    """Refuse a dataset the facility cannot show: a frame whose truth lacks what the screen frame
    is rebuilt from, or whose camera is not the facility's (the bench's camera must be the one the
    dataset was made for, as ``render --hil`` requires). One line naming the frame file."""
    seen = {}
    for k in range(len(ds)):
        truth = ds._read(k, dn=False)[0]
        where = Path(dataset_path) / "frames" / f"{k:06d}.json"
        if not isinstance(truth, dict) or any(key not in truth for key in _SCENE_KEYS):
            missing = [key for key in _SCENE_KEYS if not isinstance(truth, dict) or key not in truth]
            raise TruthSchemaError(f"{where}: frame {k}'s truth has no {', '.join(missing)}; a screen frame is rebuilt "
                                   f"from {', '.join(_SCENE_KEYS)} (run skynav dataset verify)", [])
        _check_scene_sections(truth, where, k)
        cam_d = truth["camera"]
        key = json.dumps(cam_d, sort_keys=True, default=str)
        if key not in seen:
            try:
                seen[key], extra = camera_from_record(cam_d)
                note_unknown_keys(dataset_path, extra, f"frame {k}'s camera", kind="camera")
            except (SkynavError, KeyError, TypeError, ValueError) as exc:
                raise TruthSchemaError(f"{where}: frame {k}'s camera cannot be read ({exc.__class__.__name__}: "
                                       f"{' '.join(str(exc).split())[:120]})", []) from None
        cam, fc = seen[key], facility.camera
        if cam != fc:
            diff = [f.name for f in dataclasses.fields(cam) if getattr(cam, f.name) != getattr(fc, f.name)]
            first = diff[0] if diff else "?"
            raise DatasetMismatchError(
                f"{dataset_path}: frame {k} was made with another camera than the facility's ({len(diff)} key(s) differ, "
                f"first camera.{first}: {repr(getattr(cam, first, '?'))[:40]} in the dataset, "
                f"{repr(getattr(fc, first, '?'))[:40]} in the facility; {cam.width}x{cam.height} px vs {fc.width}x{fc.height} px); export a dataset made with the "
                "facility's camera (dataset generate --set camera...), or a facility with the dataset's camera")


def facility_sha256(facility) -> str:
    """SHA-256 of the facility's canonical mapping (what a facility file holds)."""
    return hashlib.sha256(json.dumps(facility.to_mapping(), sort_keys=True, default=str).encode()).hexdigest()


def export_dataset(facility, dataset_path, out_dir, *, workers: int = 1, dask_scheduler: str | None = None,
                   client=None, progress=None) -> dict:
    """Export every frame of a dataset as a screen frame; complete frames already there are kept.

    Returns ``{"frames", "exported", "skipped", "workers", "executor"}``.

    Raises
    ------
    skynav.datasets.DatasetError
        Not a dataset; the folder holds an export of another dataset or facility
        (:class:`~skynav.datasets.errors.DatasetMismatchError`); another process is exporting
        into it (:class:`~skynav.datasets.lock.DatasetLockedError`); no Dask scheduler there.
    """
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise OutputFormatError(f"workers = {workers!r}: expected an integer >= 1")
    ds = open_dataset(dataset_path)
    if len(ds) == 0:
        raise DatasetError(f"{dataset_path}: holds no frames (its manifest says 0); there is nothing to export")
    root = str(Path(dataset_path).resolve())
    out = Path(out_dir)
    if out.resolve() == Path(root) or Path(root) in out.resolve().parents:
        raise OutputPathError(f"{out_dir}: inside the dataset {dataset_path}; export into another folder "
                              "(an export never writes into its dataset)")
    check_dataset_cameras(ds, facility, dataset_path)
    (out / "frames").mkdir(parents=True, exist_ok=True)
    ident = {"schema": EXPORT_SCHEMA,
             "dataset": {"path": root, "manifest_sha256": hashlib.sha256((Path(root) / MANIFEST_NAME).read_bytes()).hexdigest(),
                         "frames": len(ds)},
             "facility": {"name": facility.name, "sha256": facility_sha256(facility)},
             "png_scaling": PNG_SCALING, "significant_bits": int(facility.screen.bit_depth),
             "skynav_version": package_version()}
    with dataset_lock(out):
        clean_stale_temp_files(out)  # a run stopped mid-write (killed, Ctrl-C) left its temporary files
        mpath = out / EXPORT_MANIFEST
        proven = False  # the frames already there are of this dataset and facility
        if mpath.is_file():
            try:
                old = json.loads(mpath.read_bytes())
            except (OSError, ValueError):
                old = None
            if isinstance(old, dict):
                for what, a, b in (("file format", old.get("schema"), EXPORT_SCHEMA),
                                   ("source dataset", (old.get("dataset") or {}).get("manifest_sha256"),
                                    ident["dataset"]["manifest_sha256"]),
                                   ("facility", (old.get("facility") or {}).get("sha256"), ident["facility"]["sha256"]),
                                   ("skynav version", old.get("skynav_version"), ident["skynav_version"])):
                    if a != b:
                        raise DatasetMismatchError(
                            f"{out}: holds a screen export of another {what} ({EXPORT_MANIFEST}); "
                            f"export into a new folder, or delete this one to start again")
                proven = True
        atomic_write_bytes(mpath, json.dumps(dict(ident, complete=False), indent=1).encode())
        todo, checksums = [], {}
        for k in range(len(ds)):
            # without a readable export.json nothing proves which dataset and facility the frames
            # there came from (their records prove their bytes only): every frame is made again
            problem, files, record = frame_problem(out, k, FORMATS) if proven else ("unproven", None, None)
            if problem is None:
                checksums.update(files)
                checksums.update(record)
            else:
                todo.append(k)
        done = 0

        def accept(result):
            nonlocal done
            _, files = result
            checksums.update(files)
            done += 1
            if progress:
                progress(done, len(todo))

        jobs = [(facility, root, str(out), k) for k in todo]
        if dask_scheduler is not None or client is not None:
            n_workers, executor = _run_dask(jobs, accept, client, dask_scheduler)
        elif workers > 1 and len(jobs) > 1:
            n_workers, executor = _run_pool(jobs, accept, workers)
        else:
            for j in jobs:
                accept(_export_one(j))
            n_workers, executor = 1, "in-process"
        atomic_write_bytes(mpath, json.dumps(dict(ident, complete=True, checksums=dict(sorted(checksums.items()))),
                                             indent=1).encode())
    return {"frames": len(ds), "exported": len(todo), "skipped": len(ds) - len(todo), "workers": n_workers,
            "executor": executor}


def _run_pool(jobs, accept, n_workers):
    process_pool_map(_export_one, jobs, n_workers, accept=accept)
    return n_workers, "processes (spawn)"


def _run_dask(jobs, accept, client, address):
    own = client is None
    if own:
        client = connect_dask(address)
    try:
        # dask.distributed (the optional 'dask' extra) only with a Dask scheduler
        from distributed import as_completed

        n_workers = max(1, sum(w.get("nthreads", 1) for w in client.scheduler_info().get("workers", {}).values()))
        if jobs:
            facility, root, out = jobs[0][:3]
            fac_f = client.scatter(facility, broadcast=True)
            futs = client.map(_export_dask, [j[3] for j in jobs], facility=fac_f, root=root, out=out, pure=False)
            for fut in as_completed(futs):
                accept(fut.result())
        return n_workers, "dask"
    finally:
        if own:
            client.close()
