"""The navigation benchmark's measurement-noise model (:class:`CentroidNoise`)."""

import math

import numpy as np
import pytest

from skynav.pipeline.scoring_nav import CentroidNoise


def test_class_sigma_and_track_bias():
    n = CentroidNoise(sigma0_px=0.07, kappa=0.02, frames=100, track_bias_in_r=False,
                      classes=(("venus/lambert", 0.05, 40, 0.0), ("earth/saturated", 0.12, 20, 0.03)))
    assert n.sigma_px(0.5, "venus/lambert", 36) == pytest.approx(0.05)
    # unknown class: the global fit sqrt(sigma0^2 + (kappa D)^2)
    assert n.sigma_px(3.0, "mars/lambert") == pytest.approx(math.hypot(0.07, 0.06))
    # without track_bias_in_r the class's measured RMS, its track bias not added again
    assert n.sigma_px(4.0, "earth/saturated", 36) == pytest.approx(0.12)
    # with track_bias_in_r (the default), a track bias sigma_b over n frames: the track mean of n independent
    # frames of the returned sigma has the variance sigma^2 / n + sigma_b^2
    import dataclasses

    s = dataclasses.replace(n, track_bias_in_r=True).sigma_px(4.0, "earth/saturated", 36)
    assert s**2 / 36 == pytest.approx(0.12**2 / 36 + 0.03**2)
    assert "earth/saturated" in n.describe()
    assert CentroidNoise(sigma0_px=0.07).track_bias_in_r   # the default


@pytest.mark.parametrize("bias", [0.0, 0.05])
def test_track_bias_estimate_recovers_a_simulated_bias(bias):
    """:func:`track_bias_sigma` on simulated errors: 300 tracks of 9 frames, white 0.1 px plus a
    ``bias`` px constant per track (per axis). The estimate's own scatter: ~0.004 px here."""
    from skynav.pipeline.scoring_nav import track_bias_sigma

    rng = np.random.default_rng(5)
    e, tracks = [], []
    for k in range(300):
        e.append(bias * rng.standard_normal(2) + 0.1 * rng.standard_normal((9, 2)))
        tracks += [k] * 9
    e = np.concatenate(e)
    ms = float(np.mean(e * e))
    assert math.sqrt(ms) == pytest.approx(math.hypot(0.1, bias), rel=0.05)
    assert track_bias_sigma(e, tracks, ms) == pytest.approx(bias, abs=0.015)
    assert track_bias_sigma(e[:9], tracks[:9], ms) == 0.0       # one track: no estimate


class _Eph:
    """A fake ephemeris: fixed positions (km, barycentric ICRS)."""

    def __init__(self, pos):
        self.pos = pos

    def position(self, name, t):
        return np.asarray(self.pos.get(name, (1e12, 0.0, 0.0)), dtype=float)


def test_centroid_usable_blend_gate_and_photocentre_law():
    """The blend gate (another body predicted within BLEND_PX) and the choice of the saturated law
    (disc wider than 4 PSF sigmas AND full-scale pixels at the spot)."""
    from types import SimpleNamespace

    from skynav.pipeline.scoring_nav import BLEND_PX, centroid_usable
    from skynav.scenes.camera import paper_camera

    cam = paper_camera()
    ifov = 1.0 / cam.fx_px
    R = np.eye(3)                        # camera axes = ICRS: +z is the boresight
    fr = SimpleNamespace(R_cam_icrs=R)   # the image processor's result (ImageResult): its attitude
    dn = np.zeros((cam.height, cam.width), dtype=np.uint8)
    obs = SimpleNamespace(camera=cam, dn=dn)
    centre = np.array([cam.cx, cam.cy])
    beacon = SimpleNamespace(xy_px=centre)

    def use(dist_km, moon_offset_px=None):
        pos = {"earth": (0.0, 0.0, dist_km)}
        if moon_offset_px is not None:
            pos["moon"] = (moon_offset_px * ifov * dist_km, 0.0, dist_km)
        return centroid_usable(obs, fr, beacon, "earth", t=0.0, position_km=np.zeros(3), ephemeris=_Eph(pos))

    near = 6371.0 / (2.0 * ifov)         # the Earth 4 px wide
    far = 6371.0 / (0.5 * ifov)          # 1 px wide
    assert use(near) == "lambert"        # resolved but not saturated
    dn[int(cam.cy), int(cam.cx)] = cam.sensor.max_dn
    assert use(near) == "saturated"
    assert use(far) == "lambert"         # saturated but a point: the PSF keeps the photocentre
    assert use(far, moon_offset_px=BLEND_PX - 1.0) is None
    assert use(far, moon_offset_px=BLEND_PX + 4.0) == "lambert"
