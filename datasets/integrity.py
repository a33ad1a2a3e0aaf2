"""Checking and summarising dataset folders: :func:`verify` and :func:`info`.

Driver module (``skynav dataset verify`` / ``skynav dataset info``). :func:`verify` re-reads every
file: the manifest against ``manifest.schema.json``, SHA-256 against the manifest, every frame's
files present, ground truth parsed and checked against ``frame.schema.json`` (JSON Schema, with
``jsonschema``: :mod:`skynav.datasets.truth_schema`), every image decoded (PNG, EXR), counts (manifest, recipe, index rows, files
on disk). Each problem is one line naming the file (and, for a schema violation, the JSON path:
``frames/000003.json: does not follow skynav.frame/2: $.attitude.q_cam_icrs: missing``).
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from tqdm.auto import tqdm

from skynav.infra.atomic_files import sha256_file
from skynav.infra.errors import SkynavError
from skynav.scenes.camera import Camera

from . import layout
from .errors import DatasetError
from .journal import RECORD_EXT, decode_problem, record_relpath
from .truth_schema import FRAME_SCHEMA, schema_problems, validate_manifest

__all__ = ["VerifyReport", "verify", "info"]


@dataclass(frozen=True, kw_only=True)
class VerifyReport:
    """Outcome of :func:`verify`.

    Attributes
    ----------
    path : str
        The dataset folder.
    ok : bool
        No problem found.
    problems : list of str
        One line each, e.g. ``frames/000003.png: SHA-256 mismatch (file altered or corrupt)``.
    files_checked : int
        Files whose checksum (and decoding) was checked.
    frames : int
        Frames the manifest lists.

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
    >>> from skynav.datasets import verify
    >>> report = verify(tmp.name + "/ds")
    >>> report.ok, report.frames, report.problems
    (True, 2, [])
    >>> tmp.cleanup()
    """

    path: str
    ok: bool
    problems: list = field(default_factory=list)
    files_checked: int = 0
    frames: int = 0

    def lines(self) -> list:
        """The report as printable lines: a head line (OK or FAILED, counts), then the problems."""
        head = f"{self.path}: {'OK' if self.ok else 'FAILED'} ({self.frames} frames, {self.files_checked} files checked"
        head += ")" if self.ok else f", {len(self.problems)} problem(s))"
        return [head] + self.problems


def verify(path, *, check_schema: bool = True, progress=False) -> VerifyReport:
    """Check a dataset folder against its manifest; never raises for a damaged dataset.

    Every file's SHA-256 against the manifest's, every file decoded (PNG, EXR, JSON, FITS),
    ``index.csv`` against the frames, and (``check_schema``) the JSON Schemas.

    Parameters
    ----------
    path : str or os.PathLike
        The dataset folder.
    check_schema : bool
        Validate the manifest and every ground-truth JSON against their published JSON Schema
        (slower; on by default).
    progress : bool
        Show a tqdm bar over the files.

    Returns
    -------
    VerifyReport
        ``ok`` and one line per problem (a damaged dataset is reported, not raised).

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
    >>> from pathlib import Path
    >>> from skynav.datasets import verify
    >>> png = Path(tmp.name) / "ds" / "frames" / "000001.png"
    >>> png.write_bytes(png.read_bytes()[:100])   # truncate a frame
    100
    >>> report = verify(tmp.name + "/ds")
    >>> report.ok, report.problems[0].split(":")[0]
    (False, 'frames/000001.png')
    >>> tmp.cleanup()
    """
    root = Path(path)
    try:
        m = layout.read_manifest(root)
    except DatasetError as exc:
        return VerifyReport(path=str(root), ok=False, problems=[str(exc)])
    problems = _manifest_problems(m, check_schema)
    files, formats = m.get("files", {}), m.get("formats", [])
    n = int(m.get("counts", {}).get("frames", 0))
    # datasets made since per-frame checksum records exist list them in the manifest
    has_records = any(rel.endswith("." + RECORD_EXT) for rel in files)
    expected = set()
    for k in range(n):
        expected.update(layout.frame_relpaths(k, formats).values())
        if has_records:
            expected.add(record_relpath(k))
    missing: dict = {}  # frame stem -> missing file names (one line per frame)
    for rel in sorted(expected - set(files)):
        if (root / rel).is_file():
            problems.append(f"{rel}: not recorded in the manifest")
        else:
            missing.setdefault(rel.rsplit(".", 1)[0], []).append(rel)
    checked = 0
    for rel in (tqdm(sorted(files), unit="file", desc="verify") if progress else sorted(files)):
        if not (root / rel).is_file():
            missing.setdefault(rel.rsplit(".", 1)[0], []).append(rel)
            continue
        checked += 1
        why = _file_problem(root / rel, rel, files[rel], check_schema)
        if why is not None:
            problems.append(f"{rel}: {why}")
    problems += _missing_lines(missing, formats)
    problems += _stray_and_index_lines(root, expected, n, m.get("complete") is True)
    return VerifyReport(path=str(root), ok=not problems, problems=problems, files_checked=checked, frames=n)


def _manifest_problems(m: dict, check_schema: bool) -> list:
    """The manifest's own problems: its schema, completeness, and its frame count against the recipe."""
    problems = []
    if check_schema:
        bad = validate_manifest(m)
        if bad:
            more = f" (+{len(bad) - 1} more)" if len(bad) > 1 else ""
            problems.append(f"{layout.MANIFEST_NAME}: does not follow {layout.MANIFEST_SCHEMA}: {bad[0]}{more}")
    if m.get("complete") is not True:
        c = m.get("counts", {})
        problems.append(f"{layout.MANIFEST_NAME}: not complete ({c.get('frames_done')} of {c.get('frames')} frames)")
    n = int(m.get("counts", {}).get("frames", 0))
    recipe = m.get("recipe", {})
    if recipe.get("kind") == "montecarlo" and recipe.get("frames") != n:
        problems.append(f"{layout.MANIFEST_NAME}: counts.frames = {n} but the recipe asks for {recipe.get('frames')}")
    return problems


def _file_problem(p: Path, rel: str, sha: str, check_schema: bool):
    """What is wrong with one recorded file (its checksum ``sha``), or None."""
    sha_ok = sha256_file(p) == sha
    if rel.endswith(".json"):
        # JSON first: a truncated file is named as such (its checksum differs too)
        why = decode_problem(p)
        if why is not None:
            return why
        if check_schema:
            truth = json.loads(p.read_bytes().decode("utf-8"))
            bad = schema_problems(truth, FRAME_SCHEMA)  # plain JSON already: no conversion
            if bad:
                more = f" (+{len(bad) - 1} more)" if len(bad) > 1 else ""
                return f"does not follow {FRAME_SCHEMA}: {bad[0]}{more}"
    if not sha_ok:
        return "SHA-256 mismatch (file altered or corrupt)"
    # an image whose damaged bytes were checksummed (a disk that filled, a node that died
    # before per-frame records existed) still fails to decode: decode every image
    if not rel.endswith((".json", "." + RECORD_EXT)):
        return decode_problem(p)
    return None


def _missing_lines(missing: dict, formats) -> list:
    """One line per frame with missing files (``frame missing`` when all are), one per other file."""
    out = []
    for stem, rels in sorted(missing.items()):
        if stem.startswith(layout.FRAMES_DIR + "/"):
            k = int(stem.split("/")[-1])
            data = [r for r in rels if not r.endswith("." + RECORD_EXT)]
            what = "frame missing" if len(data) == len(formats) else "missing " + ", ".join(r.rsplit("/", 1)[-1] for r in rels)
            out.append(f"frame {k} ({stem}.*): {what}")
        else:
            out.extend(f"{r}: missing" for r in rels)
    return out


def _stray_and_index_lines(root: Path, expected: set, n: int, complete: bool) -> list:
    """Stray frame files (e.g. from a different run: reported, not fatal) and the index's rows."""
    out = []
    fdir = root / layout.FRAMES_DIR
    if fdir.is_dir():
        for p in sorted(fdir.iterdir()):
            rel = f"{layout.FRAMES_DIR}/{p.name}"
            if rel not in expected and not p.name.startswith("."):
                out.append(f"{rel}: unexpected file (not part of the dataset)")
    if (root / layout.INDEX_NAME).is_file():
        try:
            rows = layout.read_index(root)
            if len(rows) != n:
                out.append(f"{layout.INDEX_NAME}: {len(rows)} rows, expected {n}")
        except Exception as exc:  # noqa: BLE001 - any parse failure is a problem line
            out.append(f"{layout.INDEX_NAME}: unreadable ({exc.__class__.__name__})")
    elif complete:
        out.append(f"{layout.INDEX_NAME}: missing")
    return out


def info(path) -> dict:
    """Summary of a dataset for a table: ``{"rows": [(field, value), ...], ...}``.

    Works on incomplete datasets too (it says so). Values are strings ready to print.

    Parameters
    ----------
    path : str or os.PathLike
        The dataset folder.

    Returns
    -------
    dict
        ``rows``: (field, value) pairs of strings (kind, frames, seed, camera, formats, ...,
        with units in the values), and further keys for the command line's table.

    Raises
    ------
    DatasetError
        No dataset there, or a manifest or ``index.csv`` too damaged to summarise (one line
        naming the file; ``verify`` says more).

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
    >>> from skynav.datasets import info
    >>> rows = dict(info(tmp.name + "/ds")["rows"])
    >>> isinstance(rows, dict) and all(isinstance(v, str) for v in rows.values())
    True
    >>> tmp.cleanup()
    """
    root = Path(path)
    m = layout.read_manifest(root)
    try:
        return _info(root, m)
    except SkynavError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError, IndexError, OSError, _csv_error()) as exc:
        what = f"missing key {exc}" if isinstance(exc, KeyError) else exc.__class__.__name__
        bad = layout.INDEX_NAME if isinstance(exc, (OSError, _csv_error(), UnicodeDecodeError)) else layout.MANIFEST_NAME
        raise DatasetError(f"{root / bad}: damaged, cannot summarise ({what}); run `skynav dataset verify`") from None


def _csv_error():
    return csv.Error


def _info(root: Path, m: dict) -> dict:
    r = m["recipe"]
    cam = Camera.from_dict(m["camera"])
    c = m.get("counts", {})
    size = sum((root / rel).stat().st_size for rel in m.get("files", {}) if (root / rel).is_file())
    rows = [
        ("path", str(root)),
        ("kind", r["kind"] + (f" ({r['name']})" if r.get("name") else "")),
        ("complete", "yes" if m.get("complete") else f"no ({c.get('frames_done')} of {c.get('frames')} frames)"),
        ("frames", str(c.get("frames"))),
        ("master seed", str(m.get("master_seed"))),
        ("skynav version", str(m.get("version"))),
        ("camera", f"{cam.width} x {cam.height} px, FOV {math.degrees(cam.fov_x_rad):.2f} deg, "
                   f"f/{cam.f_number:g}, {cam.exposure_s:g} s, {cam.sensor.bit_depth}-bit"),
        ("formats", ", ".join(m.get("formats", []))),
        ("size", f"{size / 1e6:.1f} MB in {len(m.get('files', {}))} files"),
    ]
    if "scenes_drawn" in c:
        frac = c["scenes_kept"] / c["scenes_drawn"] if c["scenes_drawn"] else math.nan
        rows.append(("scenes drawn / kept", f"{c['scenes_drawn']} / {c['scenes_kept']} ({100 * frac:.1f} % kept)"))
    plan = m.get("plan", {})
    if "transfer" in plan:
        t = plan["transfer"]
        rows.append(("transfer", f"Earth {t['departure_tdb'][:10]} -> Mars {t['arrival_tdb'][:10]} "
                                 f"({t['tof_days']:.0f} d, v_inf {t['v_inf_departure_km_s']:.2f} / {t['v_inf_arrival_km_s']:.2f} km/s)"))
        rows.append(("cruise", f"{plan['cruise_start_tdb'][:16]} .. {plan['cruise_end_tdb'][:16]} TDB"))
        rows.append(("pairs", ", ".join("/".join(p) for p in plan.get("pairs", []))))
    visible = {}
    epochs = []
    if (root / layout.INDEX_NAME).is_file():
        for row in layout.read_index(root):
            epochs.append(row["epoch_tdb"])
            for name in filter(None, row["visible_bodies"].split(";")):
                visible[name] = visible.get(name, 0) + 1
    if epochs:
        rows.append(("epochs (TDB)", f"{min(epochs)} .. {max(epochs)}"))
        rows.append(("frames with a visible body", ", ".join(f"{k} {v}" for k, v in sorted(visible.items(), key=lambda x: -x[1])) or "none"))
    return {"rows": rows, "manifest": m}
