"""docs/examples/basilisk_loop.py: a Basilisk simulation takes its pictures from the service (slow;
needs the optional extra ``basilisk``, PyPI ``bsk``)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

EXAMPLE = Path(__file__).resolve().parents[2] / "docs" / "examples" / "basilisk_loop.py"


@pytest.mark.slow
def test_basilisk_steps_ask_the_service_for_frames(server):
    pytest.importorskip("Basilisk", reason="Basilisk (pip install skynav[basilisk]) is not installed")
    from skynav.scenes.presets import preset_mapping

    run = subprocess.run([sys.executable, str(EXAMPLE), "--steps", "3", "--step-s", "600", "--size", "128",
                          "--service", server.url], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    steps = re.findall(r"step (\d): \S+ TDB,\s+(\d+) km from the start, frame 128x128, (\d+) stars, mars at "
                       r"\(([\d.]+), ([\d.]+)\) px", run.stdout)
    assert [int(s[0]) for s in steps] == [0, 1, 2], run.stdout
    # Basilisk's integrator against scipy's on the same Sun-only problem: the distance moved, to the
    # printed 1 km (the GM values differ by 1e-10 relative: micrometres here)
    from scipy.integrate import solve_ivp

    from skynav.scenes.ephemeris_jpl import default_ephemeris
    from skynav.scenes.timescales import tdb_seconds

    m = preset_mapping("default")
    sun_r, sun_v = default_ephemeris().position_velocity("sun", float(tdb_seconds(m["epoch"])))
    y0 = np.concatenate([np.array(m["observer"]["position_km"]) - sun_r, np.array(m["observer"]["velocity_km_s"]) - sun_v])
    gm = 1.32712440018e11   # km^3/s^2, the Sun (IAU 2009 / DE421 TDB-compatible)
    sol = solve_ivp(lambda t, y: np.concatenate([y[3:], -gm * y[:3] / np.linalg.norm(y[:3]) ** 3]), (0, 1200), y0,
                    method="DOP853", rtol=1e-12, atol=1e-9, t_eval=[0, 600, 1200])
    for k, moved, *_ in steps:
        want = np.linalg.norm(sol.y[:3, int(k)] - y0[:3])
        assert abs(int(moved) - want) <= 1.0, (k, moved, want)
    for s in steps:   # pointed at Mars: the centre of the 128 px frame
        assert abs(float(s[3]) - 63.5) < 1 and abs(float(s[4]) - 63.5) < 1 and int(s[2]) > 0
