"""Foreign frames: star fields rendered by GalSim, written in the frame schema, for ``skynav bench ip``.

The pipeline was tuned on skynav's own renderer (a Gaussian PSF, skynav's detector model). These
frames come from another program: GalSim (Rowe et al. 2015) draws every star and every planet as a
point source through an Airy or a Moffat PSF convolved with the pixel, adds a sky level, applies
its own Poisson and read noise (``galsim.CCDNoise``) and its own flux scale (a V = 0 photon flux,
the aperture, the exposure and a flat QE), and the frame is written as a raw 16-bit PNG holding
12-bit DN (PIL, no skynav writer) with a JSON in the frame schema (``skynav.frame/2``: the keys
``datasets.reader.read_frame_pair`` and ``skynav bench ip`` read, and the stars' and bodies' truth).
skynav is used only for the geometry: which Hipparcos stars and planets are in the field and where
(:func:`skynav.scenes.build_scene` at the truth attitude: proper motion, parallax, aberration, the
pinhole camera), never for pixels.

Pixel centres. skynav (docs/conventions.md): the centre of the top-left pixel is (0, 0), x = column,
y = row, pixel [i, j] covers x in [j - 0.5, j + 0.5]. GalSim: an image's pixel (x, y) is centred
on the integer position (x, y) and covers [x - 0.5, x + 0.5]; the array row is y - ymin, the column
x - xmin. The image is made with ``xmin = ymin = 0`` and every profile is drawn with
``center=galsim.PositionD(x, y)`` at skynav's (x, y): the conventions are then the same numbers
(no half-pixel shift). ``tests/pipeline/test_foreign_frames.py`` checks it: a bright star's
first moment is its truth within 0.01 px, skynav's centroid within 0.05 px.

Sensors (same optics, f = 40 mm, f/2.2, 0.4 s; 20 deg field):

- ``paper``: the paper camera's geometry, 1024 x 1024 px of 13.78 um;
- ``fine``: 2048 x 2048 px of 6.89 um (the same optics: the PSFs twice as many pixels wide).

PSFs (the same angular size at both sensors; FWHM in paper-camera pixels): ``airy`` (no
obscuration) of FWHM 1.5 px; ``moffat`` (beta = 3) of FWHM 2.0 px.

The matrix (``--matrix``, :data:`MATRIX`): the ``paper`` geometry under sensors of 8, 12 and 16
bits from 4 to 80 e-/DN, with read noise, sky and dark current (Poisson, GalSim's ``CCDNoise``)
from a cold dark sky to a hot bright one, and Gaussian (sigma 0.4 to 1.5 px), Moffat and Airy
PSFs, each drawn by GalSim convolved with the pixel and sampled every 1/8 px (:func:`matrix_drawer`);
an 8-bit sensor's frames are 8-bit PNGs; every odd frame aims near a visible planet (beacons).
``--score`` then prints, per cell, skynav's and
tetra3rs's outcomes and medians, skynav's with Eq. 7-8 centroids only, and wrong beacons at a
1e7 km prediction error.

Usage::

    python benchmarks/foreign_frames.py OUT [--count 200] [--seed 2323] [--sensor paper fine] [--psf airy moffat]
                                            [--resume] [--first K] [--score]
    python benchmarks/foreign_frames.py OUT --matrix [--cell CELL ...] [--count 30] [--resume] [--score]
    skynav bench ip OUT/paper_airy --peers --position-sigma-km 1e4 -o REPORT

writes ``OUT/<sensor>_<psf>/frames/NNNNNN.png|.json`` (``OUT/<cell>/`` with ``--matrix``; ``--count`` is capped by
``SKYNAV_MAX_COUNT``). Frame k of a set draws its scene and its noise from
``SeedSequence([seed, k])`` (the same scenes, attitudes and stars in every set). ``--score`` then
runs ``skynav bench ip``'s engine on each set (lost in space, predicted position 1e4 km off per
axis, the improved mode, tetra3rs beside it when installed) and prints the table of
``docs/pipeline.md`` ("Other renderers' frames").
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skynav.scenes.camera import paper_camera
from skynav.scenes.constants import AU_KM, GM_SUN_KM3_S2, OBLIQUITY_J2000_RAD
from skynav.scenes.frames import rot1

V0_PHOTONS_S_M2 = 8.8e9                     # V = 0: ~1000 photons/s/cm^2/A over an 88 nm V band
EPOCH_RANGE_JD = (2461041.5, 2462867.5)     # 2026-01-01 .. 2031-01-01 TDB
STAR_V_LIMIT = 9.5                          # the faintest catalogue stars drawn (background included)


@dataclass(frozen=True)
class Sensor:
    name: str
    width: int
    pixel_pitch_um: float
    read_noise_e: float
    sky_e: float                  # sky + dark level per pixel per exposure, e-
    gain_dn_per_e: float = 0.2    # 12-bit: 20000 e- full well -> 4000 DN
    offset_dn: float = 100.0
    bit_depth: int = 12
    full_well_e: float = 20000.0
    focal_length_mm: float = 40.0
    f_number: float = 2.2
    exposure_s: float = 0.4
    qe: float = 0.49
    dark_e_s: float = 0.0         # dark current, e-/s per pixel (Poisson, added to the sky)
    label: str = ""               # the matrix table's description of the sensor


_PAPER_PITCH_UM = paper_camera().pixel_pitch_um  # 13.78 um: 1024 px across 20 deg at f = 40 mm
SENSORS = {
    "paper": Sensor("paper", 1024, _PAPER_PITCH_UM, read_noise_e=8.0, sky_e=20.0),
    # half the pitch: a quarter of the sky per pixel; a smaller, quieter pixel
    "fine": Sensor("fine", 2048, _PAPER_PITCH_UM / 2, read_noise_e=5.0, sky_e=5.0),
}
PSF_FWHM_PAPER_PX = {"airy": 1.5, "moffat": 2.0}
MOFFAT_BETA = 3.0


def make_psf(psf: str, sensor: Sensor):
    """The GalSim PSF in pixel units of ``sensor`` (the image's scale is 1 px)."""
    import galsim  # the foreign renderer (test extra)

    fwhm = PSF_FWHM_PAPER_PX[psf] * SENSORS["paper"].pixel_pitch_um / sensor.pixel_pitch_um
    if psf == "airy":
        return galsim.Airy(lam_over_diam=fwhm / 1.028993969962188)  # Airy FWHM = 1.029 lambda / D
    if psf == "moffat":
        return galsim.Moffat(beta=MOFFAT_BETA, fwhm=fwhm)
    raise ValueError(f"psf must be one of {sorted(PSF_FWHM_PAPER_PX)}, got {psf!r}")


def make_drawer(psf: str, sensor: Sensor):
    """``(profile, method)`` that draws the PSF convolved with the pixel. Airy: GalSim's own path
    (``method="auto"``: the convolution with the pixel by FFT). Moffat: the effective PSF (Moffat
    convolved with the pixel) sampled every 1/4 px to 96 px, as a quintic ``InterpolatedImage``
    drawn with ``method="no_pixel"`` (the pixel is in it already): the same pixels within 1e-4 of
    the peak, 4x faster (its wide wings make every FFT stamp large)."""
    import galsim  # the foreign renderer (test extra)

    p = make_psf(psf, sensor)
    if psf == "airy":
        return p, "auto"
    n = 2 * 96 * 4 + 1
    sampled = galsim.Convolve(p, galsim.Pixel(1.0)).drawImage(nx=n, ny=n, scale=0.25, method="no_pixel")
    return galsim.InterpolatedImage(sampled, x_interpolant="quintic", calculate_stepk=False,
                                    calculate_maxk=False), "no_pixel"


@dataclass(frozen=True)
class Psf:
    """A matrix cell's PSF: ``gaussian`` of standard deviation ``width_px``, ``moffat`` of FWHM
    ``width_px`` and index ``beta``, or ``airy`` (no obscuration) of FWHM ``width_px``; pixel units."""

    family: str
    width_px: float
    beta: float = 3.0

    @property
    def fwhm_px(self) -> float:
        return self.width_px * 2.0 * math.sqrt(2.0 * math.log(2.0)) if self.family == "gaussian" else self.width_px

    def label(self) -> str:
        if self.family == "gaussian":
            return f"Gaussian sigma {self.width_px:g} px"
        if self.family == "moffat":
            return f"Moffat beta {self.beta:g}, FWHM {self.width_px:g} px"
        return f"Airy FWHM {self.width_px:g} px"

    def to_dict(self) -> dict:
        return {"psf": self.family, "psf_fwhm_px": self.fwhm_px,
                "psf_sigma_px": self.width_px if self.family == "gaussian" else None,
                "moffat_beta": self.beta if self.family == "moffat" else None}


def _matrix_sensor(bits: int, e_per_dn: float, *, read_e: float, sky_e: float, dark_e_s: float,
                   full_well_e: float, exposure_s: float = 0.4) -> Sensor:
    offset = {8: 8.0, 12: 100.0, 16: 500.0}[bits]
    label = (f"{bits}-bit, {e_per_dn:g} e-/DN, read {read_e:g} e-, sky {sky_e:g} e-, dark {dark_e_s:g} e-/s "
             f"x {exposure_s:g} s")
    return Sensor(f"{bits}bit_{e_per_dn:g}e", 1024, _PAPER_PITCH_UM, read_noise_e=read_e, sky_e=sky_e,
                  gain_dn_per_e=1.0 / e_per_dn, offset_dn=offset, bit_depth=bits, full_well_e=full_well_e,
                  exposure_s=exposure_s, dark_e_s=dark_e_s, label=label)


#: The foreign-frame matrix: the paper camera's geometry (1024 x 1024 px, 20 deg, f = 40 mm, f/2.2)
#: under sensors of 8, 12 and 16 bits from 4 to 80 e-/DN, Gaussian, Moffat and Airy PSFs from 0.4
#: to 3 px, dark skies and bright ones, cold and hot detectors. ``g05_12bit_4e`` is the camera of
#: the report the matrix answers (12 bits, 4 e-/DN, a 0.5 px Gaussian, 20 e-/s of dark current),
#: ``g05_12bit_4e_4s`` the same with four times the exposure.
MATRIX = {
    "g05_12bit_4e": (_matrix_sensor(12, 4, read_e=8, sky_e=20, dark_e_s=20, full_well_e=16000, exposure_s=1.0),
                     Psf("gaussian", 0.5)),
    # the same camera with 4x the light: bright stars, where a centroid's pull to the pixel centre,
    # not its noise, sets the error
    "g05_12bit_4e_4s": (_matrix_sensor(12, 4, read_e=8, sky_e=20, dark_e_s=20, full_well_e=16000, exposure_s=4.0),
                        Psf("gaussian", 0.5)),
    "g04_8bit_80e": (_matrix_sensor(8, 80, read_e=25, sky_e=40, dark_e_s=5, full_well_e=20000), Psf("gaussian", 0.4)),
    "g10_16bit_4e": (_matrix_sensor(16, 4, read_e=4, sky_e=100, dark_e_s=50, full_well_e=150000),
                     Psf("gaussian", 1.0)),
    "g15_12bit_20e": (_matrix_sensor(12, 20, read_e=12, sky_e=600, dark_e_s=100, full_well_e=80000),
                      Psf("gaussian", 1.5)),
    "m12_8bit_40e": (_matrix_sensor(8, 40, read_e=10, sky_e=30, dark_e_s=10, full_well_e=10000),
                     Psf("moffat", 1.2, beta=2.5)),
    "m30_16bit_10e": (_matrix_sensor(16, 10, read_e=6, sky_e=200, dark_e_s=200, full_well_e=400000),
                      Psf("moffat", 3.0, beta=3.5)),
    "a10_12bit_80e": (_matrix_sensor(12, 80, read_e=20, sky_e=50, dark_e_s=20, full_well_e=300000),
                      Psf("airy", 1.0)),
    "a25_16bit_4e": (_matrix_sensor(16, 4, read_e=3, sky_e=10, dark_e_s=1, full_well_e=200000), Psf("airy", 2.5)),
}
MATRIX_STAMP_HALF_PX = 48       # the matrix's stamps reach at most this far (the sampled PSF's half-size)
MATRIX_SAMPLE_PX = 1.0 / 8.0    # the sampling step of the matrix's pixel-convolved PSFs


def matrix_drawer(psf: Psf):
    """``(profile, "no_pixel")`` of a matrix PSF: GalSim's profile convolved with the pixel,
    sampled every 1/8 px to :data:`MATRIX_STAMP_HALF_PX` and interpolated (quintic), as
    :func:`make_drawer` does for the Moffat (1/8 px: the narrowest Gaussian, 0.4 px, is smooth on
    that step)."""
    import galsim  # the foreign renderer (test extra)

    if psf.family == "gaussian":
        p = galsim.Gaussian(sigma=psf.width_px)
    elif psf.family == "moffat":
        p = galsim.Moffat(beta=psf.beta, fwhm=psf.width_px)
    elif psf.family == "airy":
        p = galsim.Airy(lam_over_diam=psf.width_px / 1.028993969962188)  # Airy FWHM = 1.029 lambda / D
    else:
        raise ValueError(f"psf family must be gaussian, moffat or airy, got {psf.family!r}")
    n = 2 * int(MATRIX_STAMP_HALF_PX / MATRIX_SAMPLE_PX) + 1
    sampled = galsim.Convolve(p, galsim.Pixel(1.0)).drawImage(nx=n, ny=n, scale=MATRIX_SAMPLE_PX, method="no_pixel")
    return galsim.InterpolatedImage(sampled, x_interpolant="quintic", calculate_stepk=False,
                                    calculate_maxk=False), "no_pixel"


def electrons_of_v(v_mag, sensor: Sensor):
    """Expected photo-electrons of a point source of magnitude V in one exposure."""
    area_m2 = math.pi * (sensor.focal_length_mm / sensor.f_number * 1e-3 / 2) ** 2
    return V0_PHOTONS_S_M2 * area_m2 * sensor.exposure_s * sensor.qe * 10.0 ** (-0.4 * np.asarray(v_mag, float))


def random_scene(rng):
    """Epoch (JD TDB), observer state (ICRS, km, km/s) and a uniformly random attitude."""
    jd = rng.uniform(*EPOCH_RANGE_JD)
    lon = rng.uniform(0.0, 2 * math.pi)
    r_au = rng.uniform(0.9, 1.6)
    r_ecl = r_au * AU_KM * np.array([math.cos(lon), math.sin(lon), 0.0])
    v_circ = math.sqrt(GM_SUN_KM3_S2 / (r_au * AU_KM))
    v_ecl = v_circ * np.array([-math.sin(lon), math.cos(lon), 0.0])
    ecl_to_icrs = rot1(OBLIQUITY_J2000_RAD).T  # rot1 is passive: v_ecl = rot1(eps) @ v_icrs
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)  # uniform on SO(3)
    from skynav.scenes.frames import quat_to_dcm

    return jd, ecl_to_icrs @ r_ecl, ecl_to_icrs @ v_ecl, quat_to_dcm(q)


def _aim_near_a_body(scene, rng, cam):
    """An attitude whose field holds one of the scene's bodies of V <= 7 more than 45 deg from the
    Sun (drawn at random), up to 0.35 of the half-field off the boresight, with a random twist;
    None when there is none."""
    from skynav.scenes.frames import point_boresight

    sun = np.asarray(scene.sun_u_icrs, float)
    bodies = [b for b in scene.bodies if b.v_mag <= 7.0 and np.dot(b.u_icrs, sun) < math.cos(math.radians(45.0))]
    if not bodies:
        return None
    u = np.asarray(bodies[rng.integers(len(bodies))].u_icrs, float)
    # tilt the boresight off the body by a random angle in a random direction
    off = rng.uniform(0.0, 0.35) * cam.fov_x_rad / 2
    t = np.cross(u, rng.normal(size=3))
    t /= np.linalg.norm(t)
    return point_boresight(math.cos(off) * u + math.sin(off) * t, rng.uniform(0.0, 2 * math.pi))


def skynav_camera(sensor: Sensor):
    from skynav.scenes.camera import Camera

    return Camera(width=sensor.width, height=sensor.width, focal_length_mm=sensor.focal_length_mm,
                  pixel_pitch_um=sensor.pixel_pitch_um, f_number=sensor.f_number, exposure_s=sensor.exposure_s)


def draw_points(image, psf, xy, electrons, *, stamp_fwhm: float, method: str = "auto", max_half: int = 96):
    """Add point sources (skynav pixel coordinates ``xy``, flux ``electrons``) to a GalSim image
    whose bounds start at (0, 0). Each is drawn (PSF convolved with the pixel) into a stamp
    that reaches where its PSF falls below ~0.05 e- per pixel, at most ``max_half`` px."""
    import galsim  # the foreign renderer (test extra)

    full = image.bounds
    for (x, y), f in zip(xy, electrons):
        if not (np.isfinite(x) and np.isfinite(y)) or f <= 0:
            continue
        # Airy wings ~ r^-3, Moffat(3) ~ r^-6: a radius growing as flux^(1/3) covers both
        half = int(min(max_half, max(3 * stamp_fwhm, stamp_fwhm * 1.2 * (f / 20.0) ** (1 / 3))))
        ix, iy = int(round(x)), int(round(y))
        b = galsim.BoundsI(ix - half, ix + half, iy - half, iy + half) & full
        if not b.isDefined():
            continue
        psf.withFlux(float(f)).drawImage(image=image[b], center=galsim.PositionD(float(x), float(y)),
                                         add_to_image=True, method=method)


def render_frame(k: int, *, sensor: Sensor, psf, seed: int, ephemeris=None, catalog=None, drawer=None):
    """``(dn (H, W), truth dict)`` of frame ``k`` (module docstring): uint16 DN, uint8 for an
    8-bit sensor. ``psf``: a name of :data:`PSF_FWHM_PAPER_PX` (the sets of ``galsim``) or a
    :class:`Psf` (the matrix); ``drawer``: its :func:`make_drawer` / :func:`matrix_drawer`, made
    here when None."""
    import galsim  # the foreign renderer (test extra)

    from skynav.scenes.scene import build_scene

    ss = np.random.SeedSequence([int(seed), int(k)])
    scene_seed, noise_seed = ss.generate_state(2)
    jd, r_km, v_km_s, R = random_scene(np.random.default_rng(scene_seed))
    cam = skynav_camera(sensor)
    t_tdb_s = (jd - 2451545.0) * 86400.0
    scene = build_scene(t_tdb_s, position_km=r_km, velocity_km_s=v_km_s, R_cam_icrs=R, camera=cam,
                        catalog_limiting_v_mag=STAR_V_LIMIT, ephemeris=ephemeris, catalog=catalog)
    if isinstance(psf, Psf) and k % 2 == 1:  # matrix: every other frame aims near a visible body (beacons)
        aimed = _aim_near_a_body(scene, np.random.default_rng(scene_seed), cam)
        R = scene.R_cam_icrs if aimed is None else aimed
        if aimed is not None:
            scene = build_scene(t_tdb_s, position_km=r_km, velocity_km_s=v_km_s, R_cam_icrs=R, camera=cam,
                                catalog_limiting_v_mag=STAR_V_LIMIT, ephemeris=ephemeris, catalog=catalog)
    st = scene.stars
    star_e = electrons_of_v(st.v_mag, sensor)
    bodies = [b for b in scene.bodies if b.in_fov]
    body_e = electrons_of_v([b.v_mag for b in bodies], sensor)

    if isinstance(psf, Psf):
        p, method = matrix_drawer(psf) if drawer is None else drawer
        fwhm_px, max_half, psf_meta = psf.fwhm_px, MATRIX_STAMP_HALF_PX, psf.to_dict()
    else:
        p, method = make_drawer(psf, sensor) if drawer is None else drawer
        fwhm_px = PSF_FWHM_PAPER_PX[psf] * SENSORS["paper"].pixel_pitch_um / sensor.pixel_pitch_um
        max_half = 96
        psf_meta = {"psf": psf, "psf_fwhm_px": fwhm_px, "moffat_beta": MOFFAT_BETA if psf == "moffat" else None}
    image = galsim.ImageD(sensor.width, sensor.width, xmin=0, ymin=0, scale=1.0)
    draw_points(image, p, st.xy, star_e, stamp_fwhm=fwhm_px, method=method, max_half=max_half)
    draw_points(image, p, [b.xy for b in bodies], body_e, stamp_fwhm=fwhm_px, method=method, max_half=max_half)
    background_e = sensor.sky_e + sensor.dark_e_s * sensor.exposure_s
    image += background_e
    noise = galsim.CCDNoise(galsim.BaseDeviate(int(noise_seed)), gain=1.0, read_noise=sensor.read_noise_e)
    image.addNoise(noise)  # Poisson of (signal + sky + dark) electrons, then Gaussian read noise
    e = np.minimum(image.array, sensor.full_well_e)
    max_dn = 2 ** sensor.bit_depth - 1
    dn = np.clip(np.floor(e * sensor.gain_dn_per_e + sensor.offset_dn + 0.5), 0, max_dn)
    dn = dn.astype(np.uint8 if sensor.bit_depth <= 8 else np.uint16)

    jd_s = f"{jd:.9f}"
    from skynav.scenes.frames import dcm_to_quat
    from skynav.scenes.timescales import time_from_tdb_seconds

    truth = {
        "schema": "skynav.frame/2",
        "epoch": {"tdb_iso": time_from_tdb_seconds(t_tdb_s).isot, "jd_tdb": float(jd_s),
                  "tdb_seconds_past_j2000": t_tdb_s},
        "observer": {"position_km": r_km.tolist(), "velocity_km_s": v_km_s.tolist()},
        "attitude": {"R_cam_icrs": R.tolist(), "q_cam_icrs": dcm_to_quat(R).tolist(),
                     "angular_velocity_rad_s": [0.0, 0.0, 0.0]},
        "camera": {"K": cam.K.tolist(), "width": sensor.width, "height": sensor.width,
                   "focal_length_mm": sensor.focal_length_mm, "pixel_pitch_um": sensor.pixel_pitch_um,
                   "cx": cam.cx, "cy": cam.cy, "f_number": sensor.f_number, "exposure_s": sensor.exposure_s,
                   "bit_depth": sensor.bit_depth},
        "stars": [{"hip": int(h), "v_mag": float(v), "u_icrs": u.tolist(), "xy": xy.tolist(), "electrons": float(f)}
                  for h, v, u, xy, f in zip(st.hip, st.v_mag, st.u_icrs, st.xy, star_e)],
        "bodies": [{"name": b.name, "xy": list(b.xy), "xy_geometric": list(b.xy_geometric), "u_icrs": list(b.u_icrs),
                    "light_time_s": b.light_time_s, "distance_km": b.distance_km, "v_mag": b.v_mag,
                    "phase_angle_deg": math.degrees(b.phase_angle_rad), "angular_diameter_px": b.angular_diameter_px,
                    "in_fov": True, "visible": b.visible, "resolved": False, "electrons": float(f)}
                   for b, f in zip(bodies, body_e)],
        "cosmic_rays": [],
        "seeds": {"master": int(seed), "frame": int(k), "scene": int(scene_seed), "noise": int(noise_seed)},
        "renderer": {"name": "galsim", "version": galsim.__version__, **psf_meta, "sky_e": sensor.sky_e,
                     "dark_e_s": sensor.dark_e_s, "read_noise_e": sensor.read_noise_e,
                     "gain_dn_per_e": sensor.gain_dn_per_e, "offset_dn": sensor.offset_dn,
                     "full_well_e": sensor.full_well_e, "bit_depth": sensor.bit_depth,
                     "v0_photons_s_m2": V0_PHOTONS_S_M2, "qe": sensor.qe, "star_v_limit": STAR_V_LIMIT,
                     "pixel_centres": "GalSim image bounds start at (0, 0): pixel (x, y) centred on integer (x, y), "
                                      "the same numbers as skynav's"},
    }
    return dn, truth


def write_frame(folder: Path, k: int, dn, truth) -> None:
    """``folder/frames/NNNNNN.png`` (raw 16-bit greyscale, PIL) and ``.json``."""
    from PIL import Image  # the foreign writer: no skynav code

    out = Path(folder) / "frames"
    out.mkdir(parents=True, exist_ok=True)
    dn = np.ascontiguousarray(dn)
    Image.fromarray(dn if dn.dtype == np.uint8 else dn.astype(np.uint16)).save(out / f"{k:06d}.png")
    tmp = out / f"{k:06d}.json.tmp"  # the JSON last and atomically: a frame with its JSON is complete
    tmp.write_text(json.dumps(truth), encoding="utf-8")
    tmp.replace(out / f"{k:06d}.json")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="output folder (one sub-folder per sensor and PSF, or per matrix cell)")
    ap.add_argument("--count", type=int, default=200, help="frames per sensor and PSF (default 200)")
    ap.add_argument("--seed", type=int, default=2323)
    ap.add_argument("--sensor", nargs="+", choices=sorted(SENSORS), default=["paper", "fine"])
    ap.add_argument("--psf", nargs="+", choices=sorted(PSF_FWHM_PAPER_PX), default=["airy", "moffat"])
    ap.add_argument("--matrix", action="store_true", help="draw the cells of the foreign-frame matrix (MATRIX: "
                    "sensors of 8-16 bits, Gaussian, Moffat and Airy PSFs) instead of --sensor x --psf")
    ap.add_argument("--cell", nargs="+", choices=sorted(MATRIX), default=None, help="with --matrix: these cells only")
    ap.add_argument("--resume", action="store_true", help="keep the frames already written (each frame is "
                    "the same whenever it is drawn: its own seed)")
    ap.add_argument("--first", type=int, default=0, help="draw frames FIRST..count-1 only (split a set "
                    "between processes)")
    ap.add_argument("--score", action="store_true", help="score each set (bench ip's engine, tetra3rs beside it) "
                    "and print the table")
    a = ap.parse_args(argv)
    if a.count < 1:
        print(f"foreign_frames: --count must be >= 1, got {a.count}", file=sys.stderr)
        return 2
    if a.cell and not a.matrix:
        print("foreign_frames: --cell needs --matrix", file=sys.stderr)
        return 2
    from skynav.scenes.catalog_hipparcos import load_catalog
    from skynav.infra.count_cap import cap_count
    from skynav.scenes.ephemeris_jpl import default_ephemeris

    count = cap_count(a.count, "foreign frames per set")
    eph, cat = default_ephemeris(), load_catalog()
    if a.matrix:
        sets = [(c, MATRIX[c][0], MATRIX[c][1], Path(a.out) / c) for c in (a.cell or MATRIX)]
    else:
        sets = [(f"{s}_{p}", SENSORS[s], p, Path(a.out) / f"{s}_{p}") for s in a.sensor for p in a.psf]
    for name, sensor, psf, folder in sets:
        t0 = time.perf_counter()
        drawer = matrix_drawer(psf) if a.matrix else make_drawer(psf, sensor)
        for k in range(a.first, count):
            if a.resume and (folder / "frames" / f"{k:06d}.json").exists():
                continue
            dn, truth = render_frame(k, sensor=sensor, psf=psf, seed=a.seed, ephemeris=eph, catalog=cat,
                                     drawer=drawer)
            write_frame(folder, k, dn, truth)
        print(f"{folder}: {count} frames, {time.perf_counter() - t0:.0f} s")
    if a.score and a.matrix:
        print_matrix_scores(sets, count)
    elif a.score:
        print_scores([(s, p, folder) for _, sensor, p, folder in sets for s in [sensor.name]], count)
    return 0


def score_set(folder, count):
    """``(ours, equal, peers, meta)``: ``bench ip``'s summaries of the set (lost in space, sigma
    1e4 km, improved mode) with the variance weights and with equal weights (the former final attitude),
    and its peers' (``summary["peers"]``)."""
    from skynav.pipeline.options import ProcessOptions
    from skynav.pipeline.scoring import run_benchmark, summarise, summarise_peers

    rows, meta = run_benchmark(folder, sigmas_km=(1e4,), mode="improved", progress=False, limit=count, peers=True)
    rows_eq, _ = run_benchmark(folder, sigmas_km=(1e4,), mode="improved", progress=False, limit=count,
                               options=ProcessOptions(variance_weights=False))
    return (summarise(rows, frames=meta["frames"], sigmas_km=(1e4,)),
            summarise(rows_eq, frames=meta["frames"], sigmas_km=(1e4,)),
            summarise_peers(meta["peer_rows"], rows, 1e4), meta)


def print_scores(folders, count):
    """The table of docs/pipeline.md: per set, skynav's and tetra3rs's correct rate, wrong count
    and median attitude error (lost in space; tetra3rs's "correct": solved within 500"), and
    skynav's median with equal weights."""
    print("| sensor | PSF | frames | skynav correct | skynav wrong | tetra3rs correct | tetra3rs wrong "
          "| median error skynav | tetra3rs | skynav, equal weights |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    note = None
    for s, p, folder in folders:
        ours, equal, peers, meta = score_set(folder, count)
        n = ours["frames"]
        att = ours["attitude"]
        t3 = peers.get("tetra3rs")
        note = note or meta["peer_notes"].get("tetra3rs")
        if t3 is None:
            t3c = t3w = t3e = "-"
        else:
            t3w = round(t3["wrong_rate"] * n)
            t3c = f"{100 * (t3['solved_rate'] - t3['wrong_rate']):.1f} %"
            t3e = f"{t3['error_arcsec_median']:.2f}\""
        print(f"| {s} | {p} | {n} | {100 * att['correct_rate']:.1f} % | {round(att['wrong_rate'] * n)} | {t3c} | {t3w} "
              f"| {att['error_arcsec_median']:.2f}\" | {t3e} | {equal['attitude']['error_arcsec_median']:.2f}\" |")
    if note:
        print(f"tetra3rs: {note}")


def print_matrix_scores(sets, count):
    """The matrix table of docs/pipeline.md: per cell, skynav's correct and wrong attitudes (lost in
    space, predicted position 1e4 km off per axis), tetra3rs's on the same frames, both medians,
    skynav's median with Eq. 7-8's centroids only (``--set psf_fit=false``), and skynav's wrong
    beacons with a 1e7 km prediction error."""
    from skynav.pipeline.options import ProcessOptions
    from skynav.pipeline.scoring import run_benchmark, summarise, summarise_peers

    print("| cell | sensor | PSF | frames | skynav correct | skynav wrong | tetra3rs correct | tetra3rs wrong "
          "| median skynav | median tetra3rs | skynav, Eq. 7-8 centroids | beacons wrong at 1e7 km |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, sensor, psf, folder in sets:
        rows, meta = run_benchmark(folder, sigmas_km=(1e4, 1e7), mode="improved", progress=False, limit=count,
                                   peers=True)
        rows_i2, _ = run_benchmark(folder, sigmas_km=(1e4,), mode="improved", progress=False, limit=count,
                                   options=ProcessOptions(psf_fit=False))
        ours = summarise(rows, frames=meta["frames"], sigmas_km=(1e4, 1e7))
        i2 = summarise(rows_i2, frames=meta["frames"], sigmas_km=(1e4,))["attitude"]
        peers = summarise_peers(meta["peer_rows"], rows, 1e4)
        n, att, t3 = ours["frames"], ours["attitude"], peers.get("tetra3rs")
        if t3 is None:
            t3c = t3w = t3e = "-"
        else:
            t3w = round(t3["wrong_rate"] * n)
            t3c = f"{100 * (t3['solved_rate'] - t3['wrong_rate']):.1f} %"
            t3e = f"{t3['error_arcsec_median']:.2f}\""
        b7 = ours["beacon"]["1e+07"]
        beacons = f"{round(b7['wrong_rate'] * b7['beacons'])} of {b7['beacons']}" if b7["beacons"] else "no beacon"
        print(f"| {name} | {sensor.label} | {psf.label()} | {n} | {100 * att['correct_rate']:.1f} % "
              f"| {round(att['wrong_rate'] * n)} | {t3c} | {t3w} | {att['error_arcsec_median']:.2f}\" | {t3e} "
              f"| {i2['error_arcsec_median']:.2f}\" | {beacons} |", flush=True)


if __name__ == "__main__":
    sys.exit(main())
