"""A sequence from a mission's kernels: the ``sequence`` preset's cruise written as a Type 13 SPK
and its frames' attitudes as a Type 3 CK (with its SCLK and FK), with spiceypy, drive
``skynav dataset generate`` to the built-in frames' observer (1 m), attitude (0.01") and star
pixels (1e-4 px); the manifest and the truth record each kernel's name and SHA-256."""

import hashlib
import json

import numpy as np
import pytest
import yaml

sp = pytest.importorskip("spiceypy")

from skynav.cli import main  # noqa: E402
from skynav.datasets import validate_recipe  # noqa: E402
from skynav.datasets.errors import RecipeError  # noqa: E402
from skynav.datasets.recipes import load_recipe_file, preset_recipe  # noqa: E402
from skynav.datasets.samplers import make_plan  # noqa: E402
from skynav.datasets.sequence_kernels import rotation_vector  # noqa: E402
from skynav.scenes import frames  # noqa: E402
from ..scenes.spice_texts import FK, SCLK  # noqa: E402


def small_recipe() -> dict:
    """The ``sequence`` preset, one leg, three frames of a 256 px camera, JSON only."""
    r = preset_recipe("sequence")
    r["sequence"]["legs"] = 1
    r.update(frames=3, formats=["json"], camera={"preset": "paper", "width": 256, "height": 256, "fov_deg": 20.0},
             render={"cosmic_rays_per_frame": 0})
    return r


def write_cruise_spk(path, plan, body=-999):
    """The plan's cruise, hourly states over its span, as a Type 13 (Hermite, degree 7) SPK."""
    t = np.append(np.arange(plan.start_tdb_s, plan.end_tdb_s, 3600.0), plan.end_tdb_s)
    r, v = plan.trajectory.state(t)
    h = sp.spkopn(str(path), "skynav cruise", 0)
    sp.spkw13(h, body, 0, "J2000", t[0], t[-1], "cruise", 7, len(t), np.hstack([r, v]), t)
    sp.spkcls(h)


def write_frames_ck(folder, epochs, Rs, ws):
    """The frames' attitudes as a Type 3 CK (rates in J2000, as CK stores them) with its SCLK
    (TDB ticks of 1/65536 s) and FK; a record a second before the first frame and after the
    last (propagated at the frame's rate) keeps each frame inside the segment despite the ticks."""
    (folder / "craft.tsc").write_text(SCLK.format(et0=repr(float(epochs[0]) - 60.0)))
    (folder / "craft.tf").write_text(FK)
    recs = [(epochs[0] - 1.0, frames.propagate_attitude(Rs[0], ws[0], -1.0), ws[0])]
    recs += list(zip(epochs, Rs, ws))
    recs.append((epochs[-1] + 1.0, frames.propagate_attitude(Rs[-1], ws[-1], 1.0), ws[-1]))
    sp.furnsh(str(folder / "craft.tsc"))
    try:
        ticks = np.array([sp.sce2c(-999, float(e)) for e, _, _ in recs])
    finally:
        sp.unload(str(folder / "craft.tsc"))
    quats = np.array([sp.m2q(np.asarray(R)) for _, R, _ in recs])
    av = np.array([np.asarray(R).T @ np.asarray(w) for _, R, w in recs])
    h = sp.ckopn(str(folder / "craft.bc"), "skynav frames", 0)
    sp.ckw03(h, ticks[0], ticks[-1], -999000, "J2000", True, "frames", len(ticks), ticks, quats, av, 1, ticks[:1])
    sp.ckcls(h)


def _truths(folder):
    return [json.loads(p.read_text()) for p in sorted((folder / "frames").glob("*.json"))]


def _generate(recipe_path, out):
    assert main(["dataset", "generate", str(recipe_path), "-o", str(out), "--workers", "1", "-q"]) == 0


def test_kernels_drive_dataset_generate_to_the_built_in_frames(tmp_path):
    recipe = small_recipe()
    (tmp_path / "built_in.yaml").write_text(yaml.safe_dump(recipe))
    _generate(tmp_path / "built_in.yaml", tmp_path / "built_in")
    ref = _truths(tmp_path / "built_in")
    kernels = tmp_path / "kernels"
    kernels.mkdir()
    write_cruise_spk(kernels / "cruise.bsp", make_plan(validate_recipe(recipe)))
    write_frames_ck(kernels, [t["epoch"]["tdb_seconds_past_j2000"] for t in ref],
                    [t["attitude"]["R_cam_icrs"] for t in ref], [t["attitude"]["angular_velocity_rad_s"] for t in ref])

    recipe["sequence"]["observer"] = {"spice": {"kernels": ["kernels/cruise.bsp"], "body": "-999"}}
    recipe["sequence"]["attitude"] = {"spice": {"kernels": ["kernels/craft.bc", "kernels/craft.tsc", "kernels/craft.tf"],
                                                "frame": "SKYNAV_CAM"}}
    (tmp_path / "from_kernels.yaml").write_text(yaml.safe_dump(recipe))
    _generate(tmp_path / "from_kernels.yaml", tmp_path / "from_kernels")
    mine = _truths(tmp_path / "from_kernels")

    assert len(mine) == len(ref) == 3
    for a, b in zip(mine, ref):
        assert a["epoch"]["tdb_seconds_past_j2000"] == b["epoch"]["tdb_seconds_past_j2000"]
        # Hermite of degree 7 on hourly states of a smooth cruise: well inside 1 m and 1 mm/s
        assert np.max(np.abs(np.subtract(a["observer"]["position_km"], b["observer"]["position_km"]))) < 1e-3
        assert np.max(np.abs(np.subtract(a["observer"]["velocity_km_s"], b["observer"]["velocity_km_s"]))) < 1e-6
        dR = np.asarray(a["attitude"]["R_cam_icrs"]) @ np.asarray(b["attitude"]["R_cam_icrs"]).T
        angle = np.linalg.norm(rotation_vector(dR))  # not arccos of the trace: blind below 1e-8 rad
        assert np.degrees(angle) * 3600 < 0.01   # CK ticks of 1/65536 s at the frames' rates
        assert [s["hip"] for s in a["stars"]] == [s["hip"] for s in b["stars"]] and len(a["stars"]) > 10
        assert np.max(np.abs(np.subtract([s["xy"] for s in a["stars"]], [s["xy"] for s in b["stars"]]))) < 1e-4
        assert a["dataset"]["target"] == b["dataset"]["target"]
        # the pointing error the truth gives is the CK's rotation from the nominal: the drawn one
        np.testing.assert_allclose(a["dataset"]["pointing_error_rad"], b["dataset"]["pointing_error_rad"], atol=1e-7)

    names = ["kernels/cruise.bsp", "kernels/craft.bc", "kernels/craft.tsc", "kernels/craft.tf"]
    sha = {n: hashlib.sha256((tmp_path / n).read_bytes()).hexdigest() for n in names}
    assert [(f["name"], f["sha256"]) for f in mine[0]["data_files"]] == [(n, sha[n]) for n in names]
    manifest = json.loads((tmp_path / "from_kernels" / "manifest.json").read_text())
    plan = manifest["plan"]
    assert "transfer" not in plan and plan["observer"]["spice"]["body"] == "-999"
    assert [k["name"] for k in plan["observer"]["spice"]["kernels"]] == names[:1]
    assert {k["name"]: k["sha256"] for k in plan["attitude"]["spice"]["kernels"]} == {n: sha[n] for n in names[1:]}
    assert manifest["recipe"]["sequence"]["observer"]["spice"]["kernels"] == names[:1]  # as written
    assert str(tmp_path) not in (tmp_path / "from_kernels" / "manifest.json").read_text()


def test_kernels_that_stop_before_the_legs_end_are_one_line(tmp_path):
    recipe = small_recipe()
    plan = make_plan(validate_recipe(recipe))
    write_cruise_spk(tmp_path / "cruise.bsp", plan)
    recipe["sequence"]["legs"] = 2
    recipe["sequence"]["observer"] = {"spice": {"kernels": ["cruise.bsp"], "body": "-999"}}
    (tmp_path / "r.yaml").write_text(yaml.safe_dump(recipe))
    with pytest.raises(RecipeError, match="sequence.observer.spice.kernels .*they stop at"):
        make_plan(load_recipe_file(tmp_path / "r.yaml"))
    recipe["sequence"]["observer"]["spice"]["body"] = "-555"
    (tmp_path / "r.yaml").write_text(yaml.safe_dump(recipe))
    with pytest.raises(RecipeError, match="an SPK segment of body -555"):
        make_plan(load_recipe_file(tmp_path / "r.yaml"))


@pytest.mark.parametrize("source, match", [
    ({"spice": {"kernels": [], "body": "-999"}}, "sequence.observer.spice.kernels"),
    ({"spice": {"kernels": ["a.bsp"]}}, r"sequence.observer = .*\{spice: \{kernels: \[FILE, \.\.\.\], body"),
    ({"oem": "a.oem"}, "sequence.observer = "),
])
def test_a_malformed_kernel_source_names_its_key(source, match):
    recipe = small_recipe()
    recipe["sequence"]["observer"] = source
    with pytest.raises(RecipeError, match=match):
        validate_recipe(recipe)
