"""One name per quantity (docs/conventions.md): the apparent direction is ``u_icrs`` in the truth
files, the typed truth and the scene; ``u_apparent`` is an alias that gives the same array; the
truth JSON keeps its schema (the files say ``u_icrs`` only)."""

import json

import numpy as np
import pytest

from skynav.cli import main


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    out = tmp_path_factory.mktemp("aliases")
    assert main(["render", "-o", str(out), "--backend", "numpy"]) == 0
    return out / "frame.json"


def test_truth_file_keeps_its_names(rendered):
    truth = json.loads(rendered.read_text())
    for rec in truth["stars"][:5] + truth["bodies"]:
        assert "u_icrs" in rec and "u_apparent" not in rec


def test_typed_truth_alias_is_the_same_array(rendered):
    from skynav.datasets.frame_truth import read_frame_truth

    t = read_frame_truth(rendered)
    assert len(t.stars) > 0 and t.stars.u_apparent is t.stars.u_icrs
    raw = json.loads(rendered.read_text())
    np.testing.assert_array_equal(t.stars.u_apparent, np.array([s["u_icrs"] for s in raw["stars"]]))
    for b in t.bodies:
        assert b.u_apparent is b.u_icrs


def test_scene_and_ephemeris_use_the_same_name():
    from skynav.scenes import config, presets
    from skynav.scenes.apparent import apparent_body
    from skynav.scenes.ephemeris_jpl import Ephemeris
    from skynav.scenes.scene import build_from_spec

    scene = build_from_spec(config.scene_spec_from_mapping(presets.preset_mapping("default")))
    assert scene.stars.u_apparent is scene.stars.u_icrs
    mars = next(b for b in scene.bodies if b.name == "mars")
    assert mars.u_apparent is mars.u_icrs
    d = apparent_body(Ephemeris(), "mars", scene.position_km, scene.velocity_km_s, scene.epoch_tdb_s)
    assert d.u_apparent is d.u_icrs
    # the scene's body view is the ephemeris' apparent direction under the same name
    np.testing.assert_array_equal(np.asarray(mars.u_icrs), d.u_icrs)
