"""A recipe's ``render:`` mapping (the scene file's render keys, one validator) and the commented
preset files of ``skynav dataset recipe``: real renders at 128 x 128 px, real files."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from skynav.datasets import generate
from skynav.datasets.errors import RecipeError
from skynav.datasets.frame_files import read_exr
from skynav.datasets.recipe_checks import validate_recipe
from skynav.datasets.recipes import PRESETS, load_recipe_file, preset_recipe, recipe_yaml
from skynav.datasets.runner import recipe_render_options
from skynav.infra.errors import ConfigValueError
from skynav.renderer.render import RenderOptions
from skynav.scenes.config import RENDER_KEYS, scene_spec_from_mapping
from skynav.scenes.errors import MovedKeyError
from skynav.scenes.presets import preset_mapping
from skynav.scenes.scene import RESOLVED_THRESHOLD_PX


def _small_montecarlo(frames=2, **render):
    r = preset_recipe("montecarlo")
    r.update(frames=frames, seed=7, camera={"preset": "paper", "width": 128, "height": 128})
    if render:
        r["render"] = render
    return r


def _frames(root, n):
    return [json.loads((root / "frames" / f"{k:06d}.json").read_text()) for k in range(n)]


def test_montecarlo_recipe_without_cosmic_rays(tmp_path):
    """render: {cosmic_rays_per_frame: 0} gives frames without cosmic rays; the same recipe at 15 per
    frame (same seed, same scenes) differs in the noise-free electrons by exactly the rays' charge."""
    off, on = tmp_path / "off", tmp_path / "on"
    generate(_small_montecarlo(cosmic_rays_per_frame=0), off, workers=1, progress=False)
    generate(_small_montecarlo(cosmic_rays_per_frame=15), on, workers=1, progress=False)
    m = json.loads((off / "manifest.json").read_text())
    assert m["recipe"]["render"] == {"cosmic_rays_per_frame": 0.0}
    assert m["render_options"]["cosmic_rays_per_frame"] == 0.0
    hits = 0
    for k, (t_off, t_on) in enumerate(zip(_frames(off, 2), _frames(on, 2))):
        assert t_off["cosmic_rays"] == []
        assert t_off["epoch"] == t_on["epoch"]  # the sampler drew the same scene
        e_off = read_exr(off / "frames" / f"{k:06d}.exr")["electrons"].astype(np.float64)
        e_on = read_exr(on / "frames" / f"{k:06d}.exr")["electrons"].astype(np.float64)
        ray_e = sum(c["electrons"] for c in t_on["cosmic_rays"])
        hits += len(t_on["cosmic_rays"])
        # float32 EXR: each pixel is rounded to 2^-24 of its value (a ray on a 1e7 e- planet pixel: 0.6 e-)
        tol_e = 2.0**-23 * float(np.abs(e_on).max()) + 1e-3
        assert (e_on - e_off).sum() == pytest.approx(ray_e, rel=1e-6, abs=tol_e)
        assert np.all(e_on - e_off >= -tol_e)
    assert hits > 0  # 2 frames at a Poisson mean of 15: P(no hit) = e^-30


def test_render_keys_are_the_scene_files(tmp_path):
    """Every scene-file render key but seed is taken by a recipe; resolved threshold and spp reach the run."""
    given = _small_montecarlo(resolved_threshold_px=5.0, mitsuba_spp=4, catalog_limiting_v_mag=8.0)
    del given["catalog_limiting_v_mag"]  # the scene file's spelling alone sets the cut
    r = validate_recipe(given)
    assert r["render"] == {"resolved_threshold_px": 5.0, "mitsuba_spp": 4}
    assert r["catalog_limiting_v_mag"] == 8.0
    opts = recipe_render_options(r, RenderOptions(mitsuba_spp=32, cosmic_rays_per_frame=3.0))
    assert (opts.mitsuba_spp, opts.cosmic_rays_per_frame) == (4, 3.0)  # the recipe's key wins, the rest stays


def test_defaults_written_out_are_the_same_dataset():
    explicit = _small_montecarlo(**{k: v for k, (v, _) in RENDER_KEYS.items() if k != "seed"})
    assert validate_recipe(explicit) == validate_recipe(_small_montecarlo())
    assert "render" not in validate_recipe(preset_recipe("montecarlo"))  # manifests of presets unchanged


def test_render_defaults_agree_with_the_renderer_and_scene_model():
    opts = RenderOptions()
    assert RENDER_KEYS["cosmic_rays_per_frame"][0] == opts.cosmic_rays_per_frame
    assert RENDER_KEYS["mitsuba_spp"][0] == opts.mitsuba_spp
    assert RENDER_KEYS["resolved_threshold_px"][0] == RESOLVED_THRESHOLD_PX


@pytest.mark.parametrize("render, key, says", [
    ({"seed": 3}, "render.seed", "top-level seed"),
    ({"cosmic_rays": 0}, "render.cosmic_rays", "allowed keys: catalog_limiting_v_mag, cosmic_rays_per_frame, "
                                               "mitsuba_spp, resolved_threshold_px"),
    ({"cosmic_rays_per_frame": -1}, "render.cosmic_rays_per_frame", "in [0, 163.84]"),
    ({"mitsuba_spp": 0.5}, "render.mitsuba_spp", "integer"),
    ({"resolved_threshold_px": 0}, "render.resolved_threshold_px", "> 0"),
    ({"catalog_limiting_v_mag": 8.0}, "render.catalog_limiting_v_mag", "equal to catalog_limiting_v_mag (9)"),
    ({"star_mag_limit": 8.0}, "render.star_mag_limit", "render.catalog_limiting_v_mag"),
    ([1, 2], "render", "a mapping"),
])
def test_bad_render_keys_are_refused_in_one_line(render, key, says):
    r = _small_montecarlo()
    r["render"] = render
    with pytest.raises((RecipeError, ConfigValueError)) as exc:
        validate_recipe(r)
    msg = str(exc.value)
    assert msg.startswith(key + " ") and says in msg and "\n" not in msg


def test_moved_cosmic_ray_key_points_to_a_key_that_works_in_both_contexts():
    recipe = _small_montecarlo()
    recipe["camera"] = {"preset": "paper", "width": 128, "height": 128, "cosmic_rays_per_frame": 0}
    scene = preset_mapping("default")
    scene["camera"] = {"preset": "paper", "cosmic_rays_per_frame": 0}
    for check, mapping in ((validate_recipe, recipe), (scene_spec_from_mapping, scene)):
        with pytest.raises(MovedKeyError) as exc:
            check(mapping)
        new = exc.value.new_key
        assert new == "render.cosmic_rays_per_frame"
        section, key = new.split(".")
        mapping["camera"].pop("cosmic_rays_per_frame")
        mapping.setdefault(section, {})[key] = 0  # following the message works
        check(mapping)
    assert validate_recipe(recipe)["render"] == {"cosmic_rays_per_frame": 0.0}


@pytest.mark.parametrize("kind", sorted(PRESETS))
def test_commented_preset_round_trips(kind, tmp_path):
    """The written file reads back as the preset; every key carries a comment line above it."""
    path = tmp_path / f"{kind}.yaml"
    path.write_text(recipe_yaml(kind))
    assert load_recipe_file(path) == validate_recipe(preset_recipe(kind))
    lines = path.read_text().splitlines()
    in_scenes = False
    for i, line in enumerate(lines):
        if line.startswith("scenes:"):
            in_scenes = True
        if not line.strip() or line.lstrip().startswith("#") or (in_scenes and line.startswith("  ")):
            continue
        assert lines[i - 1].lstrip().startswith("# "), f"line {i + 1} has no comment: {line!r}"


def test_commented_preset_gives_the_same_plan(tmp_path):
    """The montecarlo file's plan draws the same first scene as the preset's (same normalised recipe)."""
    from skynav.datasets.plan import frame_rng
    from skynav.datasets.samplers import make_plan

    path = tmp_path / "r.yaml"
    path.write_text(recipe_yaml("montecarlo"))
    a = make_plan(validate_recipe(yaml.safe_load(path.read_text()))).frame_request(0, frame_rng(1, 0))
    b = make_plan(validate_recipe(preset_recipe("montecarlo"))).frame_request(0, frame_rng(1, 0))
    assert a.epoch_tdb_s == b.epoch_tdb_s and np.array_equal(a.position_km, b.position_km)
    assert np.array_equal(a.R_cam_icrs, b.R_cam_icrs)


def test_scenes_recipe_per_scene_render_keys_win(tmp_path):
    """A scene's own render.mitsuba_spp / cosmic_rays_per_frame reach its frame; the recipe's the others."""
    from skynav.datasets.plan import frame_rng
    from skynav.datasets.samplers import make_plan

    r = preset_recipe("scenes")
    r["render"] = {"cosmic_rays_per_frame": 0, "resolved_threshold_px": 4.0}
    r["scenes"][1]["render"] = {"mitsuba_spp": 4, "cosmic_rays_per_frame": 2}
    r = validate_recipe(r)
    plan = make_plan(r)
    first, second = (plan.frame_request(k, frame_rng(1, k)) for k in range(2))
    assert (first.mitsuba_spp, first.cosmic_rays_per_frame) == (None, None)
    assert (second.mitsuba_spp, second.cosmic_rays_per_frame) == (4, 2.0)
    opts = recipe_render_options(r, RenderOptions())
    assert (opts.cosmic_rays_per_frame, opts.mitsuba_spp) == (0.0, 16)
