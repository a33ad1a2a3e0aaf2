"""How the flight software uses a planet's centroid: which beacon, whether it is usable, its noise.

Core module (on-board knowledge only: the image processing's result, the image, the estimate, the
on-board ephemeris and the calibrated camera; never the truth). :func:`target_beacon` picks the
pointed planet's centroid from a frame's result, :func:`centroid_usable` decides whether the
filter may use it and with which photocentre law of
:func:`skynav.pipeline.measurement.planet_pixel`, and :class:`CentroidNoise` is the filter's
measurement noise ``R = sigma_px^2 I``, whose figures the benchmark measures on the frames
(:func:`skynav.pipeline.scoring_nav.calibrate_sigma_px`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skynav.scenes.ephemeris_jpl import BODY_RADII_KM

from .measurement import spot_saturated

__all__ = ["BLEND_PX", "CentroidNoise", "centroid_usable", "diameter_px", "target_beacon"]


@dataclass(frozen=True, kw_only=True)
class CentroidNoise:
    """Measurement noise per axis. Per class of measurement (``"<target>/<photocentre law>"``, e.g.
    ``"earth/saturated"``, ``"mars/lambert"``) with enough calibration frames: the class's measured
    sigma (the planets' centroids differ: Venus's 0.04 px against the Earth's 0.11 px, both
    saturated points); else ``sigma^2 = sigma0_px^2 + (kappa D)^2`` with ``D`` the planet's
    predicted apparent diameter in px, fitted on all calibration frames by non-negative least squares."""

    sigma0_px: float
    kappa: float = 0.0
    mean_px: tuple = (0.0, 0.0)
    frames: int = 0
    clipped: int = 0
    classes: tuple = ()     # ((key, sigma_px, frames, track_bias_sigma_px), ...)
    track_bias_in_r: bool = True
    renderings: int = 1     # renderings of the cruise the frames were pooled from

    def sigma_px(self, diameter_px: float, key: str | None = None, track_frames: int = 1) -> float:
        """Per-frame sigma: the class's measured RMS per axis (its track-constant part included
        once). With ``track_bias_in_r`` (the default) a class whose error has a part constant over a
        track (sigma_b) gets ``sigma^2 + n sigma_b^2`` for a track of ``n`` frames, so that the
        filter, which takes the frames as independent, gives the track's MEAN at least the variance
        ``sigma^2 / n + sigma_b^2``. Measured over independent renderings held out of the
        calibration (docs/navigation.md): with it and R pooled from six renderings, mean NEES 6.66
        over 27 runs on 21 renderings; without it (R from one rendering) the filter was optimistic
        on held-out renderings (NEES 10.3 on ten of them)."""
        for k, sig, _, sig_b in self.classes:
            if k == key:
                n = max(1, int(track_frames)) if self.track_bias_in_r else 0
                return math.sqrt(sig**2 + n * sig_b**2)
        return math.sqrt(self.sigma0_px**2 + (self.kappa * diameter_px) ** 2)

    def describe(self) -> str:
        if not self.frames:
            return f"{self.sigma0_px:g} px (given)"
        per = "; ".join(f"{k} {sig:.3f} px, track bias {sb:.3f} px ({n})" for k, sig, n, sb in self.classes)
        return (f"sigma = sqrt({self.sigma0_px:.3f}^2 + ({self.kappa:.3f} D)^2) px, measured on {self.frames} frames"
                + (f" of {self.renderings} renderings" if self.renderings > 1 else "")
                + f" ({self.clipped} clipped as outliers; mean error {np.round(self.mean_px, 3).tolist()} px)"
                + (f"; per class: {per}" if per else "")
                + ("; track biases added to R (n sigma_b^2)" if self.track_bias_in_r and per else ""))


def diameter_px(radius_km: float, distance_km: float, camera) -> float:
    """Apparent diameter of a body, px."""
    return 2.0 * math.asin(min(1.0, radius_km / distance_km)) / camera.ifov_rad


#: A centroid is not used when another body is predicted closer than this to the target: the two
#: make one spot (the IP's ``ProcessOptions.blend_px``). Measured: the Earth with the Moon 3.6 px
#: away (leg 8 of the reference campaign) is off by 0.9 px, with the Moon 12 px away by 0.05 px.
BLEND_PX = 8.0


def centroid_usable(obs, result, beacon, target, *, t, position_km, ephemeris):
    """How the filter may use the target's centroid: None (not at all: another body is predicted
    within :data:`BLEND_PX`), else the photocentre law of
    :func:`skynav.pipeline.measurement.planet_pixel` (``"saturated"`` when the disc is resolved,
    wider than four PSF sigmas, and its spot has pixels at full scale; else ``"lambert"``).
    On-board knowledge only: the image, the frame's attitude ``result.R_cam_icrs`` (an
    :class:`~skynav.pipeline.protocols.ImageResult`), the estimate ``position_km``, the ephemeris, the camera.
    """
    cam = obs.camera
    R = result.R_cam_icrs
    r = np.asarray(position_km, dtype=float)

    def pixel(name):
        u = R @ (ephemeris.position(name, t) - r)
        return None if u[2] <= 0 else cam.project(u.reshape(1, 3))[0]

    xy_t = pixel(target)
    if xy_t is None:
        return None
    for name in BODY_RADII_KM:
        if name in (target, "sun"):
            continue
        xy = pixel(name)
        if xy is not None and np.all(np.isfinite(xy)) and float(np.hypot(*(xy - xy_t))) < BLEND_PX:
            return None
    d_px = diameter_px(BODY_RADII_KM.get(target, 0.0), float(np.linalg.norm(ephemeris.position(target, t) - r)), cam)
    if d_px > 4.0 * cam.psf.equivalent_sigma_px(cam) and spot_saturated(
            obs.dn, beacon.xy_px, 0.5 * d_px + 1.0, float(cam.sensor.max_dn)):
        return "saturated"
    return "lambert"


def target_beacon(result, target):
    """The beacon of ``target`` in an image processor's result (an
    :class:`~skynav.pipeline.protocols.ImageResult`) when found and the attitude solved, else None."""
    if result.status != "ok" or result.R_cam_icrs is None:
        return None
    for b in result.beacons:
        if b.name == target and b.status == "found" and b.xy_px is not None:
            return b
    return None
