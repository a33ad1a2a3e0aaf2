"""skynav.scenes: what is out there, and how it projects.

Epochs and ephemerides, the star catalogue, planet photometry, spacecraft state and attitude,
the camera and the hardware-in-the-loop facility, and the scene that ties them together. Pure computation, no images.

Public API at package level (listed in ``__all__``), as in Skyfield or GalSim::

    from skynav.scenes import Camera, build_from_spec, default_scene_spec

    scene = build_from_spec(default_scene_spec())
    print(scene.camera.width, len(scene.stars.xy))

Every name loads its module on first use (module ``__getattr__``, PEP 562), so ``import
skynav.scenes`` costs nothing beyond the package and a part that needs only the errors or the
constants does not load the ephemeris, the catalogue or astropy. The modules remain importable
as before (``skynav.scenes.camera``, ...).
"""

import importlib as _importlib

# name -> module that defines it (of this package, or a full dotted name); imported on first
# access. No module may share a name with an entry here: importing a submodule binds its name on
# the package, which would hide the entry.
_LAZY = {
    # the scene
    "Scene": "scene", "SkyBody": "sky", "StarsInView": "scene", "BodyInView": "scene",
    "build_scene": "scene", "build_from_spec": "scene", "resolve_spec": "scene", "sky_bodies": "sky",
    "SceneSpec": "config", "AttitudeSpec": "config", "load_scene_file": "scene_files", "read_scene_file": "scene_files",
    "OverrideError": "overrides", "parse_override": "overrides", "apply_overrides": "overrides",
    "dataclass_from_overrides": "overrides",
    "default_scene_spec": "presets",
    # camera and facility
    "Camera": "camera", "SensorParams": "camera", "BrownConrady": "distortion", "paper_camera": "camera",
    "Projection": "projection", "VisibilityCriteria": "visibility",
    "Facility": "facility", "Screen": "screen", "facility_from_mapping": "facility", "screen_preset": "facility",
    "screen_small_preset": "facility",
    "GaussianPSFModel": "psf", "AiryPSFModel": "psf", "OpticalPSFModel": "psf", "TabulatedPSFModel": "psf_measured",
    "psf_from_dict": "psf_measured",
    # ephemerides, time, catalogue, photometry
    "Ephemeris": "ephemeris_jpl", "default_ephemeris": "ephemeris_jpl",
    "to_time": "timescales", "tdb_seconds": "timescales", "time_from_tdb_seconds": "timescales",
    "StarCatalog": "catalog_hipparcos", "load_catalog": "catalog_hipparcos",
    "planet_v_mag": "photometry", "phase_angle_rad": "photometry",
    "BodyDirections": "apparent", "apparent_body": "apparent", "apparent_bodies": "apparent",
    "apparent_star_directions": "apparent",
    # frames (docs/conventions.md: passive R_cam_icrs, scalar-first quaternions)
    "radec_to_unit": "frames", "unit_to_radec": "frames", "radec_twist_to_dcm": "frames",
    "dcm_to_radec_twist": "frames", "quat_to_dcm": "frames", "dcm_to_quat": "frames", "point_boresight": "frames",
    # dynamics
    "ForceModel": "dynamics", "Trajectory": "dynamics", "propagate": "dynamics", "propagate_stm": "dynamics",
    "LambertSolution": "lambert", "solve_lambert": "lambert",
    # errors
    "SceneFileError": "errors", "MovedKeyError": "errors", "EphemerisRangeError": "errors",
    "UnknownBodyError": "errors", "LambertError": "errors", "ObserverInsideBodyError": "errors",
    # skynav's own error class and the errors every room raises (their home: skynav.infra.errors)
    "SkynavError": "skynav.infra.errors", "SkynavWarning": "skynav.infra.errors",
    "ConfigValueError": "skynav.infra.errors", "DataFileError": "skynav.infra.errors",
}

__all__ = sorted(_LAZY)


#: names that were renamed: the old one is refused naming the new ("bench" is the benchmark commands)
_RENAMED = {"bench_preset": "screen_preset", "bench_small_preset": "screen_small_preset"}


def __getattr__(name):
    module = _LAZY.get(name)
    if module is None:
        if name in _RENAMED:
            raise AttributeError(f"skynav.scenes.{name} is now {_RENAMED[name]} (the facility presets are screen and "
                                 "screen_small; 'bench' means only the benchmark commands)")
        raise AttributeError(f"module 'skynav.scenes' has no attribute {name!r}")
    value = getattr(_importlib.import_module(module if module.startswith("skynav.") else f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
