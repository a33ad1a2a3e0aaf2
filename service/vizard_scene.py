"""A skynav scene from the state Basilisk's ``vizInterface`` sends: the geometry of the Vizard endpoint.

:func:`scene_mapping` turns one camera of one ``VizMessage`` (:mod:`skynav.service.vizard_schema`)
into a scene mapping, the keys of a scene file, which ``skynav render`` reads as it would the file:

- **epoch**: the scenario's UTC calendar date (sent with the first message only, kept by the
  endpoint) plus the message's ``simTimeElapsed``, in TDB, to the millisecond (the scene file's
  precision);
- **observer**: the spacecraft's position ``r_BN_N`` (m) plus the camera's offset on the body,
  ``[BN]^T cameraPos_B``, and its velocity (m/s), in km and km/s. Basilisk's inertial frame is
  J2000, which is ICRS to the milliarcsecond. Its origin is a body's centre when the scenario links
  no SPICE data (each body's position is then zero): such a body, **at the origin**, becomes the
  observer's ``relative_to``, so the body sits at its DE421 position at the epoch and the Sun, the
  phase and the stars are right. With no body at the origin the frame is taken as barycentric;
- **attitude**: ``R_cam_icrs = [CB][BN]``, ``[BN]`` from the spacecraft's MRP sigma_BN and
  ``[CB]`` from the camera's ``cameraDir_B``, which is the MRP of Unity's camera frame Cu relative
  to B: ``[CuB] = [CuC][CB]`` with ``[CuC]`` the MRP (1/3, 1/3, -1/3), so ``[CB] = [CuC]^T [CuB]``.
  Basilisk's camera frame C is skynav's (+z the boresight, +x along columns, +y along rows);
- **camera**: Basilisk's geometry (``resolution`` [width, height], ``fieldOfView`` edge to edge along
  the image height in degrees, square pixels, the principal point at the centre) on the optics and
  sensor of the base camera (skynav's default, or the user's), whose pixel pitch sets the focal
  length ``f = (H/2) / tan(fov/2)`` px;
- **render**: the base scene's render settings, with the message's frame number as the seed.

MRPs follow Schaub and Junkins, *Analytical Mechanics of Space Systems* (4th ed.), Eq. 3.154:
``[C] = I + (8 [s x]^2 - 4 (1 - s.s) [s x]) / (1 + s.s)^2`` (the passive matrix, as Basilisk's
``MRP2C``).
"""

from __future__ import annotations

import math

import numpy as np

from skynav.infra.errors import ConfigValueError
from skynav.scenes.config import camera_from_mapping, scene_spec_from_mapping
from skynav.scenes.ephemeris_jpl import BODIES
from skynav.scenes.frames import dcm_to_quat

from .vizard_schema import CameraConfig

#: the MRP of Unity's camera frame Cu relative to Basilisk's camera frame C (vizInterface adds it)
SIGMA_CU_C = (1.0 / 3.0, 1.0 / 3.0, -1.0 / 3.0)


def mrp_to_dcm(sigma) -> np.ndarray:
    """The passive direction cosine matrix of a modified Rodrigues parameter set, shape (3, 3)."""
    s = np.asarray(sigma, dtype=float)
    if s.shape != (3,) or not np.all(np.isfinite(s)):
        raise ValueError(f"an MRP needs 3 finite numbers, got {sigma!r}")
    x = np.array([[0.0, -s[2], s[1]], [s[2], 0.0, -s[0]], [-s[1], s[0], 0.0]])
    ss = float(s @ s)
    return np.eye(3) + (8.0 * x @ x - 4.0 * (1.0 - ss) * x) / (1.0 + ss) ** 2


def camera_dcm_from_unity(camera_dir_b) -> np.ndarray:
    """``[CB]``, Basilisk's camera frame relative to the body, from ``cameraDir_B`` (``[CuB]``)."""
    return mrp_to_dcm(SIGMA_CU_C).T @ mrp_to_dcm(camera_dir_b)


def skynav_body(name: str) -> str | None:
    """skynav's name of a Basilisk celestial body (``mars barycenter`` -> ``mars``), None if unknown."""
    key = name.strip().lower().replace("_", " ")
    for suffix in (" barycenter", " barycentre"):
        if key.endswith(suffix):
            key = key[: -len(suffix)]
    return key if key in BODIES else None


def origin_body(bodies) -> tuple[str | None, str | None]:
    """``(skynav body at the origin or None, a note or None)`` among a message's celestial bodies.

    A body whose position is exactly zero is at the origin (Basilisk writes zero where no SPICE
    data is linked). Several at the origin: the one body other than the Sun, if there is one,
    else the first; the note says which was taken.
    """
    at_origin = [b.bodyName for b in bodies if len(b.position) == 3 and not any(b.position)]
    known = [n for n in at_origin if skynav_body(n) is not None]
    if not known:
        note = None if not at_origin else f"bodies at the origin not in DE421 ({', '.join(at_origin)}): frame taken as barycentric"
        return None, note
    if len(known) == 1:
        return skynav_body(known[0]), None
    planets = [n for n in known if skynav_body(n) != "sun"]
    chosen = planets[0] if len(planets) == 1 else known[0]
    return skynav_body(chosen), (f"several bodies at the origin ({', '.join(at_origin)}); the frame is "
                                 f"taken as centred on {chosen}")


def epoch_utc_iso(epoch) -> str:
    """The ISO UTC string of an ``EpochDateTime`` (year, month, day, hours, minutes, seconds)."""
    if not (1 <= epoch.month <= 12 and 1 <= epoch.day <= 31 and 0 <= epoch.hours < 24 and 0 <= epoch.minutes < 60
            and 0 <= epoch.seconds < 61):
        raise ConfigValueError("epoch", f"{epoch.year}-{epoch.month}-{epoch.day} {epoch.hours}:{epoch.minutes}:"
                               f"{epoch.seconds}", "a UTC calendar date")
    whole = int(math.floor(epoch.seconds))
    return (f"{epoch.year:04d}-{epoch.month:02d}-{epoch.day:02d}T{epoch.hours:02d}:{epoch.minutes:02d}:"
            f"{whole:02d}{f'{epoch.seconds - whole:.9f}'[1:]}")


def frame_epoch_tdb_iso(epoch_utc_iso_text: str, sim_time_ns: float) -> str:
    """The TDB ISO date (to the ms) ``sim_time_ns`` after the scenario's UTC epoch."""
    from astropy.time import Time, TimeDelta   # heavy (0.7 s): only the endpoint's frames need it

    t = Time(epoch_utc_iso_text, scale="utc") + TimeDelta(sim_time_ns * 1e-9, format="sec")
    return t.tdb.isot   # isot: milliseconds, the scene file's precision


def camera_section(base: dict, config) -> dict:
    """The ``camera`` section: Basilisk's geometry of ``config`` (a ``CameraConfig``) on ``base``."""
    if len(config.resolution) != 2 or min(config.resolution) < 1:
        raise ConfigValueError(f"camera {config.cameraID}.resolution", list(config.resolution),
                               "[width, height], two positive integers")
    if not 0 < config.fieldOfView < 180:
        raise ConfigValueError(f"camera {config.cameraID}.fieldOfView", config.fieldOfView,
                               "degrees in (0, 180), edge to edge along the image height")
    width, height = (int(v) for v in config.resolution)
    fov_y = math.radians(config.fieldOfView)
    given = {k: base[k] for k in ("width", "height", "fov_deg") if k in base}
    section = {k: v for k, v in base.items() if k not in ("width", "height", "fov_deg", "focal_length_mm", "K",
                                                          "cx", "cy", "pixel_pitch_y_um")}
    pitch_um = camera_from_mapping(section).pixel_pitch_um
    if given:
        check_geometry(given, width, height, config.fieldOfView)
    f_px = 0.5 * height / math.tan(fov_y / 2)
    section.setdefault("pixel_pitch_um", pitch_um)
    section.update(width=width, height=height, focal_length_mm=f_px * pitch_um * 1e-3)
    return section


def check_geometry(given: dict, width: int, height: int, fov_y_deg: float) -> None:
    """Refuse a camera file whose size or field of view is not Basilisk's (one line)."""
    fov_x_deg = math.degrees(2 * math.atan(width / height * math.tan(math.radians(fov_y_deg) / 2)))
    want = {"width": width, "height": height, "fov_deg": fov_x_deg}
    bad = [k for k, v in given.items() if not math.isclose(float(v), want[k], rel_tol=1e-6)]
    if bad:
        said = ", ".join(f"{k} {given[k]:g}" for k in bad)
        sent = ", ".join(f"{k} {want[k]:.6g}" for k in bad)
        raise ConfigValueError("camera", said, f"Basilisk's camera ({sent}; fov_deg is horizontal, Basilisk's "
                               f"fieldOfView {fov_y_deg:g} deg vertical)")


def scene_mapping(message, config, spacecraft, *, epoch_utc: str, base: dict, origin: str | None) -> dict:
    """The scene mapping of camera ``config`` on ``spacecraft`` at ``message``'s time.

    ``base`` holds the scene's ``camera``, ``visibility`` and ``render`` sections (the user's).
    """
    r_m = np.asarray(spacecraft.position, dtype=float)
    v_m_s = np.asarray(spacecraft.velocity, dtype=float)
    if r_m.shape != (3,) or v_m_s.shape != (3,) or len(spacecraft.rotation) != 3:
        raise ConfigValueError(f"spacecraft {spacecraft.spacecraftName!r}", "position/velocity/rotation",
                               "3 numbers each")
    bn = mrp_to_dcm(spacecraft.rotation)
    offset_b = np.asarray(config.cameraPos_B, dtype=float) if len(config.cameraPos_B) == 3 else np.zeros(3)
    cb = camera_dcm_from_unity(config.cameraDir_B) if len(config.cameraDir_B) == 3 else np.eye(3)
    q = dcm_to_quat(cb @ bn)
    observer = {"position_km": ((r_m + bn.T @ offset_b) / 1e3).tolist(), "velocity_km_s": (v_m_s / 1e3).tolist()}
    if origin is not None:
        observer = {"relative_to": origin, **observer}
    render = dict(base.get("render") or {})
    render["seed"] = int(message.currentTime.frameNumber)
    mapping = {
        "epoch": frame_epoch_tdb_iso(epoch_utc, message.currentTime.simTimeElapsed),
        "observer": observer,
        "attitude": {"q_cam_icrs": [float(x) for x in q]},
        "camera": camera_section(dict(base.get("camera") or {"preset": "paper"}), config),
    }
    if base.get("visibility"):
        mapping["visibility"] = dict(base["visibility"])
    mapping["render"] = render
    return mapping


def check_base(base: dict) -> None:
    """Validate the user's sections as a scene file would, before any message comes: a probe
    camera with the base's own size and field of view (or 64 x 64 px, 40 deg) on a fixed pose.

    Raises the scene file's one-line error (an unknown key, a bad value)."""
    cam = dict(base.get("camera") or {"preset": "paper"})
    try:
        width, height = int(cam.get("width", 64)), int(cam.get("height", 64))
        fov_x = math.radians(float(cam.get("fov_deg", 2 * math.degrees(math.atan(width / height * math.tan(
            math.radians(20.0)))))))
    except (TypeError, ValueError):
        raise ConfigValueError("camera", {k: cam[k] for k in ("width", "height", "fov_deg") if k in cam},
                               "width and height in px, fov_deg in degrees") from None
    fov_y_deg = math.degrees(2 * math.atan(height / width * math.tan(fov_x / 2))) if 0 < fov_x < math.pi else 0.0
    probe = CameraConfig(cameraID=0, fieldOfView=fov_y_deg, resolution=[width, height])
    mapping = {"epoch": "2027-02-01T00:00:00", "observer": {"position_km": [1.5e8, 0.0, 0.0],
                                                            "velocity_km_s": [0.0, 0.0, 0.0]},
               "attitude": {"q_cam_icrs": [1.0, 0.0, 0.0, 0.0]}, "camera": camera_section(cam, probe),
               "render": dict(base.get("render") or {})}
    if base.get("visibility"):
        mapping["visibility"] = dict(base["visibility"])
    scene_spec_from_mapping(mapping)
