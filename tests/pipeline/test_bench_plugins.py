"""``bench ip`` with plug-ins: skynav's pipeline through the plug-in door gives the figures of the
pipeline called directly, a plug-in's every fault is a failed frame with its reason (the run
completes), and a bad import path is one line and exit 2."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

import skynav.datasets as D
from skynav.cli import main
from skynav.pipeline import ImageResult, OnboardCatalog, process_frame
from skynav.pipeline.plugins import PluginError, call_processor, load_factory
from skynav.pipeline.scoring import open_frames, predicted_state, run_benchmark, score_frame

from ..datasets.conftest import small_recipe


@pytest.fixture(scope="module")
def mc4(tmp_path_factory):
    """Four Monte Carlo frames (256 x 256 px, 20 deg field)."""
    root = tmp_path_factory.mktemp("plugins") / "mc4"
    D.generate(small_recipe(frames=4), root, workers=1, progress=False)
    return root


SIGMAS = (1e4, 1e7)


@pytest.mark.parametrize("mode", ["paper", "improved"])
def test_the_plugin_layer_moves_no_figure(mc4, mode):
    """Every (frame, sigma) scored through ``--pipeline skynav-<mode>`` equals the score of
    :func:`process_frame` called directly with the same predicted state (same code, same seed:
    the same bits), timings apart."""
    rows, info = run_benchmark(mc4, sigmas_km=SIGMAS, seed=5, progress=False, pipelines=[f"skynav-{mode}"])
    src = open_frames(mc4)
    cat = OnboardCatalog.load(camera=src.observation(0).camera)
    direct = []
    for k in range(len(src)):
        obs, truth = src.observation(k), src.truth(k)
        for i, s in enumerate(SIGMAS):
            ps = predicted_state(truth, s, np.random.default_rng(np.random.SeedSequence([5, k, i])))
            fr = process_frame(obs, catalog=cat, predicted_state=ps, mode=mode)
            direct.append((fr, truth, k, s))
    assert len(rows) == len(direct) == 4 * len(SIGMAS)
    for row, (fr, truth, k, s) in zip(rows, direct):
        assert (row.frame, row.sigma_km, row.status, row.method, row.n_stars, row.n_spots) == \
            (k, s, fr.status, fr.star_id_method, fr.attitude.n_stars, len(fr.centroids_xy_px))
        if fr.ok:
            from skynav.pipeline.attitude import rotation_angle_rad
            from skynav.scenes.constants import ARCSEC_RAD

            assert row.error_arcsec == rotation_angle_rad(fr.attitude.R_cam_icrs, truth.R_cam_icrs) / ARCSEC_RAD
        assert [(b.name, b.outcome, b.error_px) for b in row.beacons] == \
            [(b.name, b.outcome, b.error_px) for b in _direct_beacons(fr, truth, k, s)]
    assert sum(r.attitude == "correct" for r in rows) >= 6  # a benchmark that solves


def _direct_beacons(fr, truth, k, s):
    from skynav.pipeline.plugins import image_result

    return score_frame(image_result(fr), truth, frame=k, sigma_km=s).beacons


def test_the_default_and_the_named_plugin_write_the_same_results(mc4, tmp_path):
    """``bench ip --mode paper`` and ``bench ip --pipeline skynav.pipeline.plugins:skynav_paper``:
    the same results.csv but for the processor's name and the time column."""
    a, b = tmp_path / "a", tmp_path / "b"
    assert main(["bench", "ip", str(mc4), "--mode", "paper", "--position-sigma-km", "1e4", "-q", "-o", str(a)]) == 0
    assert main(["bench", "ip", str(mc4), "--pipeline", "skynav.pipeline.plugins:skynav_paper", "--position-sigma-km",
                 "1e4", "-q", "-o", str(b)]) == 0

    def table(p):
        lines = [ln.split(",") for ln in (p / "results.csv").read_text().splitlines()[1:]]
        return [ln[1:10] + ln[11:] for ln in lines]  # pipeline name and time_ms left out

    assert table(a) == table(b) and len(table(a)) >= 4


# ----------------------------------------------------------------------------- faults
class _Faulty:
    """A processor with one fault on every frame: ``kind`` picks which."""

    def __init__(self, kind):
        self.kind = kind

    def process(self, observation, prediction):
        R = np.eye(3)
        if self.kind == "exception":
            raise RuntimeError("centroiding blew up\nsecond line")
        if self.kind == "timeout":
            time.sleep(30.0)
        if self.kind == "nan":
            R[0, 0] = np.nan
        if self.kind == "not_rotation":
            R = np.diag([1.0, 1.0, 1.01])
        if self.kind == "reflection":
            R = np.diag([1.0, 1.0, -1.0])
        if self.kind == "shape":
            R = np.eye(3, 4)
        if self.kind == "type":
            return R
        return ImageResult(R_cam_icrs=R)


FAULTS = {"exception": "exception: RuntimeError: centroiding blew up",
          "timeout": "timeout: over the 0.3 s frame time limit",
          "nan": "not_finite: R_cam_icrs has a nan or inf entry",
          "not_rotation": "not_rotation: R_cam_icrs is not orthonormal (max |R R^T - I| = 0.02 > 1e-06)",
          "reflection": "not_rotation: R_cam_icrs is a reflection (det = -1), not a rotation",
          "shape": "wrong_shape: R_cam_icrs has shape (3, 4); expected (3, 3)",
          "type": "wrong_type: returned ndarray; expected skynav.pipeline.ImageResult"}


def test_every_fault_is_a_failed_frame_with_its_reason(mc4):
    """Each fault of :data:`FAULTS` on every frame: every run counts as failed ("fault", no
    attitude) with its reason, and the benchmark completes, skynav's pipeline beside them unharmed."""
    pipes = ["skynav-improved"] + [(kind, lambda cam, kind=kind: _Faulty(kind)) for kind in FAULTS]
    t0 = time.perf_counter()
    rows, info = run_benchmark(mc4, sigmas_km=(1e4,), progress=False, pipelines=pipes, frame_timeout_s=0.3, limit=2)
    assert time.perf_counter() - t0 < 20.0   # the two 30 s sleeps were cut at 0.3 s
    assert [r.fault for r in rows] == ["", ""] and all(r.attitude == "correct" for r in rows)
    for kind, why in FAULTS.items():
        got = info["pipelines"][kind]
        assert len(got) == 2, kind
        assert all(r.status == "fault" and r.attitude == "none" and r.fault == why for r in got), (kind, got[0].fault)


def test_faults_are_listed_in_the_report(mc4, tmp_path, monkeypatch, capsys):
    """The command line: a plug-in by import path that faults; the run completes (exit 0) and
    report.md and summary.json list the reason and its count."""
    (tmp_path / "faulty_plugin.py").write_text(
        "def make(camera):\n"
        "    class P:\n"
        "        def process(self, observation, prediction):\n"
        "            raise ValueError('no PSF model for this camera')\n"
        "    return P()\n")
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "rep"
    assert main(["bench", "ip", str(mc4), "--pipeline", "skynav", "--pipeline", "faulty_plugin:make", "--limit", "2",
                 "--position-sigma-km", "1e4", "-o", str(out)]) == 0
    said = capsys.readouterr().out
    assert "fault x 2: exception: ValueError: no PSF model for this camera" in said
    s = json.loads((out / "summary.json").read_text())
    assert s["pipelines"]["faulty_plugin:make"]["faults"] == {"exception: ValueError: no PSF model for this camera": 2}
    assert s["pipelines"]["skynav-improved"]["faults"] == {}
    md = (out / "report.md").read_text()
    assert "- faulty_plugin:make: 2 x exception: ValueError: no PSF model for this camera" in md
    assert "Andreis et al. (2023a), Table 3 (published)" in md


@pytest.mark.parametrize("spec, says", [
    ("no_such_module_xyz:make", "--pipeline no_such_module_xyz:make: no module named 'no_such_module_xyz'"),
    ("skynav.pipeline.plugins:nothing_here", "has no 'nothing_here'"),
    ("skynav.pipeline.plugins", "give MODULE:FACTORY"),
    ("skynav.pipeline.plugins:ROTATION_TOLERANCE", "is not callable"),
    ("missing_file.py:make", "no such file missing_file.py"),
])
def test_a_bad_import_path_is_one_line_and_exit_2(mc4, tmp_path, capsys, spec, says):
    assert main(["bench", "ip", str(mc4), "--pipeline", spec, "-q", "-o", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and says in err and "Traceback" not in err
    with pytest.raises(PluginError, match="--pipeline"):
        load_factory(spec)
    assert not (tmp_path / "r").exists()


def test_a_module_that_fails_on_import_or_a_factory_that_raises(mc4, tmp_path, monkeypatch, capsys):
    (tmp_path / "broken_on_import.py").write_text("raise ImportError('needs libfoo')\n")
    (tmp_path / "bad_factory.py").write_text("def make(camera):\n    raise RuntimeError('no licence')\n"
                                             "def nothing(camera):\n    return 42\n")
    monkeypatch.chdir(tmp_path)
    for spec, says in (("broken_on_import:make", "importing broken_on_import failed (ImportError: needs libfoo)"),
                       ("bad_factory:make", "the factory raised RuntimeError: no licence"),
                       ("bad_factory.py:nothing", "returned a int, which has no process(observation, prediction)")):
        assert main(["bench", "ip", str(mc4), "--pipeline", spec, "-q", "-o", str(tmp_path / "r")]) == 2, spec
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and says in err, err


def test_call_processor_times_a_call_that_returns_late_off_the_main_thread(mc4):
    """Off the main thread there is no alarm: a call that returns past the limit is still a timeout."""
    import threading

    class Slow:
        def process(self, observation, prediction):
            time.sleep(0.2)
            return ImageResult(R_cam_icrs=np.eye(3))

    got = []
    t = threading.Thread(target=lambda: got.append(call_processor(Slow(), None, None, timeout_s=0.05)))
    t.start()
    t.join()
    res, fault, ms = got[0]
    assert res is None and fault.kind == "timeout" and ms >= 200.0
    res, fault, _ = call_processor(Slow(), None, None, timeout_s=5.0)
    assert fault is None and res.solved


def test_a_callers_own_alarm_survives_a_call():
    """``call_processor`` borrows SIGALRM for the frame's limit and gives a caller's timer back."""
    import signal

    fired = []
    old = signal.signal(signal.SIGALRM, lambda *a: fired.append(1))
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.5)

        class Quick:
            def process(self, observation, prediction):
                return ImageResult(R_cam_icrs=None)

        res, fault, _ = call_processor(Quick(), None, None, timeout_s=10.0)
        assert fault is None and 0.0 < signal.getitimer(signal.ITIMER_REAL)[0] <= 0.5
        time.sleep(0.8)
        assert fired == [1]
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, old)
