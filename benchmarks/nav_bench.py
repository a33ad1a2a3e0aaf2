"""Speed and accuracy of ``skynav bench nav`` on a ``sequence`` dataset.

Usage::

    python benchmarks/nav_bench.py DATASET [--runs 50] [--workers 1] [--case 1 3]

Prints the time split (setup: reading the plan and the R calibration; image processing; filter)
and the summary numbers next to Andreis et al. (2024) and the targets (final 3-sigma <= 1500 km,
0.35 m/s). Generate the dataset with ``skynav dataset generate sequence -o DATASET`` (720 frames, about 6 min on one core).
"""

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("dataset")
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--case", type=int, nargs="+", default=[1])
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as out:
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "skynav", "bench", "nav", a.dataset, "--runs", str(a.runs), "--workers",
                        str(a.workers), "--case", *map(str, a.case), "-q", "-o", out], check=True)
        wall = time.perf_counter() - t0
        s = json.loads((Path(out) / "summary.json").read_text())
    r = s["run"]
    f = s["final"]
    print(f"wall {wall:.1f} s (process), command {s['time_s']:.1f} s: setup {r['setup_time_s']:.1f} s, image processing "
          f"{r['ip_time_s']:.1f} s, filter {r['filter_time_s']:.1f} s; target <= 180 s for 50 runs x 720 frames")
    print(f"final 3-sigma: position {f['position_3sigma_km']:.0f} km (target <= 1500, Andreis et al. (2024) 1953), velocity "
          f"{f['velocity_3sigma_m_s']:.3f} m/s (target <= 0.35, Andreis et al. (2024) 0.41)")
    print(f"NEES mean {s['nees']['mean']:.2f} in [{s['nees']['band_low']:.2f}, {s['nees']['band_high']:.2f}]? "
          f"{s['nees']['band_low'] <= s['nees']['mean'] <= s['nees']['band_high']}")
    for c, v in s["cases"].items():
        print(f"case {c}: RMSE {v['position_rmse_km']:.0f} km, {v['velocity_rmse_m_s']:.3f} m/s")


if __name__ == "__main__":
    main()
