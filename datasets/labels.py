"""The label set of a batch of frames for training: what a network learns from, taken from the
frames' ground truth (``skynav.frame/2``), as arrays padded to the batch's widest frame.

Core module (numpy only): :func:`collate` is shared by :func:`skynav.datasets.stream` (frames
rendered in memory) and the loaders of dataset folders (:mod:`skynav.datasets.shards`), so the
labels of a frame are the same arrays whichever way it reaches a training loop.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["LABELS", "collate"]

#: The label set of a batch (N frames; S: the most stars in view of a frame of the batch; B: the
#: bodies of the batch's frames). Padding: NaN for floats, -1 for integers, False for flags.
LABELS = {
    "frame": "(N,) int64: the frame's index in the recipe (its seed is SeedSequence([seed, frame]))",
    "image": "(N, H, W) uint8 or uint16: digital counts at the camera's bit depth, DN",
    "electrons": "(N, H, W) float32: expected electrons plus cosmic-ray charge, no noise, e- (electrons=True)",
    "star_count": "(N,) int64: stars in the field of view",
    "star_hip": "(N, S) int64: Hipparcos numbers (the star IDs)",
    "star_v_mag": "(N, S) float64: V magnitudes",
    "star_xy": "(N, S, 2) float64: apparent position at mid-exposure, px (x = column, y = row)",
    "star_centroid_xy": "(N, S, 2) float64: centre of light of the drawn (PSF-blurred, streaked) star, px; NaN: not drawn",
    "star_electrons": "(N, S) float64: expected charge over the exposure, e-",
    "q_cam_icrs": "(N, 4) float64: attitude quaternion, scalar first, v_cam = A(q) v_icrs",
    "body_names": "tuple of B str: the bodies, in the order of the body axes",
    "body_xy": "(N, B, 2) float64: apparent centre of each body at mid-exposure, px",
    "body_radius_px": "(N, B) float64: apparent radius, px (half the angular diameter)",
    "body_in_fov": "(N, B) bool: the body's centre is in the image",
    "body_visible": "(N, B) bool: visible by the recipe's visibility rule",
    "body_resolved": "(N, B) bool: drawn as a ray-traced disc rather than a point",
    "cosmic_ray_mask": "(N, H, W) bool: pixels charged by a cosmic ray",
    "truth": "list of N dict: the frame's full ground truth (skynav.frame/2, JSON types), as the dataset's JSON",
}

def _pad(rows, width: int, tail: tuple, fill, dtype) -> np.ndarray:
    """Rows of different lengths as one (len(rows), width, *tail) array padded with ``fill``."""
    out = np.full((len(rows), width, *tail), fill, dtype=dtype)
    for i, r in enumerate(rows):
        if len(r):
            out[i, :len(r)] = np.asarray(r, dtype=dtype).reshape(len(r), *tail)
    return out


def _float_rows(records_per_frame, key: str) -> list:
    return [[math.nan if r.get(key) is None else r[key] for r in recs] for recs in records_per_frame]


def _xy_rows(records_per_frame, key: str) -> list:
    return [[[math.nan if v is None else v for v in (r.get(key) or (None, None))] for r in recs]
            for recs in records_per_frame]


def _body_labels(truths) -> dict:
    names = tuple(dict.fromkeys(b["name"] for t in truths for b in t["bodies"]))
    col = {name: j for j, name in enumerate(names)}
    n, nb = len(truths), len(names)
    xy = np.full((n, nb, 2), np.nan)
    radius = np.full((n, nb), np.nan)
    flags = {key: np.zeros((n, nb), bool) for key in ("in_fov", "visible", "resolved")}
    for i, t in enumerate(truths):
        for b in t["bodies"]:
            j = col[b["name"]]
            xy[i, j] = [math.nan if v is None else v for v in b["xy"]]
            radius[i, j] = math.nan if b["angular_diameter_px"] is None else 0.5 * b["angular_diameter_px"]
            for key in flags:
                flags[key][i, j] = bool(b[key])
    return {"body_names": names, "body_xy": xy, "body_radius_px": radius,
            **{f"body_{key}": v for key, v in flags.items()}}


def collate(frames, ks, *, image=None) -> dict:
    """One batch mapping (:data:`LABELS`, numpy) of rendered frames (each with ``dn``,
    ``electrons`` or None, and a JSON-type ``truth``) and their indices ``ks``; ``image``: the
    batch's DN as they are (an array on a device), instead of the frames' ``dn`` stacked."""
    truths = [f["truth"] for f in frames]
    stars = [t["stars"] for t in truths]
    width = max((len(s) for s in stars), default=0)
    shape = (int(truths[0]["camera"]["height"]), int(truths[0]["camera"]["width"]))
    mask = np.zeros((len(frames), *shape), bool)
    for i, t in enumerate(truths):
        for hit in t["cosmic_rays"]:
            for row, col, _ in hit.get("pixels") or ():
                mask[i, int(row), int(col)] = True
    out = {
        "frame": np.asarray(ks, dtype=np.int64),
        "image": np.stack([f["dn"] for f in frames]) if image is None else image,
        "star_count": np.asarray([len(s) for s in stars], dtype=np.int64),
        "star_hip": _pad([[r["hip"] for r in s] for s in stars], width, (), -1, np.int64),
        "star_v_mag": _pad(_float_rows(stars, "v_mag"), width, (), np.nan, np.float64),
        "star_xy": _pad(_xy_rows(stars, "xy"), width, (2,), np.nan, np.float64),
        "star_centroid_xy": _pad(_xy_rows(stars, "centre_of_light_xy"), width, (2,), np.nan, np.float64),
        "star_electrons": _pad(_float_rows(stars, "electrons"), width, (), np.nan, np.float64),
        "q_cam_icrs": np.asarray([t["attitude"]["q_cam_icrs"] for t in truths], dtype=np.float64),
        **_body_labels(truths),
        "cosmic_ray_mask": mask,
        "truth": truths,
    }
    if frames[0].get("electrons") is not None:
        out["electrons"] = np.stack([f["electrons"] for f in frames])
    return out
