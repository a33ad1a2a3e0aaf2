"""Messages and figures for people, checked on the real commands at small sizes.

- ``-q`` silences the informational lines (stdout) and the progress bars (stderr) of ``dataset
  generate``, ``bench ip``, ``bench nav``, ``hil export`` and ``calibrate``; warnings still print;
- an informational note prints once per run, not once per worker (``--workers 2``);
- ``hil export`` with a facility that was never calibrated warns in one line, once;
- a progress bar's total is the number of things its unit names (frames, captures);
- every figure the commands write has axis labels ending with a unit in parentheses, and legends,
  titles and labels without code names (no underscore outside matplotlib mathtext).

The commands run as a user runs them, in a subprocess (stdout and stderr of the whole process tree,
spawned workers included); the figures are caught in-process at ``Figure.savefig``.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from skynav.cli import main

WARNING = "skynav: warning: "
#: a tqdm bar as it redraws (``\r``-separated on a non-terminal stderr): description, n/total, rate
_BAR = re.compile(r"(?:^|\r|\n)([^\r\n:]+): *\d+%\|[^|\r\n]*\| *(\d+)/(\d+) \[[^\]\r\n]*, *([^\]\r\n]*)\]")


def skynav(*argv, cwd) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env.pop("SKYNAV_THREADS", None)
    return subprocess.run([sys.executable, "-m", "skynav", *map(str, argv)], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=600)


def bars(stderr: str) -> dict:
    """{description: (last count, total, unit)} of the tqdm bars in ``stderr``."""
    out = {}
    for desc, n, total, rate in _BAR.findall(stderr):
        # "12.5frame/s", "?frame/s" or "2.03s/frame"
        m = re.search(r"([A-Za-z]+)/s$", rate) or re.search(r"s/([A-Za-z]+)$", rate)
        out[desc.strip()] = (int(n), int(total), m.group(1) if m else rate)
    return out


#: the camera of the screen_small facility (hil export refuses a dataset of another camera)
BENCH_SMALL_CAMERA = ("--set", "camera.width=256", "--set", "camera.height=256", "--set",
                      "camera.pixel_pitch_um=55.102181471395305")


def _ok(p: subprocess.CompletedProcess) -> subprocess.CompletedProcess:
    assert p.returncode == 0, (p.stdout[-2000:], p.stderr[-2000:])
    return p


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """Small inputs made by the commands themselves, with their outputs: a 3-frame Monte Carlo
    dataset (``-q``, 2 workers), a 6-frame sequence (not quiet, 2 workers), bench patterns and
    captures, and a calibrated facility."""
    d = tmp_path_factory.mktemp("messages")
    runs = {}
    runs["generate -q"] = _ok(skynav("dataset", "generate", "montecarlo", "-o", "mc", "--count", 3, "--workers", 2, "-q",
                                     *BENCH_SMALL_CAMERA, cwd=d))
    runs["generate"] = _ok(skynav("dataset", "generate", "sequence", "-o", "seq", "--count", 6, "--workers", 2, cwd=d))
    runs["facility -q"] = _ok(skynav("hil", "facility", "screen_small", "-o", "fac.yaml", "-q", cwd=d))
    runs["patterns -q"] = _ok(skynav("calibrate", "patterns", "fac.yaml", "-o", "pat", "-q", cwd=d))
    runs["simulate"] = _ok(skynav("calibrate", "simulate", "fac.yaml", "--patterns", "pat", "-o", "cap", "--frames", 2,
                                  cwd=d))
    runs["geometric -q"] = _ok(skynav("calibrate", "geometric", "fac.yaml", "--patterns", "pat", "--captures", "cap",
                                      "-o", "geo.yaml", "-q", cwd=d))
    runs["radiometric -q"] = _ok(skynav("calibrate", "radiometric", "geo.yaml", "--measurements", "cap/power_meter.csv",
                                        "-o", "cal.yaml", "-q", cwd=d))
    return d, runs


def test_quiet_generation_and_calibration_print_nothing(work):
    _, runs = work
    for name in ("generate -q", "facility -q", "patterns -q", "geometric -q", "radiometric -q"):
        assert (runs[name].stdout, runs[name].stderr) == ("", ""), name


def test_a_note_prints_once_per_run_not_per_worker(work):
    """Two spawned workers render; the Mitsuba-variant note prints once (the parent's), as every
    other note does (one without the optional ccsds extra, say), the bar counts the 6 frames, and
    the summary lines are on stdout."""
    p = work[1]["generate"]
    notes = [ln for ln in re.split(r"[\r\n]", p.stderr) if ln.startswith("skynav:")]
    assert sum("Mitsuba variant" in n for n in notes) == 1 and len(notes) == len(set(notes)), notes
    assert bars(p.stderr)["frames"] == (6, 6, "frame")
    assert "6 frames complete" in p.stdout


def test_simulate_bar_counts_captures(work):
    d, runs = work
    n_patterns = len(list((d / "pat").glob("*.png")))
    assert n_patterns > 0
    assert bars(runs["simulate"].stderr)["capturing"] == (n_patterns, n_patterns, "capture")
    assert "wrote" in runs["simulate"].stdout


def test_bench_ip_quiet_and_bar_counts_frames_not_frame_sigma(work):
    d, _ = work
    q = _ok(skynav("bench", "ip", "mc", "--position-sigma-km", "1e4", "1e7", "-o", "ipq", "-q", cwd=d))
    assert (q.stdout, q.stderr) == ("", "")
    p = _ok(skynav("bench", "ip", "mc", "--position-sigma-km", "1e4", "1e7", "-o", "ip", cwd=d))
    assert bars(p.stderr) == {"bench ip (skynav-improved)": (3, 3, "frame")}  # 3 frames at 2 sigmas: 3, not 6
    assert "report:" in p.stdout
    check_citations(d / "ip", cited=r"Andreis et al\. \(2023a\)")


def test_bench_nav_quiet_and_bar_counts_frames(work):
    d, _ = work
    args = ("bench", "nav", "seq", "--runs", 3, "--calibration-stride", 2)
    q = _ok(skynav(*args, "-o", "navq", "-q", cwd=d))
    assert (q.stdout, q.stderr) == ("", "")
    p = _ok(skynav(*args, "-o", "nav", cwd=d))
    assert bars(p.stderr) == {"case 1, 3 runs": (6, 6, "frame")}
    assert "report:" in p.stdout
    check_citations(d / "nav", cited=r"Andreis et al\. \(2024\)")
    assert "the documented targets" in (d / "nav" / "report.md").read_text(encoding="utf-8")


def check_citations(report_dir: Path, *, cited: str) -> None:
    """A report names the papers by authors and year and lists them under References; never by
    file number, "our copy" or an issue."""
    for name in ("report.md", "report.html"):
        text = (report_dir / name).read_text(encoding="utf-8")
        assert re.search(cited, text), name
        assert "References" in text and "Andreis, E., Panicucci, P." in text, name
        for forbidden in ("paper 00", "our copy", "issue"):
            assert forbidden not in text.lower(), (name, forbidden)


def test_hil_export_warns_once_for_an_uncalibrated_facility(work):
    d, _ = work
    q = _ok(skynav("hil", "export", "mc", "--facility", "screen_small", "-o", "hilq", "--workers", 2, "-q", cwd=d))
    assert q.stdout == ""
    lines = q.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(WARNING) and "never calibrated" in lines[0], q.stderr
    p = _ok(skynav("hil", "export", "mc", "--facility", "fac.yaml", "-o", "hil", cwd=d))
    assert p.stderr.count(WARNING) == 1 and "fac.yaml was never calibrated" in p.stderr
    assert bars(p.stderr) == {"exporting": (3, 3, "frame")}
    assert "3 screen frames written" in p.stdout


def test_render_quiet_and_render_hil_warns_once(tmp_path):
    """``skynav render -q`` prints nothing; ``render --hil`` with the nominal preset prints its
    frame line without -q and, either way, one warning line that the facility is uncalibrated."""
    q = _ok(skynav("render", "-o", "r", "-q", "--set", "camera.width=128", "--set", "camera.height=128", cwd=tmp_path))
    assert (q.stdout, q.stderr) == ("", "")
    assert (tmp_path / "r" / "frame.png").is_file()
    h = _ok(skynav("render", "--facility", "screen", "-o", "s", cwd=tmp_path))
    assert "screen frame 2560x2560 10-bit" in h.stdout
    lines = h.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(WARNING) and "screen was never calibrated" in lines[0], h.stderr


def test_hil_export_with_a_calibrated_facility_does_not_warn(work):
    d, _ = work
    p = _ok(skynav("hil", "export", "mc", "--facility", "cal.yaml", "-o", "hilcal", "-q", cwd=d))
    assert (p.stdout, p.stderr) == ("", "")


def test_partly_calibrated_facility_names_what_is_missing(work):
    from skynav.calibration.facility_io import load_facility

    from skynav.cli_hil import uncalibrated_note

    d, _ = work
    assert uncalibrated_note(load_facility(d / "cal.yaml"), "cal.yaml") is None
    note = uncalibrated_note(load_facility(d / "geo.yaml"), "geo.yaml")
    assert "no radiometric calibration record" in note and "geometric" not in note.split("record")[0]


# ----------------------------------------------------------------------------------- figures
_UNIT_AT_END = re.compile(r"\([^()]*\S[^()]*\)\s*$")


def _outside_mathtext(text: str) -> str:
    return re.sub(r"(?<!\\)\$.*?(?<!\\)\$", "", text)


def figure_text_problems(fig) -> list:
    """What a reader would trip on: an axis with tick labels but no label ending in a unit in
    parentheses, and a code name (an underscore outside mathtext) in a label, title or legend."""
    fig.canvas.draw()
    problems = []
    texts = [fig._suptitle.get_text()] if fig._suptitle is not None else []
    for i, ax in enumerate(fig.axes):
        for name, label, ticks in (("x", ax.get_xlabel(), ax.get_xticklabels()),
                                   ("y", ax.get_ylabel(), ax.get_yticklabels())):
            if any(t.get_visible() and t.get_text() for t in ticks) and not _UNIT_AT_END.search(label):
                problems.append(f"axes {i}: {name} label {label!r} does not end with a unit in parentheses")
            texts.append(label)
        texts.append(ax.get_title())
        legend = ax.get_legend()
        if legend is not None:
            entries = [t.get_text() for t in legend.get_texts()]
            problems += [f"axes {i}: empty legend entry" for e in entries if not e.strip()]
            texts += entries
    for legend in fig.legends:
        texts += [t.get_text() for t in legend.get_texts()]
    problems += [f"code name in {t!r}" for t in texts if "_" in _outside_mathtext(t)]
    return problems


def test_the_checker_catches_code_names_and_missing_units():
    from skynav.datasets.plots import lines_figure

    good = lines_figure([0, 1], {"noisy camera": [1, 2]}, title="t", xlabel="time (s)", ylabel="signal (e-)")
    assert figure_text_problems(good) == []
    bad = lines_figure([0, 1], {"sw_noisy": [1, 2]}, title="t", xlabel="time", ylabel="signal (e-)")
    problems = figure_text_problems(bad)
    assert any("x label 'time'" in p for p in problems) and any("sw_noisy" in p for p in problems)


@pytest.fixture
def written_figures(monkeypatch):
    """Every matplotlib Figure saved while the test runs (the commands write PNGs with savefig)."""
    from matplotlib.figure import Figure

    seen = []
    original = Figure.savefig

    def record(self, *a, **kw):
        seen.append(self)
        return original(self, *a, **kw)

    monkeypatch.setattr(Figure, "savefig", record)
    return seen


def test_every_figure_the_commands_write_is_labelled(work, tmp_path, written_figures, capsys):
    d, _ = work
    expected = {"bench ip": 4, "bench nav": 4, "calibrate geometric": 1, "calibrate radiometric": 1,
                "dataset preview": 1}
    commands = {
        "bench ip": ["bench", "ip", d / "mc", "--position-sigma-km", "1e4", "1e7", "-o", tmp_path / "ip", "-q"],
        "bench nav": ["bench", "nav", d / "seq", "--runs", "3", "--case", "1", "3", "--calibration-stride", "2",
                      "-o", tmp_path / "nav", "-q"],
        "calibrate geometric": ["calibrate", "geometric", d / "fac.yaml", "--patterns", d / "pat", "--captures", d / "cap",
                                "-o", tmp_path / "geo.yaml", "-q"],
        "calibrate radiometric": ["calibrate", "radiometric", d / "geo.yaml", "--measurements", d / "cap" / "power_meter.csv",
                                  "-o", tmp_path / "cal.yaml", "-q"],
        "dataset preview": ["dataset", "preview", d / "seq", "-o", tmp_path / "preview.png"],
    }
    problems = []
    for name, argv in commands.items():
        before = len(written_figures)
        assert main([str(a) for a in argv]) == 0, capsys.readouterr().err
        figs = written_figures[before:]
        assert len(figs) == expected[name], name
        problems += [f"{name}, figure {k}: {p}" for k, fig in enumerate(figs) for p in figure_text_problems(fig)]
    assert problems == []


def test_time_histogram_is_not_flattened_by_the_warm_up_frame():
    """Frame 0 took 500 ms, the others ~4 ms, one straggler 300 ms: the histogram's axis covers the
    4 ms runs (not 0-500 ms), and the caption says what was left out and what overflowed."""
    import numpy as np

    from skynav.pipeline.scoring import FrameScore
    from skynav.pipeline.scoring_report import time_histogram_figure

    def run(frame, ms):
        return FrameScore(frame=frame, sigma_km=1e4, status="ok", attitude="correct", error_arcsec=1.0,
                          error_estimate_arcsec=1.0, n_stars=10, n_spots=10, method="lost_in_space", time_ms=ms, beacons=())

    rng = np.random.default_rng(3)
    rows = [run(0, 500.0)] + [run(k, float(4.0 + rng.random())) for k in range(1, 200)]
    rows.append(run(200, 300.0))
    fig, caption = time_histogram_figure(rows)
    ax = fig.axes[0]
    assert ax.get_xlim()[1] < 20.0  # 1.25 x the 99th percentile of ~4-5 ms, plus the overflow bin
    assert "Frame 0 left out" in caption and "500.0 ms" in caption
    assert "1 run(s) slower than" in caption
    heights = [p.get_height() for p in ax.patches]
    assert heights[-1] == 1  # the 300 ms straggler, in the overflow bin
    assert sum(heights) == 200
    assert figure_text_problems(fig) == []
