"""Mitsuba backend against an exact quadrature of a Lambertian sphere lit by the Sun.

The oracle (written here, independent of ``renderer/brdf.py`` and of Mitsuba): a sphere of
radius R at distance D from a pinhole observer, lit by a collimated Sun; a surface point with
unit normal n sends the radiance ``L = k E mu0 / pi`` (``mu0 = n.s``), and the irradiance at the
observer is ``integral L cos(e) / rho^2 dA`` over the part of the sphere that is lit
(``n.s > 0``) and seen from the FINITE distance (``n.o > R / D``). The surface is parametrised
around the Sun axis (``n = cos b s + sin b (cos p e1 + sin p e2)``); the visible azimuths form
one interval per colatitude, found in closed form; Gauss-Legendre in both variables, with the
colatitude split where that interval opens or closes, converges to 1e-12. The photocentre is
the same integral of the exact pinhole projection (``Camera.project``) of each surface point.

In the far limit the oracle must reduce to the Lambert phase law
``E_obs = (2/3) k E (R/D)^2 (sin a + (pi - a) cos a) / pi`` and the photocentre offset to
``3 pi / 16 sin a (1 + cos a) / (sin a + (pi - a) cos a)`` radii (Lindegren 1977).

Noise: Mitsuba samples pixel positions and wavelengths at random. The ``stratified`` sampler
jitters 16 strata per pixel in every sample dimension, including the wavelength, and the
spectral film draws 4 stratified wavelengths per sample from the QE x T x photon response, so
the spectral estimate of a pixel has 64 strata; pixel noise only remains at the limb and the
terminator. Summed over ~8e5 pixels the total's relative scatter is ~5e-6 at 16 spp (measured:
seeds 0-3 at 60 deg gave -6e-6, -3e-6, -1.3e-5, -4e-6; at 120 deg -1e-5, +4e-6, -5e-7, -7e-6),
far under 1e-4. A 120 px disk has ~70 x fewer pixels and the same relative limb: its scatter is
~5e-4 at 16 spp and ~5e-5 at 256 spp (measured over 4 seeds), which sets the scalar fallback.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.constants import c as C_M_S
from scipy.constants import h as H_J_S

from skynav.renderer import spectra
from skynav.renderer.brdf import BRDF
from skynav.renderer.mitsuba_backend import AU_KM, LAMBDA_REF_NM, render_resolved_body, solar_irradiance_nodes_w_m2_nm

K_550 = 0.3  # Lambert reflectance at 550 nm for the test sphere


# ----------------------------------------------------------------------------- the oracle
def _gl(a, b, n):
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (b - a) * x + 0.5 * (b + a), 0.5 * (b - a) * w


def lambert_sphere_quadrature(centre_km, radius_km, sun_dir, observer_km, *, n=160, project=None):
    """Finite-distance Lambert sphere: ``G = (1/pi) integral mu0 cos(e) / rho^2 dA`` (sr) and,
    if ``project`` maps points (N, 3) to pixels (N, 2), the G-weighted mean pixel position.

    The observer irradiance is ``k E G`` for reflectance k and solar irradiance E.
    """
    C = np.asarray(centre_km, float)
    O = np.asarray(observer_km, float)
    s = np.asarray(sun_dir, float) / np.linalg.norm(sun_dir)
    D = float(np.linalg.norm(O - C))
    o = (O - C) / D
    R = float(radius_km)
    c = R / D
    cos_a = float(np.clip(o @ s, -1, 1))
    sin_a = math.sqrt(max(0.0, 1.0 - cos_a * cos_a))
    alpha = math.acos(cos_a)
    if sin_a > 1e-12:
        e1 = (o - cos_a * s) / sin_a
    else:
        e1 = np.cross(s, [1.0, 0, 0]) if abs(s[0]) < 0.9 else np.cross(s, [0, 1.0, 0])
        e1 /= np.linalg.norm(e1)
    e2 = np.cross(s, e1)
    ac = math.acos(c)
    cuts = {0.0, 0.5 * math.pi}
    for b in (alpha - ac, alpha + ac, ac - alpha, -ac - alpha, ac):
        if 0.0 < b < 0.5 * math.pi:
            cuts.add(b)
    cuts = sorted(cuts)
    x, w = np.polynomial.legendre.leggauss(n)
    g_parts, p_parts = [], []
    for b0, b1 in zip(cuts[:-1], cuts[1:]):
        b = 0.5 * (b1 - b0) * x + 0.5 * (b1 + b0)
        w_b = 0.5 * (b1 - b0) * w
        cb, sb = np.cos(b), np.sin(b)
        with np.errstate(divide="ignore", invalid="ignore"):
            if sin_a > 1e-12:
                A = (c - cb * cos_a) / (sb * sin_a)
            else:
                A = np.where(cb * cos_a > c, -np.inf, np.inf)
        keep = A < 1.0
        pm = np.where(A <= -1.0, math.pi, np.arccos(np.clip(A, -1.0, 1.0)))[keep]  # visible azimuths |p| < pm
        cb, sb, w_b = cb[keep], sb[keep], w_b[keep]
        ps = pm[:, None] * x[None, :]
        wp = pm[:, None] * w[None, :]
        nvec = (cb[:, None, None] * s + sb[:, None, None] * (np.cos(ps)[..., None] * e1 + np.sin(ps)[..., None] * e2)).reshape(-1, 3)
        n_o = nvec @ o
        rho2 = D * D + R * R - 2.0 * D * R * n_o
        cos_e = (D * n_o - R) / np.sqrt(rho2)
        jac = ((R * R * sb * w_b * cb)[:, None] * wp).ravel()  # mu0 = cos b, dA = R^2 sin b db dp
        g_parts.append(cos_e / rho2 * jac / math.pi)
        p_parts.append(C + R * nvec - O)
    g = np.concatenate(g_parts)
    g_sum = float(g.sum())
    if project is None:
        return g_sum, None
    return g_sum, g @ project(np.concatenate(p_parts)) / g_sum


def _spectral_electrons_per_s_per_sr(camera, k_values, r_sun_km):
    """``A integral E(l) k(l) QE T(l) l / (h c) dl`` of the piecewise-linear spectra that the
    Mitsuba scene holds on the shared grid (exact integral of their product, 0.005 nm steps)."""
    wl = spectra.WAVELENGTHS_NM
    e_nodes = solar_irradiance_nodes_w_m2_nm(r_sun_km)
    s_nodes = spectra.response_on_grid(camera, wl) * wl / LAMBDA_REF_NM
    fine = np.linspace(wl[0], wl[-1], int(round((wl[-1] - wl[0]) / 0.005)) + 1)
    prod = np.interp(fine, wl, e_nodes) * np.interp(fine, wl, k_values) * np.interp(fine, wl, s_nodes)
    return camera.aperture_area_m2 * np.trapezoid(prod, fine) * LAMBDA_REF_NM * 1e-9 / (H_J_S * C_M_S)


def oracle(scene, body):
    cam = scene.camera
    k = K_550 * spectra.reflectance_shape(body.name, spectra.WAVELENGTHS_NM)
    centre = np.asarray(body.position_km)
    sun = np.asarray(body.sun_position_km) - centre
    observer = centre - body.distance_km * np.asarray(body.u_icrs)
    G, xy = lambert_sphere_quadrature(centre, body.radius_km, sun, observer,
                                      project=lambda p: cam.project(p @ scene.R_cam_icrs.T, distort=False))
    r_sun = float(np.linalg.norm(sun))
    return G * _spectral_electrons_per_s_per_sr(cam, k, r_sun) * cam.exposure_s, xy


# ----------------------------------------------------------------------------- oracle checks
@pytest.mark.parametrize("phase_deg", [0.0, 60.0, 120.0])
def test_oracle_reduces_to_lambert_phase_law_far_away(phase_deg):
    """Oracle self-check: at D = 1e6 R it is the Lambert phase law (to the O(R/D) finite-distance
    terms) and its photocentre offset is Lindegren's closed form."""
    a = math.radians(phase_deg)
    R, D = 1.0, 1.0e6
    s = np.array([math.sin(a), 0.0, math.cos(a)])  # observer on +z, Sun towards +x
    G, _ = lambert_sphere_quadrature([0, 0, 0], R, s, [0, 0, D])
    phase_law = (2.0 / 3.0) * (R / D) ** 2 * (math.sin(a) + (math.pi - a) * math.cos(a)) / math.pi
    assert abs(G / phase_law - 1.0) < 5e-6  # O(R/D) = 1e-6 finite-distance terms


@pytest.mark.parametrize("phase_deg", [30.0, 90.0, 150.0])
def test_oracle_photocentre_matches_lindegren_far_away(phase_deg):
    a = math.radians(phase_deg)
    R, D = 1.0, 1.0e6
    s = np.array([math.sin(a), 0.0, math.cos(a)])
    observer = np.array([0.0, 0.0, D])
    # a camera at the observer looking along -z: image x along world +x
    proj = lambda p: np.stack([p[:, 0] / -p[:, 2], p[:, 1] / -p[:, 2]], -1) * D  # noqa: E731  (radii)
    _, xy = lambert_sphere_quadrature([0, 0, 0], R, s, observer, project=proj)
    lindegren = 3 * math.pi / 16 * math.sin(a) * (1 + math.cos(a)) / (math.sin(a) + (math.pi - a) * math.cos(a))
    assert abs(xy[0] - lindegren) < 1e-5  # radii; O(R/D) terms
    assert abs(xy[1]) < 1e-9


def test_emitter_spectrum_integrates_like_the_full_resolution_sun():
    """The Sun's node spectrum (cell averages on the shared 5 nm grid) times a body reflectance and
    the camera's photon response integrates like the full-resolution CALSPEC spectrum (0.01 nm)
    to 2e-4 (measured 5-8e-5: the curvature of the smooth factors across a 5 nm cell)."""
    from skynav.scenes.camera import paper_camera

    cam = paper_camera()
    wl = spectra.WAVELENGTHS_NM
    fine = np.linspace(wl[0], wl[-1], int(round((wl[-1] - wl[0]) / 0.01)) + 1)
    for body in ("moon", "jupiter", "neptune"):
        k = spectra.reflectance_shape(body, wl)
        s = spectra.response_on_grid(cam, wl) * wl
        e = solar_irradiance_nodes_w_m2_nm(AU_KM)
        nodes = np.trapezoid(np.interp(fine, wl, e) * np.interp(fine, wl, k) * np.interp(fine, wl, s), fine)
        full = np.trapezoid(spectra.solar_irradiance_1au_w_m2_nm(fine) * spectra.reflectance_shape(body, fine)
                            * spectra.response_on_grid(cam, fine) * fine, fine)
        assert abs(nodes / full - 1.0) < 2e-4, body


# ----------------------------------------------------------------------------- Mitsuba vs oracle
@pytest.fixture(scope="module")
def big_sphere_renders(mitsuba_variant):
    """The acceptance set-up: a Lambert sphere filling a 1024 x 1024 crop, 16 spp, phases 0, 60,
    120 deg (llvm/cuda). The scalar fallback renders a 120 px disk at 256 spp instead (1024^2 x 16
    samples take minutes there); its tolerance is then set by the limb noise (module notes)."""
    from tests.renderer.conftest import make_body_scene

    big = not mitsuba_variant.startswith("scalar")
    diameter = 1016.0 if big else 120.0  # crop 2 (508 + 2) + 1 -> 1024 (8-px quantum)
    out = {}
    for phase in (0.0, 60.0, 120.0):
        scene, body = make_body_scene(xy=(511.5, 511.5), diameter_px=diameter, phase_deg=phase, sun_pa_deg=30.0,
                                      distance_km=2.0e4)
        img = render_resolved_body(scene, body, spp=16 if big else 256, brdf=BRDF(kind="lambert", reflectance_550=K_550),
                                   normalize="none", rng=np.random.default_rng(7))
        out[phase] = (scene, body, img, oracle(scene, body))
    return big, out


@pytest.mark.parametrize("phase_deg", [0.0, 60.0, 120.0])
def test_total_electrons_against_exact_quadrature(big_sphere_renders, phase_deg):
    big, renders = big_sphere_renders
    scene, body, img, (expected, _) = renders[phase_deg]
    if big:
        assert img.electrons.shape == (1024, 1024)
    rel = img.electrons_raw_total / expected - 1.0
    print(f"phase {phase_deg:5.1f} deg: Mitsuba {img.electrons_raw_total:.8e} e-, quadrature {expected:.8e} e-, rel {rel:+.2e}")
    # 1e-4: the acceptance tolerance (16 spp; MC scatter of the total ~5e-6, float32
    # accumulation per pixel < 1e-6). Scalar fallback (120 px disk, 256 spp): scatter ~5e-5, so
    # 3e-4 is 6 sigma.
    assert abs(rel) <= (1e-4 if big else 3e-4)


@pytest.mark.parametrize("phase_deg", [0.0, 60.0, 120.0])
def test_photocentre_against_exact_quadrature(big_sphere_renders, phase_deg):
    big, renders = big_sphere_renders
    scene, body, img, (_, xy) = renders[phase_deg]
    err = np.hypot(*(np.asarray(img.photocentre_xy) - xy))
    print(f"phase {phase_deg:5.1f} deg: photocentre {img.photocentre_xy}, quadrature {tuple(xy)}, |err| {err:.4f} px")
    # 0.02 px: the acceptance tolerance. Pixel binning moves a centroid only through the limb
    # and terminator pixels (the within-pixel first moments of a smooth image telescope to 0).
    assert err < 0.02


def test_far_small_sphere_against_lambert_phase_law(mitsuba_variant, body_scene):
    """A 12 px sphere 1e5 km away (D/R = 480): total electrons follow the far-field Lambert phase
    law up to the finite-distance terms, which the exact quadrature gives."""
    scene, body = body_scene(xy=(300.2, 700.9), diameter_px=12.0, phase_deg=75.0, distance_km=1.0e5)
    img = render_resolved_body(scene, body, spp=4096, brdf=BRDF(kind="lambert", reflectance_550=K_550), normalize="none")
    a = body.phase_angle_rad
    k = K_550 * spectra.reflectance_shape(body.name, spectra.WAVELENGTHS_NM)
    r_sun = float(np.linalg.norm(np.subtract(body.sun_position_km, body.position_km)))
    phase_law = ((2.0 / 3.0) * (body.radius_km / body.distance_km) ** 2 * (math.sin(a) + (math.pi - a) * math.cos(a)) / math.pi
                 * _spectral_electrons_per_s_per_sr(scene.camera, k, r_sun) * scene.camera.exposure_s)
    exact, _ = oracle(scene, body)
    finite = exact / phase_law - 1.0  # O(R/D) finite-distance correction, ~2e-3 here
    rel = img.electrons_raw_total / phase_law - 1.0
    print(f"far sphere: Mitsuba/phase law - 1 = {rel:+.2e}, finite-distance term {finite:+.2e}")
    # 1e-3 on top of the finite-distance term: the limb noise of ~40 limb pixels is 7e-4 (1 sigma)
    # at 256 spp (measured over seeds), so 4096 spp gives ~2e-4 and 1e-3 is 5 sigma
    assert abs(rel - finite) < 1e-3


def test_position_with_distortion_and_offset_principal_point(mitsuba_variant, body_scene):
    """Geometry: an off-axis full-phase body seen through a camera with an off-centre principal
    point and Brown-Conrady distortion lands where the exact quadrature, with every surface point
    projected through ``Camera.project`` (distortion included), puts it (< 0.02 px). The backend
    takes every ray from ``Camera.line_of_sight``, so the distortion's local scale and shear are
    rendered too (a crescent under strong distortion: ``tests/renderer/test_mitsuba_projection.py``)."""
    from skynav.scenes.camera import paper_camera
    from skynav.scenes.distortion import BrownConrady

    cam = paper_camera(cx=530.25, cy=497.6, distortion=BrownConrady(k1=-0.08, k2=0.01, p1=2e-4, p2=-1e-4))
    scene, body = body_scene(xy=(150.2, 880.7), diameter_px=30.0, phase_deg=0.0, sun_pa_deg=200.0,
                             distance_km=4.0e5, camera=cam)
    img = render_resolved_body(scene, body, spp=64, brdf=BRDF(kind="lambert", reflectance_550=K_550), normalize="none")
    centre = np.asarray(body.position_km)
    observer = centre - body.distance_km * np.asarray(body.u_icrs)
    _, xy = lambert_sphere_quadrature(centre, body.radius_km, np.asarray(body.sun_position_km) - centre, observer,
                                      project=lambda p: cam.project(p @ scene.R_cam_icrs.T))
    err = float(np.hypot(*(np.asarray(img.photocentre_xy) - xy)))
    print(f"distorted off-axis body: photocentre error {err:.4f} px")
    assert err < 0.02


@pytest.mark.parametrize("kind", ["lommel_seeliger", "oren_nayar"])
@pytest.mark.parametrize("phase_deg", [40.0, 100.0])
def test_other_brdfs_against_far_field_disk_quadrature(mitsuba_variant, body_scene, kind, phase_deg):
    """The Python BSDFs (Lommel-Seeliger, Oren-Nayar) render the law of ``renderer/brdf.py``:
    with a long-focal-length camera a 100 px body is 5800 radii away (far field to 2e-4), so
    the disk brightness relative to a Lambert sphere of the same scale and the photocentre
    offset in radii must match :func:`far_field_disk`."""
    from skynav.renderer.brdf import far_field_disk
    from skynav.scenes.camera import Camera

    cam = Camera(width=256, height=256, focal_length_mm=4000.0, pixel_pitch_um=13.78)
    f = cam.focal_length_px
    scene, body = body_scene(xy=(127.3, 128.6), diameter_px=100.0, phase_deg=phase_deg, sun_pa_deg=15.0,
                             distance_km=1.0e8, camera=cam)
    law = BRDF(kind=kind, reflectance_550=0.5)
    ref = BRDF(kind="lambert", reflectance_550=0.5)
    # 256 spp: the bright Lommel-Seeliger limb makes the 16-spp centroid noise ~0.015 px (measured
    # over seeds); at 256 spp it is < 0.007 px. The scalar fallback runs the Python BSDFs per ray,
    # so it renders 16 spp and gets a noise-sized tolerance.
    jit = not mitsuba_variant.startswith("scalar")
    spp = 256 if jit else 16
    a = render_resolved_body(scene, body, spp=spp, brdf=law, normalize="none")
    b = render_resolved_body(scene, body, spp=spp, brdf=ref, normalize="none")
    g = body.phase_angle_rad
    i_law, x_law = far_field_disk(law, g)
    i_ref, _ = far_field_disk(ref, g)
    ratio = (a.electrons_raw_total / b.electrons_raw_total) / (i_law / i_ref) - 1.0
    off = np.asarray(a.photocentre_xy) - np.asarray(body.xy)
    pa = math.radians(15.0)
    expected = x_law * a.radius_px * np.array([math.cos(pa), math.sin(pa)])
    err = float(np.hypot(*(off - expected)))
    print(f"{kind} phase {phase_deg}: brightness ratio error {ratio:+.2e}, photocentre error {err:.4f} px, f={f:.0f}")
    # 2e-3: limb/terminator MC noise of a 100 px disk at 16 spp plus the far-field quadrature
    # (n = 400 Gauss-Legendre, ~1e-5) and O(R/D) = 2e-4 terms
    assert abs(ratio) < 2e-3
    assert err < (0.02 if jit else 0.06)  # px (radius 50 px: 4e-4 of the radius)


def test_streak_time_samples_average_the_attitude_path(mitsuba_variant, body_scene):
    """A rotating camera: the sub-frames follow ``propagate_attitude``; the streaked photocentre
    is the mean of the sub-frame centres (phase 0, so centre of figure = photocentre) and the
    total is that of a still frame."""
    from skynav.scenes.frames import propagate_attitude

    w = (0.0, 0.0, 0.0)
    still_scene, still = body_scene(xy=(600.4, 400.2), diameter_px=20.0, phase_deg=0.0, distance_km=4e5)
    w = (8e-3, -6e-3, 5e-3)  # rad/s: a ~12 px streak over 0.4 s
    scene, body = body_scene(xy=(600.4, 400.2), diameter_px=20.0, phase_deg=0.0, distance_km=4e5, angular_velocity_rad_s=w)
    n = 8
    img = render_resolved_body(scene, body, spp=16, time_samples=n, brdf=BRDF(kind="lambert"), normalize="none")
    ref = render_resolved_body(still_scene, still, spp=16, brdf=BRDF(kind="lambert"), normalize="none")
    dt = ((np.arange(n) + 0.5) / n - 0.5) * scene.camera.exposure_s
    R_t = propagate_attitude(scene.R_cam_icrs, np.asarray(w), dt)
    centres = scene.camera.project(np.einsum("tij,j->ti", R_t, np.asarray(body.u_icrs)))
    err = float(np.hypot(*(np.asarray(img.photocentre_xy) - centres.mean(0))))
    length = float(np.hypot(*np.subtract(body.xy_end, body.xy_start)))
    print(f"streak {length:.2f} px: photocentre error {err:.4f} px, total ratio {img.electrons_raw_total / ref.electrons_raw_total - 1:+.2e}")
    assert length > 5.0
    assert err < 0.02  # px
    assert abs(img.electrons_raw_total / ref.electrons_raw_total - 1.0) < 1e-3  # MC noise ~1e-4
