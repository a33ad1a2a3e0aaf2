"""Star identification: lost-in-space (k-vector + reference-star votes + RANSAC over 3-star Wahba)
and tracking (catalog stars predicted from a previous attitude). Andreis et al. (2023a), Sec. III.A.2-3,
Andreis et al. (2023b), Fig. 4.

Core module. Inputs are camera-frame unit vectors of the spots (``camera.line_of_sight``) in a
priority order (brightest, most star-like first), outputs the attitude and the spot <-> star
matches. No wrong attitude is reported as correct: every solution is checked against the catalog
stars it predicts in the field (:func:`associate`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .attitude import wahba_svd

__all__ = ["StarDirections", "StarMatch", "lost_in_space", "associate", "refine", "C_KM_S",
           "MAX_STAR_ID_ARCSEC_PX", "MIN_STAR_ID_FOV_DEG", "star_id_camera_check"]

from skynav.scenes.constants import C_KM_S  # noqa: E402

#: The coarsest pixel scale (arcsec per pixel at the principal point) at which lost-in-space
#: identification is reliable. ``benchmarks/star_id_scale.py`` (40 frames of the ``montecarlo``
#: preset per camera, identified = attitude within 3 px of the truth), 20 deg fields: 71"/px
#: 100 %, 142-325"/px 88-95 %, 379"/px 82 %, 413"/px 90 %, 455"/px 82 %, then 505"/px 65 %,
#: 535"/px 42 %, 568"/px 35 % (30 deg fields: 432"/px 100 %, 512"/px 88 %, 576"/px 75 %). The
#: k-vector window is capped at ``ProcessOptions.eps_max_arcsec`` while the spots' centroid errors
#: grow with the pixel: past ~460"/px the true star pairs fall out of the window.
MAX_STAR_ID_ARCSEC_PX = 460.0

#: Fields narrower than this hold too few stars for a reliable identification, however fine the
#: pixels (same benchmark: 10 deg fields 18-35 % from 35 to 376"/px; 15 deg 70-80 % up to 283"/px,
#: 58 % at 377"/px; 20 deg 82-100 %).
MIN_STAR_ID_FOV_DEG = 15.0


def star_id_camera_check(camera) -> tuple[str | None, str | None]:
    """``(error, warning)``: one-line reasons why star identification will not work with ``camera``.

    ``error`` when its pixels are coarser than :data:`MAX_STAR_ID_ARCSEC_PX` (the identification
    collapses: a navigation run would quietly get no attitude, hence no measurement, on most
    frames); ``warning`` when its field is narrower than :data:`MIN_STAR_ID_FOV_DEG` (it still
    identifies some frames). Either may be None.
    """
    scale = float(np.degrees(camera.ifov_rad) * 3600.0)
    fov = float(np.degrees(min(camera.fov_x_rad, camera.fov_y_rad)))
    error = warning = None
    if scale > MAX_STAR_ID_ARCSEC_PX:
        need = int(np.ceil(camera.width * scale / MAX_STAR_ID_ARCSEC_PX))
        error = (f"camera {camera.width}x{camera.height} px over {fov:.3g} deg has {scale:.0f} arcsec/px; star "
                 f"identification needs at most {MAX_STAR_ID_ARCSEC_PX:.0f} arcsec/px (it identifies a third of the "
                 f"frames at 570): give camera.width >= {need} for this field")
    if round(fov, 6) < MIN_STAR_ID_FOV_DEG:
        warning = (f"camera field {fov:.3g} deg, narrower than {MIN_STAR_ID_FOV_DEG:.0f} deg: star identification "
                   f"finds the attitude of 18-35 % of lost-in-space frames in 10 deg fields; frames without an "
                   f"attitude give no measurement")
    return error, warning


@dataclass(frozen=True, kw_only=True, eq=False)
class StarMatch:
    """An attitude and its matches (indices into the spots and into the on-board catalog)."""

    R_cam_icrs: np.ndarray
    spot_index: np.ndarray
    star_index: np.ndarray
    residual_rad: np.ndarray


def _pair_candidates(cat, b, eps_rad, rel_eps):
    """For every spot pair (a, b): the catalog pairs within the angle window; flattened arrays."""
    n = len(b)
    ii, jj = np.triu_indices(n, 1)
    ang = np.arccos(np.clip(np.einsum("ij,ij->i", b[ii], b[jj]), -1.0, 1.0))
    eps = eps_rad + rel_eps * ang
    start, end = cat.kvector.ranges(ang - eps, ang + eps)
    lengths = end - start
    total = int(lengths.sum())
    if total == 0:
        return ii, jj, ang, eps, np.zeros(0, int), np.zeros(0, int), np.zeros(0, int)
    pair_of = np.repeat(np.arange(len(ii)), lengths)
    first = np.repeat(start - np.concatenate(([0], np.cumsum(lengths)[:-1])), lengths)
    k = first + np.arange(total)
    return ii, jj, ang, eps, pair_of, cat.pair_i[k], cat.pair_j[k]


def lost_in_space(b_cam, cat, *, eps_rad, rel_eps=2.5e-4, n_max=12, top_k=3, max_triples=200,
                  inlier_rad, rng=None, random_triples=False):
    """Reference-star votes, then RANSAC over 3-star Wahba solutions.

    Parameters
    ----------
    b_cam : ndarray, shape (N, 3)
        Spot directions in the camera frame, in priority order (the first ``n_max`` are used).
    cat : OnboardCatalog
    eps_rad : float
        k-vector range error (half window) at zero angle, rad.
    rel_eps : float
        Extra window per radian of separation (differential aberration, ~|v|/c).
    inlier_rad : float
        A hypothesis agrees with an attitude when ``angle(A r, b) < inlier_rad``.
    random_triples : bool
        Paper mode: draw ``max_triples`` random triples (``rng``) instead of trying them in the
        order of the vote counts.

    Returns
    -------
    (A, spot_index, star_index) of the best consensus, or None.
    """
    b = np.asarray(b_cam, dtype=float)[:n_max]
    n = len(b)
    if n < 3:
        return None
    ii, jj, ang, eps, pair_of, I, J = _pair_candidates(cat, b, eps_rad, rel_eps)
    if len(I) == 0:
        return None
    hyp = _vote(n, len(cat.hip), ii[pair_of], jj[pair_of], I, J, top_k)
    if hyp is None:
        return None
    hyp_spot, hyp_star = hyp
    r_h = cat.u_icrs[hyp_star]
    b_h = b[hyp_spot]
    cos_in = np.cos(inlier_rad)
    # the measured angle of every spot pair, and the tolerance, for the triangle check
    pair_ang = np.full((n, n), np.nan)
    pair_eps = np.zeros((n, n))
    pair_ang[ii, jj] = pair_ang[jj, ii] = ang
    pair_eps[ii, jj] = pair_eps[jj, ii] = eps
    best = None
    best_score = 2
    for t in _triples(len(hyp_spot), random_triples=random_triples, rng=rng, max_triples=max_triples):
        s = hyp_spot[list(t)]
        st = hyp_star[list(t)]
        if len(set(s.tolist())) < 3 or len(set(st.tolist())) < 3:
            continue
        if not _triangle_agrees(r_h[list(t)], s, pair_ang, pair_eps):
            continue
        A = wahba_svd(b_h[list(t)], r_h[list(t)])
        agree = np.einsum("ij,ij->i", (r_h @ A.T), b_h) > cos_in
        # one star per spot and one spot per star
        sp, sr = hyp_spot[agree], hyp_star[agree]
        _, first = np.unique(sp, return_index=True)
        sp, sr = sp[first], sr[first]
        _, first = np.unique(sr, return_index=True)
        sp, sr = sp[first], sr[first]
        score = len(sp)
        if score > best_score:
            best_score = score
            best = (wahba_svd(b[sp], cat.u_icrs[sr]), sp, sr)
            if score >= min(n, 8) and not random_triples:
                break
    return best


def _vote(n, ncat, a_spot, b_spot, I, J, top_k):
    """Reference-star votes: each candidate catalog pair votes for both its stars at both its
    spots; ``(hyp_spot, hyp_star)``, the ``top_k`` stars of each spot with at least 2 votes, most
    votes first, or None when fewer than 3 spots hold one."""
    flat = np.concatenate([a_spot * ncat + I, a_spot * ncat + J, b_spot * ncat + I, b_spot * ncat + J])
    votes = np.bincount(flat, minlength=n * ncat).reshape(n, ncat)
    top = np.argpartition(-votes, top_k, axis=1)[:, :top_k]
    hyp_spot = np.repeat(np.arange(n), top_k)
    hyp_star = top.ravel()
    hyp_votes = votes[hyp_spot, hyp_star]
    ok = hyp_votes >= 2
    hyp_spot, hyp_star, hyp_votes = hyp_spot[ok], hyp_star[ok], hyp_votes[ok]
    if len(np.unique(hyp_spot)) < 3:
        return None
    order = np.argsort(-hyp_votes, kind="stable")
    return hyp_spot[order], hyp_star[order]


def _triples(m, *, random_triples, rng, max_triples):
    """Index triples of the ``m`` hypotheses to try: ``max_triples`` random ones (paper mode), or
    those of the 12 best-voted in order (``a < b < c``, growing ``c``), at most ``max_triples``."""
    if random_triples:
        rng_ = np.random.default_rng(rng)
        for _ in range(max_triples):
            yield tuple(rng_.choice(m, 3, replace=False))
        return
    count = 0
    for c in range(2, min(m, 12)):
        for bb in range(1, c):
            for a in range(bb):
                yield (a, bb, c)
                count += 1
                if count >= max_triples:
                    return


def _triangle_agrees(r3, s, pair_ang, pair_eps) -> bool:
    """The three catalog angles of the stars ``r3`` (3, 3) match the measured angles of their spots
    ``s`` within the pair tolerances."""
    for p, q in ((0, 1), (0, 2), (1, 2)):
        ca = np.arccos(np.clip(r3[p] @ r3[q], -1.0, 1.0))
        if abs(ca - pair_ang[s[p], s[q]]) > pair_eps[s[p], s[q]]:
            return False
    return True


def associate(A, b_cam, star_u_icrs, star_index, *, tol_rad):
    """Nearest-direction association of predicted catalog stars with spots (mutual nearest).

    Returns (spot_index, star_index, residual_rad) arrays.
    """
    if len(star_index) == 0 or len(b_cam) == 0:
        z = np.zeros(0, dtype=int)
        return z, z, np.zeros(0)
    pred = star_u_icrs @ A.T  # (M, 3) in the camera frame
    cosm = b_cam @ pred.T  # (N, M)
    j_best = np.argmax(cosm, axis=1)
    i_best = np.argmax(cosm, axis=0)
    n = np.arange(len(b_cam))
    mutual = i_best[j_best] == n
    cbest = cosm[n, j_best]
    ok = mutual & (cbest > np.cos(tol_rad))
    spots = n[ok]
    stars = j_best[ok]
    res = np.arccos(np.clip(cbest[ok], -1.0, 1.0))
    return spots, np.asarray(star_index)[stars], res


def refine(A, b_cam, star_dirs_fn, *, half_fov_rad, tol_rad, iterations=2):
    """Re-associate every catalog star predicted in the field and re-solve Wahba.

    ``star_dirs_fn(boresight_icrs, radius_rad) -> (star_index, u_icrs)`` gives the catalog stars
    (apparent directions at the epoch) in a cone. Returns a :class:`StarMatch` or None (< 3).
    """
    for _ in range(iterations):
        boresight = A[2]
        idx, u = star_dirs_fn(boresight, half_fov_rad)
        spots, stars, res = associate(A, b_cam, u, idx, tol_rad=tol_rad)
        if len(spots) < 3:
            return None
        pos = {s: k for k, s in enumerate(idx)}
        r = u[[pos[s] for s in stars]]
        A = wahba_svd(b_cam[spots], r)
        res = np.arccos(np.clip(np.einsum("ij,ij->i", r @ A.T, b_cam[spots]), -1.0, 1.0))
    return StarMatch(R_cam_icrs=A, spot_index=spots, star_index=stars, residual_rad=res)


class StarDirections:
    """``(idx, u)`` of the catalog stars in a cone, with their directions as the mode sees them
    (``directions(source, idx)``), for one frame (the caller owns it; one per frame).

    One cone ``REUSE_RAD`` wider than asked, per catalog and radius, serves every later boresight
    within ``REUSE_RAD`` of its axis: within a frame the boresight moves by a few pixels between
    requests, and the extra stars lie outside the image by >= 2 mrad, beyond every association
    tolerance."""

    REUSE_RAD = 5e-3

    def __init__(self, catalog, directions):
        self.catalog, self.directions, self._cones = catalog, directions, {}

    def __call__(self, boresight, radius, source=None):
        src = self.catalog.stars if source is None else source
        key = (id(src), float(radius))
        hit = self._cones.get(key)
        if hit is not None and float(np.dot(hit[0], boresight)) >= np.cos(self.REUSE_RAD) * np.linalg.norm(boresight):
            return hit[1], hit[2]
        idx = src.cone(boresight, radius, margin_rad=2e-3 + self.REUSE_RAD)
        u = self.directions(src, idx)
        self._cones[key] = (np.asarray(boresight, float) / np.linalg.norm(boresight), idx, u)
        return idx, u
