"""``skynav bench score ip DATASET RESULTS``: a results file written by any program, validated on
read against its published schema and scored as ``bench ip`` scores a plug-in; a bad line is one
line naming it, exit 2. Also: frames whose truth carries keys skynav does not know are
benchmarked with one warning per dataset."""

from __future__ import annotations

import json
import shutil
import warnings

import numpy as np
import pytest

import skynav.datasets as D
from skynav.cli import main
from skynav.infra.errors import SkynavWarning
from skynav.pipeline.scoring_results_file import ResultsFileError, read_results_file, score_results_file

from ..datasets.conftest import small_recipe


@pytest.fixture(scope="module")
def mc3(tmp_path_factory):
    root = tmp_path_factory.mktemp("score") / "mc3"
    D.generate(small_recipe(frames=3), root, workers=1, progress=False)
    return root


def _rotation(axis, angle_rad):
    """Rodrigues: the rotation by ``angle_rad`` about the unit ``axis`` (independent of skynav)."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * K + (1 - np.cos(angle_rad)) * K @ K


def _write(path, records):
    path.write_text("".join(json.dumps(r) + "\n" for r in records))
    return path


def test_attitudes_rotated_by_known_angles_are_scored_to_those_angles(mc3, tmp_path):
    """Acceptance: each frame's true attitude turned by a known angle about a random axis (0.5"
    to 2000"); the score is that angle within 0.01" (float64 JSON keeps 1e-16 rad)."""
    ds = D.open(mc3)
    rng = np.random.default_rng(11)
    angles = [0.5, 37.0, 2000.0]
    recs = []
    for k, ang in enumerate(angles):
        R_true = np.asarray(ds.truth(k).R_cam_icrs, float)
        dR = _rotation(rng.normal(size=3), np.radians(ang / 3600.0))
        recs.append({"frame": k, "R_cam_icrs": (dR @ R_true).tolist(), "time_ms": 3.0})
    rows, info = score_results_file(mc3, _write(tmp_path / "r.jsonl", recs))
    assert [r.frame for r in rows] == [0, 1, 2] and info["sigmas_km"] == (1e4,)
    np.testing.assert_allclose([r.error_arcsec for r in rows], angles, atol=0.01)
    assert [r.attitude for r in rows] == ["correct", "correct", "wrong"]  # 2000" > 500": wrong


def test_the_command_scores_a_file_and_a_frame_without_a_line_is_unsolved(mc3, tmp_path, capsys):
    ds = D.open(mc3)
    recs = [{"frame": 0, "R_cam_icrs": np.asarray(ds.truth(0).R_cam_icrs).tolist(), "status": "ok"},
            {"frame": 2, "R_cam_icrs": None, "status": "no_stars"}]
    out = tmp_path / "rep"
    assert main(["bench", "score", "ip", str(mc3), str(_write(tmp_path / "mine.jsonl", recs)), "-o", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["frames"] == 3 and s["status_counts"] == {"ok": 1, "no_record": 1, "no_stars": 1}
    assert s["attitude"]["correct_rate"] == pytest.approx(1 / 3) and s["attitude"]["error_arcsec_median"] < 1e-3
    assert "mine.jsonl: 3 frames" in capsys.readouterr().out


def test_lines_at_given_sigmas_and_lines_for_every_sigma(mc3, tmp_path):
    ds = D.open(mc3)
    R = [np.asarray(ds.truth(k).R_cam_icrs).tolist() for k in range(3)]
    recs = [{"frame": 0, "sigma_km": 1e4, "R_cam_icrs": R[0]}, {"frame": 0, "sigma_km": 1e7, "R_cam_icrs": None},
            {"frame": 1, "R_cam_icrs": R[1]}]
    rows, info = score_results_file(mc3, _write(tmp_path / "r.jsonl", recs))
    assert info["sigmas_km"] == (1e4, 1e7)
    got = {(r.frame, r.sigma_km): r.attitude for r in rows}
    assert got == {(0, 1e4): "correct", (0, 1e7): "none", (1, 1e4): "correct", (1, 1e7): "correct",
                   (2, 1e4): "none", (2, 1e7): "none"}


BAD = [
    ({"frame": 3, "R_cam_icrs": None}, "line 2: frame 3 does not exist (the dataset has 3 frames, 0-2)"),
    ({"frame": 0, "R_cam_icrs": None}, "line 2: frame 0 again (first at line 1); one line per frame"),
    ({"frame": 1, "R_cam_icrs": [[1, 0, 0], [0, 1, 0]]}, "line 2: $.R_cam_icrs: "),
    ({"frame": 1, "R_cam_icrs": [[1, 0, 0], [0, 1, 0], [0, 0, "x"]]}, "line 2: $.R_cam_icrs"),
    ({"frame": 1, "R_cam_icrs": [[1, 0, 0], [0, 1, 0], [0, 0, 2]]}, "line 2: R_cam_icrs is not orthonormal"),
    ({"frame": 1, "R_cam_icrs": [[1, 0, 0], [0, 1, 0], [0, 0, -1]]}, "line 2: R_cam_icrs is a reflection"),
    ({"frame": -1, "R_cam_icrs": None}, "line 2: $.frame: -1 is less than the minimum of 0"),
    ({"R_cam_icrs": None}, "line 2: 'frame' is a required property"),
    ({"frame": 0, "sigma_km": 1e4, "R_cam_icrs": None}, "line 2: frame 0 has a line for every sigma"),
]


@pytest.mark.parametrize("rec, says", BAD)
def test_a_bad_line_is_one_line_naming_it_and_exit_2(mc3, tmp_path, capsys, rec, says):
    path = _write(tmp_path / "r.jsonl", [{"frame": 0, "R_cam_icrs": None}, rec])
    assert main(["bench", "score", "ip", str(mc3), str(path), "-o", str(tmp_path / "rep")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{path} {says}" in err, err
    with pytest.raises(ResultsFileError):
        read_results_file(path, frames=3)
    assert not (tmp_path / "rep").exists()


@pytest.mark.parametrize("text, says", [("{\"frame\": 0, \"R_cam_icrs\": [[NaN, 0, 0], [0, 1, 0], [0, 0, 1]]}\n",
                                         "line 1: not a JSON object (NaN is not JSON (write null))"),
                                        ("[1, 2]\n", "line 1: [1, 2] is not of type 'object'"),
                                        ("{\"frame\": 0,\n", "line 1: not a JSON object")])
def test_not_json_and_nan(mc3, tmp_path, capsys, text, says):
    path = tmp_path / "r.jsonl"
    path.write_text(text)
    assert main(["bench", "score", "ip", str(mc3), str(path), "-o", str(tmp_path / "rep")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and says in err, err


def test_unknown_keys_of_a_results_file_are_kept_with_one_warning(mc3, tmp_path):
    recs = [{"frame": k, "R_cam_icrs": None, "solver_version": "2.1", "beacons": [{"name": "mars", "xy_px": None,
                                                                                   "snr": 3}]} for k in range(3)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rows, _ = score_results_file(mc3, _write(tmp_path / "r.jsonl", recs))
    said = [str(w.message) for w in caught if w.category is SkynavWarning]
    assert len(said) == 1 and "beacons[].snr, solver_version" in said[0] and len(rows) == 3


def test_bench_score_without_what_prints_its_help(capsys):
    assert main(["bench", "score"]) == 2
    assert "ip" in capsys.readouterr().out


# ----------------------------------------------------------------------------- unknown keys in frame truth
@pytest.fixture(scope="module")
def foreign_folder(mc3, tmp_path_factory):
    """The frames as a plain folder, their truth JSON written by 'another program': camera keys
    skynav does not define (fov_deg, psf_sigma_px) and a top-level one."""
    root = tmp_path_factory.mktemp("foreign") / "frames"
    root.mkdir()
    for k in range(3):
        shutil.copy(mc3 / "frames" / f"{k:06d}.png", root / f"{k:06d}.png")
        d = json.loads((mc3 / "frames" / f"{k:06d}.json").read_text())
        d["camera"]["fov_deg"] = 20.0
        d["camera"]["psf_sigma_px"] = 0.8
        d["writer"] = "another program"
        (root / f"{k:06d}.json").write_text(json.dumps(d))
    return root


def test_frames_with_unknown_truth_keys_are_benchmarked_with_one_warning(foreign_folder, tmp_path, capsys):
    out = tmp_path / "rep"
    assert main(["bench", "ip", str(foreign_folder), "--position-sigma-km", "1e4", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    warned = [ln for ln in err.splitlines() if "warning" in ln]
    assert len(warned) == 1 and "fov_deg" in warned[0] and "psf_sigma_px" in warned[0], err
    assert json.loads((out / "summary.json").read_text())["frames"] == 3


def test_a_frame_missing_a_required_key_is_still_refused_in_one_line(foreign_folder, tmp_path, capsys):
    bad = tmp_path / "bad"
    shutil.copytree(foreign_folder, bad)
    d = json.loads((bad / "000001.json").read_text())
    del d["camera"]["focal_length_mm"]
    (bad / "000001.json").write_text(json.dumps(d))
    assert main(["bench", "ip", str(bad), "--position-sigma-km", "1e4", "-q", "-o", str(tmp_path / "r")]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if "warning" not in ln]
    assert len(err) == 1 and "000001.json" in err[0] and "camera.focal_length_mm" in err[0], err


def test_predictions_are_bench_ips_and_a_line_at_their_sigma_is_scored_there(mc3, tmp_path, capsys):
    """``bench predictions`` writes the predicted states every plug-in gets; a program that answers
    with their ``sigma_km`` is scored at that sigma."""
    from skynav.pipeline.scoring import open_frames, predicted_state

    pred = tmp_path / "pred.jsonl"
    assert main(["bench", "predictions", str(mc3), "--position-sigma-km", "1e4", "1e6", "--seed", "4", "-o",
                 str(pred)]) == 0
    lines = [json.loads(ln) for ln in pred.read_text().splitlines()]
    assert [(d["frame"], d["sigma_km"]) for d in lines] == [(k, s) for k in range(3) for s in (1e4, 1e6)]
    src = open_frames(mc3)
    for d in lines:
        i = (1e4, 1e6).index(d["sigma_km"])
        ps = predicted_state(src.truth(d["frame"]), d["sigma_km"],
                             np.random.default_rng(np.random.SeedSequence([4, d["frame"], i])))
        assert d["position_km"] == ps.position_km.tolist() and d["velocity_km_s"] == ps.velocity_km_s.tolist()
        assert d["position_cov_km2"] == ps.position_cov_km2.tolist()
    ds = D.open(mc3)
    recs = [{"frame": d["frame"], "sigma_km": d["sigma_km"],
             "R_cam_icrs": np.asarray(ds.truth(d["frame"]).R_cam_icrs).tolist() if d["sigma_km"] == 1e4 else None}
            for d in lines]
    rows, info = score_results_file(mc3, _write(tmp_path / "r.jsonl", recs))
    assert info["sigmas_km"] == (1e4, 1e6)
    assert {(r.sigma_km, r.attitude) for r in rows} == {(1e4, "correct"), (1e6, "none")}
    assert main(["bench", "predictions", str(mc3), "-o", str(tmp_path)]) == 2
    assert "is a folder; give a file name" in capsys.readouterr().err
