"""The one visibility predicate (VisibilityCriteria) and where it is used: the scene's
``visible`` flag, the Monte Carlo keep-filter, scene files; and ObserverInsideBodyError."""

import math

import numpy as np
import pytest

from skynav.infra.errors import ConfigValueError
from skynav.scenes import config, presets
from skynav.scenes.errors import MovedKeyError, ObserverInsideBodyError
from skynav.scenes.scene import build_from_spec
from skynav.scenes.sky import sky_bodies
from skynav.scenes.visibility import VisibilityCriteria

DEG = math.pi / 180.0


def test_predicate_boundaries_written_out():
    rule = VisibilityCriteria(limiting_v_mag=6.0, sun_exclusion_rad=30 * DEG)
    cases = [  # (V, elongation deg, visible): V <= limit inclusive, elongation > exclusion strict
        (6.0, 90.0, True), (6.000001, 90.0, False), (-3.0, 30.0, False), (-3.0, 30.0001, True),
        (float("nan"), 90.0, False), (float("inf"), 90.0, False), (5.0, 180.0, True), (5.0, 0.0, False),
    ]
    for v, e, want in cases:
        assert bool(rule.body_visible(v_mag=v, elongation_rad=e * DEG)) is want, (v, e)
    # batch equals the scalar loop
    v = np.array([c[0] for c in cases])
    e = np.array([c[1] for c in cases]) * DEG
    assert rule.body_visible(v_mag=v, elongation_rad=e).tolist() == [c[2] for c in cases]


def test_defaults_are_paper002_and_values_are_values():
    import pickle

    rule = VisibilityCriteria()
    assert rule.limiting_v_mag == 7.0 and rule.sun_exclusion_rad == math.radians(20.0)
    assert pickle.loads(pickle.dumps(rule)) == rule and hash(rule) == hash(VisibilityCriteria())
    assert eval(repr(rule)) == rule
    assert VisibilityCriteria.from_dict(rule.to_dict()) == rule
    with pytest.raises(ConfigValueError, match="visibility.sun_exclusion_deg"):
        VisibilityCriteria(sun_exclusion_rad=4.0)
    with pytest.raises(ConfigValueError, match="visibility.limiting_v_mag"):
        VisibilityCriteria(limiting_v_mag=float("nan"))


@pytest.fixture(scope="module")
def spec():
    return presets.default_scene_spec()


def test_visible_flags_follow_the_scene_criteria(spec):
    """Mars (V about -1.7, 157 deg from the Sun) is visible by default, not with a V < -2 limit,
    and not when the exclusion angle exceeds its elongation; the flag is in_fov & predicate."""
    import dataclasses

    for rule, mars_visible in [(VisibilityCriteria(), True),
                               (VisibilityCriteria(limiting_v_mag=-2.0), False),
                               (VisibilityCriteria(sun_exclusion_rad=170 * DEG), False)]:
        scene = build_from_spec(dataclasses.replace(spec, visibility=rule))
        assert scene.visibility == rule
        for b in scene.bodies:
            want = b.in_fov and np.isfinite(b.v_mag) and b.v_mag <= rule.limiting_v_mag and b.elongation_rad > rule.sun_exclusion_rad
            assert b.visible == want
        mars = next(b for b in scene.bodies if b.name == "mars")
        assert mars.visible is mars_visible


def test_elongation_and_boresight_sun_angle_are_the_two_angles(spec):
    """Independent reference: elongation = angle(u_body, u_sun); boresight angle = angle(z_cam, u_sun)."""
    scene = build_from_spec(spec)
    sun = scene.sun_u_icrs
    for b in scene.bodies:
        assert b.elongation_rad == pytest.approx(math.acos(np.clip(np.dot(b.u_icrs, sun), -1, 1)), abs=1e-12)
    assert scene.boresight_sun_angle_rad == pytest.approx(math.acos(np.clip(scene.R_cam_icrs[2] @ sun, -1, 1)), abs=1e-12)


def test_scene_file_sections_visibility_and_render():
    d = presets.preset_mapping("default")
    d["visibility"] = {"limiting_v_mag": 5.5, "sun_exclusion_deg": 30.0}
    d["render"] = {"catalog_limiting_v_mag": 8.0, "cosmic_rays_per_frame": 3.0, "seed": 4}
    s = config.scene_spec_from_mapping(d)
    assert s.visibility == VisibilityCriteria(limiting_v_mag=5.5, sun_exclusion_rad=math.radians(30.0))
    assert s.catalog_limiting_v_mag == 8.0 and s.cosmic_rays_per_frame == 3.0
    assert config.scene_spec_from_mapping(presets.preset_mapping("default")).visibility == VisibilityCriteria()
    with pytest.raises(ConfigValueError, match="visibility.sun_exclusion_deg"):
        config.visibility_from_mapping({"sun_exclusion_deg": 180.0})
    with pytest.raises(ConfigValueError, match="visibility.v_mag"):
        config.visibility_from_mapping({"v_mag": 6})
    with pytest.raises(ConfigValueError, match="render.cosmic_rays_per_frame"):
        config.scene_spec_from_mapping({**d, "render": {"cosmic_rays_per_frame": -1}})


@pytest.mark.parametrize("section, key, new", [
    ("camera", "limiting_v_mag", "visibility.limiting_v_mag"),
    ("camera", "sun_exclusion_deg", "visibility.sun_exclusion_deg"),
    ("camera", "cosmic_rays_per_frame", "render.cosmic_rays_per_frame"),
    ("render", "star_mag_limit", "render.catalog_limiting_v_mag"),
])
def test_old_keys_give_one_line_naming_the_new_key(section, key, new):
    d = presets.preset_mapping("default")
    d[section] = {**d[section], key: 7.0}
    with pytest.raises(MovedKeyError) as info:
        config.scene_spec_from_mapping(d)
    msg = str(info.value)
    assert msg.startswith(f"{section}.{key} has moved: write it as {new}") and "\n" not in msg


def test_observer_inside_a_body_is_its_own_error():
    from skynav.scenes.ephemeris_jpl import default_ephemeris
    from skynav.scenes.timescales import tdb_seconds

    eph = default_ephemeris()
    t = float(tdb_seconds("2027-02-01T00:00:00"))
    r_earth, v_earth = eph.position_velocity("earth", t)
    with pytest.raises(ObserverInsideBodyError) as info:
        sky_bodies(t, np.asarray(r_earth) + [1000.0, 0.0, 0.0], v_earth, ephemeris=eph)
    err = info.value
    assert err.body == "earth" and err.radius_km > 6000 and err.distance_km == pytest.approx(1000.0, rel=1e-3)
    assert isinstance(err, ValueError) and not isinstance(err, ConfigValueError)
    assert "inside earth" in str(err) and "\n" not in str(err)


def test_sampler_rejects_a_pose_inside_a_body_by_that_error():
    """The Monte Carlo sampler rejects (and redraws) a pose inside a body; other errors propagate."""
    from skynav.datasets.recipe_checks import validate_recipe
    from skynav.datasets.recipes import preset_recipe
    from skynav.datasets.samplers import make_plan
    from skynav.scenes.timescales import tdb_seconds

    rec = preset_recipe("montecarlo")
    rec["frames"] = 1
    plan = make_plan(validate_recipe(rec))
    t = float(tdb_seconds("2027-02-01T00:00:00"))
    r_earth, v_earth = plan.ephemeris.position_velocity("earth", t)
    r = np.asarray(r_earth) + [100.0, 0.0, 0.0]
    assert plan._sky(t, r, np.asarray(v_earth), np.eye(3), None) == (False, None, None)


def test_recipes_carry_the_criteria_and_refuse_the_old_keys():
    from skynav.datasets.recipe_checks import validate_recipe
    from skynav.datasets.recipes import preset_recipe, recipe_visibility
    from skynav.datasets.samplers import make_plan

    rec = preset_recipe("montecarlo")
    rec.update(frames=1, visibility={"limiting_v_mag": 3.0})
    norm = validate_recipe(rec)
    assert norm["visibility"] == {"limiting_v_mag": 3.0, "sun_exclusion_deg": 20.0}
    assert recipe_visibility(norm) == VisibilityCriteria(limiting_v_mag=3.0)
    assert make_plan(norm).visibility == VisibilityCriteria(limiting_v_mag=3.0)
    assert validate_recipe(preset_recipe("sequence"))["visibility"] == VisibilityCriteria().to_dict()
    for bad, new in [({"star_mag_limit": 8.0}, "catalog_limiting_v_mag"),
                     ({"camera": {"preset": "paper", "limiting_v_mag": 6.0}}, "visibility.limiting_v_mag")]:
        with pytest.raises(MovedKeyError, match=f"write it as {new}"):
            validate_recipe({**rec, **bad})
