"""``skynav serve --vizard``: the Vizard-compatible image endpoint, against a message-level client.

The client here is this file's own: a ZeroMQ REQ socket that speaks Basilisk's vizInterface
protocol (PING, ``[SIM_UPDATE | | | VizMessage]``, ``REQUEST_IMAGE_<id>``) with the VizMessage
built from the declared schema. The geometry (MRPs, Unity's camera frame) is checked against
scipy's rotations, an independent implementation; tests/service/test_vizard_basilisk.py drives
Basilisk's own vizInterface.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

zmq = pytest.importorskip("zmq", reason="pyzmq (pip install skynav[basilisk]) is not installed")
pytest.importorskip("google.protobuf", reason="protobuf (pip install skynav[basilisk]) is not installed")

from skynav.service.vizard_scene import camera_dcm_from_unity, mrp_to_dcm, origin_body  # noqa: E402
from skynav.service.vizard_schema import VizMessage  # noqa: E402

READY = re.compile(r"Vizard endpoint ready at (tcp://\S+)")


class Endpoint:
    def __init__(self, proc, address, lines):
        self.proc, self.address, self.lines = proc, address, lines

    def stop(self, sig=signal.SIGTERM, timeout_s=60) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        return self.proc.wait(timeout_s)

    @property
    def output(self) -> str:
        return "".join(self.lines)


def start_vizard(*args, timeout_s=120) -> Endpoint:
    """``skynav serve --vizard --vizard-port 0 ARGS`` as a subprocess; waits for its ready line."""
    proc = subprocess.Popen([sys.executable, "-m", "skynav", "serve", "--vizard", "--vizard-port", "0", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines, found = [], []

    def pump():
        for line in proc.stdout:
            lines.append(line)
            m = READY.search(line)
            if m and not found:
                found.append(m.group(1))

    threading.Thread(target=pump, daemon=True).start()
    t_end = time.monotonic() + timeout_s
    while not found:
        if proc.poll() is not None or time.monotonic() > t_end:
            proc.kill()
            proc.wait(10)
            raise RuntimeError(f"skynav serve --vizard did not start: {''.join(lines)[-2000:]}")
        time.sleep(0.05)
    return Endpoint(proc, found[0], lines)


def render_scene_file(scene: Path, out: Path) -> bytes:
    """The PNG ``skynav render SCENE`` writes."""
    run = subprocess.run([sys.executable, "-m", "skynav", "render", str(scene), "-o", str(out), "-q"],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    return (out / "frame.png").read_bytes()


def passive_mrp(dcm) -> np.ndarray:
    """The MRP of a passive direction cosine matrix, from scipy (whose matrices are active)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(np.asarray(dcm).T).as_mrp()


def skyfield_tdb_seconds(*utc) -> float:
    """TDB seconds past J2000 of a UTC calendar date, by skyfield (independent of astropy)."""
    from skyfield.api import load

    t = load.timescale(builtin=True).utc(*utc)
    return (t.whole - 2451545.0) * 86400.0 + t.tdb_fraction * 86400.0


def tdb_iso_seconds(iso: str) -> float:
    """TDB seconds past J2000 of an ISO date read as TDB (a TDB calendar is a plain 86400 s-day count)."""
    import datetime as dt

    d = dt.datetime.fromisoformat(iso) - dt.datetime(2000, 1, 1, 12)
    return d.days * 86400.0 + d.seconds + d.microseconds * 1e-6


# ----------------------------------------------------------------------------- geometry
def test_mrp_matrix_is_scipys_passive_rotation():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(5)
    for _ in range(20):
        rotvec = rng.normal(size=3)
        rotvec *= rng.uniform(0.1, 3.0) / np.linalg.norm(rotvec)
        sigma = Rotation.from_rotvec(rotvec).as_mrp()   # e tan(phi/4), the same attitude as rotvec
        np.testing.assert_allclose(mrp_to_dcm(sigma), Rotation.from_rotvec(rotvec).as_matrix().T, atol=1e-14)


def test_camera_frame_recovered_from_unitys():
    """[CuB] = [CuC][CB] with [CuC] the MRP (1/3, 1/3, -1/3): the endpoint gives back [CB]."""
    rng = np.random.default_rng(6)
    cu_c = mrp_to_dcm((1 / 3, 1 / 3, -1 / 3))
    # [CuC] maps Basilisk's camera axes (+z boresight, +y down) to Unity's: a 120 deg turn about (1, 1, -1)
    np.testing.assert_allclose(cu_c @ [1, 1, -1], [1, 1, -1], atol=1e-15)
    for _ in range(10):
        cb = mrp_to_dcm(rng.uniform(-0.5, 0.5, size=3))
        camera_dir_b = passive_mrp(cu_c @ cb)
        np.testing.assert_allclose(camera_dcm_from_unity(camera_dir_b), cb, atol=1e-13)
    # sigma_CB = (1/3, 1/3, 1/3) is sent as (0, 1, 0)
    np.testing.assert_allclose(camera_dcm_from_unity([0, 1, 0]), mrp_to_dcm((1 / 3, 1 / 3, 1 / 3)), atol=1e-14)


def test_the_body_at_the_origin_centres_the_frame():
    m = VizMessage()
    m.celestialBodies.add(bodyName="sun", position=[0, 0, 0])
    m.celestialBodies.add(bodyName="mars barycenter", position=[0, 0, 0])
    assert origin_body(m.celestialBodies)[0] == "mars"
    m = VizMessage()
    m.celestialBodies.add(bodyName="earth", position=[1.4e11, 0, 0])
    assert origin_body(m.celestialBodies) == (None, None)      # SPICE linked: barycentric


# ----------------------------------------------------------------------------- the endpoint
R_M = np.array([1.2e7, -9.0e6, 3.0e6])       # the spacecraft, Mars-centred, m
CAMERA_POS_B = [0.5, 0.0, -1.0]
CAMERA_DIR_B = [0.2, 0.1, -0.4]


def sigma_bn_at_mars() -> np.ndarray:
    """sigma_BN that puts the camera's boresight on Mars: [BN] = [CB]^T [CN]."""
    z = -R_M / np.linalg.norm(R_M)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    cn = np.array([x, np.cross(z, x), z])
    return passive_mrp(camera_dcm_from_unity(CAMERA_DIR_B).T @ cn)


def sim_update(*, frame=3, t_ns=60e9, epoch=True, resolution=(96, 64), fov_deg=40.0, render_rate=60_000_000_000):
    m = VizMessage()
    m.currentTime.frameNumber, m.currentTime.simTimeElapsed = frame, t_ns
    if epoch:
        m.epoch.year, m.epoch.month, m.epoch.day, m.epoch.hours, m.epoch.minutes, m.epoch.seconds = 2027, 2, 1, 0, 0, 30.5
    m.celestialBodies.add(bodyName="mars barycenter", position=[0, 0, 0], radiusEq=3396.19)
    m.spacecraft.add(spacecraftName="bsk-Sat", position=R_M.tolist(), velocity=[1e3, 500.0, 0.0],
                     rotation=sigma_bn_at_mars().tolist())
    m.cameras.add(cameraID=1, parentName="bsk-Sat", fieldOfView=fov_deg, resolution=list(resolution),
                  cameraPos_B=CAMERA_POS_B, cameraDir_B=CAMERA_DIR_B, renderRate=render_rate)
    return [b"SIM_UPDATE", b"", b"", m.SerializeToString()]


@pytest.fixture(scope="module")
def endpoint(tmp_path_factory):
    truth = tmp_path_factory.mktemp("vizard_truth")
    ep = start_vizard("--truth-dir", str(truth), "--set", "camera.exposure_s=1e-4")
    ep.truth = truth
    yield ep
    assert ep.stop() == 0, ep.output


@pytest.fixture()
def req(endpoint):
    ctx = zmq.Context.instance()
    sock = ctx.socket(zmq.REQ)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.RCVTIMEO, 300_000)
    sock.connect(endpoint.address)

    def ask(frames):
        sock.send_multipart(frames)
        return sock.recv_multipart()

    yield ask
    sock.close(0)


def test_an_image_is_the_png_skynav_render_makes_of_the_derived_scene(endpoint, req, tmp_path):
    import yaml

    assert req([b"PING"]) == [b"PONG"]
    assert req(sim_update()) == [b"OK"]
    length, png = req([b"REQUEST_IMAGE_1"])
    assert struct.unpack(">i", length)[0] == len(png) > 0
    kept = sorted(endpoint.truth.glob("*.scene.yaml"))[-1]
    assert (endpoint.truth / kept.name.replace(".scene.yaml", ".png")).read_bytes() == png
    assert render_scene_file(kept, tmp_path / "render") == png
    scene = yaml.safe_load(kept.read_text())
    truth = json.loads((endpoint.truth / kept.name.replace(".scene.yaml", ".json")).read_text())
    mars = next(b for b in truth["bodies"] if b["name"] == "mars")
    assert mars["in_fov"] and np.hypot(mars["xy"][0] - 47.5, mars["xy"][1] - 31.5) < 1.0   # at the centre
    # the scene's geometry from the message: the spacecraft's state plus the camera's offset on the body
    bn = mrp_to_dcm(sigma_bn_at_mars())
    r_km = (R_M + bn.T @ CAMERA_POS_B) / 1e3
    assert scene["observer"]["relative_to"] == "mars"
    np.testing.assert_allclose(scene["observer"]["position_km"], r_km, rtol=0, atol=1e-9)
    # 2027-02-01T00:00:30.5 UTC + 60 s, in TDB by skyfield's time scales: the scene file's ms
    assert abs(tdb_iso_seconds(scene["epoch"]) - skyfield_tdb_seconds(2027, 2, 1, 0, 0, 90.5)) <= 1e-3
    assert scene["camera"]["width"] == 96 and scene["camera"]["height"] == 64
    f_px = scene["camera"]["focal_length_mm"] / (scene["camera"]["pixel_pitch_um"] * 1e-3)
    assert math.degrees(2 * math.atan(32 / f_px)) == pytest.approx(40.0, abs=1e-12)   # fov along the height


def test_bad_messages_are_one_line_and_the_endpoint_keeps_serving(endpoint, req):
    n_before = len(endpoint.lines)
    assert req([b"SIM_UPDATE", b"", b"", b"\xff\xff\xff"])[0].startswith(b"ERROR")
    assert req([b"HELLO", b"there"])[0].startswith(b"ERROR")
    assert req([b"REQUEST_IMAGE_9"]) == [struct.pack(">i", 0), b""]          # no such camera: an empty image
    assert req([b"REQUEST_IMAGE_x"]) == [struct.pack(">i", 0), b""]
    assert req(sim_update(render_rate=0, resolution=(0, 64))) == [b"OK"]
    assert req([b"REQUEST_IMAGE_1"]) == [struct.pack(">i", 0), b""]          # a zero-size camera: one line
    assert req([b"PING"]) == [b"PONG"]
    time.sleep(0.5)
    said = endpoint.lines[n_before:]
    assert len(said) >= 6 and all("Traceback" not in line for line in said), said
    assert any("does not parse" in line for line in said) and any("renderRate 0" in line for line in said)


def test_sigterm_stops_the_endpoint(tmp_path):
    ep = start_vizard()
    assert ep.stop(signal.SIGINT) == 0
    assert "stopped" in ep.output


def test_a_taken_port_is_one_line():
    ctx = zmq.Context.instance()
    sock = ctx.socket(zmq.REP)
    port = sock.bind_to_random_port("tcp://127.0.0.1")
    try:
        run = subprocess.run([sys.executable, "-m", "skynav", "serve", "--vizard", "--vizard-port", str(port)],
                             capture_output=True, text=True, timeout=120, env={**os.environ})
    finally:
        sock.close(0)
    assert run.returncode == 2
    assert run.stderr.strip().count("\n") == 0 and f"--vizard-port {port}" in run.stderr, run.stderr


def test_a_client_gone_mid_request_leaves_the_endpoint_serving(endpoint):
    ctx = zmq.Context.instance()
    gone = ctx.socket(zmq.REQ)
    gone.setsockopt(zmq.LINGER, 0)
    gone.connect(endpoint.address)
    gone.send_multipart(sim_update(frame=7))
    gone.close(0)                                   # before the answer
    ask = ctx.socket(zmq.REQ)
    ask.setsockopt(zmq.LINGER, 0)
    ask.setsockopt(zmq.RCVTIMEO, 120_000)
    ask.connect(endpoint.address)
    try:
        ask.send_multipart([b"PING"])
        assert ask.recv_multipart() == [b"PONG"]
    finally:
        ask.close(0)


def test_a_camera_file_that_is_not_basilisks_is_one_line(tmp_path):
    (tmp_path / "camera.yaml").write_text("camera:\n  preset: paper\n  width: 64\n  height: 64\n  exposure_s: 0.001\n")
    ep = start_vizard("--camera", str(tmp_path / "camera.yaml"))
    sock = zmq.Context.instance().socket(zmq.REQ)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(ep.address)
    try:
        for frames, reply in ((sim_update(), [b"OK"]), ([b"REQUEST_IMAGE_1"], [struct.pack(">i", 0), b""])):
            sock.send_multipart(frames)
            assert sock.recv_multipart() == reply
    finally:
        sock.close(0)
        assert ep.stop() == 0
    said = [line for line in ep.lines if "REQUEST_IMAGE_1" in line]
    assert len(said) == 1 and "width 64" in said[0] and "Basilisk's camera (width 96" in said[0], ep.output


def test_the_benchmark_prints_its_ratio():
    """benchmarks/vizard_bench.py in its quickest form (nothing timed here: its lines are printed)."""
    run = subprocess.run([sys.executable, str(Path(__file__).resolve().parents[2] / "benchmarks" / "vizard_bench.py"),
                          "--frames", "1", "--warmup", "0", "--size", "64"], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "same PNG bytes on every frame: True" in run.stdout, run.stdout
    assert re.search(r"VIZARD / HTTP FRAME TIME: [0-9.]+ x", run.stdout), run.stdout


def test_a_saturated_disc_is_reported_once(tmp_path):
    """The default camera's 0.4 s saturates Mars's disc: one line, however many frames."""
    ep = start_vizard("--truth-dir", str(tmp_path))
    sock = zmq.Context.instance().socket(zmq.REQ)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(ep.address)
    try:
        for k in (1, 2):
            sock.send_multipart(sim_update(frame=k, t_ns=60e9 * k))
            assert sock.recv_multipart() == [b"OK"]
            sock.send_multipart([b"REQUEST_IMAGE_1"])
            assert len(sock.recv_multipart()[1]) > 0
    finally:
        sock.close(0)
        assert ep.stop() == 0
    said = [line for line in ep.lines if "saturates" in line]
    assert len(said) == 1 and "mars's disc" in said[0], ep.output


def test_beside_the_http_service():
    """``--vizard --http``: both answer; a signal stops both."""
    import urllib.request

    proc = subprocess.Popen([sys.executable, "-m", "skynav", "serve", "--vizard", "--http", "--vizard-port", "0",
                             "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines, found = [], {}

    def pump():
        for line in proc.stdout:
            lines.append(line)
            for key, pattern in (("tcp", READY), ("http", re.compile(r"ready at (http://\S+)"))):
                m = pattern.search(line)
                if m:
                    found[key] = m.group(1)

    threading.Thread(target=pump, daemon=True).start()
    t_end = time.monotonic() + 300
    while len(found) < 2 and proc.poll() is None and time.monotonic() < t_end:
        time.sleep(0.1)
    try:
        assert len(found) == 2, "".join(lines)
        sock = zmq.Context.instance().socket(zmq.REQ)
        sock.setsockopt(zmq.LINGER, 0)
        sock.connect(found["tcp"])
        sock.send_multipart([b"PING"])
        assert sock.recv_multipart() == [b"PONG"]
        sock.close(0)
        with urllib.request.urlopen(found["http"] + "/v1/health", timeout=60) as answer:
            assert answer.status == 200
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        assert proc.wait(120) == 0, "".join(lines)
    assert "stopped" in "".join(lines)


def test_http_without_vizard_is_one_line():
    run = subprocess.run([sys.executable, "-m", "skynav", "serve", "--http"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and run.stderr.count("\n") == 1 and "--http" in run.stderr, run.stderr


def test_a_bad_override_is_one_line_at_start():
    run = subprocess.run([sys.executable, "-m", "skynav", "serve", "--vizard", "--set", "camera.exposure_s=-1"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and run.stderr.count("\n") == 1 and "camera.exposure_s" in run.stderr, run.stderr
