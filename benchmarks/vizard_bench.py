"""A frame through ``skynav serve --vizard`` against the same frame through ``skynav serve``'s HTTP path.

Both servers run on this machine, one frame at a time, alternating (each idle while the other
is measured: the render takes both cores; a load on the machine falls on both alike). Vizard side: a ZeroMQ REQ client that speaks vizInterface's protocol
sends ``[SIM_UPDATE | | | VizMessage]`` (a spacecraft 18,000 km from Mars, a 256 x 256 px, 40 deg
camera, the sim time advanced by 60 s a frame) and ``REQUEST_IMAGE_1``; a frame's time is both
round trips. HTTP side: the scene the endpoint derived for each frame
(:func:`skynav.service.vizard_scene.scene_mapping`, the endpoint's function) through ``Client.render(scene, outputs=("png",))`` against ``skynav serve --workers 1``, one
kept-alive connection. The two sides get the same frames, whose PNG bytes are compared. Both
start warm (``--warmup`` frames each, not counted). Printed: each side's median and the line
``VIZARD / HTTP FRAME TIME: R x``.

    python benchmarks/vizard_bench.py [--frames 20] [--warmup 3] [--exposure-s 1e-5]
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import time

import numpy as np


def start(args, pattern: str):
    proc = subprocess.Popen([sys.executable, "-m", "skynav", "serve", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    for line in proc.stdout:
        m = re.search(pattern, line)
        if m:
            return proc, m.group(1)
    raise SystemExit(f"skynav serve {' '.join(args)} did not start")


def stop(proc) -> None:
    proc.terminate()
    proc.wait(120)


def sim_update(k: int, size: int) -> list:
    from skynav.service.vizard_schema import VizMessage

    m = VizMessage()
    m.currentTime.frameNumber, m.currentTime.simTimeElapsed = k, 60e9 * k
    m.epoch.year, m.epoch.month, m.epoch.day = 2027, 2, 1
    m.celestialBodies.add(bodyName="mars barycenter", position=[0, 0, 0])
    # on the Sun's side of Mars (phase ~5 deg at the epoch), the camera (body +z) at Mars
    r = np.array([1.3e7, -1.0e7, -5.8e6])
    r *= 1.8e7 / np.linalg.norm(r)
    z = -r / np.linalg.norm(r)
    x = np.cross([0, 0, 1.0], z)
    x /= np.linalg.norm(x)
    from scipy.spatial.transform import Rotation

    sigma = Rotation.from_matrix(np.array([x, np.cross(z, x), z]).T).as_mrp()   # passive [BN]
    m.spacecraft.add(spacecraftName="sc", position=r.tolist(), velocity=[0, 0, 0], rotation=sigma.tolist())
    m.cameras.add(cameraID=1, parentName="sc", fieldOfView=40.0, resolution=[size, size],
                  cameraDir_B=[1 / 3, 1 / 3, -1 / 3], renderRate=60_000_000_000)
    return [b"SIM_UPDATE", b"", b"", m.SerializeToString()]


def measure(n: int, size: int, exposure_s: float) -> tuple[list, list, list, list]:
    """Frame k through the endpoint, then the scene it derived through HTTP, k = 1..n (interleaved:
    a load on the machine falls on both sides alike)."""
    import zmq

    from skynav.service import Client

    from skynav.service.vizard_scene import epoch_utc_iso, scene_mapping
    from skynav.service.vizard_schema import VizMessage

    viz, address = start(["--vizard", "--vizard-port", "0", "--set", f"camera.exposure_s={exposure_s}"],
                         r"ready at (tcp://\S+)")
    http, url = start(["--port", "0", "--workers", "1"], r"ready at (http://\S+)")
    sock = zmq.Context.instance().socket(zmq.REQ)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(address)
    client = Client(url)
    viz_t, viz_png, http_t, http_png = [], [], [], []
    try:
        for k in range(1, n + 1):
            t0 = time.perf_counter()
            update = sim_update(k, size)
            sock.send_multipart(update)
            assert sock.recv_multipart() == [b"OK"]
            sock.send_multipart([b"REQUEST_IMAGE_1"])
            _, png = sock.recv_multipart()
            viz_t.append(time.perf_counter() - t0)
            viz_png.append(png)
            # the scene the endpoint derived, by the same function (tests/service/test_vizard.py checks
            # that its PNG is the one skynav render makes of that scene)
            msg = VizMessage.FromString(update[3])
            scene = scene_mapping(msg, msg.cameras[0], msg.spacecraft[0], epoch_utc=epoch_utc_iso(msg.epoch),
                                  base={"camera": {"exposure_s": exposure_s}}, origin="mars")
            time.sleep(0.03)     # the render's thread pool spins down (benchmarks/service_bench.py)
            t0 = time.perf_counter()
            frame = client.render(scene, outputs=("png",))
            http_t.append(time.perf_counter() - t0)
            http_png.append(frame.png)
            time.sleep(0.03)
    finally:
        sock.close(0)
        stop(viz)
        stop(http)
    return viz_t, viz_png, http_t, http_png


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20, help="frames measured on each side")
    ap.add_argument("--warmup", type=int, default=3, help="frames first, not measured")
    ap.add_argument("--size", type=int, default=256, help="camera width and height, px")
    ap.add_argument("--exposure-s", type=float, default=1e-5, help="exposure, s")
    args = ap.parse_args()
    n = args.warmup + args.frames
    load = os.getloadavg()[0]
    viz_t, viz_png, http_t, http_png = measure(n, args.size, args.exposure_s)
    load_after = os.getloadavg()[0]
    viz_med = statistics.median(viz_t[args.warmup:]) * 1e3
    http_med = statistics.median(http_t[args.warmup:]) * 1e3
    print(f"{args.size}x{args.size} Mars frames, {args.frames} measured after {args.warmup}; load average "
          f"{load:.2f} -> {load_after:.2f}")
    print(f"vizard endpoint (SIM_UPDATE + REQUEST_IMAGE round trips): median {viz_med:.1f} ms")
    print(f"HTTP service (Client.render, png): median {http_med:.1f} ms")
    print(f"same PNG bytes on every frame: {viz_png == http_png}")
    print(f"VIZARD / HTTP FRAME TIME: {viz_med / http_med:.3f} x (target <= 1.2)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
