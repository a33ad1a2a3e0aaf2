"""``skynav bench loop --filter MODULE:FACTORY``: anyone's filter points the camera, through the same
interface as skynav's EKF; a bad import path is one line before any frame is asked for."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from .test_loop import SMALL

UKF = Path(__file__).resolve().parents[2] / "docs" / "examples" / "ukf_filter.py"
EKF = "skynav.pipeline.flight:skynav_ekf"


def test_the_example_ukf_flies_the_closed_loop_beside_the_ekf(server, tmp_path):
    out = tmp_path / "r"
    run = subprocess.run([sys.executable, "-m", "skynav", "bench", "loop", "sequence", "-o", str(out), "-q",
                          "--service", server.url, *SMALL, "--bias-km", "none", "--sigma-px", "0.1",
                          "--filter", EKF, "--filter", f"{UKF}:make_filter"], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    s = json.loads((out / "summary.json").read_text())
    rows = {r["filter"]: r for r in s["filters"]}
    assert list(rows) == [EKF, f"{UKF}:make_filter"]
    for r in rows.values():
        # the planet stayed in the field (the runs measured every frame) and nothing failed
        assert r["faults"]["steps_failed"] == 0 and r["measurements_accepted_fraction"] > 0.9
        assert r["final"]["position_3sigma_km"] < 3 * r["final"]["filter_position_3sigma_km"]
    assert s["measurements"]["frames_with_centroid"] == s["frames"] == 12
    assert "Filters side by side" in (out / "report.md").read_text()


def test_a_bad_filter_is_one_line_before_the_service_is_asked(tmp_path):
    run = subprocess.run([sys.executable, "-m", "skynav", "bench", "loop", "sequence", "-o", "x", "--service",
                          "http://127.0.0.1:9", "--filter", "no_such_module_xyz:make"],
                         capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "--filter no_such_module_xyz:make: no module named" in lines[0], run.stderr


FAULTY = Path(__file__).resolve().parents[1] / "pipeline" / "faulty_filters.py"


def test_a_faulty_filter_fails_its_steps_and_the_closed_loop_completes(server, tmp_path):
    """From its third update on the filter's covariance is not positive definite: those steps
    fail with the reason, the flight software holds its last pointing command, the loop runs to
    the last frame and writes its report."""
    out = tmp_path / "r"
    run = subprocess.run([sys.executable, "-m", "skynav", "bench", "loop", "sequence", "-o", str(out), "-q",
                          "--service", server.url, *SMALL, "--bias-km", "none", "--sigma-px", "0.1",
                          "--filter", f"{FAULTY}:not_positive_definite"], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    s = json.loads((out / "summary.json").read_text())
    assert list(s["faults"]["reasons"]) == ["covariance not positive definite"]
    assert s["faults"]["runs_failed"] == 1 and s["faults"]["steps_failed"] == 12 - s["faults"]["first_per_run"][0]["frame"]
    assert json.loads((out / "loop.json").read_text())["frames"] == 12


IP_PLUGIN = Path(__file__).resolve().parents[2] / "docs" / "examples" / "ip_plugin.py"


def test_the_documented_plugin_is_the_closed_loops_image_processing_with_the_ukf(server, tmp_path):
    """docs/examples/ip_plugin.py (scikit-image centroids, tetra3rs) processes the frames the UKF
    asked for: the loop runs to its last frame. The plug-in returns attitudes and no planet, so the
    filter only propagates, and no frame is a processor fault."""
    pytest.importorskip("tetra3rs")
    pytest.importorskip("skimage")
    out = tmp_path / "r"
    run = subprocess.run([sys.executable, "-m", "skynav", "bench", "loop", "sequence", "-o", str(out), "-q",
                          "--service", server.url, *SMALL, "--bias-km", "none", "--sigma-px", "0.1",
                          "--pipeline", f"{IP_PLUGIN}:make", "--filter", f"{UKF}:make_filter"],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    s = json.loads((out / "summary.json").read_text())
    assert s["run"]["pipeline"] == f"{IP_PLUGIN}:make" and s["filters"][0]["filter"] == f"{UKF}:make_filter"
    assert json.loads((out / "loop.json").read_text())["frames"] == s["frames"] == 12
    assert s["faults"]["steps_failed"] == 0 and s["measurements"]["frames_with_centroid"] == 0
    assert not any(k.startswith("processor fault") for k in s["ip_status_counts"]), s["ip_status_counts"]


def test_a_processor_fault_in_the_closed_loop_is_a_failed_measurement(server, tmp_path):
    """skynav's pipeline raising on its third frame: that frame is not measured, with the reason;
    the loop runs on and measures the others."""
    out = tmp_path / "r"
    run = subprocess.run([sys.executable, "-m", "skynav", "bench", "loop", "sequence", "-o", str(out), "-q",
                          "--service", server.url, *SMALL, "--bias-km", "none", "--sigma-px", "0.1",
                          "--pipeline", f"{FAULTY.parent / 'faulty_processors.py'}:raising"],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    s = json.loads((out / "summary.json").read_text())
    assert s["ip_status_counts"]["processor fault (exception: RuntimeError: the detector's driver crashed)"] == 1
    assert s["measurements"]["frames_with_centroid"] == 11 and s["faults"]["steps_failed"] == 0
