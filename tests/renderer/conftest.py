"""Fixtures for the renderer tests: the Mitsuba variant (the only place besides
``renderer/mitsuba_backend.py`` that touches ``mi.set_variant``) and a synthetic resolved body.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from skynav.scenes import frames
from skynav.scenes.camera import paper_camera
from skynav.scenes.scene import BodyInView, Scene, StarsInView


def llvm_or_skip():
    """Skip the calling test, with the probe's reason, when Dr.Jit's LLVM backend does not work."""
    from skynav.renderer import jit_backend

    status = jit_backend.configure_llvm()
    if not status.available:
        pytest.skip(f"Dr.Jit LLVM backend unavailable: {status.reason}")


def cuda_or_skip():
    """Skip the calling test, with the probe's reason, when Dr.Jit's CUDA backend does not work."""
    from skynav.renderer import jit_backend

    status = jit_backend.probe_cuda()
    if not status.available:
        pytest.skip(f"Dr.Jit CUDA backend unavailable: {status.reason}")


@pytest.fixture(params=["numpy", "llvm", pytest.param("cuda", marks=pytest.mark.gpu)])
def backend(request):
    """Each sensor backend in turn (``"llvm"`` and ``"cuda"`` skip with a reason where they do
    not work; ``"cuda"`` runs only with ``-m gpu``)."""
    if request.param == "llvm":
        llvm_or_skip()
    elif request.param == "cuda":
        cuda_or_skip()
    return request.param


@pytest.fixture(params=["llvm", pytest.param("cuda", marks=pytest.mark.gpu)])
def jit_backend_name(request):
    """Each Dr.Jit sensor backend in turn (skipped with a reason where it does not work)."""
    (llvm_or_skip if request.param == "llvm" else cuda_or_skip)()
    return request.param


@pytest.fixture(scope="session")
def mitsuba_variant():
    """The Mitsuba variant the backend selects here (llvm_ad_spectral when a libLLVM >= 19 passes
    the subprocess probe, else scalar_spectral), set for the session."""
    from skynav.renderer import mitsuba_backend

    return mitsuba_backend.current_variant(None)


def _no_stars() -> StarsInView:
    z = np.zeros(0)
    return StarsInView(hip=z.astype(int), v_mag=z, b_v=z, teff_k=z, u_icrs=np.zeros((0, 3)), xy=np.zeros((0, 2)),
                       xy_start=np.zeros((0, 2)), xy_end=np.zeros((0, 2)), in_fov=z.astype(bool))


def make_body_scene(*, xy=(511.5, 511.5), diameter_px=40.0, phase_deg=60.0, sun_pa_deg=30.0, distance_km=4.0e5,
                    name="moon", v_mag=-5.0, camera=None, angular_velocity_rad_s=(0.0, 0.0, 0.0), sun_distance_km=1.5e8):
    """A scene with one body whose centre projects (pinhole) at ``xy``.

    ``diameter_px`` is ``2 f tan(asin(R / d))`` (the apparent diameter on the axis); the Sun is at
    ``sun_distance_km`` from the body, at phase angle ``phase_deg``, its projection on the image
    at position angle ``sun_pa_deg`` measured from +x towards +y.
    """
    cam = camera or paper_camera()
    R = frames.radec_twist_to_dcm(1.0, 0.3, 0.2)
    u = R.T @ cam.back_project(np.asarray(xy, dtype=float), distorted=False)
    f = cam.focal_length_px
    radius_km = distance_km * math.sin(math.atan(0.5 * diameter_px / f))
    obs = np.array([1.2e8, -5.0e7, 2.0e7])
    body = obs + distance_km * u
    pa = math.radians(sun_pa_deg)
    e1 = R.T @ np.array([math.cos(pa), math.sin(pa), 0.0])
    e1 = e1 - (e1 @ u) * u
    e1 /= np.linalg.norm(e1)
    g = math.radians(phase_deg)
    s = -u * math.cos(g) + e1 * math.sin(g)  # body -> Sun
    sun = body + sun_distance_km * s
    w = np.asarray(angular_velocity_rad_s, dtype=float)
    half = 0.5 * cam.exposure_s
    tup = lambda a: tuple(float(x) for x in np.asarray(a).ravel())  # noqa: E731
    b = BodyInView(
        name=name, u_icrs=tup(u), u_geometric=tup(u), u_light_time=tup(u), xy=tup(cam.project(R @ u)),
        xy_geometric=tup(xy), xy_light_time=tup(xy),
        xy_start=tup(cam.project(frames.propagate_attitude(R, w, -half) @ u)),
        xy_end=tup(cam.project(frames.propagate_attitude(R, w, half) @ u)),
        light_time_s=distance_km / 299792.458, distance_km=float(distance_km), position_km=tup(body),
        sun_position_km=tup(sun), radius_km=float(radius_km), v_mag=float(v_mag), phase_angle_rad=g, elongation_rad=1.0,
        angular_diameter_px=float(diameter_px), aberration_arcsec=0.0, in_fov=True, visible=True, resolved=True,
    )
    scene = Scene(epoch_tdb_s=0.0, position_km=obs, velocity_km_s=np.zeros(3), R_cam_icrs=R,
                  angular_velocity_rad_s=w, camera=cam, stars=_no_stars(), bodies=(b,))
    return scene, b


@pytest.fixture
def body_scene():
    """Factory: ``body_scene(**kw) -> (Scene, BodyInView)``, see :func:`make_body_scene`."""
    return make_body_scene
