"""Optimal planet pair (Andreis et al. (2024), Eq. 1-2)."""

import math

import numpy as np
import pytest

from skynav.pipeline.pairs import PairCandidate, candidates_from_state, figure_of_merit, optimal_pair
from skynav.scenes.constants import AU_KM
from skynav.scenes.ephemeris_jpl import default_ephemeris


def _c(name, los, d_au, v=0.0, elong_deg=90.0):
    return PairCandidate(name=name, los_icrs=tuple(los), distance_km=d_au * AU_KM, v_mag=v,
                         elongation_rad=math.radians(elong_deg))


def test_figure_of_merit_is_trace_of_triangulation_covariance():
    # l1 = x at 2 au, l2 = y at 1 au: A = diag(0, 1, 1)/4 + diag(1, 0, 1) = diag(1, 1/4, 5/4)
    J = figure_of_merit([1, 0, 0], 2 * AU_KM, [0, 1, 0], AU_KM, sigma_rad=1e-4)
    assert J == pytest.approx(1e-8 * (1 + 4 + 0.8), rel=1e-12)
    assert figure_of_merit([1, 0, 0], AU_KM, [1, 0, 0], 2 * AU_KM) == math.inf


def test_prefers_near_orthogonal_and_near_planets_and_applies_limits():
    cands = [_c("mars", [1, 0, 0], 0.5, v=-1.0), _c("jupiter", [0, 1, 0], 4.5, v=-2.0),
             _c("venus", [0.9, 0.1, 0], 0.7, v=-4.0), _c("saturn", [0, 0, 1], 1.0, v=8.0),  # too faint
             _c("mercury", [0, 0.0, -1], 0.8, v=0.0, elong_deg=10.0)]  # too close to the Sun
    ch = optimal_pair(cands)
    assert {ch.first, ch.second} == {"mars", "jupiter"}
    assert ch.first == "jupiter"  # brighter first
    assert all(p[0] not in ("saturn", "mercury") and p[1] not in ("saturn", "mercury") for p in ch.all_pairs)
    assert optimal_pair([_c("mars", [1, 0, 0], 1.0)]).second == "mars"
    assert optimal_pair([_c("mars", [1, 0, 0], 1.0, v=9.0)]) is None


def test_candidates_from_a_cruise_state():
    eph = default_ephemeris()
    t = 8.5e8
    r, v = eph.position_velocity("earth", t)
    cands = candidates_from_state(t, r + 5e6, v, ephemeris=eph)
    assert {c.name for c in cands} >= {"mars", "jupiter", "venus"}
    assert optimal_pair(cands) is not None
