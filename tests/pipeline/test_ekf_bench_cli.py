"""``skynav bench nav`` end to end on a small rendered ``sequence`` dataset, and its one-line errors."""

import json
import shutil
from pathlib import Path

import numpy as np

import pytest

from skynav.cli import main

SUMMARY_KEYS = {"runs", "frames", "final", "nees", "measurement_error_px", "cases", "time_s"}


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    d = tmp_path_factory.mktemp("nav") / "seq"
    assert main(["dataset", "generate", "sequence", "-o", str(d), "--count", "6", "--workers", "1", "-q"]) == 0
    return d


@pytest.fixture(scope="module")
def renderings(tmp_path_factory):
    """Two more renderings of ``seq``'s cruise (other seeds: other image noise and pointing errors)."""
    out = []
    for seed in (98, 99):
        d = tmp_path_factory.mktemp("nav") / f"seq{seed}"
        assert main(["dataset", "generate", "sequence", "-o", str(d), "--count", "6", "--seed", str(seed),
                     "--workers", "1", "-q"]) == 0
        out.append(d)
    return out


def test_bench_nav_writes_the_report(seq, tmp_path, capsys):
    out = tmp_path / "rep"
    rc = main(["bench", "nav", str(seq), "--runs", "4", "--case", "1", "3", "--seed", "3", "-q",
               "--calibration-stride", "2", "-o", str(out)])
    assert rc == 0
    s = json.loads((out / "summary.json").read_text())
    assert SUMMARY_KEYS <= set(s)
    assert set(s["final"]) >= {"position_3sigma_km", "velocity_3sigma_m_s", "position_error_rms_km", "velocity_error_rms_m_s"}
    assert set(s["nees"]) >= {"mean", "band_low", "band_high", "fraction_inside"}
    assert set(s["measurement_error_px"]) >= {"mean", "std"}
    assert set(s["cases"]) == {"1", "3"} and set(s["cases"]["1"]) == {"position_rmse_km", "velocity_rmse_m_s"}
    assert s["runs"] == 4 and s["frames"] == 6
    assert s["measurements"]["frames_with_centroid"] >= 4  # the image processing found the target
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 4 and "<script" not in html and "http" not in html
    assert (out / "runs.csv").read_text().count("\n") == 1 + 2 * 4
    assert capsys.readouterr().out == ""  # -q: the report is in the files, no informational lines


def _err(argv, capsys):
    rc = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    return rc, err


def test_wrong_inputs_one_line_exit_2(seq, tmp_path, capsys):
    mc = tmp_path / "mc"
    assert main(["dataset", "generate", "montecarlo", "-o", str(mc), "--count", "1", "--workers", "1", "-q"]) == 0
    rc, err = _err(["bench", "nav", str(mc), "-o", str(tmp_path / "r1")], capsys)
    assert rc == 2 and len(err) == 1 and "sequence" in err[0]

    missing = tmp_path / "missing"
    shutil.copytree(seq, missing)
    (missing / "frames" / "000003.png").unlink()
    rc, err = _err(["bench", "nav", str(missing), "-o", str(tmp_path / "r2")], capsys)
    assert rc == 2 and len(err) == 1 and "frame 3 is missing" in err[0]

    blind = tmp_path / "blind"
    shutil.copytree(seq, blind)
    for js in (blind / "frames").glob("*.json"):
        t = json.loads(js.read_text())
        for b in t["bodies"]:
            b["visible"] = False
        js.write_text(json.dumps(t))
    rc, err = _err(["bench", "nav", str(blind), "-o", str(tmp_path / "r3")], capsys)
    assert rc == 2 and len(err) == 1 and "no visible planet" in err[0]

    rc, err = _err(["bench", "nav", str(seq), "--case", "7", "-o", str(tmp_path / "r4")], capsys)
    assert rc == 2 and len(err) == 1
    rc, err = _err(["bench", "nav", str(tmp_path / "nothing"), "-o", str(tmp_path / "r5")], capsys)
    assert rc == 2 and len(err) == 1
    rc, err = _err(["bench", "nav", str(seq), "--gm-sigma", "-1", "-o", str(tmp_path / "r6")], capsys)
    assert rc == 2 and len(err) == 1 and "--gm-sigma" in err[0]


def test_images_option_uses_the_given_images(seq, tmp_path):
    """``--images DIR``: the same frames from another folder (here copies, flat NNNNNN.png) give the
    same campaign; the copies shifted by one pixel along x (stars and planet alike, as a bench
    camera offset would) move the measured planet-centroid error (centroid minus the truth's xy) by
    +1 px in x, to 0.05 px (the centroid noise of these frames is ~0.1 px; the shift is an exact
    integer roll, so only the image-processing noise differs)."""
    import numpy as np

    from skynav.datasets.frame_files import read_png, read_png_layout, write_png

    argv = ["bench", "nav", str(seq), "--runs", "3", "--case", "1", "--seed", "4", "-q", "--calibration-stride", "2"]
    assert main(argv + ["-o", str(tmp_path / "ref")]) == 0
    same, shifted = tmp_path / "same", tmp_path / "shifted"
    same.mkdir()
    shifted.mkdir()
    for png in sorted((seq / "frames").glob("*.png")):
        shutil.copy(png, same / png.name)
        # the frames' own PNG layout (DN scaled to 16 bits with sBIT), as a lab tool would keep it
        bits = read_png_layout(png)["significant_bits"]
        write_png(shifted / png.name, np.roll(read_png(png), 1, axis=1), bit_depth=bits)
    assert main(argv + ["--images", str(same), "-o", str(tmp_path / "same_r")]) == 0
    assert main(argv + ["--images", str(shifted), "-o", str(tmp_path / "shift_r")]) == 0
    ref, cp, sh = (json.loads((tmp_path / d / "summary.json").read_text()) for d in ("ref", "same_r", "shift_r"))
    assert cp["final"] == ref["final"] and cp["measurement_error_px"] == ref["measurement_error_px"]
    assert cp["run"]["images"] == str(same)
    dx = sh["measurement_error_px"]["mean_xy"][0] - ref["measurement_error_px"]["mean_xy"][0]
    dy = sh["measurement_error_px"]["mean_xy"][1] - ref["measurement_error_px"]["mean_xy"][1]
    assert abs(dx - 1.0) < 0.05 and abs(dy) < 0.05


@pytest.mark.slow
def test_nav_report_html_in_headless_chromium(seq, tmp_path):
    """The nav report.html loads in a real browser with no console errors and its plots
    decode (benchmarks/check_report_html.py, shared with bench ip)."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location(
        "check_report_html", Path(__file__).resolve().parents[2] / "benchmarks" / "check_report_html.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    if mod.chromium() is None:
        pytest.skip("no chromium on PATH (Debian: apt-get install chromium)")
    out = tmp_path / "rep"
    assert main(["bench", "nav", str(seq), "--runs", "3", "--case", "1", "-q", "--calibration-stride", "2",
                 "-o", str(out)]) == 0
    ok, msg = mod.check(out / "report.html", tmp_path / "shot.png")
    assert ok, msg


def test_synthetic_reference_mode_replaces_the_centroids(seq):
    """run_campaign(synthetic_seed=...): the filter gets the model at the true state plus seeded
    white noise of its own R (benchmarks/nav_consistency.py): reproducible per seed, different
    between seeds and from the images' centroids."""
    import numpy as np

    from skynav.pipeline.scoring_nav import CentroidNoise, load_plan, run_campaign

    plan = load_plan(seq)
    noise = CentroidNoise(sigma0_px=0.05, frames=1)
    real = run_campaign(plan, runs=2, noise=noise, seed=1)
    a = run_campaign(plan, runs=2, noise=noise, seed=1, synthetic_seed=7)
    b = run_campaign(plan, runs=2, noise=noise, seed=1, synthetic_seed=7)
    c = run_campaign(plan, runs=2, noise=noise, seed=1, synthetic_seed=8)
    ok = np.all(np.isfinite(a.measured_error_px), 1)
    assert ok.sum() >= 4
    assert np.array_equal(a.measured_error_px[ok], b.measured_error_px[ok])
    assert not np.allclose(a.measured_error_px[ok], c.measured_error_px[ok])
    assert not np.allclose(a.measured_error_px[ok], real.measured_error_px[ok])


def test_realisations_deal_the_runs_over_independent_sequences(seq, renderings, tmp_path, capsys):
    """``--realisations``: the same cruise rendered with other seeds; one run per sequence gives
    independent runs, and the summary's band is that of the sequences (chi-square, 6 M dof / M)."""
    from scipy.stats import chi2

    out = tmp_path / "rep"
    rc = main(["bench", "nav", str(seq), "--realisations", *map(str, renderings), "--runs", "2", "-q",
               "--calibration-stride", "2", "-o", str(out)])
    assert rc == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["runs"] == 2 and s["nees"]["independent_sequences"] == 2
    lo, hi = chi2.ppf([0.025, 0.975], 12) / 2
    assert abs(s["nees"]["band_sequences_low"] - lo) < 1e-12 and abs(s["nees"]["band_sequences_high"] - hi) < 1e-12
    assert "independent image sequences" in (out / "report.md").read_text()
    capsys.readouterr()
    other = renderings[1]

    short = tmp_path / "seq_short"
    assert main(["dataset", "generate", "sequence", "-o", str(short), "--count", "4", "--workers", "1", "-q"]) == 0
    rc, err = _err(["bench", "nav", str(seq), "--realisations", str(short), "-o", str(tmp_path / "r")], capsys)
    assert rc == 2 and len(err) == 1 and "not a rendering" in err[0]
    rc, err = _err(["bench", "nav", str(seq), "--realisations", str(other), "--images", str(seq),
                    "-o", str(tmp_path / "r2")], capsys)
    assert rc == 2 and len(err) == 1 and "--realisations" in err[0]


def test_calibrate_on_pools_renderings_for_r(seq, renderings, tmp_path, capsys):
    """``--calibrate-on``: R measured on the frames of DATASET and of other renderings of the same
    cruise together (every calibration frame of both, none lost or doubled); it must stay out of
    sample for ``--realisations`` and cannot be combined with a given ``--sigma-px``."""
    from skynav.pipeline.scoring_nav import calibrate_sigma_px, load_plan

    other = renderings[0]
    a, b = load_plan(seq), load_plan(other)
    na, nb, nab = calibrate_sigma_px(a), calibrate_sigma_px(b), calibrate_sigma_px([a, b])
    assert nab.renderings == 2 and "of 2 renderings" in nab.describe()
    assert nab.frames + nab.clipped == na.frames + na.clipped + nb.frames + nb.clipped
    out = tmp_path / "rep"
    assert main(["bench", "nav", str(seq), "--calibrate-on", str(other), "--runs", "2", "-q", "-o", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert len(s["run"]["calibrated_on"]) == 2
    capsys.readouterr()
    rc, err = _err(["bench", "nav", str(seq), "--calibrate-on", str(other), "--realisations", str(other),
                    "-o", str(tmp_path / "r")], capsys)
    assert rc == 2 and len(err) == 1 and "out of sample" in err[0] and "--calibrate-on" in err[0]
    rc, err = _err(["bench", "nav", str(seq), "--calibrate-on", str(other), "--sigma-px", "0.1",
                    "-o", str(tmp_path / "r2")], capsys)
    assert rc == 2 and len(err) == 1 and "--calibrate-on" in err[0]


def test_r_calibrated_on_other_renderings_only(seq, renderings, tmp_path, capsys):
    """Out-of-sample R, as the closed loop has it (benchmarks/loop_vs_nav.py): DATASET and
    ``--calibrate-on`` give R, ``--realisations`` the navigated rendering; the navigated frames are
    in no calibration. The report's R and errors are those of R measured on the two calibration
    renderings alone (pooled) and runs on the navigated one, which differ from the in-sample ones;
    DATASET among the navigated renderings is refused (R would be in sample)."""
    from skynav.pipeline.scoring_nav import calibrate_sigma_px, load_plan, run_realisations

    cal, cal2 = renderings
    out = tmp_path / "rep"
    assert main(["bench", "nav", str(cal), "--calibrate-on", str(cal2), "--realisations", str(seq), "--runs", "2",
                 "-q", "-o", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert [Path(p).name for p in s["run"]["calibrated_on"]] == [cal.name, cal2.name]
    assert [Path(p).name for p in s["run"]["realisations"]] == [seq.name]
    outside = calibrate_sigma_px([load_plan(cal), load_plan(cal2)])
    inside = calibrate_sigma_px([load_plan(seq), load_plan(cal2)])
    assert s["run"]["noise"] == outside.describe() != inside.describe()
    nav = load_plan(seq)
    res = run_realisations([nav], runs=2, noise=outside, reference=load_plan(cal))
    last = nav.leg == nav.leg[-1]
    rms = float(np.sqrt(np.mean(np.sum(res.error[:, last, :3] ** 2, -1))))
    assert s["final"]["position_error_rms_km"] == pytest.approx(rms, rel=1e-9)   # the same code and seeds
    capsys.readouterr()
    rc, err = _err(["bench", "nav", str(seq), "--realisations", str(seq), "-o", str(tmp_path / "r")], capsys)
    assert rc == 2 and len(err) == 1 and "DATASET" in err[0] and "out of sample" in err[0]


def test_set_changes_the_filter_dynamics(seq, tmp_path, capsys):
    """``--set dynamics.FIELD=VALUE`` reaches the filter: recorded in summary.json, and a 100x
    larger process noise gives a larger filter velocity 3-sigma at the end (the covariance grows with Q);
    bad keys and values are one line, exit 2, before anything is read or written."""
    common = ["bench", "nav", str(seq), "--runs", "2", "--case", "1", "-q", "--sigma-px", "0.3"]
    assert main([*common, "-o", str(tmp_path / "base")]) == 0
    assert main([*common, "--set", "dynamics.sigma_residual_km_s2=1e-9", "--set", "dynamics.sigma_srp_km_s2=1e-9",
                 "-o", str(tmp_path / "q")]) == 0
    base = json.loads((tmp_path / "base" / "summary.json").read_text())
    q = json.loads((tmp_path / "q" / "summary.json").read_text())
    assert base["run"]["dynamics"]["sigma_residual_km_s2"] == 1e-11
    assert q["run"]["dynamics"]["sigma_residual_km_s2"] == 1e-9 and q["run"]["dynamics"]["sigma_srp_km_s2"] == 1e-9
    # 6 frames of one leg: the larger Q shows in the velocity covariance only (position rounds equal)
    assert q["final"]["filter_velocity_3sigma_m_s"] > base["final"]["filter_velocity_3sigma_m_s"]
    capsys.readouterr()
    for bad, says in ((["--set", "dynamics.sigma=1"], "allowed keys: dynamics.correlation_time_s"),
                      (["--set", "runs=3"], "bench nav has no key runs"),
                      (["--set", "dynamics.rtol=-1"], "expected a positive finite number"),
                      (["--set", "dynamics.atol=fast"], "expected a positive finite number")):
        rc, err = _err([*common, *bad, "-o", str(tmp_path / "bad")], capsys)
        assert rc == 2 and len(err) == 1 and says in err[0] and err[0].startswith("skynav: error: "), err
        assert not (tmp_path / "bad").exists()


def test_centroid_errors_are_the_calibrations_frame_by_frame(seq):
    """``centroid_errors`` (benchmarks/loop_vs_nav.py compares two renderings of a cruise with it):
    the frames ``calibrate_sigma_px`` measures, none lost or doubled, each error the centroid minus
    the model at the true state (well under a pixel: the paper camera's planets, 0.05-0.15 px RMS),
    NaN elsewhere; the same frames through ``--images`` give the same errors."""
    from skynav.pipeline.scoring_nav import calibrate_sigma_px, load_plan
    from skynav.pipeline.scoring_nav_noise import centroid_errors

    plan = load_plan(seq)
    e, keys = centroid_errors(plan, seed=3)
    noise = calibrate_sigma_px(plan, seed=3)
    used = np.array([bool(k) for k in keys])
    assert used.sum() == noise.frames + noise.clipped > 0
    assert np.isnan(e[~used]).all() and np.isfinite(e[used]).all() and np.abs(e[used]).max() < 0.5
    again, _ = centroid_errors(load_plan(seq, images=seq / "frames"), seed=3)
    np.testing.assert_array_equal(again, e)
