"""Calibration patterns: phased dot grids with a fiducial constellation, flats and a dark.

Every dot sits on an integer screen pixel, so its drawn disc is symmetric and its centroid is
exactly its centre. Fiducials are dots 1.6x larger at grid nodes forming an asymmetric
constellation (no rotation maps it onto itself), so the identification cannot slip by a grid
step nor turn by 90 deg. ``patterns.json`` (``schema: skynav.patterns/2``) lists, per pattern, its
file, its dot centres (screen px, CONVENTIONS pixel centres) and, as extra keys, ``kind``
(``dots``, ``flat``, ``dark``), ``fiducials`` (indices into ``dots``), ``dot_radius_px``,
``grid_step_px`` and ``level_dn`` (screen DN), and at the top how the PNGs store the screen's DN
(``png_scaling``: ``"sbit"``, scaled to the PNG's full range with an ``sBIT`` chunk, and
``significant_bits``; written by :mod:`skynav.calibration.bench_files`). Version 1 (skynav <= 0.3.0)
had no such keys and stored the DN unscaled; both are read.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skynav.scenes.facility import Facility

from .errors import CalibrationInputError

SCHEMA = "skynav.patterns/2"
#: versions :func:`read_patterns` reads (1: PNGs of unscaled DN; 2: ``png_scaling`` says how)
READABLE_SCHEMAS = ("skynav.patterns/1", SCHEMA)
#: grid-node offsets (columns, rows) of the fiducials from the node nearest the screen centre
FIDUCIAL_NODES = ((0, 0), (3, 0), (0, 2), (-4, -3), (5, -5), (-2, 5), (-6, 2))
#: most grid phases per axis (``phases**2`` dot grids, each a screen-sized PNG and a capture; 8
#: gives 64, minutes of capture on the full-size bench)
MAX_PHASES = 8
#: fewest dots a grid may hold (the fit needs >= 50 over all grids, the fiducials several)
MIN_DOTS = 16


@dataclass(frozen=True)
class Pattern:
    file: str
    kind: str
    dots: np.ndarray          # (N, 2) screen px
    fiducials: tuple           # indices into dots
    dot_radius_px: float
    grid_step_px: float
    level_dn: int

    def to_json(self) -> dict:
        return {"file": self.file, "dots": self.dots.tolist(), "kind": self.kind, "fiducials": list(self.fiducials),
                "dot_radius_px": self.dot_radius_px, "grid_step_px": self.grid_step_px, "level_dn": self.level_dn}


def design(facility: Facility, *, phases: int = 3, flat_levels=(0.5, 0.8, 1.0)) -> list[Pattern]:
    """The pattern set of a facility: ``phases**2`` dot grids, flats at ``flat_levels`` of full
    scale and a dark frame.

    Raises
    ------
    CalibrationInputError
        ``phases`` outside 1..:data:`MAX_PHASES`; a screen too small for a dot grid (fewer than
        :data:`MIN_DOTS` dots per grid).
    """
    if isinstance(phases, bool) or not isinstance(phases, int) or not 1 <= phases <= MAX_PHASES:
        raise CalibrationInputError(f"phases = {phases!r}: expected an integer in 1..{MAX_PHASES} (phases**2 dot grids; "
                                    f"{MAX_PHASES} gives {MAX_PHASES ** 2}, each a screen-sized PNG and a capture)")
    sc = facility.screen
    cam = facility.camera
    scale = facility.geometric.focal_length_mm / (sc.pixel_pitch_um * 1e-3) / cam.focal_length_px  # screen px per camera px
    step = int(round(max(16.0, cam.width / 40.0) * scale))
    radius = max(2.0, round(2.5 * scale, 1))
    # dots at about 0.8 of the camera's full well, through the nominal curve
    e_target = 0.8 * cam.sensor.full_well_e
    per_cam_px_per_dn = facility.electrons_per_s_per_w_m2() * cam.exposure_s * scale ** 2
    level = int(np.clip(np.round(facility.radiometric.digital_count(facility.radiometric.black_w_m2 + e_target / per_cam_px_per_dn)),
                        1, sc.max_dn))
    cxn, cyn = (sc.width_px - 1) // 2, (sc.height_px - 1) // 2
    out = []
    for k in range(phases * phases):
        ox = int(round((k % phases) * step / phases))
        oy = int(round((k // phases) * step / phases))
        xs = np.arange(cxn + ox - step * (cxn // step + 1), sc.width_px, step)
        ys = np.arange(cyn + oy - step * (cyn // step + 1), sc.height_px, step)
        margin = math.ceil(1.6 * radius) + 2
        xs = xs[(xs >= margin) & (xs <= sc.width_px - 1 - margin)]
        ys = ys[(ys >= margin) & (ys <= sc.height_px - 1 - margin)]
        X, Y = np.meshgrid(xs, ys)
        dots = np.stack([X.ravel(), Y.ravel()], -1).astype(float)
        fid = []
        for i, j in FIDUCIAL_NODES:
            p = np.array([cxn + ox + i * step, cyn + oy + j * step], dtype=float)
            hit = np.flatnonzero(np.all(dots == p, axis=1))
            if hit.size:
                fid.append(int(hit[0]))
        if len(dots) < MIN_DOTS:
            raise CalibrationInputError(f"the {sc.width_px}x{sc.height_px} px screen holds {len(dots)} dots per grid at a step "
                                        f"of {step} screen px (from the camera's {cam.width} px width and the collimator); "
                                        f"need >= {MIN_DOTS}: a larger screen (screen.width_px, height_px) or pitch")
        out.append(Pattern(file=f"dots_{k:02d}.png", kind="dots", dots=dots, fiducials=tuple(fid), dot_radius_px=float(radius),
                           grid_step_px=float(step), level_dn=level))
    for f in flat_levels:
        out.append(Pattern(file=f"flat_{int(round(f * 100)):03d}.png", kind="flat", dots=np.zeros((0, 2)), fiducials=(),
                           dot_radius_px=0.0, grid_step_px=0.0, level_dn=int(round(f * level))))
    out.append(Pattern(file="dark.png", kind="dark", dots=np.zeros((0, 2)), fiducials=(), dot_radius_px=0.0, grid_step_px=0.0, level_dn=0))
    return out


def draw(pattern: Pattern, width: int, height: int, bit_depth: int) -> np.ndarray:
    """The pattern image, DN, uint8 (bit depth <= 8) or uint16."""
    dtype = np.uint8 if bit_depth <= 8 else np.uint16
    img = np.zeros((height, width), dtype=dtype)
    if pattern.kind == "flat":
        img[:] = pattern.level_dn
        return img
    fid = set(pattern.fiducials)
    for i, (x, y) in enumerate(pattern.dots):
        r = pattern.dot_radius_px * (1.6 if i in fid else 1.0)
        n = int(math.ceil(r)) + 1
        xi, yi = int(x), int(y)
        dy, dx = np.mgrid[-n:n + 1, -n:n + 1]
        # 4x4 sub-samples per pixel give a symmetric anti-aliased disc (the dot is on a pixel centre)
        sub = (np.arange(4) + 0.5) / 4 - 0.5
        cover = np.zeros(dx.shape)
        for sy in sub:
            for sx in sub:
                cover += ((dx + sx) ** 2 + (dy + sy) ** 2 <= r * r)
        cover /= 16.0
        y0, x0 = yi - n, xi - n
        ys, xs = slice(max(y0, 0), min(y0 + 2 * n + 1, height)), slice(max(x0, 0), min(x0 + 2 * n + 1, width))
        patch = np.round(cover * pattern.level_dn)[ys.start - y0:ys.stop - y0, xs.start - x0:xs.stop - x0].astype(dtype)
        img[ys, xs] = np.maximum(img[ys, xs], patch)
    return img


#: most patterns a set may hold (``calibrate patterns --phases 8`` writes 68)
MAX_PATTERNS = 1024
#: most dots a pattern may list (a grid step of 16 px on an 8192 px screen: ~262 000)
MAX_DOTS = 1 << 20
KINDS = ("dots", "flat", "dark")


def _bad(path, where, value, allowed):
    text = repr(value)
    return CalibrationInputError(f"{path}: {where} = {text if len(text) <= 60 else text[:57] + '...'} is not allowed; "
                                 f"expected {allowed}")


def check_pattern_file_name(name, path, where) -> str:
    """A pattern's ``file``: a plain ``*.png`` name inside the pattern folder (no folder part, not
    hidden, not ``..``), so no path read from ``patterns.json`` leaves its folder."""
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,99}\.png", name) or ".." in name:
        raise _bad(path, where, name, "a plain file name ending .png, inside the pattern folder (letters, digits, _ . -; "
                   "no folder, not hidden)")
    return name


def read_patterns(directory):
    """(screen dict, list of :class:`Pattern`) from ``DIR/patterns.json``, every key checked.

    Raises
    ------
    CalibrationInputError
        One line naming the file and the key (``patterns[3].dots[7]``).
    """
    path = Path(directory) / "patterns.json"
    if not Path(directory).is_dir():
        raise CalibrationInputError(f"{directory}: no such pattern folder (make one with `skynav calibrate patterns "
                                    "FACILITY -o DIR`)")
    if not path.is_file():
        raise CalibrationInputError(f"{path}: no patterns.json (make one with `skynav calibrate patterns FACILITY -o DIR`)")
    try:
        doc = json.loads(path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise CalibrationInputError(f"{path}: not a JSON patterns file ({exc.__class__.__name__})") from None
    if not isinstance(doc, dict):
        raise _bad(path, "the file", type(doc).__name__, "a JSON object")
    if doc.get("schema") not in READABLE_SCHEMAS:
        raise CalibrationInputError(f"{path}: schema {doc.get('schema')!r}; expected one of "
                                    f"{', '.join(map(repr, READABLE_SCHEMAS))}")
    screen = doc.get("screen")
    if not isinstance(screen, dict):
        raise _bad(path, "screen", screen, "a mapping with width_px, height_px, bit_depth")
    for key, lo, hi in (("width_px", 16, 1 << 16), ("height_px", 16, 1 << 16), ("bit_depth", 1, 16)):
        v = screen.get(key)
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            raise _bad(path, f"screen.{key}", v, f"an integer in {lo}..{hi}")
    width, height, max_dn = screen["width_px"], screen["height_px"], (1 << screen["bit_depth"]) - 1
    items = doc.get("patterns")
    if not isinstance(items, list) or not 1 <= len(items) <= MAX_PATTERNS:
        raise _bad(path, "patterns", items if not isinstance(items, list) else f"{len(items)} patterns",
                   f"a list of 1 to {MAX_PATTERNS} patterns")
    pats, seen = [], set()
    for i, p in enumerate(items):
        where = f"patterns[{i}]"
        if not isinstance(p, dict):
            raise _bad(path, where, p, "a mapping (file, dots, kind, ...)")
        file = check_pattern_file_name(p.get("file"), path, f"{where}.file")
        if file in seen:
            raise _bad(path, f"{where}.file", file, "a file name no other pattern uses")
        seen.add(file)
        raw = p.get("dots", [])
        if not isinstance(raw, list) or len(raw) > MAX_DOTS:
            raise _bad(path, f"{where}.dots", raw, f"a list of at most {MAX_DOTS} [x, y] pairs")
        for j, xy in enumerate(raw):
            if not (isinstance(xy, list) and len(xy) == 2 and all(isinstance(c, (int, float)) and not isinstance(c, bool)
                                                                 and math.isfinite(c) for c in xy)
                    and -0.5 <= xy[0] <= width - 0.5 and -0.5 <= xy[1] <= height - 0.5):
                raise _bad(path, f"{where}.dots[{j}]", xy, f"[x, y] screen px on the {width}x{height} screen")
        dots = np.asarray(raw, dtype=float).reshape(-1, 2)
        kind = p.get("kind", "dots" if len(dots) else "flat")
        if kind not in KINDS:
            raise _bad(path, f"{where}.kind", kind, "one of: " + ", ".join(KINDS))
        if kind == "dots" and not len(dots):
            raise _bad(path, f"{where}.dots", raw, "at least one dot in a 'dots' pattern")
        fid = p.get("fiducials", [])
        if not isinstance(fid, list) or any(isinstance(k, bool) or not isinstance(k, int) or not 0 <= k < len(dots)
                                            for k in fid) or len(set(fid)) != len(fid):
            raise _bad(path, f"{where}.fiducials", fid, f"distinct indices into dots (0..{len(dots) - 1})")
        nums = {}
        for key, lo, hi in (("dot_radius_px", 0.0, 256.0), ("grid_step_px", 0.0, float(max(width, height))),
                            ("level_dn", 0, max_dn)):
            v = p.get(key, 0)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi \
                    or (key == "level_dn" and v != int(v)):
                raise _bad(path, f"{where}.{key}", v, f"{'an integer' if key == 'level_dn' else 'a number'} in {lo:g}..{hi:g}")
            nums[key] = v
        if kind == "dots" and not nums["dot_radius_px"] > 0:
            raise _bad(path, f"{where}.dot_radius_px", nums["dot_radius_px"], "> 0 in a 'dots' pattern")
        pats.append(Pattern(file=file, kind=kind, dots=dots, fiducials=tuple(fid), dot_radius_px=float(nums["dot_radius_px"]),
                            grid_step_px=float(nums["grid_step_px"]), level_dn=int(nums["level_dn"])))
    return screen, pats
