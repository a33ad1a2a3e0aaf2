"""Calibration patterns: phased dot grids with a fiducial constellation, flats and a dark.

Every dot sits on an integer screen pixel, so its drawn disc is symmetric and its centroid is
exactly its centre. Fiducials are dots 1.6x larger at grid nodes forming an asymmetric
constellation (no rotation maps it onto itself), so the identification cannot slip by a grid
step nor turn by 90 deg. ``patterns.json`` (``schema: skynav.patterns/2``) lists, per pattern, its
file, its dot centres (screen px, CONVENTIONS pixel centres) and, as extra keys, ``kind``
(``dots``, ``flat``, ``dark``), ``fiducials`` (indices into ``dots``), ``dot_radius_px``,
``grid_step_px`` and ``level_dn`` (screen DN), and at the top how the PNGs store the screen's DN
(``png_scaling``: ``"sbit"``, scaled to the PNG's full range with an ``sBIT`` chunk, and
``significant_bits``; written by :mod:`skynav.datasets.bench_files`). Version 1 (skynav <= 0.3.0)
had no such keys and stored the DN unscaled; both are read.
"""

from __future__ import annotations

import json
import math
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
    scale and a dark frame."""
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


def read_patterns(directory):
    """(screen dict, list of :class:`Pattern`) from ``DIR/patterns.json``."""
    path = Path(directory) / "patterns.json"
    if not path.is_file():
        raise CalibrationInputError(f"{path}: no patterns.json (make one with `skynav calibrate patterns FACILITY -o DIR`)")
    try:
        doc = json.loads(path.read_text())
        if doc.get("schema") not in READABLE_SCHEMAS:
            raise CalibrationInputError(f"{path}: schema {doc.get('schema')!r}; expected one of "
                                        f"{', '.join(map(repr, READABLE_SCHEMAS))}")
        pats = []
        for p in doc["patterns"]:
            dots = np.asarray(p.get("dots", []), dtype=float).reshape(-1, 2)
            kind = p.get("kind", "dots" if len(dots) else "flat")
            pats.append(Pattern(file=str(p["file"]), kind=kind, dots=dots, fiducials=tuple(int(i) for i in p.get("fiducials", ())),
                                dot_radius_px=float(p.get("dot_radius_px", 0.0)), grid_step_px=float(p.get("grid_step_px", 0.0)),
                                level_dn=int(p.get("level_dn", 0))))
        return doc["screen"], pats
    except (KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, CalibrationInputError):
            raise
        raise CalibrationInputError(f"{path}: malformed patterns file ({exc})") from None
