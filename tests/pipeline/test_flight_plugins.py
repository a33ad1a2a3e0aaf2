"""Navigation filters as plug-ins (``bench nav --filter MODULE:FACTORY``): faults are results, a bad
import path is one line, anyone's filter flies beside skynav's EKF."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from skynav.cli import main

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
FAULTY = HERE / "faulty_filters.py"
UKF = REPO / "docs" / "examples" / "ukf_filter.py"


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    d = tmp_path_factory.mktemp("flight") / "seq"
    assert main(["dataset", "generate", "sequence", "-o", str(d), "--count", "6", "--workers", "1", "-q"]) == 0
    return d


def _nav(seq, out, *args):
    return main(["bench", "nav", str(seq), "--runs", "3", "--seed", "3", "--sigma-px", "0.1", "-q", "-o", str(out),
                 *args])


@pytest.mark.parametrize("factory, reason, runs_failed", [
    ("raising", "update raised FloatingPointError: the innovation covariance is singular", 3),
    ("nan_state", "non-finite state or covariance", 1),
    ("not_positive_definite", "covariance not positive definite", 1),
])
def test_a_filter_fault_fails_the_step_with_its_reason_and_the_run_completes(seq, tmp_path, factory, reason, runs_failed):
    out = tmp_path / "r"
    assert _nav(seq, out, "--filter", f"{FAULTY}:{factory}") == 0
    s = json.loads((out / "summary.json").read_text())
    f = s["faults"]
    assert list(f["reasons"]) == [reason]
    assert f["runs_failed"] == runs_failed
    # the third frame with a centroid is the first failed step, and every step after it fails
    assert f["steps_failed"] == runs_failed * (s["frames"] - f["first_per_run"][0]["frame"])
    assert s["frames"] == 6 and s["runs"] == (3 if runs_failed == 3 else 2)   # statistics over usable runs
    assert reason in (out / "report.md").read_text()


@pytest.mark.parametrize("spec, words", [
    ("nosuch_module_xyz:make", "--filter nosuch_module_xyz:make: no module named 'nosuch_module_xyz'"),
    ("skynav.pipeline.flight:no_such_factory", "has no 'no_such_factory'"),
    ("skynav.pipeline.flight", "give MODULE:FACTORY"),
    (f"{FAULTY}:failing_factory", "the factory failed (RuntimeError: no licence for this filter)"),
    (f"{FAULTY}:not_a_filter", "has no initialise, propagate, update, state"),
    ("missing/dir/filter.py:make", "no such file missing/dir/filter.py"),
])
def test_a_bad_filter_path_is_one_line_exit_2(seq, tmp_path, capsys, spec, words):
    assert _nav(seq, tmp_path / "r", "--filter", spec) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0] and "Traceback" not in err[0], err


def test_the_example_ukf_flies_beside_the_ekf_and_agrees_with_it(seq, tmp_path):
    """Two implementations of one estimator (skynav's iterated EKF, the example's UKF; the same
    force model, measurement and initial states): their final position errors agree to 10 % of
    the filter's own position sigma, far inside it."""
    out = tmp_path / "r"
    assert _nav(seq, out, "--filter", "skynav.pipeline.flight:skynav_ekf", "--filter", f"{UKF}:make_filter") == 0
    s = json.loads((out / "summary.json").read_text())
    rows = {r["filter"]: r for r in s["filters"]}
    assert set(rows) == {"skynav.pipeline.flight:skynav_ekf", f"{UKF}:make_filter"}
    ekf, ukf = rows["skynav.pipeline.flight:skynav_ekf"], rows[f"{UKF}:make_filter"]
    assert ukf["faults"]["steps_failed"] == 0 and ukf["measurements_accepted_fraction"] == 1.0
    sigma_km = ekf["final"]["filter_position_3sigma_km"] / 3
    assert abs(ukf["final"]["position_error_rms_km"] - ekf["final"]["position_error_rms_km"]) < 0.1 * sigma_km
    assert abs(ukf["final"]["filter_position_3sigma_km"] - ekf["final"]["filter_position_3sigma_km"]) < 0.1 * 3 * sigma_km
    md = (out / "report.md").read_text()
    assert "Filters side by side" in md and "Andreis et al. (2024) (published" in md
    assert (out / "report.html").read_text().count("data:image/png;base64,") == 5


def test_the_line_of_sight_and_its_covariance_through_the_camera():
    """The measurement's line of sight projects back to its pixel, and its covariance at the
    principal point is sigma^2 / f^2 on the two axes across it (pinhole: d(x/z)/dx = 1/f)."""
    from skynav.pipeline.flight import _line_of_sight
    from skynav.scenes.camera import paper_camera
    from skynav.scenes.frames import radec_twist_to_dcm

    cam = paper_camera()
    R = np.asarray(radec_twist_to_dcm(0.3, -0.2, 0.1))
    xy0 = cam.K[:2, 2]
    u, C = _line_of_sight(xy0, 0.1, R, cam)
    assert np.isclose(np.linalg.norm(u), 1.0, atol=1e-12)
    assert np.allclose(cam.project((R @ u).reshape(1, 3))[0], xy0, atol=1e-6)   # px
    w = np.linalg.eigvalsh(C)
    assert abs(w[0]) < 1e-20                                                       # none along the line of sight
    assert np.allclose(w[1:], (0.1 / cam.focal_length_px) ** 2, rtol=1e-3)
    xy1 = np.array([900.3, 120.7])
    u1, _ = _line_of_sight(xy1, 0.1, R, cam)
    assert np.allclose(cam.project((R @ u1).reshape(1, 3))[0], xy1, atol=1e-6)


# ---- the image processor of the flight (``--pipeline MODULE:FACTORY``), through the same door
PROCESSORS = HERE / "faulty_processors.py"
IP_PLUGIN = REPO / "docs" / "examples" / "ip_plugin.py"


def _frames(out):
    with open(out / "frames.csv", newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


@pytest.mark.parametrize("factory, reason", [
    ("raising", "processor fault (exception: RuntimeError: the detector's driver crashed)"),
    ("reflection", "processor fault (not_rotation: R_cam_icrs is a reflection (det = -1), not a rotation)"),
    ("wrong_type", "processor fault (wrong_type: returned str; expected skynav.pipeline.ImageResult)"),
    ("slow", "processor fault (timeout: over the 5 s frame time limit)"),
])
def test_a_processor_fault_is_a_failed_measurement_with_its_reason_and_the_flight_goes_on(seq, tmp_path, factory,
                                                                                         reason):
    """The third frame's processor faults: that frame gives the filter nothing (its status says
    why); every other frame is measured exactly as skynav's default pipeline measures it."""
    ref, out = tmp_path / "ref", tmp_path / "r"
    assert _nav(seq, ref) == 0
    assert _nav(seq, out, "--pipeline", f"{PROCESSORS}:{factory}", "--frame-timeout", "5") == 0
    s, s_ref = (json.loads((d / "summary.json").read_text()) for d in (out, ref))
    assert s["run"]["pipeline"] == f"{PROCESSORS}:{factory}"
    rows, rows_ref = _frames(out), _frames(ref)
    assert [r["ip_status"] for r in rows] == [reason if i == 2 else r["ip_status"] for i, r in enumerate(rows_ref)]
    assert s["ip_status_counts"][reason] == 1 and s["faults"]["steps_failed"] == 0   # the filter did not fault
    assert rows[2]["measured_dx_px"] == "nan" != rows_ref[2]["measured_dx_px"]
    assert [r["measured_dx_px"] for r in rows[:2]] == [r["measured_dx_px"] for r in rows_ref[:2]]
    assert s["measurements"]["frames_with_centroid"] == s_ref["measurements"]["frames_with_centroid"] - 1
    assert reason in (out / "report.md").read_text()


@pytest.mark.parametrize("args, words", [
    (["--pipeline", "nosuch_tracker_xyz:make"], "--pipeline nosuch_tracker_xyz:make: no module named 'nosuch_tracker_xyz'"),
    (["--pipeline", "skynav", "--pipeline", f"{IP_PLUGIN}:make"], "a flight has one image processor"),
    (["--pipeline", f"{PROCESSORS}:failing_factory"], "the factory raised RuntimeError: no licence for this tracker"),
    (["--pipeline", "missing/dir/tracker.py:make"], "no such file missing/dir/tracker.py"),
])
def test_a_bad_pipeline_is_one_line_exit_2(seq, tmp_path, capsys, args, words):
    assert _nav(seq, tmp_path / "r", *args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0] and "Traceback" not in err[0], err


def test_the_documented_plugin_and_ukf_fly_bench_nav_unchanged(seq, tmp_path):
    """docs/examples/ip_plugin.py (scikit-image centroids, tetra3rs) is the image processing and
    docs/examples/ukf_filter.py the filter: the flight completes. The plug-in finds no planet
    (it returns attitudes only), so the filter is never given a centroid: it only propagates."""
    pytest.importorskip("tetra3rs")
    pytest.importorskip("skimage")
    out = tmp_path / "r"
    assert _nav(seq, out, "--pipeline", f"{IP_PLUGIN}:make", "--filter", f"{UKF}:make_filter") == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["run"]["pipeline"] == f"{IP_PLUGIN}:make" and s["frames"] == 6
    assert s["faults"]["steps_failed"] == 0 and s["measurements"]["frames_with_centroid"] == 0
    assert not any(k.startswith("processor fault") for k in s["ip_status_counts"]), s["ip_status_counts"]
