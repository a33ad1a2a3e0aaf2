"""Speed of the render service against ``skynav render`` and an in-process render, measured in one run.

Three parts (``--parts``), each printing its numbers, ratios and the load average before and after
(a shared machine's other users slow both sides; the sides are interleaved so that it falls on
both alike, and medians are taken):

- ``overhead``: the default 1024^2 frame with its PNG and truth, ``--frames`` x ``--repeats`` pairs.
  In-process: :func:`skynav.service.worker.render_outputs` in this process, warm: what a program
  that imports skynav does to get the same two outputs as bytes (validate the scene mapping,
  build the scene, render with ``skynav render``'s options, encode the PNG and the truth JSON).
  Service: the same mapping through ``Client.render(scene, outputs=("png", "truth"))`` against
  ``skynav serve --workers 1`` (one kept-alive connection), which returns the same bytes. Both sides
  use every core for the render (``--workers 1`` gives its worker ``cores`` threads, as this
  process has). The two alternate, which goes first switching every pair, with ``--pause-ms``
  between calls (the render's thread pool spins 17-20 ms after a frame, measured from its
  ``schedstat``: the pause, 30 ms by default, keeps that off the next measurement, of either side;
  with 20 ms a tenth of the frames after an in-process render had their own time raised to 3-5 ms). Printed: medians, p99 (of 60 pairs by default: close to
  the largest), the paired median difference, the service's own time (its client's wall time less
  the worker's render time: HTTP, the hand-off to the worker and back, the client's parsing; it
  does not carry the render's own noise, so on a loaded machine it is the steadier measure of the
  overhead; its lower quartile, the frames least delayed by other processes, the steadier still;
  the line ``OWN TIME`` against the target of 2 ms a frame), the server's share of it (the
  ``service`` duration of each answer's ``Server-Timing`` header),
  and the CPU per frame of the server process and of the client. Also one
  ``skynav render`` (a fresh process: imports, tables, kernels, then one frame and its files),
  the cost the service saves.
- ``throughput``: ``skynav serve --workers 2``; frames/s of one client asking one frame after the
  other, then of two clients at once (threads), and, as the machine's own ceiling, of the same
  render in one and in two plain processes (no service; each with the thread budget of a
  service worker, ``cores // 2``); all four interleaved, ``--repeats`` times after a warm-up,
  medians and the spread (min-max) of the per-repeat ratios. The line ``THROUGHPUT RATIO`` holds
  the service's ratio and the ceiling's: two renders that contend for memory bandwidth slow each
  other down without any service, and the service cannot scale better than that. Also: renders
  in flight, the cores the workers obtained, and the CPU per frame (workers, server, client).
- ``loop``: the closed loop's speed, like for like: ``skynav bench loop RECIPE --runs 1
  --bias-km none`` against ``skynav dataset generate RECIPE`` + ``skynav bench nav --runs 2`` (its
  least: bench nav needs two runs for sample statistics; the runs share the image processing, the
  second adds only its filter) on the same recipe, each with its default measurement noise (both
  calibrate R: the loop on about 180 frames it asks the service for, nav on all its dataset's
  frames; ``--sigma-px`` gives both a constant instead). The two alternate ``--loop-repeats`` times;
  medians of the wall times and of the CPU times (the commands' processes and their children), the
  ratio on the line ``LOOP TIME RATIO`` beside the load average, and the final 3-sigma / errors
  side by side.

    python benchmarks/service_bench.py [--parts overhead throughput loop] [--frames 20] [--repeats 3] [--recipe sequence]
        [--loop-repeats 1] [--sigma-px S] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

OUTPUTS = ("png", "truth")


def _pct(a, q):
    return float(np.percentile(np.asarray(a), q))


def _load() -> str:
    return " ".join(f"{x:.1f}" for x in os.getloadavg())


def part_overhead(frames: int, repeats: int, pause_s: float) -> None:
    from skynav.scenes.presets import preset_mapping
    from skynav.service import Client, LocalServer
    from skynav.service.worker import render_outputs

    scene = preset_mapping("default")
    for _ in range(3):
        render_outputs(scene, OUTPUTS)   # warm this process
    n = frames * repeats
    local, remote, in_worker, in_server = [], [], [], []
    load0 = _load()
    server = LocalServer(workers=1)
    with server as url:
        client = Client(url)
        for _ in range(3):
            client.render(scene, outputs=OUTPUTS)

        def one_local():
            t0 = time.perf_counter()
            render_outputs(scene, OUTPUTS)
            local.append(time.perf_counter() - t0)

        def one_remote():
            t0 = time.perf_counter()
            r = client.render(scene, outputs=OUTPUTS)
            remote.append(time.perf_counter() - t0)
            in_worker.append(r.render_seconds)
            in_server.append(r.server_timing["service"])

        s0, cpu_client = _proc_cpu_s(server.proc.pid), 0.0
        for i in range(n):
            for side in ((one_local, one_remote) if i % 2 == 0 else (one_remote, one_local)):
                time.sleep(pause_s)
                t = time.thread_time()   # the client is this thread (the render's pool is not)
                side()
                if side is one_remote:
                    cpu_client += time.thread_time() - t
        cpu_server = (_proc_cpu_s(server.proc.pid) - s0) / n
        cpu_client /= n
    load1 = _load()
    with tempfile.TemporaryDirectory() as d:
        cli = []
        for _ in range(3):
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "skynav", "render", "-o", d], check=True, capture_output=True)
            cli.append(time.perf_counter() - t0)
    lm, rm = float(np.median(local)), float(np.median(remote))
    own = np.subtract(remote, in_worker)
    print(f"overhead ({n} pairs, default 1024x1024, png + truth, {1e3 * pause_s:.0f} ms pause; "
          f"load average {load0} -> {load1}):")
    print(f"  in-process render_outputs: median {1e3 * lm:.1f} ms, p99 {1e3 * _pct(local, 99):.1f} ms")
    print(f"  service round trip:        median {1e3 * rm:.1f} ms, p99 {1e3 * _pct(remote, 99):.1f} ms "
          f"(the worker's render: median {1e3 * float(np.median(in_worker)):.1f} ms)")
    print(f"OVERHEAD per request: median {100 * (rm / lm - 1):+.1f} %, p99 "
          f"{100 * (_pct(remote, 99) / _pct(local, 99) - 1):+.1f} %; paired: median of the differences "
          f"{1e3 * float(np.median(np.subtract(remote, local))):+.2f} ms")
    print(f"ROUND TRIP less the worker's render (the client's time, the transfer and the server's): median "
          f"{1e3 * float(np.median(own)):.2f} ms = {100 * float(np.median(own)) / lm:.1f} % of the in-process median, lower quartile "
          f"{1e3 * _pct(own, 25):.2f} ms, p99 {1e3 * _pct(own, 99):.2f} ms; "
          f"CPU per frame: server process {1e3 * cpu_server:.2f} ms, client {1e3 * cpu_client:.2f} ms")
    print(f"OWN TIME of the service (its Server-Timing 'service'; target <= 2 ms): median {1e3 * float(np.median(in_server)):.2f} ms, "
          f"p99 {1e3 * _pct(in_server, 99):.2f} ms")
    print(f"  skynav render (fresh process, one frame and its files): median {float(np.median(cli)):.2f} s "
          f"= {float(np.median(cli)) / rm:.0f} x a service frame")


def _proc_cpu_s(pid: int) -> float:
    """CPU seconds of process ``pid``: its threads' run time in ns (``/proc/PID/task/*/schedstat``),
    else user + system in clock ticks (``/proc/PID/stat``, 10 ms resolution)."""
    total, found = 0, False
    try:
        for task in Path(f"/proc/{pid}/task").iterdir():
            try:
                total += int((task / "schedstat").read_text().split()[0])
                found = True
            except (OSError, ValueError, IndexError):
                pass
    except OSError:
        return 0.0
    if found:
        return total * 1e-9
    try:
        st = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(st[11]) + int(st[12])) / os.sysconf("SC_CLK_TCK")


def _children(pid: int) -> list:
    """The processes whose parent is ``pid`` (Linux /proc)."""
    kids = []
    for p in os.listdir("/proc"):
        if p.isdigit():
            try:
                if int(Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                    kids.append(int(p))
            except (OSError, ValueError, IndexError):
                continue
    return kids


def _render_loop(conn) -> None:
    """A plain process rendering the default frame in a loop on request: the ceiling's side."""
    from skynav.scenes.presets import preset_mapping
    from skynav.service.worker import render_outputs

    scene = preset_mapping("default")
    for _ in range(3):
        render_outputs(scene, OUTPUTS)
    conn.send("ready")
    while True:
        n = conn.recv()
        if not n:
            return
        c0 = time.process_time()
        for _ in range(n):
            render_outputs(scene, OUTPUTS)
        conn.send(time.process_time() - c0)


class _Plain:
    """Two warm plain render processes (spawned with a service worker's thread budget)."""

    def __init__(self, threads: int):
        from skynav.infra.pool import WorkerThreads

        ctx = multiprocessing.get_context("spawn")
        self.conns, self.procs = [], []
        for _ in range(2):
            a, b = ctx.Pipe()
            proc = ctx.Process(target=_render_loop, args=(b,), daemon=True)
            with WorkerThreads(2, threads=threads):
                proc.start()
            self.conns.append(a)
            self.procs.append(proc)
        for c in self.conns:
            if c.recv() != "ready":
                raise SystemExit("a plain render process did not start")

    def run(self, n_procs: int, frames: int) -> dict:
        t0 = time.perf_counter()
        for c in self.conns[:n_procs]:
            c.send(frames)
        cpu = sum(c.recv() for c in self.conns[:n_procs])
        wall = time.perf_counter() - t0
        return {"fps": n_procs * frames / wall, "cpu_worker": cpu / (n_procs * frames), "cores": cpu / wall}

    def close(self) -> None:
        for c, p in zip(self.conns, self.procs):
            c.send(0)
            p.join(30)


def part_throughput(frames: int, repeats: int = 3) -> None:
    """Frames/s of one and of two clients against ``--workers 2``, and of one and two plain render
    processes, interleaved (after a warm-up round) ``repeats`` times; medians, spreads, and what
    lets one read the ratio on a shared machine:

    - the ceiling: two plain processes rendering the same frame with the same thread budget. Two
      renders that stream through memory slow each other down (shared L3 and memory bandwidth);
      their ratio is what the machine allows, the service's can only be lower;
    - renders in flight: the sum of the workers' render times (``render`` of each answer's ``Server-Timing``) over the
      wall time. Two clients on two parallel workers keep ~2 in flight; 1 would mean the renders
      were serialised (a lock, one worker);
    - cores obtained: the workers' CPU seconds over the wall time. The ratio of frames/s cannot
      exceed the ratio of cores obtained: on a machine other processes share, the cores (not the
      service) are the limit, and this shows it;
    - CPU per frame: of the workers (the render), of the server process (HTTP, the hand-off to the
      worker: the event loop's share, taken from the cores the workers would use) and of the client.
    """
    from skynav.scenes.presets import preset_mapping
    from skynav.service import Client, LocalServer

    scene = preset_mapping("default")
    threads = max(1, (os.cpu_count() or 1) // 2)
    load0 = _load()
    plain = _Plain(threads)
    server = LocalServer(workers=2)
    try:
        with server as url:
            spid = server.proc.pid
            workers = [p for p in _children(spid) if b"multiprocessing" in Path(f"/proc/{p}/cmdline").read_bytes()
                       and b"resource_tracker" not in Path(f"/proc/{p}/cmdline").read_bytes()]

            def client_loop(n, out):
                c = Client(url)
                for _ in range(n):
                    out.append(c.render(scene, outputs=OUTPUTS).render_seconds)

            def service(n_clients, n):
                done = []
                threads_ = [threading.Thread(target=client_loop, args=(n, done)) for _ in range(n_clients)]
                c0 = sum(_proc_cpu_s(p) for p in workers)
                s0, m0 = _proc_cpu_s(spid), time.process_time()
                t0 = time.perf_counter()
                for t in threads_:
                    t.start()
                for t in threads_:
                    t.join()
                wall = time.perf_counter() - t0
                cpu_w = sum(_proc_cpu_s(p) for p in workers) - c0
                k = len(done)
                return {"fps": k / wall, "in_flight": sum(done) / wall, "cores": cpu_w / wall,
                        "cpu_worker": cpu_w / k, "cpu_server": (_proc_cpu_s(spid) - s0) / k,
                        "cpu_client": (time.process_time() - m0) / k, "render_s": float(np.median(done))}

            warm = max(2, frames // 4)
            service(1, warm), service(2, warm), plain.run(1, warm), plain.run(2, warm)   # steady state
            rows = {"s1": [], "s2": [], "p1": [], "p2": []}
            for _ in range(repeats):
                rows["s1"].append(service(1, frames))
                rows["s2"].append(service(2, frames))
                rows["p1"].append(plain.run(1, frames))
                rows["p2"].append(plain.run(2, frames))
    finally:
        plain.close()
    load1 = _load()
    med = {k: {f: float(np.median([r[f] for r in v])) for f in v[0]} for k, v in rows.items()}
    print(f"throughput (--workers 2, {threads} thread{'s' if threads > 1 else ''} each, on {os.cpu_count()} cores; "
          f"default 1024x1024 frame, png + truth; {frames} frames per client or process, {repeats} interleaved "
          f"repeats after a warm-up, medians; load average {load0} -> {load1}):")
    for k, label in (("s1", "service, 1 client "), ("s2", "service, 2 clients")):
        m = med[k]
        print(f"  {label}: {m['fps']:.2f} frames/s; renders in flight {m['in_flight']:.2f}; "
              f"the workers got {m['cores']:.2f} cores; CPU per frame: workers {1e3 * m['cpu_worker']:.1f} ms, "
              f"server {1e3 * m['cpu_server']:.2f} ms, client {1e3 * m['cpu_client']:.2f} ms; "
              f"render {1e3 * m['render_s']:.1f} ms (wall, in the worker)")
    for k, label in (("p1", "plain, 1 process  "), ("p2", "plain, 2 processes")):
        m = med[k]
        print(f"  {label}: {m['fps']:.2f} frames/s; {m['cores']:.2f} cores; CPU per frame {1e3 * m['cpu_worker']:.1f} ms")
    ratio = [b["fps"] / a["fps"] for a, b in zip(rows["s1"], rows["s2"])]
    ceiling = [b["fps"] / a["fps"] for a, b in zip(rows["p1"], rows["p2"])]
    single = [a["fps"] / b["fps"] for a, b in zip(rows["s1"], rows["p1"])]
    print(f"  per repeat, two clients / one: {', '.join(f'{x:.2f}' for x in ratio)}; two plain processes / one: "
          f"{', '.join(f'{x:.2f}' for x in ceiling)}; one client / one plain process: "
          f"{', '.join(f'{x:.2f}' for x in single)}")
    print(f"THROUGHPUT RATIO two clients / one client: {float(np.median(ratio)):.2f} x frames/s "
          f"(min {min(ratio):.2f}, max {max(ratio):.2f}; issue: >= 1.8 on 2 idle cores); "
          f"the machine's ceiling (two plain processes / one): {float(np.median(ceiling)):.2f} x "
          f"(min {min(ceiling):.2f}, max {max(ceiling):.2f}); service / ceiling "
          f"{float(np.median(ratio)) / float(np.median(ceiling)):.2f}")
    print(f"  two clients vs one: cores obtained {med['s2']['cores'] / med['s1']['cores']:.2f} x, renders in flight "
          f"{med['s2']['in_flight'] / med['s1']['in_flight']:.2f} x, worker CPU per frame "
          f"{med['s2']['cpu_worker'] / med['s1']['cpu_worker']:.2f} x (plain processes: "
          f"{med['p2']['cpu_worker'] / med['p1']['cpu_worker']:.2f} x)")


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
    ap.add_argument("--repeats", type=int, default=3,
                    help="throughput: interleaved repeats of one and two clients; overhead: frames x repeats pairs")
    ap.add_argument("--pause-ms", type=float, default=30.0, help="overhead: pause before each call (default 30)")
    ap.add_argument("--recipe", default="sequence")
    ap.add_argument("--loop-repeats", type=int, default=1, help="loop: alternations of loop and nav (medians)")
    ap.add_argument("--sigma-px", type=float, default=None, help="loop: a constant R for both (default: calibrated)")
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                    help="--set for the loop part's recipe (bench loop and dataset generate alike)")
    args = ap.parse_args()
    frames = int(os.environ.get("SKYNAV_MAX_COUNT", args.frames)) if "SKYNAV_MAX_COUNT" in os.environ else args.frames
    if "overhead" in args.parts:
        part_overhead(frames, args.repeats, args.pause_ms / 1e3)
    if "throughput" in args.parts:
        part_throughput(frames, args.repeats)
    if "loop" in args.parts:
        part_loop(args.recipe, [x for s in args.sets for x in ("--set", s)], args.loop_repeats, args.sigma_px)


if __name__ == "__main__":
    main()
