"""docs/examples/basilisk_opnav.py: Basilisk's houghCircles -> pixelLineConverter -> relativeODuKF on
skynav frames through ``skynav serve --vizard`` (needs the ``basilisk`` extra: ``bsk``, ``bsk-opnav``).

The bounds are the ones the documentation states: at a non-saturating exposure (1e-5 s) every
Hough circle's centre within 2 px of the truth's apparent centre of Mars (Hough on an exact
silhouette errs by up to ~1.8 px) and its radius within 2 % of the truth's on-axis apparent radius
f tan(asin(R/d)), pixelLineConverter's range within 3 % of the simulation's, and the filter's final
position error inside its own 3-sigma.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLE = Path(__file__).resolve().parents[2] / "docs" / "examples" / "basilisk_opnav.py"
ROW = re.compile(r"image\s+(\d+): circle centre\s+([\d.]+) px, radius\s+([-+\d.]+) %, range\s+([-+\d.]+) %; "
                 r"filter position error\s+([\d.]+) m \(3-sigma\s+([\d.]+) m\)")


def test_basilisks_opnav_chain_on_skynav_frames(tmp_path):
    pytest.importorskip("Basilisk.fswAlgorithms.houghCircles", reason="bsk-opnav (pip install skynav[basilisk]) is not installed")
    pytest.importorskip("zmq", reason="pyzmq (pip install skynav[basilisk]) is not installed")
    run = subprocess.run([sys.executable, str(EXAMPLE), "--images", "20", "--truth-dir", str(tmp_path),
                          "--figure", str(tmp_path / "figure.png")],
                         capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr[-3000:]
    rows = [tuple(float(v) for v in m.groups()) for m in ROW.finditer(run.stdout)]
    assert [int(r[0]) for r in rows] == list(range(1, 21)), run.stdout
    for k, centre_px, radius_pct, range_pct, _, _ in rows:
        assert centre_px <= 2.0 and abs(radius_pct) <= 2.0 and abs(range_pct) <= 3.0, f"image {k:.0f}: {run.stdout}"
    assert rows[-1][4] <= rows[-1][5], run.stdout       # the filter's final error inside its 3-sigma
    assert len(list(tmp_path.glob("0*.png"))) == 20     # the truth of every frame is kept
    assert (tmp_path / "figure.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
