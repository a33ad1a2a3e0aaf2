"""Earth-Mars navigation sequence: transfer, cruise, leg timeline (Andreis et al. (2023b, 2024) CONOPS), frames."""

from __future__ import annotations

import csv
import io
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from skynav.datasets import preset_recipe, validate_recipe
from skynav.datasets.samplers import frame_rng, make_plan
from skynav.scenes.constants import GM_KM3_S2
from skynav.scenes.ephemeris_jpl import default_ephemeris
from skynav.scenes.sky import sky_bodies
from skynav.scenes.timescales import tdb_seconds

DAY = 86400.0


@pytest.fixture(scope="module")
def plan():
    return make_plan(validate_recipe(preset_recipe("sequence")))


def test_leg_timeline_matches_the_conops(plan):
    # Andreis et al. (2024), Sec. 4.2: "Each planet is tracked for an hour with a frequency of 0.01 Hz, the slew
    # maneuver lasts 30 minutes, and the window in which the state is only propagated is ten days
    # ... 10 navigation legs of 10 days 2 hours, and 30 minutes each are repeated."
    w = plan.windows
    assert len(w) == 40
    assert [x.phase for x in w[:4]] == ["track_A", "slew", "track_B", "propagate"]
    durations = {x.phase: x.end_tdb_s - x.start_tdb_s for x in w}
    assert durations == {"track_A": 3600.0, "slew": 1800.0, "track_B": 3600.0, "propagate": 10 * DAY}
    starts = np.array([x.start_tdb_s for x in w if x.phase == "track_A"])
    np.testing.assert_allclose(np.diff(starts), 10 * DAY + 2.5 * 3600.0)
    assert all(b.start_tdb_s == a.end_tdb_s for a, b in zip(w, w[1:]))  # contiguous
    # frames: 0.01 Hz over each 1 h tracking window -> 36 per window, 72 per leg, none while slewing
    assert plan.n_frames == 720
    for x in w:
        inside = (plan.frame_tdb_s >= x.start_tdb_s) & (plan.frame_tdb_s < x.end_tdb_s)
        if x.phase.startswith("track"):
            assert inside.sum() == 36
            np.testing.assert_allclose(np.diff(plan.frame_tdb_s[inside]), 100.0)
            assert {plan.frame_info[i][2] for i in np.flatnonzero(inside)} == {x.target}
        else:
            assert inside.sum() == 0
    rows = list(csv.DictReader(io.StringIO(plan.legs_csv())))
    assert len(rows) == 40 and rows[2]["phase"] == "track_B" and float(rows[3]["duration_s"]) == 864000.0


def test_pairs_are_visible_planets_away_from_the_sun(plan):
    for x in plan.windows:
        if not x.phase.startswith("track"):
            continue
        leg_start = plan.start_tdb_s + x.leg * (10 * DAY + 9000.0)
        r, v = plan.trajectory.state(leg_start)
        body = next(b for b in sky_bodies(leg_start, r, v)[0] if b.name == x.target)
        assert body.v_mag < 7.0 and math.degrees(body.elongation_rad) > 20.0


def test_transfer_is_a_late_2026_earth_mars_lambert_arc(plan):
    eph = default_ephemeris()
    tr = plan.transfer
    assert tdb_seconds("2026-10-01") <= tr.departure_tdb_s <= tdb_seconds("2027-01-15")
    assert 180 * DAY <= tr.tof_s <= 360 * DAY
    assert 2.5 < tr.v_inf_departure_km_s < 4.5  # 2026 window: C3 ~ 9-13 km^2/s^2
    # independent check: Sun-only two-body arc from the Earth reaches Mars (DE421)
    mu = GM_KM3_S2["sun"]
    re = eph.position("earth", tr.departure_tdb_s) - eph.position("sun", tr.departure_tdb_s)
    ta = tr.departure_tdb_s + tr.tof_s
    rm = eph.position("mars", ta) - eph.position("sun", ta)
    sol = solve_ivp(lambda _t, y: np.concatenate([y[3:], -mu * y[:3] / np.linalg.norm(y[:3]) ** 3]),
                    (0, tr.tof_s), np.concatenate([re, tr.v1_km_s]), method="DOP853", rtol=1e-13, atol=1e-9)
    assert np.linalg.norm(sol.y[:3, -1] - rm) < 1.0  # km
    # the cruise starts outside the Earth's sphere of influence (0.93e6 km)
    r0, _ = plan.trajectory.state(plan.start_tdb_s)
    d = np.linalg.norm(r0 - eph.position("earth", plan.start_tdb_s))
    assert 2e6 < d < 2e7


def test_frames_point_at_the_target_within_the_pointing_error(plan):
    for k in (0, 40, 700):
        req = plan.frame_request(k, frame_rng(5, k))
        body = next(b for b in req.sky[0] if b.name == req.meta["target"])
        off = math.degrees(math.acos(np.clip(req.R_cam_icrs[2] @ body.directions.u_apparent, -1, 1)))
        assert off < 5 * 0.01 * math.sqrt(2)  # 0.01 deg per axis, 5 sigma
        again = plan.frame_request(k, frame_rng(5, k))
        np.testing.assert_array_equal(again.R_cam_icrs, req.R_cam_icrs)
        np.testing.assert_array_equal(req.position_km, plan.trajectory.state(req.epoch_tdb_s)[0])


def test_trajectory_csv(plan):
    rows = list(csv.DictReader(io.StringIO(plan.trajectory_csv())))
    t = np.array([float(r["t_tdb_s"]) for r in rows])
    assert t[0] == plan.start_tdb_s and np.all(np.diff(t) == 3600.0) and t[-1] <= plan.end_tdb_s
    r = np.array([[float(rw[c]) for c in ("x_km", "y_km", "z_km")] for rw in rows[:5]])
    np.testing.assert_array_equal(r, plan.trajectory.state(t[:5])[0])


def test_small_sequence_dataset(tmp_path):
    import skynav.datasets as D

    rec = preset_recipe("sequence")
    rec["frames"] = 3
    rec["camera"] = {"preset": "paper", "width": 256, "height": 256, "fov_deg": 20.0}
    rec["catalog_limiting_v_mag"] = 7.0
    D.generate(rec, tmp_path / "seq", workers=1, progress=False)
    ds = D.open(tmp_path / "seq")
    assert (tmp_path / "seq" / "trajectory.csv").is_file() and (tmp_path / "seq" / "legs.csv").is_file()
    assert set(ds.manifest["files"]) >= {"trajectory.csv", "legs.csv", "index.csv"}
    for row, fr in zip(ds.index, ds):
        assert row["phase"] == "track_A" and row["leg"] == "0"
        target = next(b for b in fr.truth["bodies"] if b["name"] == row["target"])
        assert target["in_fov"]
        # boresight on the target: within 5 sigma of pointing error (0.01 deg ~ 0.13 px here)
        assert np.hypot(target["xy"][0] - 127.5, target["xy"][1] - 127.5) < 1.0
    assert D.verify(tmp_path / "seq").ok
    # the leg plot of a sequence (the CLI's preview writes it beside the contact sheet)
    from PIL import Image

    from skynav.cli import main

    assert main(["dataset", "preview", str(tmp_path / "seq"), "-o", str(tmp_path / "sheet.png")]) == 0
    with Image.open(tmp_path / "sheet_legs_vmag.png") as im:
        assert im.size == (900, 520)
        colours = np.unique(np.asarray(im.convert("RGB")).reshape(-1, 3), axis=0)
        assert len(colours) > 6  # axes, legs and one colour per planet


def test_leg_plot_refuses_a_montecarlo_dataset(reference_dataset, tmp_path):
    import skynav.datasets as D

    with pytest.raises(D.DatasetError, match="'montecarlo' dataset has no navigation legs"):
        D.leg_plot(reference_dataset[0], tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()
