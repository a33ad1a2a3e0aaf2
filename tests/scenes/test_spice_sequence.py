"""The ``sequence`` preset's cruise and attitudes written as a Type 13 SPK and a Type 3 CK with
spiceypy drive scenes to the built-in frames' observer (1 m), attitude (0.01") and star pixels
(1e-4 px)."""

import numpy as np
import pytest

sp = pytest.importorskip("spiceypy")

from skynav.datasets import preset_recipe, validate_recipe  # noqa: E402
from skynav.datasets.samplers import frame_rng, make_plan  # noqa: E402
from skynav.scenes import frames  # noqa: E402
from skynav.scenes.config import scene_spec_from_mapping  # noqa: E402
from skynav.scenes.scene import build_from_spec  # noqa: E402
from skynav.scenes.scene_files import load_scene_file  # noqa: E402
from skynav.scenes.timescales import time_from_tdb_seconds  # noqa: E402

from .test_spice import FK, SCLK  # noqa: E402


def _iso(t):
    x = time_from_tdb_seconds(t).tdb
    x.precision = 6
    return x.isot


def test_sequence_from_kernels_matches_the_built_in_frames(tmp_path):
    rec = validate_recipe(preset_recipe("sequence"))
    plan = make_plan(rec)
    reqs = [plan.frame_request(k, frame_rng(int(rec["seed"]), k)) for k in range(3)]
    t0 = plan.start_tdb_s
    # SPK: the cruise's first day, hourly states of the propagated trajectory
    t = t0 + np.arange(0.0, 86400.0 + 1.0, 3600.0)
    r, v = plan.trajectory.state(t)
    h = sp.spkopn(str(tmp_path / "cruise.bsp"), "skynav", 0)
    sp.spkw13(h, -999, 0, "J2000", t[0], t[-1], "cruise", 7, len(t), np.hstack([r, v]), t)
    sp.spkcls(h)
    # CK: the frames' attitudes at their epochs, SCLK in TDB ticks from the cruise's start
    (tmp_path / "craft.tsc").write_text(SCLK.format(et0=repr(t0 - 60.0)))
    (tmp_path / "craft.tf").write_text(FK)
    # one record per frame, plus one a second before the first and after the last (propagated at
    # the frame's rate) so that each frame's epoch lies inside the segment despite tick rounding
    recs = [(reqs[0].epoch_tdb_s - 1.0, frames.propagate_attitude(reqs[0].R_cam_icrs, reqs[0].angular_velocity_rad_s, -1.0),
             reqs[0].angular_velocity_rad_s)]
    recs += [(q.epoch_tdb_s, q.R_cam_icrs, q.angular_velocity_rad_s) for q in reqs]
    recs.append((reqs[-1].epoch_tdb_s + 1.0, frames.propagate_attitude(reqs[-1].R_cam_icrs, reqs[-1].angular_velocity_rad_s, 1.0),
                 reqs[-1].angular_velocity_rad_s))
    sp.furnsh(str(tmp_path / "craft.tsc"))
    try:
        ticks = np.array([sp.sce2c(-999, e) for e, _, _ in recs])
    finally:
        sp.kclear()
    quats = np.array([sp.m2q(R) for _, R, _ in recs])
    av = np.array([R.T @ w for _, R, w in recs])
    h = sp.ckopn(str(tmp_path / "craft.bc"), "skynav", 0)
    sp.ckw03(h, ticks[0], ticks[-1], -999000, "J2000", True, "frames", len(ticks), ticks, quats, av, 1, ticks[:1])
    sp.ckcls(h)

    for req in reqs:
        epoch = _iso(req.epoch_tdb_s)
        path = tmp_path / "scene.yaml"
        path.write_text(f"epoch: {epoch}\nobserver: {{spice: {{kernels: [cruise.bsp], body: '-999'}}}}\n"
                        f"attitude: {{spice: {{kernels: [craft.bc, craft.tsc, craft.tf], frame: SKYNAV_CAM}}}}\n"
                        f"camera: {{preset: paper, width: 256, height: 256, fov_deg: 20.0}}\n")
        mine = load_scene_file(path)
        ref = scene_spec_from_mapping({
            "epoch": epoch, "camera": {"preset": "paper", "width": 256, "height": 256, "fov_deg": 20.0},
            "observer": {"position_km": [float(x) for x in req.position_km],
                         "velocity_km_s": [float(x) for x in req.velocity_km_s]},
            "attitude": {"q_cam_icrs": [float(x) for x in frames.dcm_to_quat(req.R_cam_icrs)],
                         "angular_velocity_deg_s": [float(x) for x in np.degrees(req.angular_velocity_rad_s)]}})
        assert np.max(np.abs(np.subtract(mine.position_km, ref.position_km))) < 1e-3  # 1 m
        assert np.max(np.abs(np.subtract(mine.velocity_km_s, ref.velocity_km_s))) < 1e-6
        dR = frames.quat_to_dcm(mine.attitude.q_cam_icrs) @ frames.quat_to_dcm(ref.attitude.q_cam_icrs).T
        angle = np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))
        assert np.degrees(angle) * 3600 < 0.01
        a, b = build_from_spec(mine), build_from_spec(ref)
        assert len(a.stars.xy) == len(b.stars.xy) > 10
        assert np.max(np.abs(a.stars.xy - b.stars.xy)) < 1e-4
