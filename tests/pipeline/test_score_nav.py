"""``skynav bench score nav DATASET RESULTS``: navigation states written by any program, scored
against the dataset's truth as ``bench nav`` scores its runs; bad records are one line."""

import json

import numpy as np
import pytest

from skynav.cli import main


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    d = tmp_path_factory.mktemp("score_nav") / "seq"
    assert main(["dataset", "generate", "sequence", "-o", str(d), "--count", "4", "--workers", "1", "-q"]) == 0
    return d


@pytest.fixture(scope="module")
def plan(seq):
    from skynav.pipeline.scoring_nav import load_plan

    return load_plan(seq)


def _records(plan, *, offset_km=100.0, dv_km_s=1e-3, sigma_km=100.0, sigma_km_s=1e-3):
    """Two runs: the truth plus/minus ``offset_km`` along x and plus ``dv_km_s`` along y, with a
    diagonal covariance of those sigmas: the scores are known without skynav."""
    P = np.diag([sigma_km**2] * 3 + [sigma_km_s**2] * 3)
    out = []
    for k in range(plan.frames):
        for run, s in ((0, 1.0), (1, -1.0)):
            out.append({"frame": k, "run": run, "t_tdb_s": float(plan.t_tdb_s[k]),
                        "position_km": (plan.position_km[k] + [s * offset_km, 0.0, 0.0]).tolist(),
                        "velocity_km_s": (plan.velocity_km_s[k] + [0.0, dv_km_s, 0.0]).tolist(),
                        "covariance_km_km_s": P.tolist()})
    return out


def _write(path, records):
    path.write_text("".join(json.dumps(r) + "\n" for r in records))
    return path


def test_states_with_known_errors_score_to_those_errors(seq, plan, tmp_path, capsys):
    """Errors of +-100 km and 1 m/s with sigmas 100 km and 1 m/s: final sample 3-sigma 300 km and
    3 m/s, filter 3-sigma 3 sqrt(3) x 100 km, NEES (1 + 1) = 2 at every frame (to float rounding
    of positions ~1e8 km: 1e-7 km)."""
    recs = _records(plan)
    recs[0]["my_filter_flag"] = True                          # an unknown key: kept, ignored, one warning
    res = _write(tmp_path / "states.jsonl", recs)
    out = tmp_path / "rep"
    assert main(["bench", "score", "nav", str(seq), str(res), "-o", str(out)]) == 0
    cap = capsys.readouterr()
    assert cap.err.count("my_filter_flag") == 1
    s = json.loads((out / "summary.json").read_text())
    f = s["final"]
    assert s["runs"] == 2 and s["frames"] == plan.frames
    assert f["position_3sigma_km"] == pytest.approx(300.0, abs=1e-5)
    assert f["velocity_3sigma_m_s"] == pytest.approx(3.0, abs=1e-5)
    assert f["filter_position_3sigma_km"] == pytest.approx(300.0 * np.sqrt(3), rel=1e-12)
    assert f["common_position_error_km"] == pytest.approx(0.0, abs=1e-5)
    assert s["nees"]["mean"] == pytest.approx(2.0, abs=1e-6)
    assert s["filters"][0]["filter"] == str(res)
    assert "final 3-sigma 300 km, 3.000 m/s" in cap.out


def test_without_covariance_the_errors_are_scored_and_the_nees_is_not(seq, plan, tmp_path):
    recs = _records(plan)
    for r in recs:
        del r["covariance_km_km_s"]
    out = tmp_path / "rep"
    assert main(["bench", "score", "nav", str(seq), str(_write(tmp_path / "s.jsonl", recs)), "-o", str(out), "-q"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["final"]["position_3sigma_km"] == pytest.approx(300.0, abs=1e-5)
    assert s["final"]["filter_position_3sigma_km"] is None and s["nees"]["mean"] is None


def _bad(plan, edit):
    recs = _records(plan)
    edit(recs)
    return recs


@pytest.mark.parametrize("edit, words", [
    (lambda r: r[3].update(frame=99), "line 4: frame 99 does not exist (the dataset has 4 frames, 0-3)"),
    (lambda r: r.append(dict(r[2])), "line 9: run 0 frame 1 again (first at line 3)"),
    (lambda r: r[1].update(covariance_km_km_s=[[1.0] * 6] * 5), "line 2: $.covariance_km_km_s: "),
    (lambda r: r[1]["covariance_km_km_s"][0].__setitem__(0, -1.0), "line 2: covariance_km_km_s is not positive definite"),
    (lambda r: r[1]["covariance_km_km_s"][0].__setitem__(1, 5.0), "line 2: covariance_km_km_s is not symmetric"),
    (lambda r: r[5].update(t_tdb_s=r[5]["t_tdb_s"] + 60.0), "line 6: t_tdb_s"),
    (lambda r: r[0].pop("velocity_km_s"), "line 1: 'velocity_km_s' is a required property"),
    (lambda r: r[0].update(position_km=[1.0, 2.0]), "line 1: $.position_km: "),
])
def test_a_bad_record_is_one_line_naming_it(seq, plan, tmp_path, capsys, edit, words):
    res = _write(tmp_path / "bad.jsonl", _bad(plan, edit))
    assert main(["bench", "score", "nav", str(seq), str(res), "-o", str(tmp_path / "rep")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0] and str(res) in err[0], err
    assert not (tmp_path / "rep").exists()


def test_not_json_is_one_line(seq, tmp_path, capsys):
    res = tmp_path / "bad.jsonl"
    res.write_text('{"frame": 0, "position_km": [NaN, 0, 0], "velocity_km_s": [0, 0, 0]}\n')
    assert main(["bench", "score", "nav", str(seq), str(res), "-o", str(tmp_path / "rep")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "line 1: not a JSON object (NaN is not JSON" in err[0], err


def test_bench_nav_states_scored_from_their_file_give_bench_nav_figures(seq, tmp_path):
    """bench nav --write-states writes the runs' states in the published schema; scored back by
    bench score nav they give bench nav's figures (to the file's float rounding, 1e-8 km at 1 au:
    relative 1e-9 here)."""
    rep, back = tmp_path / "rep", tmp_path / "back"
    assert main(["bench", "nav", str(seq), "--runs", "3", "--seed", "4", "--sigma-px", "0.1", "-q", "--write-states",
                 "-o", str(rep)]) == 0
    assert main(["bench", "score", "nav", str(seq), str(rep / "states.jsonl"), "-q", "-o", str(back)]) == 0
    a, b = (json.loads((p / "summary.json").read_text()) for p in (rep, back))
    for group in ("final", "nees"):
        for key, v in a[group].items():
            if isinstance(v, float):
                assert b[group][key] == pytest.approx(v, rel=1e-9, abs=1e-9), (group, key)
    assert (a["runs"], a["frames"]) == (b["runs"], b["frames"])
