"""``skynav bench loop``: the flight software points the camera from its own estimate and reaches the
renderer only through the service's client."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np
import pytest

# two legs of three frames per planet; 256 px over the paper camera's 20 deg (star ID needs the
# field's stars; 284"/px works since the k-vector window is capped in angle, ProcessOptions)
SMALL = ["--set", "sequence.legs=2", "--set", "sequence.track_s=300", "--set", "camera.width=256",
         "--set", "camera.height=256", "--set", "camera.fov_deg=20"]

DRIVER = """
import json, sys
from skynav.cli import main
rc = main(sys.argv[1:])
loaded = sorted(m for m in sys.modules if m.split(".")[0] in ("mitsuba", "drjit")
                or m == "skynav.renderer" or m.startswith("skynav.renderer."))
print(json.dumps({"rc": rc, "loaded": loaded}))
"""


def _loop(server, out, *args):
    run = subprocess.run([sys.executable, "-c", DRIVER, "bench", "loop", "sequence", "-o", str(out), "-q",
                          "--service", server.url, *SMALL, *args], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    return json.loads(run.stdout.strip().splitlines()[-1]), run


def test_closed_loop_keeps_its_planet_and_loses_it_from_a_biased_start(server, tmp_path):
    got, run = _loop(server, tmp_path / "r", "--bias-km", "auto")
    assert got["rc"] == 0
    assert got["loaded"] == [], "the flight software's process must not load the renderer"
    loop = json.loads((tmp_path / "r" / "loop.json").read_text())
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    for name in ("report.html", "frames.csv", "runs.csv"):
        assert (tmp_path / "r" / name).is_file()
    assert summary["closed_loop"] == loop
    # good pointing: the planet in every frame, near the centre (the controller's 0.01 deg is 0.3 px)
    assert loop["target_in_field_fraction"] == 1.0 and loop["target_centred_fraction"] == 1.0
    assert summary["measurements"]["frames_with_centroid"] == loop["frames"] == 12
    # R measured as bench nav measures it (calibrate_sigma_px), on a rendering no run sees
    assert summary["noise"]["frames"] == 12 and 0 < summary["noise"]["sigma0_px"] < 0.5
    b = loop["biased_initial_state"]
    # the same biased start (1.5 half-fields off, and the filter told so by P0): pointed from the
    # truth, as a dataset is, the planet is always in view and the filter converges; pointed from
    # the estimate, the planet is out of the field from the first frame and the error stays
    assert b["open_loop"]["target_in_field_fraction"] == 1.0
    assert b["closed_loop"]["first_frame_lost"] == [0]
    assert b["closed_loop"]["target_in_field_fraction"] < 1.0
    assert b["open_loop"]["final_position_error_km"] < 0.05 * b["bias_km"]
    assert b["closed_loop"]["final_position_error_km"] > 10 * b["open_loop"]["final_position_error_km"]


def test_realtime_counts_deadline_misses_on_a_wall_clock(server, tmp_path):
    # a million simulated s per wall s: 0.1 ms per frame, which no frame meets
    got, _ = _loop(server, tmp_path / "b", "--bias-km", "none", "--limit", "3", "--realtime", "1e6")
    assert got["rc"] == 0
    loop = json.loads((tmp_path / "b" / "loop.json").read_text())
    assert loop["realtime_scale"] == 1e6 and loop["deadline_misses"] == 3
    assert loop["latency_s"]["median"] > 0 and loop["latency_s"]["p99"] >= loop["latency_s"]["median"]


def test_realtime_waits_for_the_wall_clock(server):
    """Frames 100 s apart at 500 simulated s per wall s: the three frames span at least 0.4 s."""
    from skynav import datasets
    from skynav.datasets.recipes import read_recipe_mapping
    from skynav.pipeline.ekf import initial_covariance
    from skynav.service import Client
    from skynav.service.loop import Simulator, run_loop

    r = read_recipe_mapping("sequence")
    r["sequence"].update(legs=1, track_s=300)
    r["camera"].update(width=256, height=256, fov_deg=20)
    sim = Simulator(datasets.validate_recipe(r), limit=3)
    x0 = np.concatenate([*sim.state(sim.schedule()[0][0]), np.zeros(6)])
    t0 = time.perf_counter()
    run = run_loop(sim, Client(server.url), x0=x0, P0=initial_covariance(), noise=0.1, realtime=500.0)
    assert time.perf_counter() - t0 >= 0.4
    assert run.in_field.all() and 0 <= int(run.late.sum()) <= 3


def test_given_sigma_is_the_filters_noise(server, tmp_path):
    got, _ = _loop(server, tmp_path / "g", "--bias-km", "none", "--limit", "3", "--sigma-px", "0.2")
    summary = json.loads((tmp_path / "g" / "summary.json").read_text())
    assert summary["noise"] == {"sigma0_px": 0.2, "kappa": 0.0, "frames": 0, "classes": {}}


def test_runs_and_the_calibration_see_renderings_of_their_own():
    """Frame k of rendering 0 keeps the dataset's seed scheme SeedSequence([seed, k]); other
    renderings (later runs, the noise calibration) draw other controller errors and image noise;
    the observer is the same."""
    from skynav import datasets
    from skynav.datasets.recipes import read_recipe_mapping
    from skynav.service.loop import CALIBRATION_RENDERING, Simulator

    r = read_recipe_mapping("sequence")
    r["sequence"].update(legs=1, track_s=300)
    r["render"] = {"resolved_threshold_px": 5.0, "cosmic_rays_per_frame": 0}
    sim = Simulator(datasets.validate_recipe(r), limit=2)
    t = sim.schedule()[1][0]
    scenes = {g: sim.scene(1, t, np.eye(3), g) for g in (0, 1, CALIBRATION_RENDERING)}
    assert scenes[0]["render"]["seed"] == int(np.random.SeedSequence([sim.master_seed, 1]).generate_state(1)[0])
    assert len({s["render"]["seed"] for s in scenes.values()}) == 3
    assert len({tuple(s["attitude"]["q_cam_icrs"]) for s in scenes.values()}) == 3
    # the recipe's render keys reach the service, as they reach the dataset's frames
    assert scenes[0]["render"]["resolved_threshold_px"] == 5.0 and scenes[0]["render"]["cosmic_rays_per_frame"] == 0
    assert all(s["observer"] == scenes[0]["observer"] for s in scenes.values())


def test_pointed_from_the_truth_the_loop_sees_the_datasets_attitudes():
    """Rendering 0 of the loop draws the controller's pointing errors of the recipe's dataset,
    frame by frame: pointed from the truth, its attitudes are the dataset sampler's
    (skynav.datasets.sequence, with its own apparent directions) to 0.01 px, where another draw
    of the 0.01 deg errors (0.5 px per axis on the paper camera) is ~0.7 px off. The planet's pixel
    phase, and with it most of the centroid error, is then the dataset's (docs/service.md)."""
    from skynav import datasets
    from skynav.datasets.plan import frame_rng
    from skynav.datasets.recipes import read_recipe_mapping, recipe_camera
    from skynav.scenes import frames
    from skynav.scenes.ephemeris_jpl import default_ephemeris
    from skynav.service.loop import Simulator, point_at

    r = read_recipe_mapping("sequence")
    r["seed"] = 5
    sim = Simulator(datasets.validate_recipe(r))
    ifov_arcsec = np.degrees(recipe_camera(sim.recipe).ifov_rad) * 3600
    eph = default_ephemeris()
    sched = sim.schedule()
    twist = np.radians(sim.recipe["sequence"]["twist_deg"])
    for k in (0, 1, len(sched) // 2, len(sched) - 1):
        t, _, _, target = sched[k]
        scene = sim.scene(k, t, point_at(eph, target, t, *sim.state(t), twist))
        R_loop = frames.quat_to_dcm(scene["attitude"]["q_cam_icrs"])
        R_data = sim.plan.frame_request(k, frame_rng(5, k)).R_cam_icrs
        R_other = sim.plan.frame_request(k, frame_rng(6, k)).R_cam_icrs
        off = [np.degrees(np.arccos(min(1.0, (np.trace(R_loop @ R.T) - 1) / 2))) * 3600 / ifov_arcsec
               for R in (R_data, R_other)]
        assert off[0] < 0.01 and off[1] > 0.05, (k, off)


@pytest.mark.parametrize("args, words", [
    (["montecarlo", "-o", "x"], "sequence"),
    (["sequence", "-o", "x", "--runs", "0"], "--runs"),
    (["sequence", "-o", "x", "--realtime", "-2"], "--realtime"),
    (["sequence", "-o", "x", "--bias-km", "far"], "--bias-km"),
    (["sequence", "-o", "x", "--sigma-px", "0"], "--sigma-px"),
    (["sequence", "-o", "x", "--calibration-stride", "0"], "--calibration-stride"),
    (["sequence", "-o", "x", "--calibration-stride", "2", "--sigma-px", "0.1"], "one or the other"),
    # 128 px over 20 deg, 568 arcsec/px: star ID finds a third of the attitudes (pipeline/star_id.py)
    (["sequence", "-o", "x", "--set", "camera.width=128", "--set", "camera.height=128", "--set", "camera.fov_deg=20"],
     "568 arcsec/px; star identification needs at most 460 arcsec/px"),
])
def test_bad_loop_arguments_are_one_line(tmp_path, args, words):
    run = subprocess.run([sys.executable, "-m", "skynav", "bench", "loop", *args, "--service", "http://127.0.0.1:9"],
                         capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], run.stderr


def test_the_command_points_at_the_apparent_direction():
    """point_at puts the planet's apparent direction (light time and the observer's aberration) on
    the boresight, where a dataset points: checked against the scene model's iterated light time,
    deflection and exact aberration (skynav.scenes.sky.sky_bodies) to 0.05 arcsec (the first-order
    light time and the Sun's deflection, mas). Without the aberration it is ~20 arcsec off, 0.3 px."""
    from skynav import datasets
    from skynav.datasets.recipes import read_recipe_mapping
    from skynav.scenes.ephemeris_jpl import default_ephemeris
    from skynav.scenes.sky import sky_bodies
    from skynav.service.loop import Simulator, point_at

    sim = Simulator(datasets.validate_recipe(read_recipe_mapping("sequence")))
    eph = default_ephemeris()
    sched = sim.schedule()
    for k in (0, len(sched) // 2, len(sched) - 1):
        t, _, _, target = sched[k]
        r, v = sim.state(t)
        body = next(b for b in sky_bodies(t, r, v, ephemeris=eph)[0] if b.name == target)
        u = np.asarray(body.directions.u_icrs)
        off = [np.degrees(np.arccos(min(1.0, float(point_at(eph, target, t, r, vel)[2] @ u)))) * 3600
               for vel in (v, np.zeros(3))]
        assert off[0] < 0.05 and off[1] > 10.0, (k, off)
