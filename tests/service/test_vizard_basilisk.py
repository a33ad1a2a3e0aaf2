"""Basilisk's own ``vizInterface`` against ``skynav serve --vizard`` (needs the ``basilisk`` extra).

A Basilisk scenario (a spacecraft about Mars, Basilisk's gravity and integrator, no SPICE data:
Mars at the origin) asks for a camera's images through vizInterface in noDisplay mode. Basilisk
runs in a subprocess (this file run as a script: vizInterface blocks, holding the GIL, while it
waits for an answer), which writes each image it received on ``opnavImageOutMsgs`` and the
simulation's state. The test checks that each image is, byte for byte, the PNG ``skynav render``
makes of the scene the endpoint derived and kept, and that the frame's truth has the simulation's
observer (to 1 m: Mars's DE421 position by skyfield added to Basilisk's state and the camera's
offset), attitude (to 1e-6 rad: Basilisk's own MRP2C of sigma_BN and sigma_CB) and epoch (to 1 ms:
skyfield's UTC to TDB).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

EPOCH_UTC = (2027, 2, 1, 0, 0, 0.0)
SIGMA_CB = (0.1, -0.2, 0.05)
CAMERA_POS_B = (0.5, -0.3, 1.2)
R0_M = (15000e3, -8000e3, 6000e3)
V0_M_S = (0.5e3, 1.2e3, -0.3e3)
STEP_S = 60.0


def run_basilisk(port: int, out_dir: Path, steps: int) -> None:
    """The Basilisk scenario (this file's ``__main__``): ``steps`` images, one every ``STEP_S``."""
    import ctypes

    from Basilisk.architecture import messaging
    from Basilisk.simulation import spacecraft
    from Basilisk.utilities import RigidBodyKinematics as rbk
    from Basilisk.utilities import SimulationBaseClass, macros, simIncludeGravBody, vizSupport

    sim = SimulationBaseClass.SimBaseClass()
    sim.CreateNewProcess("dynamics").addTask(sim.CreateNewTask("step", macros.sec2nano(STEP_S)))
    sc = spacecraft.Spacecraft()
    sc.ModelTag = "bsk-Sat"
    sim.AddModelToTask("step", sc, 100)      # dynamics before vizInterface
    gravity = simIncludeGravBody.gravBodyFactory()
    gravity.createMarsBarycenter().isCentralBody = True
    gravity.addBodiesTo(sc)
    r0 = np.array(R0_M)
    sc.hub.r_CN_NInit, sc.hub.v_CN_NInit = list(R0_M), list(V0_M_S)
    # the boresight (+z of C) at Mars at the start: [CN] rows x, y, z with z = -r0/|r0|
    z = -r0 / np.linalg.norm(r0)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    cn = np.array([x, np.cross(z, x), z])
    sc.hub.sigma_BNInit = [[v] for v in rbk.C2MRP(rbk.MRP2C(list(SIGMA_CB)).T @ cn)]
    viz = vizSupport.enableUnityVisualization(sim, "step", sc, noDisplay=True)
    viz.reqComAddress, viz.reqPortNumber = "127.0.0.1", str(port)
    epoch = messaging.EpochMsgPayload()
    epoch.year, epoch.month, epoch.day, epoch.hours, epoch.minutes, epoch.seconds = EPOCH_UTC
    epoch_msg = messaging.EpochMsg().write(epoch)
    viz.epochInMsg.subscribeTo(epoch_msg)
    config, config_msg = vizSupport.createCameraConfigMsg(
        viz, cameraID=1, fieldOfView=np.radians(40.0), resolution=[128, 96], cameraPos_B=list(CAMERA_POS_B),
        sigma_CB=list(SIGMA_CB), renderRate=STEP_S)
    config.isOn = 1                          # createCameraConfigMsg leaves the camera off
    config_msg.write(config)
    sim.InitializeSimulation()
    record = []
    for k in range(1, steps + 1):
        sim.ConfigureStopTime(macros.sec2nano(STEP_S * k))
        sim.ExecuteSimulation()
        image = viz.opnavImageOutMsgs[0].read()
        state = sc.scStateOutMsg.read()
        data = ctypes.string_at(int(image.imagePointer), image.imageBufferLength) if image.valid else b""
        (out_dir / f"basilisk_{k}.png").write_bytes(data)
        record.append({"t_ns": int(image.timeTag), "valid": int(image.valid), "r_BN_N": list(state.r_BN_N),
                       "sigma_BN": list(state.sigma_BN),
                       "R_cam_N": (rbk.MRP2C(list(SIGMA_CB)) @ rbk.MRP2C(list(state.sigma_BN))).tolist(),
                       "BN": np.asarray(rbk.MRP2C(list(state.sigma_BN))).tolist()})
    (out_dir / "basilisk.json").write_text(json.dumps(record))


def test_vizinterface_gets_skynavs_frames(tmp_path):
    import pytest

    pytest.importorskip("Basilisk.simulation.vizInterface", reason="Basilisk (pip install skynav[basilisk]) is not installed")
    pytest.importorskip("zmq", reason="pyzmq (pip install skynav[basilisk]) is not installed")
    from scipy.spatial.transform import Rotation
    from skyfield.api import load

    from skynav.infra.data_files import de421_path

    from .test_vizard import render_scene_file, start_vizard

    truth = tmp_path / "truth"
    endpoint = start_vizard("--truth-dir", str(truth), "--set", "camera.exposure_s=1e-5")
    try:
        port = endpoint.address.rsplit(":", 1)[1]
        run = subprocess.run([sys.executable, __file__, port, str(tmp_path), "2"], capture_output=True, text=True,
                             timeout=600)
        assert run.returncode == 0, run.stderr[-3000:] + endpoint.output[-2000:]
    finally:
        assert endpoint.stop() == 0, endpoint.output
    record = json.loads((tmp_path / "basilisk.json").read_text())
    ts = load.timescale(builtin=True)
    mars = load(str(de421_path()))["mars"]
    for k, rec in enumerate(record):
        assert rec["valid"] == 1 and rec["t_ns"] == int(STEP_S * (k + 1) * 1e9)
        received = (tmp_path / f"basilisk_{k + 1}.png").read_bytes()
        scene = truth / f"{k:06d}.scene.yaml"
        assert received == (truth / f"{k:06d}.png").read_bytes()
        assert received == render_scene_file(scene, tmp_path / f"render_{k}"), f"image {k}"
        frame = json.loads((truth / f"{k:06d}.json").read_text())
        t = ts.utc(*EPOCH_UTC[:5], EPOCH_UTC[5] + STEP_S * (k + 1))
        tdb_s = (t.whole - 2451545.0) * 86400.0 + t.tdb_fraction * 86400.0
        epoch_err_s = abs(frame["epoch"]["tdb_seconds_past_j2000"] - tdb_s)
        assert epoch_err_s <= 1e-3
        # observer: Basilisk's Mars-centred state plus the camera's offset, placed at Mars's DE421 position
        mars_km = mars.at(ts.tdb_jd(2451545.0, frame["epoch"]["tdb_seconds_past_j2000"] / 86400.0)).position.km
        want_km = mars_km + (np.array(rec["r_BN_N"]) + np.array(rec["BN"]).T @ CAMERA_POS_B) / 1e3
        observer_err_m = np.linalg.norm(np.array(frame["observer"]["position_km"]) - want_km) * 1e3
        assert observer_err_m <= 1.0
        # attitude: the rotation angle between the truth's R_cam_icrs and Basilisk's [CB][BN]
        d = np.array(frame["attitude"]["R_cam_icrs"]) @ np.array(rec["R_cam_N"]).T
        attitude_err_rad = Rotation.from_matrix(d).magnitude()     # exact near zero, unlike arccos of the trace
        assert attitude_err_rad <= 1e-6
        print(f"image {k}: {len(received)} bytes identical; observer {observer_err_m:.2e} m, attitude "
              f"{attitude_err_rad:.2e} rad, epoch {epoch_err_s * 1e3:.3f} ms")


if __name__ == "__main__":
    run_basilisk(int(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3]))
