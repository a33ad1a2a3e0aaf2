"""A Basilisk simulation that takes its navigation camera's pictures from the skynav render service.

Basilisk (``pip install skynav[basilisk]``, PyPI ``bsk``) propagates the spacecraft about the Sun
(point-mass gravity, its own integrator); at every camera step this script reads the spacecraft's
state message, asks the service for the frame the camera takes there through
:class:`skynav.service.Client`, and gets the image and its truth back. The spacecraft starts where
the built-in ``default`` scene has it (1.2 AU from the Sun, 2027-02-01 TDB), the camera pointed at
Mars. It loads no skynav renderer: the frames come from ``skynav serve`` (started here unless
``--service URL`` names a running one).

    python docs/examples/basilisk_loop.py [--steps 5] [--step-s 600] [--size 256] [--service URL]
"""

from __future__ import annotations

import argparse

import numpy as np


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=5, help="camera steps")
    ap.add_argument("--step-s", type=float, default=600.0, help="time between pictures, s")
    ap.add_argument("--size", type=int, default=256, help="camera width and height, px")
    ap.add_argument("--service", default=None, help="URL of a running skynav serve (default: start one)")
    args = ap.parse_args()

    import contextlib

    from astropy.time import Time, TimeDelta
    from Basilisk.simulation import spacecraft
    from Basilisk.utilities import SimulationBaseClass, macros, simIncludeGravBody

    from skynav.scenes.ephemeris_jpl import default_ephemeris
    from skynav.scenes.presets import preset_mapping
    from skynav.scenes.timescales import tdb_seconds
    from skynav.service import Client, LocalServer

    scene = preset_mapping("default")
    epoch0 = Time(scene["epoch"], scale="tdb")
    # the default scene's barycentric state, made heliocentric: Basilisk integrates about the Sun
    sun_r, sun_v = default_ephemeris().position_velocity("sun", float(tdb_seconds(scene["epoch"])))
    r0 = np.array(scene["observer"]["position_km"]) - sun_r
    v0 = np.array(scene["observer"]["velocity_km_s"]) - sun_v

    sim = SimulationBaseClass.SimBaseClass()
    process = sim.CreateNewProcess("dynamics")
    process.addTask(sim.CreateNewTask("camera", macros.sec2nano(args.step_s)))
    sc = spacecraft.Spacecraft()
    sc.ModelTag = "spacecraft"
    sim.AddModelToTask("camera", sc)
    gravity = simIncludeGravBody.gravBodyFactory()
    sun = gravity.createSun()
    sun.isCentralBody = True
    gravity.addBodiesTo(sc)
    sc.hub.r_CN_NInit = (r0 * 1e3).tolist()     # Basilisk works in m and m/s
    sc.hub.v_CN_NInit = (v0 * 1e3).tolist()
    sim.InitializeSimulation()

    server = contextlib.nullcontext(args.service) if args.service else LocalServer(workers=1)
    with server as url:
        client = Client(url)
        for k in range(args.steps):
            sim.ConfigureStopTime(macros.sec2nano(k * args.step_s))
            sim.ExecuteSimulation()
            state = sc.scStateOutMsg.read()
            r_km, v_km_s = np.array(state.r_BN_N) / 1e3, np.array(state.v_BN_N) / 1e3
            epoch = (epoch0 + TimeDelta(k * args.step_s, format="sec")).tdb.isot
            frame = client.render({
                "epoch": epoch,
                "observer": {"relative_to": "sun", "position_km": r_km.tolist(), "velocity_km_s": v_km_s.tolist()},
                "attitude": {"point_at": "mars"},
                "camera": {"preset": "paper", "width": args.size, "height": args.size},
                "render": {"seed": k},
            }, outputs=("png", "truth"))
            mars = next(b for b in frame.truth["bodies"] if b["name"] == "mars")
            moved = np.linalg.norm(r_km - r0)
            print(f"step {k}: {epoch} TDB, {moved:9.0f} km from the start, frame {frame.dn.shape[1]}x{frame.dn.shape[0]}, "
                  f"{len(frame.truth['stars'])} stars, mars at ({mars['xy'][0]:.2f}, {mars['xy'][1]:.2f}) px, "
                  f"{mars['electrons']:.3g} e-")


if __name__ == "__main__":
    main()
