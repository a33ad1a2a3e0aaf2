"""Built-in scenes. Each has a YAML twin in ``docs/examples/`` (tested to give the same scene).

``default``: the paper camera (Andreis et al. (2024), Table 4) on an Earth-Mars cruise, 2027-02-01 TDB,
1.2 AU from the Sun between the Earth and Mars (Mars is near opposition, 2027-02-19), moving at
1.05 x the local circular speed in the ecliptic; the camera points at Mars (V about -1.7 from
there, 157 deg from the Sun). ``point_at: auto`` would pick the brightest planet outside the Sun
exclusion angle instead (Venus, that day).
"""

from __future__ import annotations

import copy

from skynav.infra.errors import ConfigValueError

from .config import scene_spec_from_mapping

DEFAULT_SCENE = {
    "epoch": "2027-02-01T00:00:00",
    "observer": {
        "position_km": [-128731399.4, 113269566.7, 51647643.2],
        "velocity_km_s": [-19.9093, -18.773, -8.1391],
    },
    "attitude": {"point_at": "mars", "twist_deg": 0.0},
    "camera": {"preset": "paper"},
    "visibility": {"limiting_v_mag": 7.0, "sun_exclusion_deg": 20.0},
    "render": {"catalog_limiting_v_mag": 9.0, "cosmic_rays_per_frame": 1.0, "seed": 1},
}

#: Ten days after an Earth departure, 1.2 million km out, looking back: the Earth (~31 px across)
#: at 58 deg phase and the Moon (~8 px) 6 deg from it, both resolved and ray-traced by Mitsuba.
EARTH_DEPARTURE_SCENE = {
    "epoch": "2026-12-05T00:00:00",
    "observer": {
        "relative_to": "earth",
        "position_km": [-1161280.1, -240597.3, -183143.3],
        "velocity_km_s": [-1.2, -0.25, -0.19],
    },
    "attitude": {"point_at": "earth", "twist_deg": 0.0},
    "camera": {"preset": "paper", "exposure_s": 0.01},
    "render": {"catalog_limiting_v_mag": 9.0, "seed": 2},
}

PRESETS = {"default": DEFAULT_SCENE, "earth_departure": EARTH_DEPARTURE_SCENE}


def preset_mapping(name: str = "default") -> dict:
    """A deep copy of a built-in scene mapping (the same keys a scene YAML file has)."""
    if name not in PRESETS:
        raise ConfigValueError("scene", name, "a YAML file or one of the presets: " + ", ".join(PRESETS))
    return copy.deepcopy(PRESETS[name])


def default_scene_spec():
    """The ``default`` built-in scene: the paper camera on an Earth-Mars cruise, pointing at Mars.

    2027-02-01 TDB, 1.2 AU from the Sun (module docstring); the same scene as
    ``docs/examples/default_scene.yaml``.

    Returns
    -------
    SceneSpec
        A new spec (the camera of Andreis et al. (2024), Table 4), ready for
        :func:`~skynav.scenes.scene.build_from_spec`.

    Examples
    --------
    >>> from skynav.scenes import default_scene_spec
    >>> spec = default_scene_spec()
    >>> spec.epoch_tdb_iso, spec.attitude.point_at, spec.camera.width
    ('2027-02-01T00:00:00.000', 'mars', 1024)
    """
    return scene_spec_from_mapping(preset_mapping("default"))
