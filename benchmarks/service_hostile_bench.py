"""Hostile requests against ``skynav serve`` while another client asks for small frames.

Starts ``skynav serve --workers 2`` (each worker under its address-space cap, ``--worker-memory``,
4 GiB by default) on loopback with a ``--data-dir`` holding an 8 MB PSF image, and sends it, one
after the other, requests that each make a worker's work grow without the cost model
(:mod:`skynav.service.budget`): a Gaussian ``sigma_px`` of 1000, a ``defocus_sigma_px`` of 1000,
an Airy ``max_half_px`` of 64 at 256^2, a 1024^2 streak of 50 s at 1 deg/s, the 8 MB PSF at 900
field-grid points, and Mitsuba at 1024 samples per pixel on a 1024^2 Earth, 4096 at 256^2 and
65536. Meanwhile a second client asks for a 64 x 64 frame after the other. Printed per hostile
request: its status and one line, its round trip, the largest peak RSS of the workers over it
(``VmHWM`` of each worker process, reset through ``/proc/PID/clear_refs`` before it, and RSS
sampled every 20 ms, which also catches a worker that ends), and the other client's slowest frame
while it ran; then the other client's frames in all (how many, all 200, all the same bytes, their
median and largest round trip). Linux only (``/proc``).

With ``--no-budget`` the cost model is off (budgets far above any request): what stands then is
each worker's address-space cap and the request deadline (``--request-deadline``), which
answer 503 and replace the worker.

    python benchmarks/service_hostile_bench.py                 # every hostile request
    python benchmarks/service_hostile_bench.py --no-budget     # the cap and the deadline alone
    python benchmarks/service_hostile_bench.py -k sigma        # the requests whose name matches 'sigma'
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import http.client
import json
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.parse

import numpy as np

READY = re.compile(r"ready at (http://\S+)")


def _scene(name="default", size=64, camera=None, render=None, attitude=None, observer_scale=None):
    from skynav.scenes.presets import preset_mapping

    m = preset_mapping(name)
    m["camera"].update({"width": size, "height": size, **(camera or {})})
    m.setdefault("render", {}).update(render or {})
    m["attitude"].update(attitude or {})
    if observer_scale is not None:   # the observer nearer its body: a larger disk
        m["observer"]["position_km"] = [x * observer_scale for x in m["observer"]["position_km"]]
    return m


def hostile_requests(data_dir: str) -> dict:
    """``{name: (request mapping, refused before rendering)}``; ``data_dir`` gets the 8 MB PSF image."""
    y, x = np.mgrid[-512:512, -512:512]
    np.save(os.path.join(data_dir, "psf8mb.npy"), np.exp(-(x**2 + y**2) / 200.0))   # 1024^2 float64: 8 MB
    field = [{"x_px": float(i), "y_px": float(j), "file": "psf8mb.npy"} for j in range(30) for i in range(30)]
    return {
        "gaussian sigma_px 1000": (_scene(camera={"psf": {"model": "gaussian", "sigma_px": 1000}}), True),
        "defocus_sigma_px 1000": (_scene(camera={"defocus_sigma_px": 1000}), True),
        "airy max_half_px 64 at 256^2": (_scene(size=256, camera={"psf": {"model": "airy", "max_half_px": 64}}), True),
        "streak 50 s at 1 deg/s, 1024^2": (_scene(size=1024, camera={"exposure_s": 50.0},
                                                  attitude={"angular_velocity_deg_s": [1.0, 0.0, 0.0]}), True),
        "8 MB PSF at 900 grid points": (_scene(camera={"psf": {"model": "tabulated", "oversampling": 4,
                                                                "field": field}}), True),
        "mitsuba_spp 1024 on a 1024^2 Earth": (_scene("earth_departure", size=1024, render={"mitsuba_spp": 1024},
                                                      observer_scale=0.03), True),
        "mitsuba_spp 4096 at 256^2": (_scene("earth_departure", size=256, render={"mitsuba_spp": 4096},
                                             observer_scale=0.1), True),
        "mitsuba_spp 65536 at 256^2": (_scene("earth_departure", size=256, render={"mitsuba_spp": 65536},
                                              observer_scale=0.1), True),
    }


def start_server(*args) -> tuple:
    """``(process, url)`` of ``skynav serve --port 0 ARGS`` once ready."""
    proc = subprocess.Popen([sys.executable, "-m", "skynav", "serve", "--port", "0", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    lines = []
    for line in proc.stdout:
        lines.append(line)
        m = READY.search(line)
        if m:
            threading.Thread(target=lambda: [print("  server:", line.rstrip(), flush=True) for line in proc.stdout
                                             if "Warning" not in line], daemon=True).start()
            return proc, m.group(1)
    raise RuntimeError("skynav serve did not start: " + "".join(lines)[-2000:])


def post(url: str, mapping: dict, timeout_s: float = 600.0) -> tuple:
    """``(status, body bytes, seconds)`` of one render request."""
    u = urllib.parse.urlsplit(url)
    c = http.client.HTTPConnection(u.hostname, u.port, timeout=timeout_s)
    t0 = time.perf_counter()
    try:
        c.request("POST", "/v1/render", body=json.dumps(mapping).encode(), headers={"Content-Type": "application/json"})
        r = c.getresponse()
        return r.status, r.read(), time.perf_counter() - t0
    finally:
        c.close()


def worker_pids(server_pid: int) -> list:
    """The render workers' process ids (the server's spawned children, not its resource tracker)."""
    out = []
    for tid in os.listdir(f"/proc/{server_pid}/task"):
        try:
            with open(f"/proc/{server_pid}/task/{tid}/children") as f:
                kids = [int(p) for p in f.read().split()]
        except OSError:
            continue
        for pid in kids:
            try:
                with open(f"/proc/{pid}/cmdline", "rb") as f:
                    cmd = f.read()
            except OSError:
                continue
            if b"spawn_main" in cmd and b"resource_tracker" not in cmd:
                out.append(pid)
    return out


def _status(pid: int) -> dict:
    try:
        with open(f"/proc/{pid}/status") as f:
            d = dict(line.split(":", 1) for line in f)
        return {k: int(d[k].split()[0]) * 1024 for k in ("VmRSS", "VmHWM")}
    except (OSError, KeyError):
        return {}


def address_space_cap(pid: int):
    """The ``Max address space`` soft limit of a process, bytes (None: unlimited)."""
    with open(f"/proc/{pid}/limits") as f:
        for line in f:
            if line.startswith("Max address space"):
                value = line.split()[3]
                return None if value == "unlimited" else int(value)
    return None


class PeakWatch:
    """The largest RSS of the server's workers while it runs (``VmHWM`` reset at the start, RSS
    sampled every 20 ms: a worker that ends has its last sample)."""

    def __init__(self, server_pid: int):
        self.server_pid, self.peak, self._stop = server_pid, 0, threading.Event()
        for pid in worker_pids(server_pid):
            try:
                with open(f"/proc/{pid}/clear_refs", "w") as f:
                    f.write("5")
            except OSError:
                pass
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _sample(self) -> None:
        for pid in worker_pids(self.server_pid):
            s = _status(pid)
            self.peak = max(self.peak, s.get("VmHWM", 0), s.get("VmRSS", 0))

    def _run(self) -> None:
        while not self._stop.wait(0.02):
            self._sample()

    def stop(self) -> int:
        self._stop.set()
        self._thread.join()
        self._sample()
        return self.peak


class OtherClient:
    """A client asking for a 64 x 64 frame after the other: ``(start time, seconds, status, digest)``."""

    def __init__(self, url: str):
        self.url, self.frames, self._stop = url, [], threading.Event()
        self.mapping = _scene()
        self.mapping["outputs"] = ["png"]
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            t = time.perf_counter()
            status, body, seconds = post(self.url, self.mapping, timeout_s=120)
            self.frames.append((t, seconds, status, hashlib.sha256(body).hexdigest()))
            time.sleep(0.05)

    def slowest_between(self, t0: float, t1: float) -> float:
        """The longest round trip of the frames that overlapped ``[t0, t1]``, s."""
        return max((s for t, s, _, _ in self.frames if t <= t1 and t + s >= t0), default=0.0)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-k", default="", help="only the requests whose name matches this regular expression")
    ap.add_argument("--no-budget", action="store_true", help="the cost model off: the cap and the deadline alone")
    ap.add_argument("--worker-memory", type=int, default=4 * 1024**3, help="each worker's address-space cap, bytes")
    ap.add_argument("--request-deadline", type=float, default=60.0, help="the server's request deadline, s")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as data_dir:
        requests = hostile_requests(data_dir)
        requests = {k: v for k, v in requests.items() if re.search(args.k, k)}
        budget = ["--max-request-memory", str(1 << 50), "--max-request-seconds", "86400"] if args.no_budget else []
        proc, url = start_server("--workers", "2", "--data-dir", data_dir, "--max-data-file-bytes", str(16 << 20),
                                 "--worker-memory", str(args.worker_memory), "--request-deadline",
                                 str(args.request_deadline), *budget)
        try:
            caps = {address_space_cap(pid) for pid in worker_pids(proc.pid)}
            print(f"server {url}, workers {worker_pids(proc.pid)}, address-space cap {sorted(caps, key=str)}; "
                  f"load {os.getloadavg()[0]:.1f}", flush=True)
            other = OtherClient(url)
            time.sleep(1.0)
            for name, (mapping, _) in requests.items():
                watch = PeakWatch(proc.pid)
                t0 = time.perf_counter()
                status, body, seconds = post(url, copy.deepcopy(mapping))
                peak = watch.stop()
                line = json.loads(body)["error"] if status != 200 else f"{len(body)} bytes"
                print(f"HOSTILE {name}: {status} in {seconds:.2f} s; worker peak RSS {peak / 2**20:.0f} MiB "
                      f"(cap {args.worker_memory / 2**30:.1f} GiB); other client's slowest frame "
                      f"over it {other.slowest_between(t0, t0 + seconds):.3f} s (0: none ran); {line[:160]}", flush=True)
            time.sleep(1.0)
            other.stop()
            lat = [s for _, s, _, _ in other.frames]
            print(f"OTHER CLIENT: {len(lat)} frames, all 200: {all(f[2] == 200 for f in other.frames)}, "
                  f"identical bytes: {len({f[3] for f in other.frames}) == 1}, median {statistics.median(lat):.3f} s, "
                  f"slowest {max(lat):.3f} s; load {os.getloadavg()[0]:.1f}", flush=True)
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(120)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
