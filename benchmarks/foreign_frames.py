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

Usage::

    python benchmarks/foreign_frames.py OUT [--count 200] [--seed 2323] [--sensor paper fine] [--psf airy moffat]
                                            [--resume] [--first K] [--score]
    skynav bench ip OUT/paper_airy --peers --position-sigma-km 1e4 -o REPORT

writes ``OUT/<sensor>_<psf>/frames/NNNNNN.png|.json`` (``--count`` is capped by
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


def skynav_camera(sensor: Sensor):
    from skynav.scenes.camera import Camera

    return Camera(width=sensor.width, height=sensor.width, focal_length_mm=sensor.focal_length_mm,
                  pixel_pitch_um=sensor.pixel_pitch_um, f_number=sensor.f_number, exposure_s=sensor.exposure_s)


def draw_points(image, psf, xy, electrons, *, stamp_fwhm: float, method: str = "auto"):
    """Add point sources (skynav pixel coordinates ``xy``, flux ``electrons``) to a GalSim image
    whose bounds start at (0, 0). Each is drawn (PSF convolved with the pixel) into a stamp
    that reaches where its PSF falls below ~0.05 e- per pixel, at most 96 px."""
    import galsim  # the foreign renderer (test extra)

    full = image.bounds
    for (x, y), f in zip(xy, electrons):
        if not (np.isfinite(x) and np.isfinite(y)) or f <= 0:
            continue
        # Airy wings ~ r^-3, Moffat(3) ~ r^-6: a radius growing as flux^(1/3) covers both
        half = int(min(96, max(3 * stamp_fwhm, stamp_fwhm * 1.2 * (f / 20.0) ** (1 / 3))))
        ix, iy = int(round(x)), int(round(y))
        b = galsim.BoundsI(ix - half, ix + half, iy - half, iy + half) & full
        if not b.isDefined():
            continue
        psf.withFlux(float(f)).drawImage(image=image[b], center=galsim.PositionD(float(x), float(y)),
                                         add_to_image=True, method=method)


def render_frame(k: int, *, sensor: Sensor, psf: str, seed: int, ephemeris=None, catalog=None, drawer=None):
    """``(dn uint16 (H, W), truth dict)`` of frame ``k`` (module docstring); ``drawer``: the
    :func:`make_drawer` of ``psf`` and ``sensor``, made here when None."""
    import galsim  # the foreign renderer (test extra)

    from skynav.scenes.scene import build_scene

    ss = np.random.SeedSequence([int(seed), int(k)])
    scene_seed, noise_seed = ss.generate_state(2)
    jd, r_km, v_km_s, R = random_scene(np.random.default_rng(scene_seed))
    cam = skynav_camera(sensor)
    t_tdb_s = (jd - 2451545.0) * 86400.0
    scene = build_scene(t_tdb_s, position_km=r_km, velocity_km_s=v_km_s, R_cam_icrs=R, camera=cam,
                        catalog_limiting_v_mag=STAR_V_LIMIT, ephemeris=ephemeris, catalog=catalog)
    st = scene.stars
    star_e = electrons_of_v(st.v_mag, sensor)
    bodies = [b for b in scene.bodies if b.in_fov]
    body_e = electrons_of_v([b.v_mag for b in bodies], sensor)

    p, method = make_drawer(psf, sensor) if drawer is None else drawer
    fwhm_px = PSF_FWHM_PAPER_PX[psf] * SENSORS["paper"].pixel_pitch_um / sensor.pixel_pitch_um
    image = galsim.ImageD(sensor.width, sensor.width, xmin=0, ymin=0, scale=1.0)
    draw_points(image, p, st.xy, star_e, stamp_fwhm=fwhm_px, method=method)
    draw_points(image, p, [b.xy for b in bodies], body_e, stamp_fwhm=fwhm_px, method=method)
    image += sensor.sky_e
    noise = galsim.CCDNoise(galsim.BaseDeviate(int(noise_seed)), gain=1.0, read_noise=sensor.read_noise_e)
    image.addNoise(noise)  # Poisson of (signal + sky) electrons, then Gaussian read noise
    e = np.minimum(image.array, sensor.full_well_e)
    max_dn = 2 ** sensor.bit_depth - 1
    dn = np.clip(np.floor(e * sensor.gain_dn_per_e + sensor.offset_dn + 0.5), 0, max_dn).astype(np.uint16)

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
        "renderer": {"name": "galsim", "version": galsim.__version__, "psf": psf, "psf_fwhm_px": fwhm_px,
                     "moffat_beta": MOFFAT_BETA if psf == "moffat" else None, "sky_e": sensor.sky_e,
                     "read_noise_e": sensor.read_noise_e, "gain_dn_per_e": sensor.gain_dn_per_e,
                     "offset_dn": sensor.offset_dn, "full_well_e": sensor.full_well_e,
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
    Image.fromarray(np.ascontiguousarray(dn, dtype=np.uint16)).save(out / f"{k:06d}.png")
    tmp = out / f"{k:06d}.json.tmp"  # the JSON last and atomically: a frame with its JSON is complete
    tmp.write_text(json.dumps(truth), encoding="utf-8")
    tmp.replace(out / f"{k:06d}.json")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="output folder (one sub-folder per sensor and PSF)")
    ap.add_argument("--count", type=int, default=200, help="frames per sensor and PSF (default 200)")
    ap.add_argument("--seed", type=int, default=2323)
    ap.add_argument("--sensor", nargs="+", choices=sorted(SENSORS), default=["paper", "fine"])
    ap.add_argument("--psf", nargs="+", choices=sorted(PSF_FWHM_PAPER_PX), default=["airy", "moffat"])
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
    from skynav.scenes.catalog_hipparcos import load_catalog
    from skynav.infra.count_cap import cap_count
    from skynav.scenes.ephemeris_jpl import default_ephemeris

    count = cap_count(a.count, "foreign frames per set")
    eph, cat = default_ephemeris(), load_catalog()
    folders = []
    for s in a.sensor:
        for p in a.psf:
            folder = Path(a.out) / f"{s}_{p}"
            folders.append((s, p, folder))
            t0 = time.perf_counter()
            drawer = make_drawer(p, SENSORS[s])
            for k in range(a.first, count):
                if a.resume and (folder / "frames" / f"{k:06d}.json").exists():
                    continue
                dn, truth = render_frame(k, sensor=SENSORS[s], psf=p, seed=a.seed, ephemeris=eph, catalog=cat,
                                         drawer=drawer)
                write_frame(folder, k, dn, truth)
            print(f"{folder}: {count} frames, {time.perf_counter() - t0:.0f} s")
    if a.score:
        print_scores(folders, count)
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


if __name__ == "__main__":
    sys.exit(main())
