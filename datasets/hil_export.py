"""Export frames as bench screen frames: ``DIR/frames/NNNNNN.png`` (screen resolution and bit
depth) + ``NNNNNN.json`` (``schema: skynav.hil_frame/1``: the source frame, where each source was
placed on the screen, its intended electrons and peak DN, what was clipped), resumable (a frame
whose PNG and JSON exist is skipped) and parallel over local processes.

The scene of each source frame is rebuilt from its ground truth (epoch, observer, attitude,
camera, visibility, catalogue limit) and drawn by :func:`skynav.renderer.display.screen_frame`.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from .frame_files import atomic_write_bytes, write_png

SCHEMA = "skynav.hil_frame/1"


def scene_from_truth(truth: dict):
    from skynav.scenes.camera import Camera
    from skynav.scenes.scene import build_scene
    from skynav.scenes.visibility import VisibilityCriteria

    from .frame_truth import epoch_tdb_seconds

    kw = {}
    if "visibility" in truth:
        kw["visibility"] = VisibilityCriteria.from_dict(truth["visibility"])
    if "catalog_limiting_v_mag" in truth:
        kw["catalog_limiting_v_mag"] = float(truth["catalog_limiting_v_mag"])
    return build_scene(epoch_tdb_seconds(truth["epoch"]), position_km=np.array(truth["observer"]["position_km"]),
                       velocity_km_s=np.array(truth["observer"]["velocity_km_s"]), R_cam_icrs=np.array(truth["attitude"]["R_cam_icrs"]),
                       camera=Camera.from_dict(truth["camera"]), angular_velocity_rad_s=truth["attitude"]["angular_velocity_rad_s"], **kw)


def write_screen_frame(facility, scene, out_dir, name: str, *, source: dict, seed: int = 0, options=None) -> dict:
    """Render and write one screen frame; returns its JSON record."""
    from skynav.renderer.display import screen_frame

    t0 = time.perf_counter()
    sf = screen_frame(scene, facility, rng=np.random.default_rng(seed), options=options)
    frames = Path(out_dir) / "frames"
    frames.mkdir(parents=True, exist_ok=True)
    sc = facility.screen
    on = facility.projection.in_screen(sf.stars_xy) if len(sf.stars_xy) else np.zeros(0, bool)
    rec = {
        "schema": SCHEMA,
        "source": source,
        "facility": {"name": facility.name, "screen": {"width_px": sc.width_px, "height_px": sc.height_px, "bit_depth": sc.bit_depth},
                     "geometric_fit": (facility.calibrated_geometric or {}).get("fit"),
                     "radiometric_fit": (facility.calibrated_radiometric or {}).get("fit")},
        "pixel_convention": "screen px: x = column, y = row, centre of the top-left pixel at (0, 0)",
        "stars": [{"hip": int(h), "v_mag": float(v), "screen_xy": [float(x), float(y)], "electrons": float(e), "peak_dn": int(d),
                   "on_screen": bool(o)}
                  for h, v, (x, y), e, d, o in zip(scene.stars.hip, scene.stars.v_mag, sf.stars_xy, sf.stars_electrons, sf.stars_peak_dn, on)],
        "bodies": sf.bodies,
        "clipped": {"too_bright_px": sf.clipped_bright_px, "too_faint_sources": sf.clipped_faint_sources},
        "black_pedestal_e_per_camera_px": sf.black_pedestal_e_per_camera_px,
        "seconds": round(time.perf_counter() - t0, 3),
    }
    write_png(frames / f"{name}.png", sf.dn, bit_depth=sc.bit_depth)
    atomic_write_bytes(frames / f"{name}.json", json.dumps(rec, indent=1).encode())
    return rec


def _export_one(job):
    facility, root, out, k, path_png = job
    from . import open_dataset

    ds = open_dataset(root)
    truth = ds[k].truth  # the raw ground-truth dict
    scene = scene_from_truth(truth)
    name = f"{k:06d}"
    write_screen_frame(facility, scene, out, name, source={"dataset": str(root), "frame": int(k)}, seed=k)
    return k


def export_dataset(facility, dataset_path, out_dir, *, workers: int = 1, progress=None) -> dict:
    """Export every frame of a dataset; frames already exported are skipped (resume)."""
    from . import open_dataset

    ds = open_dataset(dataset_path)
    out = Path(out_dir)
    (out / "frames").mkdir(parents=True, exist_ok=True)
    todo = [k for k in range(len(ds)) if not ((out / "frames" / f"{k:06d}.png").is_file() and (out / "frames" / f"{k:06d}.json").is_file())]
    jobs = [(facility, str(dataset_path), str(out), k, None) for k in todo]
    done = 0
    if workers > 1 and len(jobs) > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(workers) as ex:
            for _ in ex.map(_export_one, jobs):
                done += 1
                if progress:
                    progress(done, len(jobs))
    else:
        for j in jobs:
            _export_one(j)
            done += 1
            if progress:
                progress(done, len(jobs))
    return {"frames": len(ds), "exported": len(jobs), "skipped": len(ds) - len(jobs)}
