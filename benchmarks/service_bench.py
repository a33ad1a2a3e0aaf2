"""Speed of the render service against ``skynav render`` and an in-process render, measured in one run.

Three parts (``--parts``), each printing its numbers and ratios:

- ``overhead``: the default 1024^2 frame (PNG + truth). In-process: ``render_outputs`` (what a
  worker runs: validate, build, render, encode) in this process, warm; service: the same mapping
  through ``Client.render`` against ``skynav serve --workers 1``; the two alternate, frame by
  frame, so that the load of a shared machine falls on both alike. Also one ``skynav render`` (a
  fresh process: imports, tables, kernels, then one frame and its files), the cost the service saves.
- ``throughput``: ``skynav serve --workers 2``; frames/s of one client asking one frame after the
  other, then of two clients at once (threads), and their ratio.
- ``loop``: ``skynav bench loop RECIPE --runs 1 --bias-km none`` against ``skynav dataset
  generate RECIPE`` + ``skynav bench nav --runs 2`` (bench nav needs two runs) on the same recipe,
  both with ``--sigma-px 0.1``: wall time and final 3-sigma / errors side by side.

    python benchmarks/service_bench.py [--parts overhead throughput loop] [--frames 20] [--recipe sequence]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np


def _pct(a, q):
    return float(np.percentile(np.asarray(a), q))


def part_overhead(frames: int) -> None:
    from skynav.scenes.presets import preset_mapping
    from skynav.service import Client, LocalServer
    from skynav.service.worker import render_outputs

    scene = preset_mapping("default")
    render_outputs(scene, ("png", "truth"))   # warm this process
    local, remote = [], []
    with LocalServer(workers=1) as url:
        client = Client(url)
        client.render(scene)
        for _ in range(frames):
            t0 = time.perf_counter()
            render_outputs(scene, ("png", "truth"))
            local.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            client.render(scene, outputs=("png", "truth"))
            remote.append(time.perf_counter() - t0)
    with tempfile.TemporaryDirectory() as d:
        cli = []
        for _ in range(3):
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "skynav", "render", "-o", d], check=True, capture_output=True)
            cli.append(time.perf_counter() - t0)
    lm, rm = float(np.median(local)), float(np.median(remote))
    print(f"overhead ({frames} frames, default 1024x1024, png + truth):")
    print(f"  in-process render_outputs: median {1e3 * lm:.0f} ms, p99 {1e3 * _pct(local, 99):.0f} ms")
    print(f"  service round trip:        median {1e3 * rm:.0f} ms, p99 {1e3 * _pct(remote, 99):.0f} ms")
    print(f"  per-request overhead: median {100 * (rm / lm - 1):+.1f} % "
          f"(paired: median of the differences {1e3 * float(np.median(np.subtract(remote, local))):+.1f} ms)")
    print(f"  skynav render (fresh process, one frame and its files): median {float(np.median(cli)):.2f} s "
          f"= {float(np.median(cli)) / rm:.1f} x a service frame")


def _children_cpu_s(pid: int) -> float:
    """CPU seconds (user + system) of the processes whose parent is ``pid`` (Linux /proc)."""
    total = 0.0
    for p in os.listdir("/proc"):
        if p.isdigit():
            try:
                st = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(st[1]) == pid:
                total += (int(st[11]) + int(st[12])) / os.sysconf("SC_CLK_TCK")
    return total


def part_throughput(frames: int) -> None:
    """Frames/s of one and two clients, and the cores the workers got meanwhile: on a machine other
    processes share, the cores obtained (not the service) can be the limit, and this shows it."""
    from skynav.scenes.presets import preset_mapping
    from skynav.service import Client, LocalServer

    scene = preset_mapping("default")
    server = LocalServer(workers=2)
    with server as url:
        Client(url).render(scene)

        def client_loop(n, out):
            c = Client(url)
            for _ in range(n):
                c.render(scene, outputs=("png", "truth"))
            out.append(n)

        rows = []
        for n_clients in (1, 2):
            done = []
            threads = [threading.Thread(target=client_loop, args=(frames, done)) for _ in range(n_clients)]
            c0, t0 = _children_cpu_s(server.proc.pid), time.perf_counter()
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            wall = time.perf_counter() - t0
            cpu = _children_cpu_s(server.proc.pid) - c0
            rows.append((sum(done) / wall, cpu / wall, cpu / sum(done)))
    print(f"throughput (--workers 2, {os.cpu_count()} cores, default frame; load average "
          f"{os.getloadavg()[0]:.1f}):")
    for n, (fps, cores, cpu_frame) in zip((1, 2), rows):
        print(f"  {n} client{'s' if n > 1 else ''}: {fps:.2f} frames/s; the workers got {cores:.2f} cores, "
              f"{1e3 * cpu_frame:.0f} ms CPU per frame")
    print(f"  two clients / one: {rows[1][0] / rows[0][0]:.2f} x frames/s, {rows[1][1] / rows[0][1]:.2f} x cores obtained")


def _timed(cmd, **kw):
    t0 = time.perf_counter()
    run = subprocess.run(cmd, capture_output=True, text=True, **kw)
    if run.returncode:
        raise SystemExit(f"{' '.join(cmd)} failed: {run.stderr[-2000:]}")
    return time.perf_counter() - t0, run.stdout


def part_loop(recipe: str, extra: list) -> None:
    sk = [sys.executable, "-m", "skynav"]
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        t_loop, _ = _timed(sk + ["bench", "loop", recipe, "-o", str(d / "loop"), "--runs", "1", "--bias-km", "none",
                                 "--sigma-px", "0.1", "-q", *extra])
        t_gen, _ = _timed(sk + ["dataset", "generate", recipe, "-o", str(d / "ds"), "--workers", "2", "-q", *extra])
        t_nav, _ = _timed(sk + ["bench", "nav", str(d / "ds"), "-o", str(d / "nav"), "--runs", "2", "--sigma-px", "0.1",
                                "-q"])
        a = json.loads((d / "loop" / "summary.json").read_text())
        b = json.loads((d / "nav" / "summary.json").read_text())
    print(f"loop ({recipe} {' '.join(extra)}; {a['frames']} frames):")
    print(f"  bench loop --runs 1: {t_loop:.0f} s; dataset generate {t_gen:.0f} s + bench nav --runs 2 {t_nav:.0f} s "
          f"= {t_gen + t_nav:.0f} s: ratio {t_loop / (t_gen + t_nav):.2f}")
    for key, unit in (("filter_position_3sigma_km", "km"), ("filter_velocity_3sigma_m_s", "m/s"),
                      ("position_3sigma_km", "km"), ("velocity_3sigma_m_s", "m/s"),
                      ("position_error_rms_km", "km"), ("velocity_error_rms_m_s", "m/s")):
        x, y = a["final"][key], b["final"][key]
        print(f"  {key}: loop {x:.4g} {unit}, nav {y:.4g} {unit} (loop/nav {x / y:.2f})")
    cl = a["closed_loop"]
    print(f"  closed loop: target in the field {100 * cl['target_in_field_fraction']:.1f} %, centred "
          f"{100 * cl['target_centred_fraction']:.1f} %, latency median {1e3 * cl['latency_s']['median']:.0f} ms, "
          f"p99 {1e3 * cl['latency_s']['p99']:.0f} ms")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", nargs="+", default=["overhead", "throughput"], choices=("overhead", "throughput", "loop"))
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--recipe", default="sequence")
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                    help="--set for the loop part's recipe (bench loop and dataset generate alike)")
    args = ap.parse_args()
    frames = int(os.environ.get("SKYNAV_MAX_COUNT", args.frames)) if "SKYNAV_MAX_COUNT" in os.environ else args.frames
    if "overhead" in args.parts:
        part_overhead(frames)
    if "throughput" in args.parts:
        part_throughput(frames)
    if "loop" in args.parts:
        part_loop(args.recipe, [x for s in args.sets for x in ("--set", s)])


if __name__ == "__main__":
    main()
