"""Closed loop on the virtual bench: a scene exported for the bench, shown on the virtual screen,
captured by the virtual camera, and measured like the software frame of the same scene.

For every isolated star in the camera's field (12 px from the edges) brighter than ``v_max``: the centroid
(background-subtracted first moment in a 9 x 9 window around the software truth position) turned
into a direction by the camera model, against the star's true apparent direction and against the software frame's centroid measured
the same way (the bench's own contribution: the simple centroid has its own error); and the aperture
electrons (radius 4 px, local background from a 7-10 px annulus) of the capture against those of the
software frame, noise-free (the bench's systematic error) and with noise (what a lab measures),
for stars whose software frame is below 80 % of full well.
"""

from __future__ import annotations

import numpy as np

from skynav.scenes.facility import ARCSEC


def _measure(e_img, xy, r_ap=4.0):
    H, W = e_img.shape
    out_xy, out_f = [], []
    yy, xx = np.mgrid[-10:11, -10:11]
    rr = np.hypot(xx, yy)
    for x, y in xy:
        i, j = int(round(y)), int(round(x))
        if i < 10 or j < 10 or i >= H - 10 or j >= W - 10:
            out_xy.append((np.nan, np.nan))
            out_f.append(np.nan)
            continue
        w = e_img[i - 10:i + 11, j - 10:j + 11]
        bg = np.median(w[(rr >= 7) & (rr <= 10)])
        s = w - bg
        c = (np.abs(xx) <= 4) & (np.abs(yy) <= 4)
        tot = s[c].sum()
        cx = j + (s[c] * xx[c]).sum() / tot
        cy = i + (s[c] * yy[c]).sum() / tot
        out_xy.append((cx, cy))
        out_f.append(s[rr <= r_ap].sum())
    return np.array(out_xy), np.array(out_f)


def closed_loop(bench, calibrated, scene, *, seed: int = 0, v_max: float = 6.0) -> dict:
    """``bench``: a :class:`~skynav.calibration.virtual_bench.VirtualBench`; ``calibrated``: the
    facility fitted from its captures; ``scene``: a scene with the facility's camera."""
    from skynav.renderer.detector import Sensor
    from skynav.renderer.display import screen_frame
    from skynav.renderer.render import RenderOptions, detect, expected_image

    cam = scene.camera
    rng = np.random.default_rng(seed)
    opts = RenderOptions(cosmic_rays_per_frame=0)
    sw = expected_image(scene, rng=np.random.default_rng(seed), options=opts)
    sw_noisy = detect(sw, cam, np.random.default_rng(seed + 1), opts).dn
    sf = screen_frame(scene, calibrated, rng=np.random.default_rng(seed))
    cap_e = bench.expected_electrons(sf.dn.astype(float))
    cap_dn = Sensor(cam.sensor, cap_e.shape).expose(cap_e, cam.exposure_s, rng, backend="numpy")
    g = cam.sensor.gain_dn_per_e
    stars = scene.stars
    v_cam = np.einsum("ij,nj->ni", scene.R_cam_icrs, stars.u_icrs)
    xy_true = cam.project(v_cam)
    keep = (stars.v_mag < v_max) & cam.in_image(xy_true, margin_px=-12)
    # isolated: no other catalogued star brighter than v_max + 3 within 12 px
    near = np.linalg.norm(xy_true[:, None, :] - xy_true[None, :, :], axis=-1)
    bright = (stars.v_mag < v_max + 3)[None, :] & (near < 12) & ~np.eye(len(near), dtype=bool)
    keep &= ~bright.any(axis=1)
    xy_true, v_cam, vmag = xy_true[keep], v_cam[keep], stars.v_mag[keep]
    v_cam = v_cam / np.linalg.norm(v_cam, axis=-1, keepdims=True)
    res = {}
    for label, img_sw, img_cap in (("noise_free", sw.electrons, cap_e),
                                    ("noisy", (sw_noisy.astype(float) - cam.sensor.offset_dn) / g,
                                     (cap_dn.astype(float) - cam.sensor.offset_dn) / g)):
        c_xy, c_f = _measure(img_cap, xy_true)
        s_xy, s_f = _measure(img_sw, xy_true)
        err = np.linalg.norm(np.cross(cam.line_of_sight(c_xy), v_cam), axis=-1) / ARCSEC
        err_sw = np.linalg.norm(np.cross(cam.line_of_sight(s_xy), v_cam), axis=-1) / ARCSEC
        err_vs = np.linalg.norm(np.cross(cam.line_of_sight(c_xy), cam.line_of_sight(s_xy)), axis=-1) / ARCSEC
        peak = np.array([sw.electrons[int(round(y)) - 2:int(round(y)) + 3, int(round(x)) - 2:int(round(x)) + 3].max()
                         for x, y in xy_true])
        ph = (peak < 0.8 * cam.sensor.full_well_e) & (s_f > 0) & (c_f > 0)
        dmag = -2.5 * np.log10(c_f[ph] / s_f[ph])
        res[label] = {"n_stars": int(len(err)), "within_5_arcsec": float(np.mean(err < 5.0)), "rms_arcsec": float(np.sqrt(np.mean(err ** 2))),
                      "max_arcsec": float(err.max()), "software_rms_arcsec": float(np.sqrt(np.mean(err_sw ** 2))),
                      "vs_software_rms_arcsec": float(np.sqrt(np.mean(err_vs ** 2))), "vs_software_max_arcsec": float(err_vs.max()),
                      "vs_software_within_5_arcsec": float(np.mean(err_vs < 5.0)),
                      "n_photometry": int(ph.sum()), "dmag_rms": float(np.sqrt(np.mean(dmag ** 2))), "dmag_bias": float(np.mean(dmag))}
    res["v_max"] = v_max
    return res
