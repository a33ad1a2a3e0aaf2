"""Recipes (validation, presets, YAML) and the Monte Carlo sampler's distributions (Andreis et al. (2023a), Sec. V.A)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from scipy import stats

from skynav.datasets import preset_recipe, validate_recipe
from skynav.datasets.errors import RecipeError
from skynav.datasets.recipe_checks import KINDS
from skynav.datasets.recipes import PRESETS, load_recipe_file
from skynav.datasets.samplers import R_ECL_ICRS, frame_rng, make_plan
from skynav.infra.errors import ConfigValueError, SkynavError
from skynav.scenes.constants import AU_KM, GM_KM3_S2


@pytest.mark.parametrize("kind", KINDS)
def test_presets_validate_and_round_trip_through_yaml(kind, tmp_path):
    rec = validate_recipe(preset_recipe(kind))
    assert validate_recipe(rec) == rec  # normalised form is a fixed point
    path = tmp_path / f"{kind}.yaml"
    path.write_text(yaml.safe_dump(PRESETS[kind]))
    assert load_recipe_file(path) == rec
    assert load_recipe_file(kind) == rec  # a preset name works as a "file"


@pytest.mark.parametrize(("edit", "key", "allowed"), [
    (lambda r: r["montecarlo"].update(position_sigma_au=[3, 3, -0.1]), "montecarlo.position_sigma_au.2", "[0, 100]"),
    (lambda r: r["montecarlo"].update(keep=["planets"]), "montecarlo.keep", "visible_planet"),
    (lambda r: r["montecarlo"].update(epoch_start_tdb="2060-01-01"), "montecarlo.epoch_start_tdb", "DE421"),
    (lambda r: r.update(frames=0), "frames", "[1, 1e+09]"),
    (lambda r: r.update(formats=["png"]), "formats", "json"),
    (lambda r: r.update(colour="red"), "colour", "allowed keys"),
    (lambda r: r.pop("seed"), "seed", "master seed"),
])
def test_bad_recipes_name_the_key_and_the_range(edit, key, allowed):
    rec = preset_recipe("montecarlo")
    edit(rec)
    with pytest.raises(RecipeError) as err:
        validate_recipe(rec)
    assert err.value.key == key and allowed in str(err.value)
    assert isinstance(err.value, SkynavError) and isinstance(err.value, ValueError)


def test_bad_camera_and_sequence_keys():
    rec = preset_recipe("montecarlo")
    rec["camera"] = {"preset": "paper", "exposure_s": -1}
    with pytest.raises(ConfigValueError, match="camera.exposure_s"):
        validate_recipe(rec)
    rec = preset_recipe("sequence")
    rec["sequence"]["cadence_s"] = 7200.0  # longer than the tracking window
    with pytest.raises(RecipeError, match="sequence.cadence_s"):
        validate_recipe(rec)


def test_ecliptic_rotation_against_astropy():
    from astropy import units as u
    from astropy.coordinates import ICRS, BarycentricMeanEcliptic, SkyCoord

    rng = np.random.default_rng(3)
    v = rng.normal(size=(20, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    c = SkyCoord(x=v[:, 0], y=v[:, 1], z=v[:, 2], representation_type="cartesian", frame=ICRS())
    e = c.transform_to(BarycentricMeanEcliptic(equinox="J2000")).cartesian.xyz.value.T
    ours = v @ R_ECL_ICRS.T
    # astropy includes the ICRS frame bias (~23 mas) that the sampler ignores
    assert np.degrees(np.arccos(np.clip(np.sum(ours * e, 1), -1, 1))).max() * 3600 < 0.1


def test_montecarlo_pose_distribution_chi_square():
    rec = validate_recipe(preset_recipe("montecarlo"))
    plan = make_plan(rec)
    rng = np.random.default_rng(11)
    n = 4000
    pos, bore_ecl, t = np.empty((n, 3)), np.empty((n, 3)), np.empty(n)
    for i in range(n):
        t[i], r, R = plan.draw_pose(rng)
        pos[i] = R_ECL_ICRS @ r / AU_KM
        bore_ecl[i] = R_ECL_ICRS @ R[2]
    # sample variances: (n - 1) s^2 / sigma^2 ~ chi2(n - 1); two-sided 0.1 % bounds
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], n - 1) / (n - 1)
    for j, sigma in enumerate((3.0, 3.0, 0.07)):
        assert lo < pos[:, j].var(ddof=1) / sigma**2 < hi
    dec = np.arcsin(np.clip(bore_ecl[:, 2], -1, 1))
    assert lo < dec.var(ddof=1) / 0.2**2 < hi  # 3-sigma 0.6 rad
    ra = np.arctan2(bore_ecl[:, 1], bore_ecl[:, 0]) % (2 * np.pi)
    assert stats.kstest(ra / (2 * np.pi), "uniform").pvalue > 1e-3
    assert stats.kstest((t - plan.start_tdb_s) / (plan.end_tdb_s - plan.start_tdb_s), "uniform").pvalue > 1e-3


def test_montecarlo_circular_velocity():
    from skynav.scenes.ephemeris_jpl import default_ephemeris

    rec = validate_recipe(preset_recipe("montecarlo"))
    plan = make_plan(rec)
    eph = default_ephemeris()
    rng = np.random.default_rng(2)
    for _ in range(5):
        t, r, _R = plan.draw_pose(rng)
        sr, sv = eph.position_velocity("sun", t)
        rel_r, rel_v = R_ECL_ICRS @ (r - sr), R_ECL_ICRS @ (plan.velocity(t, r) - sv)
        assert np.linalg.norm(rel_v) == pytest.approx(math.sqrt(GM_KM3_S2["sun"] / np.linalg.norm(rel_r)), rel=1e-12)
        assert abs(rel_v[2]) < 1e-12 and abs(rel_v @ rel_r) < 1e-6 * np.linalg.norm(rel_r)
        assert np.cross(rel_r, rel_v)[2] > 0  # prograde


def test_frame_request_depends_only_on_its_own_stream():
    rec = preset_recipe("montecarlo")
    rec["frames"] = 10
    plan = make_plan(validate_recipe(rec))
    a = plan.frame_request(7, frame_rng(99, 7))
    b = plan.frame_request(7, frame_rng(99, 7))
    assert a.epoch_tdb_s == b.epoch_tdb_s and np.array_equal(a.R_cam_icrs, b.R_cam_icrs)
    assert a.meta["draws"] >= 1 and a.meta["visible_bodies"]


def test_montecarlo_keep_decision_equals_brute_force_on_all_bodies():
    # Oracle: replay frame k's stream with draw_pose and evaluate the keep-filters on the full
    # sky_bodies of every drawn pose (no candidate pre-selection). The sampler must keep the same
    # draw, with the same facts and the same sky.
    from skynav.datasets.samplers import keep_filters_pass
    from skynav.scenes.sky import sky_bodies

    rec = validate_recipe(dict(preset_recipe("montecarlo"), frames=12))
    plan = make_plan(rec)
    s = rec["montecarlo"]
    for k in range(12):
        got = plan.frame_request(k, frame_rng(rec["seed"], k))
        rng = frame_rng(rec["seed"], k)
        for draws in range(1, s["max_draws_per_frame"] + 1):
            t, r, R = plan.draw_pose(rng)
            if np.linalg.norm(r - plan.ephemeris.position("sun", t)) < s["min_sun_distance_au"] * AU_KM:
                continue
            v = plan.velocity(t, r)
            try:
                sky = sky_bodies(t, r, v, ephemeris=plan.ephemeris)
            except ConfigValueError:
                continue
            ok, facts = keep_filters_pass(s["keep"], sky, R, plan.camera, plan.visibility)
            if ok:
                break
        assert got.meta["draws"] == draws and got.epoch_tdb_s == t
        assert got.meta["visible_bodies"] == facts["visible_bodies"] and got.meta["bodies_in_fov"] == facts["bodies_in_fov"]
        assert [b.name for b in got.sky[0]] == [b.name for b in sky[0]]
        for a, b in zip(got.sky[0], sky[0]):
            np.testing.assert_array_equal(a.directions.u_apparent, b.directions.u_apparent)
            assert a.v_mag == b.v_mag or (np.isnan(a.v_mag) and np.isnan(b.v_mag))  # NaN: no phase law there
        np.testing.assert_array_equal(got.sky[1], sky[1])
