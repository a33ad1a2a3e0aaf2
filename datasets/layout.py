"""Dataset folder layout (docs/conventions.md "Files"): paths, manifest, index.

Adapter module: the one place that knows the folder layout::

    <dataset>/manifest.json        recipe, package version, master seed, camera, counts,
                                   SHA-256 of every file, "complete": true only when complete
    <dataset>/frames/NNNNNN.png    DN (uint8 / uint16 raw)
    <dataset>/frames/NNNNNN.exr    float32 electrons, irradiance_w_m2
    <dataset>/frames/NNNNNN.json   ground truth, schema skynav.frame/2 (+ "dataset" section)
    <dataset>/index.csv            one row per frame
    <dataset>/trajectory.csv       (sequences) the cruise, barycentric ICRS
    <dataset>/legs.csv             (sequences) the leg timeline
    <dataset>/trajectory.oem       (sequences, ccsds extra) the cruise as a CCSDS OEM
    <dataset>/attitude.aem         (sequences, ccsds extra) the frames' attitudes as a CCSDS AEM
    <dataset>/trajectory_oem.xml   (sequences, ccsds extra) the same OEM in XML
    <dataset>/attitude_aem.xml     (sequences, ccsds extra) the same AEM in XML

The manifest holds nothing that depends on how or when the dataset was made (no dates, hosts,
worker counts), so the same recipe gives byte-identical folders whatever the parallelism.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from importlib.metadata import version
from pathlib import Path

import numpy as np

from skynav.infra.atomic_files import atomic_write_bytes, sha256_file
from skynav.scenes.frames import dcm_to_radec_twist

from .errors import DatasetError, DatasetMismatchError, IncompleteDatasetError

__all__ = [
    "MANIFEST_SCHEMA",
    "MANIFEST_NAME",
    "INDEX_NAME",
    "FRAMES_DIR",
    "frame_stem",
    "frame_relpaths",
    "read_manifest",
    "write_manifest",
    "index_row",
    "index_csv_bytes",
    "package_version",
    "clean_stale_temp_files",
]

MANIFEST_SCHEMA = "skynav.dataset/1"
MANIFEST_NAME = "manifest.json"
INDEX_NAME = "index.csv"
FRAMES_DIR = "frames"
INDEX_COLUMNS = [
    "frame", "epoch_tdb", "jd_tdb", "x_km", "y_km", "z_km", "vx_km_s", "vy_km_s", "vz_km_s",
    "ra_deg", "dec_deg", "twist_deg", "boresight_sun_angle_deg", "stars_in_fov", "bodies_in_fov", "visible_bodies",
    "draws", "leg", "phase", "target", "files",
]


def package_version() -> str:
    """Installed version of the ``skynav`` distribution."""
    try:
        return version("skynav")
    except Exception:  # pragma: no cover - not installed
        return "unknown"


def frame_stem(k: int) -> str:
    """``NNNNNN`` (six digits, more if needed)."""
    return f"{int(k):06d}"


def frame_relpaths(k: int, formats) -> dict:
    """``{format: "frames/NNNNNN.<format>"}`` relative to the dataset root (POSIX separators)."""
    stem = frame_stem(k)
    return {fmt: f"{FRAMES_DIR}/{stem}.{fmt}" for fmt in formats}


def read_manifest(root) -> dict:
    """The manifest of a dataset folder (any completeness); clear errors otherwise."""
    root = Path(root)
    path = root / MANIFEST_NAME
    if not root.is_dir():
        raise DatasetError(f"{root}: no such dataset folder")
    if not path.is_file():
        raise IncompleteDatasetError(f"{root}: no {MANIFEST_NAME}; not a skynav dataset (or its generation never started)",
                                     path=str(root))
    try:
        m = json.loads(path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DatasetError(f"{path}: unreadable manifest ({exc.__class__.__name__}: {exc})") from None
    if not isinstance(m, dict) or m.get("schema") != MANIFEST_SCHEMA:
        got = m.get("schema") if isinstance(m, dict) else type(m).__name__
        raise DatasetError(f"{path}: schema is {got!r}, expected {MANIFEST_SCHEMA!r}")
    return m


def write_manifest(root, manifest: dict) -> None:
    """Write ``manifest.json`` atomically (sorted file table, 2-space indent, ASCII)."""
    m = dict(manifest)
    m["files"] = dict(sorted(m.get("files", {}).items()))
    data = (json.dumps(m, indent=2, ensure_ascii=True, allow_nan=False) + "\n").encode("ascii")
    atomic_write_bytes(Path(root) / MANIFEST_NAME, data)


def check_same_dataset(existing: dict, new: dict, root) -> None:
    """Refuse to resume into a folder that holds a different dataset (one line).

    The recipe, master seed, package version and PNG layout (``png_scaling``: absent before the
    PNGs were scaled to their full range) must be equal, and so must what fixes the bits
    beyond them: the render options (``render_options``, each option named with its old and new
    value) and the backends that run (``backends``: the resolved sensor backend and Mitsuba
    variant).
    """
    for key in ("recipe", "master_seed", "version", "png_scaling"):
        if existing.get(key) != new.get(key):
            detail = ""
            if key == "recipe" and isinstance(existing.get(key), dict) and isinstance(new.get(key), dict):
                diff = sorted(k for k in set(existing[key]) | set(new[key]) if existing[key].get(k) != new[key].get(k))
                detail = f" (differs at: {', '.join(diff)})"
            raise DatasetMismatchError(
                f"{root} holds a different dataset: its {key} differs{detail}; use a new folder or remove it")
    for key, what in (("render_options", "render option"), ("backends", "backend")):
        old, new_v = existing.get(key), new.get(key)
        if not isinstance(old, dict):
            raise DatasetMismatchError(
                f"{root} records no {key} (made by an older skynav); its bits cannot be matched: use a new folder")
        for name in sorted(set(old) | set(new_v)):
            if old.get(name) != new_v.get(name):
                raise DatasetMismatchError(
                    f"{root} was made with {what} {name} = {old.get(name)!r}, this run has {new_v.get(name)!r};"
                    f" the bits would differ: use the same {key.replace('_', ' ')} or a new folder")


def _fmt(x) -> str:
    if x is None:
        return ""
    if isinstance(x, float):
        return repr(float(x)) if math.isfinite(x) else ""
    return str(x)


def index_row(truth: dict, k: int, files: dict) -> dict:
    """One ``index.csv`` row from a frame's ground truth (numbers as ``repr``: exact)."""
    ds = truth.get("dataset", {}) or {}
    obs = truth["observer"]
    R = np.asarray(truth["attitude"]["R_cam_icrs"], dtype=float)
    ra, dec, tw = dcm_to_radec_twist(R)
    stars = truth.get("stars", []) or []
    bodies = truth.get("bodies", []) or []
    in_fov = [b["name"] for b in bodies if b.get("in_fov")]
    visible = [b["name"] for b in bodies if b.get("visible")]
    sun = truth.get("sun") if isinstance(truth.get("sun"), dict) else {}
    sun_angle = sun.get("boresight_angle_deg")
    n_stars = len(stars)  # the ground truth lists the stars in the field
    return {
        "frame": int(k),
        "epoch_tdb": truth["epoch"]["tdb_iso"],
        "jd_tdb": float(truth["epoch"]["jd_tdb"]),
        "x_km": float(obs["position_km"][0]), "y_km": float(obs["position_km"][1]), "z_km": float(obs["position_km"][2]),
        "vx_km_s": float(obs["velocity_km_s"][0]), "vy_km_s": float(obs["velocity_km_s"][1]),
        "vz_km_s": float(obs["velocity_km_s"][2]),
        "ra_deg": math.degrees(ra), "dec_deg": math.degrees(dec), "twist_deg": math.degrees(tw),
        "boresight_sun_angle_deg": float(sun_angle) if sun_angle is not None else None,
        "stars_in_fov": n_stars,
        "bodies_in_fov": ";".join(in_fov),
        "visible_bodies": ";".join(visible),
        "draws": ds.get("draws"),
        "leg": ds.get("leg"),
        "phase": ds.get("phase"),
        "target": ds.get("target"),
        "files": ";".join(sorted(files)),
    }


def index_csv_bytes(rows) -> bytes:
    """``index.csv`` content: header + rows sorted by frame, ``\\n`` line ends."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(INDEX_COLUMNS)
    for row in sorted(rows, key=lambda r: r["frame"]):
        w.writerow([_fmt(row.get(c)) for c in INDEX_COLUMNS])
    return buf.getvalue().encode("utf-8")


def read_index(root) -> list:
    """Rows of ``index.csv`` as dicts of strings."""
    with open(Path(root) / INDEX_NAME, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def clean_stale_temp_files(root) -> int:
    """Remove temp files left by killed writers (``.<name>.<pid>.<random>.tmp``); returns count."""
    n = 0
    for d in (Path(root), Path(root) / FRAMES_DIR):
        if not d.is_dir():
            continue
        for entry in os.scandir(d):
            if entry.name.startswith(".") and entry.name.endswith(".tmp") and entry.is_file():
                try:
                    os.unlink(entry.path)
                    n += 1
                except FileNotFoundError:
                    pass
    return n


def file_sha256(root, relpath: str) -> str:
    return sha256_file(Path(root) / relpath)
