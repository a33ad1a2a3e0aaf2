"""Beacon identification (Andreis et al. (2023a), Sec. III.B, Eq. 23-24): which spot is each predicted beacon.

Beside beacon prediction (:mod:`skynav.pipeline.beacons`). The paper takes, beacon by beacon, the
closest spot inside the 3-sigma ellipse ``d^T P^-1 d <= 11.8292`` (:func:`identify_closest`); the
improved mode assigns the spots to the beacons jointly (:func:`identify_joint`) with a cost that
adds the brightness mismatch to the Mahalanobis distance, leaves out spots on catalog stars, and
widens the gates of blended beacons (the Earth and the Moon seen as one spot).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.optimize import linear_sum_assignment

from .beacons import CHI2_2DOF_3SIGMA, max_eig_2x2, select_spot
from .results import BeaconResult

__all__ = ["identify_closest", "identify_joint", "add_attitude_covariance", "assign_beacons", "assign_from_m2",
           "mahalanobis2", "inv_2x2_stack", "near_any", "beacon_result"]


def identify_closest(preds, spots, match, opt):
    """Paper mode (Eq. 23-24): each beacon in turn takes the closest spot inside its 3-sigma
    ellipse among the spots not matched to catalog stars nor taken by an earlier beacon."""
    candidate = np.ones(len(spots), dtype=bool)
    candidate[match.spot_index] = False  # spots matched to catalog stars are not beacons
    out = []
    for p in preds:
        k = select_spot(p, spots.xy_px, candidate, mode="paper", spot_mag=None, mag_sigma=opt.mag_sigma)
        if k is not None:
            candidate[k] = False
        out.append(beacon_result(p, spots, k))
    return tuple(out)


def add_attitude_covariance(preds, P_att):
    """The predictions of :func:`~skynav.pipeline.beacons.predict_beacons` made without the
    attitude covariance (windowed tracking), with ``F_a P_att F_a^T`` added."""
    return [replace(p, cov_px2=p.cov_px2 + p.attitude_jacobian_px_rad @ P_att @ p.attitude_jacobian_px_rad.T)
            for p in preds]


def identify_joint(preds, cam, A, spots, match, catalog, opt, ref_vmag):
    """Improved mode: one spot per beacon and one beacon per spot, jointly
    (:func:`assign_from_m2`), among the spots not matched to catalog stars and not on a deep
    catalog star, with the predicted brightness against a photometric zero point from the
    matched stars."""
    n = len(spots)
    candidate = np.ones(n, dtype=bool)
    candidate[match.spot_index] = False  # spots matched to catalog stars are not beacons
    if not preds:
        return ()
    preds = list(preds)
    # the deep stars that may lie on a spot a beacon can take: those within each beacon's
    # 3-sigma reach plus the exclusion radius (from its covariance before the blend widening)
    deep_cones = []
    if n:
        los = cam.line_of_sight(np.array([p.xy_px for p in preds])) @ A  # rows: A^T b
        ifov = cam.ifov_rad
        deep_cones = [(los[k], (math.sqrt(CHI2_2DOF_3SIGMA * max(max_eig_2x2(p.cov_px2), 0.0)) + opt.deep_star_radius_px + 2.0)
                       * ifov * 1.5) for k, p in enumerate(preds)]
    # blends: two beacons predicted within a few pixels (the Earth and the Moon) make one spot
    # whose centroid lies between them; widen both gates by half the separation, and predict
    # the blend's total brightness
    for i in range(len(preds)):
        for j in range(i + 1, len(preds)):
            sep = float(np.hypot(*(preds[i].xy_px - preds[j].xy_px)))
            if sep < opt.blend_px:
                for a in (i, j):
                    preds[a] = replace(preds[a], cov_px2=preds[a].cov_px2 + np.eye(2) * (0.5 * sep) ** 2)
                mi, mj = preds[i].v_mag, preds[j].v_mag
                if np.isfinite(mi) and np.isfinite(mj):
                    m = -2.5 * np.log10(10 ** (-0.4 * mi) + 10 ** (-0.4 * mj))
                    preds[i] = replace(preds[i], v_mag=m)
                    preds[j] = replace(preds[j], v_mag=m)
    # only the candidates inside some beacon's 3-sigma ellipse can be chosen: the deep-star test
    # and the brightness model are evaluated for those alone
    cand = np.flatnonzero(candidate)
    m2 = mahalanobis2(preds, spots.xy_px.take(cand, axis=0))
    cand_in = m2[0] <= CHI2_2DOF_3SIGMA if len(m2) == 1 else np.logical_or.reduce(m2 <= CHI2_2DOF_3SIGMA, axis=0)
    cand, m2 = cand.compress(cand_in), m2.compress(cand_in, axis=1)
    if len(cand):
        # ... nor spots on fainter catalog stars (the deep catalog, V < deep_v_mag), predicted
        # with the solved attitude: the field's faint stars are the usual wrong beacons
        deep = catalog.deep_stars()
        cones = [deep.cone(c, r, margin_rad=2e-3) for c, r in deep_cones]
        # a cone's indices are ascending and unique already (StarCatalog.cone sorts them)
        idx = cones[0] if len(cones) == 1 else np.unique(np.concatenate(cones))
        xy = np.zeros((0, 2))
        if len(idx):  # no deep star near any beacon (the usual case): nothing to project
            xy = cam.project(deep.u_icrs.take(idx, axis=0) @ A.T)
            xy = xy.compress(np.logical_and.reduce(np.isfinite(xy), axis=1), axis=0)
        if len(xy):
            on_star = near_any(spots.xy_px[cand], xy, opt.deep_star_radius_px)
            cand, m2 = cand[~on_star], m2[:, ~on_star]
    spot_mag = None
    if len(cand):
        # photometric zero point from the matched, unsaturated stars: m = zp - 2.5 log10(flux)
        ms = match.spot_index
        flux_ms = spots.flux_dn.take(ms)
        good = (~spots.saturated.take(ms)) & (flux_ms > 0)
        vm = np.asarray(ref_vmag).take(match.star_index)
        # every log10 argument is > 0 (NaN fluxes are not good; the rest clipped at 1e-9): no
        # division by zero to silence
        zp = float(np.median(vm.compress(good) + 2.5 * np.log10(flux_ms.compress(good)))) if np.count_nonzero(good) >= 3 else np.nan
        spot_mag = zp - 2.5 * np.log10(np.maximum(spots.flux_dn.take(cand), 1e-9))
        # saturated spots are at least as bright as measured: no penalty for a brighter prediction
        spot_mag = np.where(spots.saturated.take(cand), np.nan, spot_mag)
    chosen = assign_from_m2(preds, m2, spot_mag, opt.mag_sigma)
    return tuple(beacon_result(p, spots, None if k is None else int(cand[k])) for p, k in zip(preds, chosen))



def beacon_result(p, spots, k):
    """The :class:`~skynav.pipeline.results.BeaconResult` of prediction ``p`` and spot ``k`` (or None)."""
    if k is None:
        return BeaconResult(name=p.name, xy_px=None, predicted_xy_px=p.xy_px, predicted_cov_px2=p.cov_px2,
                            status="not_found")
    return BeaconResult(name=p.name, xy_px=spots.xy_px[k].copy(), predicted_xy_px=p.xy_px,
                        predicted_cov_px2=p.cov_px2, status="found")


def near_any(xy, ref, radius):
    """True where a point of ``xy`` (M, 2) has a point of ``ref`` (K, 2) closer than ``radius``
    (strictly, squared distances compared as :class:`scipy.spatial.cKDTree` with
    ``distance_upper_bound`` does)."""
    d0 = xy[:, None, 0] - ref[None, :, 0]
    d1 = xy[:, None, 1] - ref[None, :, 1]
    return np.any(d0 * d0 + d1 * d1 < radius * radius, axis=1)


def mahalanobis2(preds, xy):
    """``m2[i, j] = d^T P_i^-1 d`` with ``d = xy[j] - preds[i].xy_px``, shape (nb, M); a row
    of ``inf`` where ``P_i`` is singular (that beacon can take no spot)."""
    nb, m = len(preds), len(xy)
    if m == 0 or nb == 0:
        return np.zeros((nb, m))
    out = np.empty((nb, m))
    for i, (p, Pinv) in enumerate(zip(preds, inv_2x2_stack([p.cov_px2 for p in preds]))):
        if Pinv is None:
            out[i] = np.inf
            continue
        d = xy - p.xy_px[None]
        out[i] = np.einsum("ni,ij,nj->n", d, Pinv, d)
    return out


def inv_2x2_stack(mats):
    """``[numpy.linalg.inv(M) for M in mats]`` with None where ``inv`` raises LinAlgError
    (singular): one call on the stack, each matrix alone only when some matrix is singular."""
    a = np.asarray(mats, dtype=float)
    try:
        return list(np.linalg.inv(a))
    except np.linalg.LinAlgError:
        return [_inv_or_none(M) for M in a]


def _inv_or_none(M):
    try:
        return np.linalg.inv(M)
    except np.linalg.LinAlgError:
        return None


def assign_beacons(preds, spots_xy, candidate, spot_mag, mag_sigma):
    """Improved mode: one spot per beacon and one beacon per spot, jointly (a beacon with a huge
    ellipse must not take the spot of one with a small ellipse, as the paper's one-at-a-time
    closest-spike rule lets it). Cost of beacon i on spot j inside its 3-sigma ellipse:
    ``m2_ij + ((m_j - m_pred_i) / mag_sigma)^2``; "not found" costs the ellipse's edge plus a
    3-sigma brightness mismatch, so any spot inside the ellipse is preferred over none.
    Returns the chosen spot index (into ``spots_xy``) of each beacon, or None."""
    cand = np.flatnonzero(candidate)
    if len(preds) == 0:
        return []
    chosen = assign_from_m2(preds, mahalanobis2(preds, spots_xy[cand]), None if spot_mag is None else spot_mag[cand],
                             mag_sigma)
    return [None if k is None else int(cand[k]) for k in chosen]


def assign_from_m2(preds, m2, spot_mag, mag_sigma):
    """:func:`assign_beacons` on the candidates' Mahalanobis^2 ``m2`` (nb, M) and magnitudes
    ``spot_mag`` (M,) or None; returns column indices into ``m2`` or None. A spot outside every
    ellipse has only forbidden entries, so leaving it out does not change the assignment."""
    nb, m = m2.shape
    if nb == 0:
        return []
    chosen = [None] * nb
    inside = m2 <= CHI2_2DOF_3SIGMA
    if not inside.any():
        return chosen
    BIG = 1e9
    if nb == 1:
        # fast path for one beacon (the usual case), beside the general solver below: the
        # cheapest spot inside the ellipse, or "not found" when none costs less than the
        # ellipse's edge; ties to the lowest index, as linear_sum_assignment resolves them
        # (tests/pipeline/test_beacon_assignment.py holds the two to the same choice, ties
        # included). The costs as below: m2 + ((m - m_pred) / mag_sigma)^2
        vm = float(preds[0].v_mag)
        mags = spot_mag.tolist() if spot_mag is not None and math.isfinite(vm) else None
        best, j_best = CHI2_2DOF_3SIGMA + 9.0, None
        for j, (m2j, ok) in enumerate(zip(m2[0].tolist(), inside[0].tolist())):
            if not ok:
                continue  # BIG
            cj = m2j
            if mags is not None:
                dm = mags[j] - vm
                dm = dm / mag_sigma if math.isfinite(dm) else 0.0
                cj = m2j + dm * dm
            if cj < BIG and (cj < best or (cj == best and j_best is None)):
                best, j_best = cj, j
        chosen[0] = j_best
        return chosen
    c = m2
    if spot_mag is not None:
        vmag = np.array([p.v_mag for p in preds], dtype=float)
        dm = spot_mag[None, :] - vmag[:, None]
        c = c + np.where(np.isfinite(vmag)[:, None], np.where(np.isfinite(dm), dm / mag_sigma, 0.0) ** 2, 0.0)
    cost = np.full((nb, m + nb), BIG)
    cost[:, :m] = np.where(inside, c, BIG)
    cost[np.arange(nb), m + np.arange(nb)] = CHI2_2DOF_3SIGMA + 9.0
    rows, cols = linear_sum_assignment(cost)
    for i, j in zip(rows.tolist(), cols.tolist()):
        if j < m and cost[i, j] < BIG:
            chosen[i] = j
    return chosen
