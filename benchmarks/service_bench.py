"""Speed of the render service against ``skynav render`` and an in-process render, measured in one run.

Three parts (``--parts``), each printing its numbers and ratios:

- ``overhead``: the default 1024^2 frame (PNG + truth). In-process: ``render_outputs`` (what a
  worker runs: validate, build, render, encode) in this process, warm; service: the same mapping
  through ``Client.render`` against ``skynav serve --workers 1``; the two alternate, frame by
  frame, so that the load of a shared machine falls on both alike. Also one ``skynav render`` (a
  fresh process: imports, tables, kernels, then one frame and its files), the cost the service saves.
- ``throughput``: ``skynav serve --workers 2``; frames/s of one client asking one frame after the
  other, then of two clients at once (threads), interleaved and repeated; their ratio on the line
  ``THROUGHPUT RATIO``, with the renders in flight, the cores the workers obtained and the CPU per
  frame (workers, server, client) that tell a loaded machine from a service that serialises.
- ``loop``: the issue's speed criterion, like for like: ``skynav bench loop RECIPE --runs 1
  --bias-km none`` against ``skynav dataset generate RECIPE`` + ``skynav bench nav --runs 2`` (its
  least: bench nav needs two runs for sample statistics; the runs share the image processing, the
  second adds only its filter) on the same recipe, each with its default measurement noise (both
  calibrate R: the loop on about 180 frames it asks the service for, nav on all its dataset's
  frames; ``--sigma-px`` gives both a constant instead). The two alternate ``--loop-repeats`` times;
  medians of the wall times and of the CPU times (the commands' processes and their children), the
  ratio on the line ``LOOP TIME RATIO`` beside the load average, and the final 3-sigma / errors
  side by side.

    python benchmarks/service_bench.py [--parts overhead throughput loop] [--frames 20] [--recipe sequence]
        [--loop-repeats 1] [--sigma-px S] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
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


def _proc_cpu_s(pid: int) -> float:
    """CPU seconds (user + system) of process ``pid`` (Linux /proc)."""
    try:
        st = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(st[11]) + int(st[12])) / os.sysconf("SC_CLK_TCK")


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


def part_throughput(frames: int, repeats: int = 3) -> None:
    """Frames/s of one and of two clients against ``--workers 2``, interleaved (1, 2, 1, 2, ...)
    ``repeats`` times, medians; and what lets one read the ratio on a shared machine:

    - renders in flight: the sum of the workers' render times (``Skynav-Render-Seconds``) over the
      wall time. Two clients on two parallel workers keep ~2 in flight, whatever the machine's
      load; 1 would mean the renders were serialised (a lock, one worker);
    - cores obtained: the workers' CPU seconds over the wall time. With two clients the ratio of
      frames/s cannot exceed the ratio of cores obtained: on a machine other processes share, the
      cores (not the service) are the limit, and this shows it;
    - CPU per frame: of the workers (the render), of the server process (HTTP, parsing, the
      multipart answer: the event loop's share) and of the client: equal with one and two
      clients when nothing in the service contends.
    """
    from skynav.scenes.presets import preset_mapping
    from skynav.service import Client, LocalServer

    scene = preset_mapping("default")
    server = LocalServer(workers=2)
    with server as url:
        warm = [threading.Thread(target=lambda: Client(url).render(scene)) for _ in range(2)]   # both workers
        for t in warm:
            t.start()
        for t in warm:
            t.join()

        def client_loop(n, out):
            c = Client(url)
            for _ in range(n):
                r = c.render(scene, outputs=("png", "truth"))
                out.append(r.render_seconds)

        rows = {1: [], 2: []}
        for _ in range(repeats):
            for n_clients in (1, 2):
                done = []
                threads = [threading.Thread(target=client_loop, args=(frames, done)) for _ in range(n_clients)]
                c0, s0, m0 = (_children_cpu_s(server.proc.pid), _proc_cpu_s(server.proc.pid),
                              time.process_time())
                t0 = time.perf_counter()
                for t in threads:
                    t.start()
                for t in threads:
                    t.join()
                wall = time.perf_counter() - t0
                cpu_w = _children_cpu_s(server.proc.pid) - c0
                cpu_s = _proc_cpu_s(server.proc.pid) - s0
                cpu_c = time.process_time() - m0
                n = len(done)
                rows[n_clients].append({"fps": n / wall, "in_flight": sum(done) / wall, "cores": cpu_w / wall,
                                        "cpu_worker": cpu_w / n, "cpu_server": cpu_s / n, "cpu_client": cpu_c / n,
                                        "render_s": float(np.median(done))})
    med = {k: {f: float(np.median([r[f] for r in v])) for f in v[0]} for k, v in rows.items()}
    print(f"throughput (--workers 2 on {os.cpu_count()} cores, default 1024x1024 frame, png + truth; "
          f"{frames} frames per client, {repeats} interleaved repeats, medians; load average "
          f"{' '.join(f'{x:.1f}' for x in os.getloadavg())}):")
    for n, m in med.items():
        print(f"  {n} client{'s' if n > 1 else ''}: {m['fps']:.2f} frames/s; renders in flight {m['in_flight']:.2f}; "
              f"the workers got {m['cores']:.2f} cores; CPU per frame: workers {1e3 * m['cpu_worker']:.0f} ms, "
              f"server {1e3 * m['cpu_server']:.1f} ms, client {1e3 * m['cpu_client']:.1f} ms; "
              f"render {1e3 * m['render_s']:.0f} ms (wall, in the worker)")
    ratio = [b["fps"] / a["fps"] for a, b in zip(rows[1], rows[2])]
    cores = med[2]["cores"] / med[1]["cores"]
    print(f"  per repeat, two clients / one: {', '.join(f'{x:.2f}' for x in ratio)}")
    print(f"THROUGHPUT RATIO two clients / one client: {float(np.median(ratio)):.2f} x frames/s (issue: >= 1.8 on "
          f"2 idle cores); cores obtained {cores:.2f} x, renders in flight "
          f"{med[2]['in_flight'] / med[1]['in_flight']:.2f} x, "
          f"worker CPU per frame {med[2]['cpu_worker'] / med[1]['cpu_worker']:.2f} x")


def _timed(cmd, **kw):
    """Run ``cmd``; (wall s, CPU s of it and its children, stdout)."""
    c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    run = subprocess.run(cmd, capture_output=True, text=True, **kw)
    wall = time.perf_counter() - t0
    c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if run.returncode:
        raise SystemExit(f"{' '.join(cmd)} failed: {run.stderr[-2000:]}")
    return wall, (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime), run.stdout


def part_loop(recipe: str, extra: list, repeats: int = 1, sigma_px: float | None = None) -> None:
    sk = [sys.executable, "-m", "skynav"]
    given = ["--sigma-px", f"{sigma_px:g}"] if sigma_px is not None else []
    times = {"loop": [], "generate": [], "nav": []}
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        for i in range(repeats):
            load = os.getloadavg()[0]
            times["loop"].append(_timed(sk + ["bench", "loop", recipe, "-o", str(d / f"loop{i}"), "--runs", "1",
                                              "--bias-km", "none", "-q", *given, *extra])[:2])
            times["generate"].append(_timed(sk + ["dataset", "generate", recipe, "-o", str(d / f"ds{i}"), "-q",
                                                  *extra])[:2])
            times["nav"].append(_timed(sk + ["bench", "nav", str(d / f"ds{i}"), "-o", str(d / f"nav{i}"), "--runs",
                                             "2", "-q", *given])[:2])
            w = {k: v[-1][0] for k, v in times.items()}
            print(f"  repeat {i + 1}: bench loop {w['loop']:.0f} s; dataset generate {w['generate']:.0f} s + bench nav "
                  f"{w['nav']:.0f} s; ratio {w['loop'] / (w['generate'] + w['nav']):.2f} (load average {load:.1f} "
                  f"before, {os.getloadavg()[0]:.1f} after)", flush=True)
        a = json.loads((d / "loop0" / "summary.json").read_text())
        b = json.loads((d / "nav0" / "summary.json").read_text())
    med = {k: np.median(np.array(v), 0) for k, v in times.items()}   # (wall, cpu)
    print(f"loop ({recipe} {' '.join(extra)}; {a['frames']} frames; R: {'given' if given else 'calibrated'}; "
          f"medians of {repeats}):")
    print(f"  bench loop --runs 1: {med['loop'][0]:.0f} s wall, {med['loop'][1]:.0f} s CPU (R calibration "
          f"{a['run']['setup_time_s']:.0f} s of it); dataset generate {med['generate'][0]:.0f} s wall, "
          f"{med['generate'][1]:.0f} s CPU + bench nav --runs 2 {med['nav'][0]:.0f} s wall, {med['nav'][1]:.0f} s CPU "
          f"(R calibration {b['run']['setup_time_s']:.0f} s of it)")
    wall = med["loop"][0] / (med["generate"][0] + med["nav"][0])
    cpu = med["loop"][1] / (med["generate"][1] + med["nav"][1])
    print(f"LOOP TIME RATIO bench loop / (dataset generate + bench nav): {wall:.2f} x wall, {cpu:.2f} x CPU "
          f"(issue: <= 1.5); load average {os.getloadavg()[0]:.1f}")
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
    ap.add_argument("--frames", type=int, default=20, help="frames per client and part (default 20)")
    ap.add_argument("--repeats", type=int, default=3, help="throughput: interleaved repeats of one and two clients")
    ap.add_argument("--recipe", default="sequence")
    ap.add_argument("--loop-repeats", type=int, default=1, help="loop: alternations of loop and nav (medians)")
    ap.add_argument("--sigma-px", type=float, default=None, help="loop: a constant R for both (default: calibrated)")
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                    help="--set for the loop part's recipe (bench loop and dataset generate alike)")
    args = ap.parse_args()
    frames = int(os.environ.get("SKYNAV_MAX_COUNT", args.frames)) if "SKYNAV_MAX_COUNT" in os.environ else args.frames
    if "overhead" in args.parts:
        part_overhead(frames)
    if "throughput" in args.parts:
        part_throughput(frames, args.repeats)
    if "loop" in args.parts:
        part_loop(args.recipe, [x for s in args.sets for x in ("--set", s)], args.loop_repeats, args.sigma_px)


if __name__ == "__main__":
    main()
