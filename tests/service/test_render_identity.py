"""The service's frames are byte-identical to ``skynav render`` of the same scene file (same code,
same seed: equal bytes is the contract here, not an agreement of two implementations)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from .conftest import small_scene


def _render_files(mapping, tmp_path, name):
    """``skynav render`` of the mapping written as a scene file (JSON is YAML), run in this process
    (the command's own code; a fresh interpreter per call would add ~4 s of imports each)."""
    from skynav.cli import main

    scene = tmp_path / f"{name}.yaml"
    scene.write_text(json.dumps(mapping))
    out = tmp_path / name
    assert main(["render", str(scene), "-o", str(out)]) == 0
    return {k: (out / f"frame.{ext}").read_bytes() for k, ext in (("png", "png"), ("exr", "exr"), ("truth", "json"))}


def test_default_scene_and_a_resolved_body_with_a_streak_are_byte_identical(client, tmp_path):
    """A determinism test: the worker runs the same code as skynav render (validator, options,
    encoders) with the same seed, on this machine, so the bytes must be equal."""
    default = small_scene("default", size=256)
    # Earth and Moon resolved (Mitsuba), the camera turning 3 deg/s: a ~3 px streak in 10 ms
    streak = small_scene("earth_departure", size=256, attitude={"angular_velocity_deg_s": [0.0, 3.0, 0.0]})
    for name, mapping in (("default", default), ("streak", streak)):
        files = _render_files(mapping, tmp_path, name)
        got = client.render(mapping, outputs=("png", "exr", "truth"))
        assert got.png == files["png"], name
        assert got.exr == files["exr"], name
        assert got.truth_json == files["truth"], name
        truth = got.truth
        if name == "streak":
            resolved = [b for b in truth["bodies"] if b["resolved"]]
            assert {b["name"] for b in resolved} >= {"earth"}
            assert truth["attitude"]["angular_velocity_rad_s"][1] == pytest.approx(np.radians(3.0))
        assert got.dn.shape == (256, 256) and got.dn.max() > 0
        assert got.electrons.shape == (256, 256) and float(got.electrons.sum()) > 0


def test_one_output_comes_with_its_media_type_and_curl_gets_the_same_png(server, client, tmp_path):
    curl = shutil.which("curl")
    if curl is None:
        pytest.skip("curl is not installed")
    mapping = small_scene(size=128)
    req = tmp_path / "req.json"
    req.write_text(json.dumps({**mapping, "outputs": ["png"]}))
    out = tmp_path / "c.png"
    run = subprocess.run([curl, "-sS", "-f", "-X", "POST", "-H", "Content-Type: application/json", "--data-binary",
                          f"@{req}", "-o", str(out), "-w", "%{content_type}", f"{server.url}/v1/render"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout == "image/png"
    assert out.read_bytes() == client.render(mapping, outputs=("png",)).png
    assert out.read_bytes() == _render_files(mapping, tmp_path, "cli")["png"]


def test_the_seed_is_the_scene_files_render_seed(client):
    a = client.render(small_scene(render={"seed": 5}), outputs=("png",)).dn
    b = client.render(small_scene(render={"seed": 6}), outputs=("png",)).dn
    a2 = client.render(small_scene(render={"seed": 5}), outputs=("png",)).dn
    assert np.array_equal(a, a2) and not np.array_equal(a, b)


def test_a_seed_past_64_bits_is_refused_naming_the_field(client):
    """A seed is an integer in 0..2**63-1 everywhere (``--seed`` and the service's numeric check):
    a request with a seed past 64 bits (here 2**97 + 3, which a float reader would round to
    another frame's seed) is a 400 naming ``render.seed``, never another frame."""
    from skynav.service import ServiceError

    with pytest.raises(ServiceError, match="render.seed"):
        client.render(small_scene(size=64, render={"seed": 2**97 + 3}), outputs=("png",))


CLIENT_DECODES = """
import json, sys
from skynav.service import Client
from skynav.scenes.presets import preset_mapping
m = preset_mapping("default"); m["camera"].update({"width": 64, "height": 64})
r = Client(sys.argv[1]).render(m, outputs=("png", "exr", "truth"))
assert r.dn.shape == (64, 64) and r.electrons.shape == (64, 64) and r.truth["schema"] == "skynav.frame/2"
print(json.dumps(sorted(k for k in sys.modules if k.split(".")[0] in ("mitsuba", "drjit")
                        or k.startswith("skynav.renderer"))))
"""


def test_a_client_process_decodes_frames_without_loading_the_renderer(server):
    run = subprocess.run([sys.executable, "-c", CLIENT_DECODES, server.url], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    assert json.loads(run.stdout.strip().splitlines()[-1]) == []
