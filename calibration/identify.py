"""Identification of detected dots with the pattern's dots, robust to missing dots, extra blobs,
hot pixels, cosmic rays, a bench displaced by grid steps or rolled by any angle.

1. Fiducials (1.6x larger dots, an asymmetric constellation) are the blobs whose flux is well
   above the median of their neighbours'.
2. Every pairing of two detected fiducials with two pattern fiducials gives a similarity
   transform screen -> camera; a hypothesis must map >= 3 pattern fiducials onto detected ones
   and predict most blobs. The best hypothesis must beat the runner-up (a different placement)
   clearly, else the identification is ambiguous and refused.
3. Matching grows from the centre outwards with polynomials of rising degree (affine -> cubic),
   each match the unique mutual nearest neighbour within a fraction of a grid step.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .errors import IdentificationError


@dataclass(frozen=True)
class Matches:
    dot_index: np.ndarray   # (M,) indices into the pattern's dots
    xy_px: np.ndarray       # (M, 2) camera centroids
    fiducials_found: int


def _poly_terms(s, deg):
    x, y = s[:, 0], s[:, 1]
    cols = [np.ones_like(x)]
    for d in range(1, deg + 1):
        for i in range(d + 1):
            cols.append(x ** (d - i) * y ** i)
    return np.stack(cols, -1)


def _fit_poly(src, dst, deg, centre, scale):
    A = _poly_terms((src - centre) / scale, deg)
    coef, *_ = np.linalg.lstsq(A, dst, rcond=None)
    return lambda s: _poly_terms((np.asarray(s) - centre) / scale, deg) @ coef


def _mutual(pred, det, tol):
    if len(det) == 0 or len(pred) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    d1, j = cKDTree(det).query(pred, distance_upper_bound=tol)
    ok = np.isfinite(d1)
    i = np.flatnonzero(ok)
    j = j[ok]
    _, back = cKDTree(pred).query(det[j])
    keep = back == i
    return i[keep], j[keep]


def identify(dots_screen, fiducials, blobs, *, step_screen_px: float, cam_per_screen_px: float, image_size,
             name: str = "capture") -> Matches:
    """Match a pattern's dots (screen px) with a capture's blobs (camera px)."""
    det = blobs.xy_px
    n_det = len(det)
    step = step_screen_px * cam_per_screen_px
    if n_det < 20:
        raise IdentificationError(f"{name}: only {n_det} dots detected; is the pattern shown and the camera exposed?")
    fl = blobs.flux
    k = min(7, n_det - 1)
    _, nb = cKDTree(det).query(det, k + 1)
    ratio = fl / np.median(fl[nb[:, 1:]], axis=1)
    fid_det = np.flatnonzero(ratio > 1.8)
    fid_pat = np.asarray(fiducials, dtype=int)
    if len(fid_det) < 3 or len(fid_pat) < 3:
        raise IdentificationError(f"{name}: {len(fid_det)} fiducial dots found (need >= 3); the bench may not show the whole pattern")
    S = dots_screen[fid_pat]
    D = det[fid_det]
    tree_det = cKDTree(det)
    hyps = []
    for a, b in itertools.permutations(range(len(S)), 2):
        vs = S[b] - S[a]
        zs = complex(vs[0], vs[1])
        for c, d in itertools.permutations(range(len(D)), 2):
            vd = D[d] - D[c]
            m = complex(vd[0], vd[1]) / zs  # rotation + scale
            if not 0.8 < abs(m) / cam_per_screen_px < 1.25:
                continue
            # map all pattern fiducials; count those landing on detected fiducials
            zf = (S[:, 0] - S[a, 0]) + 1j * (S[:, 1] - S[a, 1])
            pf = zf * m + complex(D[c, 0], D[c, 1])
            pf = np.stack([pf.real, pf.imag], -1)
            dist = np.min(np.linalg.norm(pf[:, None, :] - D[None, :, :], axis=-1), axis=1)
            nf = int((dist < 0.3 * step).sum())
            if nf >= 3:
                hyps.append((nf, m, S[a], D[c]))
    if not hyps:
        raise IdentificationError(f"{name}: the fiducial constellation was not recognised (mirrored screen, or too few fiducials in view)")

    def place(h):
        _, m, s0, d0 = h
        z = (dots_screen[:, 0] - s0[0]) + 1j * (dots_screen[:, 1] - s0[1])
        p = z * m + complex(d0[0], d0[1])
        return np.stack([p.real, p.imag], -1)

    scored = []
    for h in hyps:
        p = place(h)
        d, _ = tree_det.query(p, distance_upper_bound=0.3 * step)
        scored.append((h[0] * 1000 + int(np.isfinite(d).sum()), p, h))
    scored.sort(key=lambda t: -t[0])
    best_score, best_p, best = scored[0]
    centre_img = np.array(image_size, dtype=float) / 2
    for sc, p, h in scored[1:]:
        # a different placement (not the same transform found from another fiducial pair)
        if np.median(np.linalg.norm(p - best_p, axis=-1)) > 0.3 * step and sc >= 0.9 * best_score:
            raise IdentificationError(f"{name}: ambiguous identification ({best[0]} and {h[0]} fiducials match two "
                                      "placements one or more grid steps apart); refusing to fit")
    pred = best_p
    # grow from the image centre with polynomials of rising degree
    r_img = np.hypot(*centre_img)
    centre_scr = dots_screen.mean(0)
    scale_scr = float(np.ptp(dots_screen, axis=0).max() / 2)
    i = j = None
    for frac, deg, tol in ((0.35, 1, 0.3), (0.6, 2, 0.3), (0.85, 3, 0.25), (1.5, 3, 0.2), (1.5, 3, 0.15)):
        near = np.linalg.norm(pred - centre_img, axis=-1) < frac * r_img
        i, j = _mutual(pred[near], det, tol * step)
        i = np.flatnonzero(near)[i]
        if len(i) < 3 * (deg + 1) * (deg + 2) // 2:
            raise IdentificationError(f"{name}: too few dots identified near the centre ({len(i)})")
        f = _fit_poly(dots_screen[i], det[j], deg, centre_scr, scale_scr)
        pred = f(dots_screen)
    i, j = _mutual(pred, det, 0.15 * step)
    return Matches(dot_index=i, xy_px=det[j], fiducials_found=int(best[0]))
