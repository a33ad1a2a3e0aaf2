"""Windowed tracking (issue 13, speed): spots only in windows around the stars and beacons
predicted from the previous attitude give the same matched stars and attitude as full-frame
tracking, and a wrong prior falls back to the full frame (then lost in space)."""

from __future__ import annotations

import numpy as np
import pytest

import skynav.pipeline.process as process
from skynav.pipeline import PredictedState, ProcessOptions, process_frame
from skynav.pipeline.attitude import rotation_angle_rad

from .conftest import attitude_towards, render_observation

ARCSEC = np.pi / 180 / 3600


def _state(truth, sigma_km=1e4):
    return PredictedState(position_km=np.asarray(truth["observer"]["position_km"]) + sigma_km,
                          velocity_km_s=np.asarray(truth["observer"]["velocity_km_s"]),
                          position_cov_km2=np.eye(3) * sigma_km**2)


@pytest.fixture
def spy(monkeypatch):
    calls = []
    orig = process._track_windowed

    def wrapped(*a, **k):
        out = orig(*a, **k)
        calls.append(out is not None)
        return out

    monkeypatch.setattr(process, "_track_windowed", wrapped)
    return calls


@pytest.mark.parametrize("pointing,seed", [((83.0, -5.0, 20.0), 3), ((250.0, 40.0, -70.0), 5)])
def test_windowed_tracking_matches_full_frame_tracking(paper_cam, onboard, spy, pointing, seed):
    from skynav.scenes.frames import rotation_vector_to_dcm

    obs, truth = render_observation(R_cam_icrs=attitude_towards(*pointing), camera=paper_cam, seed=seed)
    R = np.asarray(truth["attitude"]["R_cam_icrs"])
    prev = rotation_vector_to_dcm(np.array([3e-4, -2e-4, 5e-4])) @ R  # ~ 2 arcmin off
    st = _state(truth)
    full = process_frame(obs, catalog=onboard, predicted_state=st, previous_attitude=prev,
                         options=ProcessOptions(track_window_px=0))
    assert spy == []
    win = process_frame(obs, catalog=onboard, predicted_state=st, previous_attitude=prev)
    assert spy == [True], "the windowed path fell back"
    assert full.status == win.status == "ok"
    assert full.star_id_method == win.star_id_method == "tracking"
    assert rotation_angle_rad(full.attitude.R_cam_icrs, win.attitude.R_cam_icrs) < 0.1 * ARCSEC
    # the final association offers the refine_max_spots brightest spots: the full frame's noise
    # spots can push a few faint stars out of that list; offering all spots, the same stars match
    assert set(full.matched_star_ids) <= set(win.matched_star_ids)
    all_spots = ProcessOptions(refine_max_spots=10**6)
    full_all = process_frame(obs, catalog=onboard, predicted_state=st, previous_attitude=prev,
                             options=ProcessOptions(track_window_px=0, refine_max_spots=10**6))
    win_all = process_frame(obs, catalog=onboard, predicted_state=st, previous_attitude=prev, options=all_spots)
    assert set(full_all.matched_star_ids) == set(win_all.matched_star_ids)
    assert rotation_angle_rad(full_all.attitude.R_cam_icrs, win_all.attitude.R_cam_icrs) < 0.1 * ARCSEC
    assert rotation_angle_rad(win.attitude.R_cam_icrs, R) < 40 * ARCSEC
    assert [b.status for b in full.beacons] == [b.status for b in win.beacons]
    for a, b in zip(full.beacons, win.beacons):
        if a.xy_px is not None:
            assert np.allclose(a.xy_px, b.xy_px, atol=1e-9)
    assert len(win.centroids_xy_px) < len(full.centroids_xy_px)  # fewer pixels looked at


def test_windowed_tracking_falls_back_when_the_prior_is_wrong(paper_cam, onboard, spy):
    from skynav.scenes.frames import rotation_vector_to_dcm

    obs, truth = render_observation(R_cam_icrs=attitude_towards(83.0, -5.0, 20.0), camera=paper_cam, seed=3)
    R = np.asarray(truth["attitude"]["R_cam_icrs"])
    prev = rotation_vector_to_dcm(np.radians([2.0, 0.0, 0.0])) @ R  # 2 deg off
    res = process_frame(obs, catalog=onboard, predicted_state=_state(truth), previous_attitude=prev)
    assert spy == [False], "the windows accepted a 2-deg-off prior"
    assert res.status == "ok"
    assert rotation_angle_rad(res.attitude.R_cam_icrs, R) < 40 * ARCSEC
