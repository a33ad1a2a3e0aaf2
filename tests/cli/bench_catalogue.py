"""The shared part of the bench and calibration bad-input catalogues.

``test_bench_bad_input_catalogue.py`` (damaged facility files, pattern manifests, captures,
power-meter tables and datasets) and ``test_bench_command_line_catalogue.py`` (bad flags and
output paths, and the documented good paths) both run their cases through this module: the
inputs they start from (:func:`build_world`), the command run in this process
(:func:`run_cli`), and the standard every case is held to (:func:`check_catalogue`).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from skynav.__main__ import main


def sha_tree(folder: Path) -> dict:
    """SHA-256 of every file under ``folder`` (hidden ones included), by relative path."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
            for p in sorted(folder.rglob("*"))}


def build_world(tmp_path_factory):
    """Inputs under ``in/`` (hashed around every case), outputs under ``out/``: a ``screen_small``
    facility file and its calibrated twin, one dot grid with simulated captures and a power-meter
    table, a one-frame dataset of the facility's camera and one of a 512 x 512 camera."""
    from skynav import datasets
    from skynav.calibration.facility_io import load_facility, write_facility
    from skynav.calibration.bench_files import calibrate_geometric, simulate, write_patterns

    tmp = tmp_path_factory.mktemp("bench_catalogue")
    inp, out = tmp / "in", tmp / "out"
    inp.mkdir()
    out.mkdir()
    fac = load_facility("screen_small")
    write_facility(fac, inp / "fac.yaml")
    write_patterns(fac, inp / "pats", phases=2)
    simulate(fac, inp / "pats", inp / "caps", frames=1, seed=3)
    cal = calibrate_geometric(fac, inp / "pats", inp / "caps", holdout=0.2).facility
    write_facility(cal, inp / "cal.yaml")
    recipe = datasets.preset_recipe("montecarlo")
    recipe.update(frames=1, formats=["png", "json"], camera=fac.camera.to_dict())
    datasets.generate(recipe, inp / "ds", workers=1, progress=False)
    big = datasets.preset_recipe("montecarlo")
    big.update(frames=1, formats=["png", "json"], camera={"preset": "paper", "width": 512, "height": 512})
    datasets.generate(big, inp / "ds512", workers=1, progress=False)
    (inp / "a_file.txt").write_text("x")
    return tmp, inp, out


def run_cli(argv, capsys):
    """``skynav ARGV`` in this process: (exit code, stdout, stderr); a traceback is appended to stderr
    with the code None."""
    import traceback

    try:
        code = main(argv)
    except SystemExit as exc:  # argparse
        code = exc.code
    except Exception:  # noqa: BLE001 - the command line would print this traceback
        out, err = capsys.readouterr()
        return None, out, err + "\n" + traceback.format_exc()
    out, err = capsys.readouterr()
    return code, out, err


def check_catalogue(world, catalogue, capsys):
    """Run every case of a catalogue in turn; fail listing every case that broke the standard.

    Each must end with exit 2 and exactly one stderr line ``skynav: error: ...`` containing the
    expected text (no traceback, no temporary file named), and leave every input unchanged.
    """
    tmp, inp, out = world
    before = sha_tree(inp)
    failures = []
    for ident, argv, expect in catalogue:
        code, stdout, err = run_cli(argv, capsys)
        lines = [ln for ln in err.splitlines() if ln.strip()]
        if "Traceback" in err or "Traceback" in stdout:
            failures.append(f"{ident}: traceback: {err.strip().splitlines()[-1][:200]}")
        elif code != 2:
            failures.append(f"{ident}: exit {code}; {err.strip()[:200]}")
        elif len(lines) != 1 or not lines[0].startswith("skynav: error:"):
            failures.append(f"{ident}: {len(lines)} stderr lines: {err.strip()[:300]}")
        elif expect not in lines[0]:
            failures.append(f"{ident}: {expect!r} not named in: {lines[0]}")
        elif ".tmp" in lines[0]:
            failures.append(f"{ident}: names a temporary file: {lines[0]}")
        after = sha_tree(inp)
        if after != before:
            changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
            failures.append(f"{ident}: changed its inputs: {changed[:5]}")
            before = after
    assert not failures, f"{len(failures)} of {len(catalogue)} cases:\n" + "\n".join(failures)
