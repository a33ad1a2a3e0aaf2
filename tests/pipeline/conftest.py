"""Shared fixtures of the pipeline tests: the on-board catalog and rendered frames (tests may use
the renderer; the pipeline package may not)."""

from __future__ import annotations

import numpy as np
import pytest

EPOCH_TDB_S = 8.0e8  # 2025-05-09, inside DE421


@pytest.fixture(scope="session")
def paper_cam():
    from skynav.scenes.camera import paper_camera

    return paper_camera()


@pytest.fixture(scope="session")
def onboard(paper_cam):
    from skynav.pipeline import OnboardCatalog

    return OnboardCatalog.load(camera=paper_cam)


def attitude_towards(ra_deg, dec_deg, twist_deg=0.0):
    from skynav.scenes import frames

    return np.asarray(frames.radec_twist_to_dcm(np.radians(ra_deg), np.radians(dec_deg), np.radians(twist_deg)))


def render_observation(*, R_cam_icrs, camera, position_km=(1.2e8, -8.0e7, 1.0e6), velocity_km_s=(15.0, 22.0, 0.3),
                       angular_velocity_rad_s=(0.0, 0.0, 0.0), seed=1, epoch_tdb_s=EPOCH_TDB_S):
    """(Observation, truth dict) of one rendered frame."""
    from skynav.datasets.observation import make_observation
    from skynav.renderer.render import render
    from skynav.scenes.scene import build_scene

    scene = build_scene(float(epoch_tdb_s), position_km=np.asarray(position_km, float),
                        velocity_km_s=np.asarray(velocity_km_s, float), R_cam_icrs=R_cam_icrs, camera=camera,
                        angular_velocity_rad_s=angular_velocity_rad_s, catalog_limiting_v_mag=8.0)
    frame = render(scene, seed=seed)
    truth = frame.truth
    return make_observation(truth, frame.dn, index=0), truth
