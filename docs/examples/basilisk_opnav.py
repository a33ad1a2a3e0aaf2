"""Basilisk's optical-navigation chain around Mars on skynav frames, through ``skynav serve --vizard``.

Basilisk (``pip install skynav[basilisk]``: PyPI ``bsk`` and ``bsk-opnav``) propagates a spacecraft
about Mars (its gravity and integrator; no SPICE data, so Mars is at the origin of Basilisk's frame
and the endpoint places it at its DE421 position). Its ``vizInterface`` (``noDisplay``) asks the
endpoint for each camera image; Basilisk's own flight software, as it ships, reads the images from
``opnavImageOutMsgs``: ``houghCircles`` finds Mars's disc, ``pixelLineConverter`` turns the circle
into a position, ``relativeODuKF`` filters the positions into an orbit. Each image's circle is
scored against the frame's truth (kept with ``--truth-dir``), and the filter's position error
against its 3-sigma.

    python docs/examples/basilisk_opnav.py [--images 20] [--size 256] [--exposure-s 1e-5] [--step-s 60] [--figure PNG]
"""

from __future__ import annotations

import argparse
import json
import math
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

MU_MARS_M3_S2 = 4.28283100e13    # Basilisk's Mars gravity parameter (simIncludeGravBody)
EPOCH_UTC = (2027, 2, 1, 0, 0, 0.0)
RADIUS_M = 18000e3               # orbit radius: Mars's disc ~140 px across a 256 px, 40 deg camera


def start_endpoint(truth_dir: Path, exposure_s: float):
    """``skynav serve --vizard`` on a free loopback port; ``(process, port)``."""
    proc = subprocess.Popen([sys.executable, "-m", "skynav", "serve", "--vizard", "--vizard-port", "0", "--truth-dir",
                             str(truth_dir), "--set", f"camera.exposure_s={exposure_s}",
                             "--set", "render.cosmic_rays_per_frame=0"],
                            stdout=subprocess.PIPE, text=True)
    for line in proc.stdout:
        m = re.search(r"ready at tcp://[^:]+:(\d+)", line)
        if m:
            return proc, int(m.group(1))
    raise SystemExit("skynav serve --vizard did not start")


def initial_state():
    """A circular orbit whose start sees Mars's day side (phase ~5 deg), Mars-centred J2000, m and m/s."""
    from skynav.scenes.ephemeris_jpl import default_ephemeris
    from skynav.scenes.timescales import tdb_seconds

    eph = default_ephemeris()
    t = tdb_seconds("2027-02-01T00:01:09")
    sun = eph.position("sun", t) - eph.position("mars", t)
    u_sun = sun / np.linalg.norm(sun)
    pole = np.cross(u_sun, [0.0, 0.0, 1.0])
    pole /= np.linalg.norm(pole)
    along = np.cross(pole, u_sun)
    r = RADIUS_M * (math.cos(math.radians(5)) * u_sun + math.sin(math.radians(5)) * along)
    v = math.sqrt(MU_MARS_M3_S2 / RADIUS_M) * np.cross(pole, r / RADIUS_M)
    return r, v


def build(port: int, size: int, step_s: float, r0, v0):
    """The Basilisk simulation: dynamics, then vizInterface, then houghCircles -> pixelLineConverter -> uKF."""
    from Basilisk.architecture import messaging
    from Basilisk.fswAlgorithms import houghCircles, pixelLineConverter, relativeODuKF
    from Basilisk.simulation import simpleNav, spacecraft
    from Basilisk.utilities import RigidBodyKinematics as rbk
    from Basilisk.utilities import SimulationBaseClass, macros, simIncludeGravBody, vizSupport

    sim = SimulationBaseClass.SimBaseClass()
    proc = sim.CreateNewProcess("opnav")
    dt = macros.sec2nano(step_s)
    proc.addTask(sim.CreateNewTask("dynamics", dt), 100)     # tasks run by priority: dynamics, images, flight software
    proc.addTask(sim.CreateNewTask("viz", dt), 50)
    proc.addTask(sim.CreateNewTask("fsw", dt), 10)
    m = {}
    sc = m["sc"] = spacecraft.Spacecraft()
    sc.ModelTag = "bsk-Sat"
    sim.AddModelToTask("dynamics", sc)
    gravity = m["gravity"] = simIncludeGravBody.gravBodyFactory()
    gravity.createMarsBarycenter().isCentralBody = True
    gravity.addBodiesTo(sc)
    sc.hub.r_CN_NInit, sc.hub.v_CN_NInit = r0.tolist(), v0.tolist()
    # the camera (body +z) at Mars, turning with the circular orbit's mean motion about its normal
    # (a torque-free spin about a principal axis): Mars stays on the optical axis
    z = -r0 / np.linalg.norm(r0)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    bn = np.array([x, np.cross(z, x), z])
    h = np.cross(r0, v0)
    sc.hub.sigma_BNInit = [[s] for s in rbk.C2MRP(bn)]
    sc.hub.omega_BN_BInit = [[w] for w in bn @ (h / np.dot(r0, r0))]
    nav = m["nav"] = simpleNav.SimpleNav()
    nav.scStateInMsg.subscribeTo(sc.scStateOutMsg)
    sim.AddModelToTask("dynamics", nav)

    viz = m["viz"] = vizSupport.enableUnityVisualization(sim, "viz", sc, noDisplay=True)
    viz.reqComAddress, viz.reqPortNumber = "127.0.0.1", str(port)
    epoch = messaging.EpochMsgPayload()
    epoch.year, epoch.month, epoch.day, epoch.hours, epoch.minutes, epoch.seconds = EPOCH_UTC
    m["epoch"] = messaging.EpochMsg().write(epoch)
    viz.epochInMsg.subscribeTo(m["epoch"])
    config, m["camera"] = vizSupport.createCameraConfigMsg(viz, cameraID=1, fieldOfView=math.radians(40.0),
                                                           resolution=[size, size], cameraPos_B=[0.0, 0.0, 0.0],
                                                           sigma_CB=[0.0, 0.0, 0.0], renderRate=step_s)
    config.isOn = 1                        # createCameraConfigMsg leaves the camera off
    m["camera"].write(config)

    hough = m["hough"] = houghCircles.HoughCircles()
    hough.ModelTag = "houghCircles"
    hough.imageInMsg.subscribeTo(viz.opnavImageOutMsgs[0])
    hough.expectedCircles, hough.cannyThresh, hough.voteThresh = 1, 200, 25
    hough.houghMinDist, hough.houghMinRadius, hough.houghMaxRadius = 50, size // 16, size // 2
    hough.blurrSize, hough.noiseSF, hough.dpValue = 7, 1, 1
    sim.AddModelToTask("fsw", hough, 30)
    pixel = m["pixel"] = pixelLineConverter.pixelLineConverter()
    pixel.ModelTag = "pixelLineConverter"
    pixel.circlesInMsg.subscribeTo(hough.opnavCirclesOutMsg)
    pixel.cameraConfigInMsg.subscribeTo(m["camera"])
    pixel.attInMsg.subscribeTo(nav.attOutMsg)
    pixel.planetTarget = 2                 # Mars
    sim.AddModelToTask("fsw", pixel, 20)
    ukf = m["ukf"] = relativeODuKF.relativeODuKF()
    ukf.ModelTag = "relativeODuKF"
    ukf.opNavInMsg.subscribeTo(pixel.opNavOutMsg)
    ukf.planetIdInit = 2
    ukf.alpha, ukf.beta, ukf.kappa, ukf.noiseSF = 0.02, 2.0, 0.0, 7.5
    # the filter starts 10 km and 1 m/s off the truth, with a 3-sigma a little wider
    ukf.stateInit = (np.concatenate([r0, v0]) + [1e4, -1e4, 5e3, 1.0, -0.5, 0.5]).tolist()
    ukf.covarInit = np.diag([1e4 ** 2] * 3 + [1.0 ** 2] * 3).reshape(36).tolist()
    q = np.diag([1e-8 ** 2] * 3 + [1e-7 ** 2] * 3)
    ukf.qNoise = q.reshape(36).tolist()
    sim.AddModelToTask("fsw", ukf, 10)
    return sim, m


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=int, default=20, help="images (one per step)")
    ap.add_argument("--size", type=int, default=256, help="camera width and height, px")
    ap.add_argument("--exposure-s", type=float, default=1e-5, help="exposure, s (0.4 s saturates Mars's disc)")
    ap.add_argument("--step-s", type=float, default=60.0, help="time between images, s")
    ap.add_argument("--truth-dir", default=None, help="keep the frames and their truth here (default: a temporary folder)")
    ap.add_argument("--figure", default=None, metavar="PNG", help="draw the last frame with Hough's circle and the truth's")
    args = ap.parse_args(argv)
    from Basilisk.utilities import macros

    with tempfile.TemporaryDirectory() as tmp:
        truth_dir = Path(args.truth_dir or tmp)
        endpoint, port = start_endpoint(truth_dir, args.exposure_s)
        try:
            r0, v0 = initial_state()
            sim, m = build(port, args.size, args.step_s, r0, v0)
            sim.InitializeSimulation()
            rows = []
            for k in range(1, args.images + 1):
                sim.ConfigureStopTime(macros.sec2nano(args.step_s * k))
                sim.ExecuteSimulation()
                rows.append(score(k, m, truth_dir / f"{k - 1:06d}.json"))
            if args.figure:
                figure(args.figure, truth_dir / f"{args.images - 1:06d}", m["hough"].opnavCirclesOutMsg.read())
        finally:
            endpoint.terminate()
            endpoint.wait(60)
    report(rows)
    return 0


def score(k: int, m: dict, truth_path: Path) -> dict:
    """One image's figures: Hough's circle against the truth's disc, the range, the filter's error and 3-sigma."""
    circles = m["hough"].opnavCirclesOutMsg.read()
    opnav = m["pixel"].opNavOutMsg.read()
    filt = m["ukf"].filtDataOutMsg.read()
    state = m["sc"].scStateOutMsg.read()
    truth = json.loads(truth_path.read_text())
    mars = next(b for b in truth["bodies"] if b["name"] == "mars")
    r_true = np.array(state.r_BN_N)
    row = {"k": k, "valid": bool(circles.valid) and bool(opnav.valid)}
    centre = np.array(circles.circlesCenters[:2])
    row["centre_err_px"] = float(np.linalg.norm(centre - np.array(mars["xy"])))
    # the disc's apparent radius on the optical axis, f tan(asin(R/d)): the limb cone's half-angle, projected
    radius_px = truth["camera"]["K"][1][1] * math.tan(math.asin(mars["radius_km"] / mars["distance_km"]))
    row["radius_err"] = circles.circlesRadii[0] / radius_px - 1
    row["range_err"] = np.linalg.norm(opnav.r_BN_N) / np.linalg.norm(r_true) - 1
    row["pos_err_m"] = float(np.linalg.norm(np.array(filt.state[:3]) - r_true))
    row["pos_3sigma_m"] = 3 * math.sqrt(sum(np.array(filt.covar).reshape(6, 6)[i, i] for i in range(3)))
    return row


def figure(path: str, stem: Path, circles) -> None:
    """The frame Basilisk received (the kept PNG), Hough's circle and the truth's disc."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image

    dn = np.asarray(Image.open(stem.with_suffix(".png")))
    truth = json.loads(stem.with_suffix(".json").read_text())
    mars = next(b for b in truth["bodies"] if b["name"] == "mars")
    radius_px = truth["camera"]["K"][1][1] * math.tan(math.asin(mars["radius_km"] / mars["distance_km"]))
    fig, ax = plt.subplots(figsize=(5, 5), dpi=100)
    ax.imshow(dn, cmap="gray", origin="upper")
    cx, cy = circles.circlesCenters[:2]
    ax.add_patch(plt.Circle((cx, cy), circles.circlesRadii[0], fill=False, color="tab:red", lw=1.2,
                            label=f"houghCircles: ({cx:.1f}, {cy:.1f}), r {circles.circlesRadii[0]:.1f} px"))
    ax.add_patch(plt.Circle(mars["xy"], radius_px, fill=False, color="tab:cyan", lw=1.0, ls="--",
                            label=f"truth: ({mars['xy'][0]:.1f}, {mars['xy'][1]:.1f}), r {radius_px:.1f} px"))
    ax.legend(loc="lower center", fontsize=8)
    ax.set_title(f"Mars from {mars['distance_km']:,.0f} km, {truth['camera']['exposure_s']:g} s", fontsize=9)
    ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def report(rows) -> None:
    for r in rows:
        print(f"image {r['k']:2d}: circle centre {r['centre_err_px']:5.2f} px, radius {100 * r['radius_err']:+6.2f} %, "
              f"range {100 * r['range_err']:+6.2f} %; filter position error {r['pos_err_m']:8.1f} m "
              f"(3-sigma {r['pos_3sigma_m']:8.1f} m)")
    worst = max(rows, key=lambda r: r["centre_err_px"])
    print(f"worst: centre {worst['centre_err_px']:.2f} px, radius {100 * max(abs(r['radius_err']) for r in rows):.2f} %, "
          f"range {100 * max(abs(r['range_err']) for r in rows):.2f} %; final position error "
          f"{rows[-1]['pos_err_m']:.1f} m inside 3-sigma {rows[-1]['pos_3sigma_m']:.1f} m: "
          f"{rows[-1]['pos_err_m'] <= rows[-1]['pos_3sigma_m']}")


if __name__ == "__main__":
    sys.exit(main())
