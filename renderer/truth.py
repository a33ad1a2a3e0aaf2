"""Ground truth of a rendered frame, schema ``skynav.frame/2`` (docs/conventions.md "Files").

Version 2 (PSF models) adds ``camera.psf`` and, for each star and drawn body,
``centre_of_light_xy``: the first moment of its drawn (PSF-blurred, streaked) image, beside its
geometric ``xy``, so an asymmetric PSF's bias (coma) is in the ground truth.

Built from the scene (the truth: exact light-time, deflection, relativistic aberration) and from
what the renderer drew (electrons per source, cosmic rays, seeds). Extra keys beyond the fixed
ones are welcome; the fixed names are read by outside tools.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from skynav.scenes import frames
from skynav.scenes.timescales import time_from_tdb_seconds

SCHEMA = "skynav.frame/2"


def _seed_record(seed):
    if seed is None:
        return None
    if isinstance(seed, np.random.SeedSequence):
        return {"entropy": seed.entropy if isinstance(seed.entropy, int) else list(seed.entropy),
                "spawn_key": list(seed.spawn_key)}
    if isinstance(seed, (list, tuple)):
        return [int(s) for s in seed]
    return int(seed)


def _star_records(stars, expected) -> list:
    """The truth's ``stars``: one record per star in the field of view, with its electrons and,
    when the renderer drew them, its centre of light and the fraction of its light drawn."""
    star_electrons = expected.star_electrons
    in_fov = np.asarray(stars.in_fov, dtype=bool)
    sel = np.flatnonzero(in_fov)
    # one tolist() per column, then zip: far cheaper than per-star conversions
    cols = {
        "hip": stars.hip[sel].astype(int).tolist(),
        "v_mag": stars.v_mag[sel].astype(float).tolist(),
        "b_v": stars.b_v[sel].astype(float).tolist(),
        "teff_k": stars.teff_k[sel].astype(float).tolist(),
        "u_icrs": stars.u_icrs[sel].tolist(),
        "xy": stars.xy[sel].tolist(),
        "xy_start": stars.xy_start[sel].tolist(),
        "xy_end": stars.xy_end[sel].tolist(),
        "electrons": np.asarray(star_electrons, dtype=float)[sel].tolist(),
    }
    col = getattr(expected, "star_centre_of_light", None)
    if col is not None:
        col_sel = np.asarray(col, dtype=float)[sel]
        rows = col_sel.tolist()
        for i in np.flatnonzero(~np.isfinite(col_sel).all(axis=1)):  # a star not drawn: null, not NaN
            rows[i] = [v if math.isfinite(v) else None for v in rows[i]]
        cols["centre_of_light_xy"] = rows
    frac = getattr(expected, "star_fraction_drawn", None)
    if frac is not None:  # a truncated kernel: the share of each star's electrons its stamps hold
        cols["flux_fraction_drawn"] = [v if math.isfinite(v) else None for v in np.asarray(frac, dtype=float)[sel].tolist()]
    names = tuple(cols)
    star_list = [dict(zip(names, row)) for row in zip(*cols.values())]
    return star_list


def _body_record(b, expected) -> dict:
    """The truth's record of one body: where it is, how it was drawn (Mitsuba, a point or not
    at all) and, when drawn, its centre of light and the fraction of its light drawn."""
    body_electrons = expected.body_electrons
    resolved = expected.resolved
    body_photocentre = expected.body_photocentre
    d = {
        "name": b.name,
        "xy": list(b.xy),
        "xy_geometric": list(b.xy_geometric),
        "xy_light_time": list(b.xy_light_time),
        "xy_start": list(b.xy_start),
        "xy_end": list(b.xy_end),
        "u_icrs": list(b.u_icrs),
        "u_geometric": list(b.u_geometric),
        "u_light_time": list(b.u_light_time),
        "light_time_s": b.light_time_s,
        "distance_km": b.distance_km,
        "position_km": list(b.position_km),
        "radius_km": b.radius_km,
        "v_mag": b.v_mag,
        "phase_angle_deg": math.degrees(b.phase_angle_rad),
        "elongation_deg": math.degrees(b.elongation_rad),
        "aberration_arcsec": b.aberration_arcsec,
        "angular_diameter_px": b.angular_diameter_px,
        "in_fov": b.in_fov,
        "visible": b.visible,
        "resolved": b.resolved,
        "electrons": float(body_electrons.get(b.name, 0.0)),
    }
    bcol = (getattr(expected, "body_centre_of_light", None) or {}).get(b.name)
    if bcol is not None and np.all(np.isfinite(bcol)):
        d["centre_of_light_xy"] = [float(bcol[0]), float(bcol[1])]
    bfrac = (getattr(expected, "body_fraction_drawn", None) or {}).get(b.name)
    if bfrac is not None and math.isfinite(bfrac):
        d["flux_fraction_drawn"] = bfrac
    img = resolved.get(b.name)
    if img is not None:
        d["rendered_as"] = "mitsuba"
        d["centre_of_figure_xy"] = list(map(float, img.centre_of_figure_xy))
        d["photocentre_xy"] = list(map(float, img.photocentre_xy))
        d["radius_px"] = float(img.radius_px)
        d["electrons_raw"] = float(img.electrons_raw_total)
        d["mitsuba_variant"] = img.variant
        d["mitsuba_seeds"] = [int(v) for v in img.seeds]
    else:
        d["rendered_as"] = "point" if b.in_fov else "none"
        pc = (body_photocentre or {}).get(b.name)
        if pc is not None:
            d["photocentre_xy"] = [float(pc[0]), float(pc[1])]
    return d


def frame_truth(scene, expected, detection, *, seed, options) -> dict:
    """The ground-truth dict of one frame (JSON-ready apart from numpy scalars/arrays).

    Parameters
    ----------
    scene : skynav.scenes.scene.Scene
        The rendered scene (epoch, observer, attitude, camera, stars, bodies).
    expected : skynav.renderer.expected.ExpectedImage
        Electrons per source, the Mitsuba crops and the variant that made them.
    detection : skynav.renderer.render.Detection
        The cosmic-ray hits and the sensor backend that ran.
    seed : int, sequence of int, numpy.random.SeedSequence or None
        The frame's seed, as given to :func:`~skynav.renderer.render.render`.
    options : skynav.renderer.options.RenderOptions
        The options the frame was rendered with.

    Returns
    -------
    dict
        ``render`` holds the options as requested plus ``backend_used`` (``"llvm"`` or
        ``"numpy"``) and ``mitsuba_variant`` (None when no body was ray-traced); each
        ``cosmic_rays`` record the hit's whole track (:meth:`CosmicRayHits.to_ground_truth`).
        Keys, names and units: docs/conventions.md "Files" (``skynav.frame/2``).

    Examples
    --------
    >>> import dataclasses
    >>> from skynav.renderer import RenderOptions, render
    >>> from skynav.scenes import build_from_spec, default_scene_spec
    >>> spec = default_scene_spec()   # the paper camera, pointing at Mars
    >>> camera = spec.camera.replace(width=64, height=64, pixel_pitch_um=spec.camera.pixel_pitch_um * 16)
    >>> scene = build_from_spec(dataclasses.replace(spec, camera=camera))   # 64 px, 20 deg
    >>> from skynav.datasets import validate_truth
    >>> from skynav.renderer import detect, expected_image, frame_truth
    >>> opts = RenderOptions(backend="numpy")
    >>> rng = np.random.default_rng(1)
    >>> ex = expected_image(scene, rng=rng, options=opts)
    >>> truth = frame_truth(scene, ex, detect(ex, scene.camera, rng, opts), seed=1, options=opts)
    >>> truth["render"]["backend_used"], validate_truth(truth)
    ('numpy', [])
    """
    cam = scene.camera
    t = time_from_tdb_seconds(scene.epoch_tdb_s)
    R = scene.R_cam_icrs
    ra, dec, twist = frames.dcm_to_radec_twist(R)
    star_list = _star_records(scene.stars, expected)
    body_list = [_body_record(b, expected) for b in scene.bodies]
    render = dataclasses.asdict(options)
    render["backend_used"] = detection.backend
    render["mitsuba_variant"] = expected.mitsuba_variant
    projection = expected.projection
    if projection is not cam:
        render["projection"] = type(projection).__name__
    out = {
        "schema": SCHEMA,
        "epoch": {"tdb_iso": t.isot, "jd_tdb": float(t.jd1 + t.jd2), "tdb_seconds_past_j2000": scene.epoch_tdb_s},
        "observer": {"position_km": scene.position_km.tolist(), "velocity_km_s": scene.velocity_km_s.tolist()},
        "attitude": {
            "R_cam_icrs": R.tolist(),
            "q_cam_icrs": frames.dcm_to_quat(R).tolist(),
            "angular_velocity_rad_s": np.asarray(scene.angular_velocity_rad_s).tolist(),
            "ra_deg": math.degrees(ra), "dec_deg": math.degrees(dec), "twist_deg": math.degrees(twist),
            "quaternion_convention": "scalar first (q0, q1, q2, q3); A = (q0^2 - qv.qv) I + 2 qv qv^T - 2 q0 [qv x] "
                                     "(Andreis et al. 2023a, Eq. 14); v_cam = A v_icrs",
        },
        "camera": cam.to_dict(),
        "render": render,
        "sun": {"u_icrs": np.asarray(scene.sun_u_icrs).tolist(), "boresight_angle_deg": math.degrees(scene.boresight_sun_angle_rad)},
        "visibility": scene.visibility.to_dict(),
        "catalog_limiting_v_mag": scene.catalog_limiting_v_mag,
        "pixel_convention": "x = column, y = row, centre of the top-left pixel at (0, 0)",
        "stars": star_list,
        "bodies": body_list,
        "cosmic_rays": detection.hits.to_ground_truth(),
        "seeds": {"frame": _seed_record(seed), "sensor_pattern": cam.sensor.pattern_seed},
    }
    if getattr(scene, "data_files", ()):  # the mission files read: name as given and SHA-256
        out["data_files"] = [dict(r) for r in scene.data_files]
    return out

