"""Windowed tracking (speed): spots only in windows around the stars and beacons
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
    orig = process.track_windowed

    def wrapped(*a, **k):
        out = orig(*a, **k)
        calls.append(out is not None)
        return out

    monkeypatch.setattr(process, "track_windowed", wrapped)
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
    # judged against the truth: the windowed centroids (each star's ROI in its own box) differ
    # from the full frame's connected regions only where a neighbour shares a ROI, so the
    # attitude must be as good. Tolerance: 0.3 arcsec, a quarter of the ~1.2 arcsec attitude
    # noise of ~150 stars at 70 arcsec/px
    e_full = rotation_angle_rad(full.attitude.R_cam_icrs, R) / ARCSEC
    e_win = rotation_angle_rad(win.attitude.R_cam_icrs, R) / ARCSEC
    assert e_win < e_full + 0.3, (e_win, e_full)
    assert e_win < 10.0
    # the same stars carry the solution (at least 90 % of the full frame's matches)
    assert len(set(full.matched_star_ids) & set(win.matched_star_ids)) >= 0.9 * len(full.matched_star_ids)
    # beacons: the same outcome, the same spot (the box labelling repeats detect_spots' regions
    # and Eq. 7-8 centroids; 1e-6 px allows for the order of the sums)
    assert [b.status for b in full.beacons] == [b.status for b in win.beacons]
    for a, b in zip(full.beacons, win.beacons):
        if a.xy_px is not None:
            assert np.allclose(a.xy_px, b.xy_px, atol=1e-6)
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
