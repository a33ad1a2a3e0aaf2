"""Dataset recipes: validated, YAML-able mappings, each kind with a built-in preset.

A recipe is a plain mapping (parsed YAML or a Python dict). :func:`validate_recipe` checks every
key, fills defaults and returns the *normalised* mapping (plain JSON types, angles in degrees as
in files) that is stored in ``manifest.json`` and compared on resume; errors are
:class:`~skynav.datasets.errors.RecipeError` naming the dotted key and the allowed range.

Common keys::

    kind: montecarlo | sequence | scenes
    frames: 100              # montecarlo: required; sequence: optional (first N of the plan)
    seed: 20260101           # master seed (non-negative integer)
    camera: {preset: paper}  # as in scene files (skynav.scenes.config.camera_from_mapping)
    visibility: {limiting_v_mag: 7.0, sun_exclusion_deg: 20.0}   # detection rule (visible flag, filters)
    catalog_limiting_v_mag: 9.0                                   # star catalogue cut
    render: {cosmic_rays_per_frame: 0}   # the scene file's render: keys (skynav.scenes.config.RENDER_KEYS)
    formats: [png, exr, json]

``render:`` takes every render option a scene file takes and is validated by the same function
(:func:`~skynav.scenes.config.render_settings_from_mapping`): ``cosmic_rays_per_frame``,
``resolved_threshold_px``, ``mitsuba_spp`` and ``catalog_limiting_v_mag`` (the scene file's
spelling of the top-level key; the normalised recipe keeps it at the top). ``render.seed`` is
refused: frame k draws from ``SeedSequence([seed, k])``. The normalised recipe keeps only the
render keys that differ from their defaults, so a recipe that writes the defaults out is the same
dataset as one that leaves them out. :func:`recipe_yaml` writes a preset as a commented YAML file.

Kind-specific sections (``montecarlo:``, ``sequence:``, ``scenes:``) are documented in
``docs/datasets.md`` and in :data:`PRESETS`.
"""

from __future__ import annotations

import copy
import math
import os

import yaml

from skynav.infra.count_cap import cap_count
from skynav.scenes.config import (
    RENDER_KEYS,
    camera_from_mapping,
    render_settings_from_mapping,
    scene_spec_from_mapping,
    visibility_from_mapping,
)
from skynav.scenes.errors import MovedKeyError
from skynav.scenes.psf import resolve_psf_files
from skynav.scenes.scene_files import load_yaml
from skynav.scenes.timescales import to_time

from .errors import RecipeError

__all__ = ["KINDS", "PRESETS", "preset_recipe", "validate_recipe", "recipe_camera", "recipe_visibility", "load_recipe_file",
           "read_recipe_mapping", "recipe_render", "recipe_yaml", "RECIPE_RENDER_OPTIONS", "RECIPE_RENDER_KEYS"]

#: The ``render:`` keys that set :class:`~skynav.renderer.render.RenderOptions` fields of the same name.
RECIPE_RENDER_OPTIONS = ("cosmic_rays_per_frame", "mitsuba_spp")
#: The ``render:`` keys a recipe takes: the scene file's but ``seed`` (frame k's stream is fixed by the recipe's seed).
RECIPE_RENDER_KEYS = tuple(k for k in RENDER_KEYS if k != "seed")

KINDS = ("montecarlo", "sequence", "scenes")
FORMATS = ("png", "exr", "json", "fits")
FILTERS = ("visible_planet", "sun_outside_exclusion", "body_in_fov")
PLANETS = ("mercury", "venus", "earth", "mars", "jupiter", "saturn", "uranus", "neptune")

_MONTECARLO_DEFAULTS = {
    # Andreis et al. (2023a), Sec. V.A: Gaussian position about the barycentre, ecliptic J2000 axes (N frame)
    "epoch_start_tdb": "2026-01-01T00:00:00",
    "epoch_end_tdb": "2031-01-01T00:00:00",
    "position_sigma_au": [3.0, 3.0, 0.07],
    "attitude_frame": "ecliptic",
    "dec_3sigma_deg": math.degrees(0.6),
    "velocity": "circular",
    "min_sun_distance_au": 0.1,
    "keep": ["visible_planet"],
    "max_draws_per_frame": 2000,
}

_SEQUENCE_DEFAULTS = {
    # Earth-Mars ballistic transfer, late-2026 window; legs of Andreis et al. (2023b), Sec. IV, and Andreis et al. (2024), Sec. 4
    "departure_window_tdb": ["2026-10-01T00:00:00", "2027-01-15T00:00:00"],
    "tof_days": [180.0, 360.0],
    "grid_days": 5.0,
    "start_offset_days": 30.0,
    "legs": 10,
    "track_s": 3600.0,
    "cadence_s": 100.0,
    "slew_s": 1800.0,
    "propagate_s": 864000.0,
    "pair_limiting_v_mag": 7.0,
    "pair_elongation_min_deg": 20.0,
    "pointing_error_deg": 0.01,
    "jitter_rate_deg_s": 0.0,
    "angular_velocity_deg_s": [0.0, 0.0, 0.0],
    "twist_deg": 0.0,
    "spacecraft": {"mass_kg": 24.0, "area_m2": 0.25, "reflectivity_coefficient": 1.3},
    "relativity": True,
    "rtol": 1e-12,
    "trajectory_step_s": 3600.0,
}

PRESETS = {
    "montecarlo": {
        "kind": "montecarlo",
        "frames": 3000,
        "seed": 20230214,
        "camera": {"preset": "paper"},
        "catalog_limiting_v_mag": 9.0,
        "formats": ["png", "exr", "json"],
        "montecarlo": copy.deepcopy(_MONTECARLO_DEFAULTS),
    },
    "sequence": {
        "kind": "sequence",
        "seed": 20240101,
        "camera": {"preset": "paper"},
        "catalog_limiting_v_mag": 9.0,
        "formats": ["png", "exr", "json"],
        "sequence": copy.deepcopy(_SEQUENCE_DEFAULTS),
    },
    "scenes": {
        "kind": "scenes",
        "seed": 1,
        "camera": {"preset": "paper"},
        "catalog_limiting_v_mag": 9.0,
        "formats": ["png", "exr", "json"],
        "scenes": [
            {"epoch": "2027-03-15T00:00:00",
             "observer": {"position_km": [1.2e8, -9.0e7, -3.9e7], "velocity_km_s": [18.0, 21.0, 9.0]},
             "attitude": {"point_at": "mars"}},
            {"epoch": "2027-03-15T00:10:00",
             "observer": {"position_km": [1.2e8, -9.0e7, -3.9e7], "velocity_km_s": [18.0, 21.0, 9.0]},
             "attitude": {"ra_deg": 83.6, "dec_deg": 22.0, "twist_deg": 30.0}},
        ],
    },
}
"""The built-in recipes by kind (``montecarlo``, ``sequence``, ``scenes``): the mappings
:func:`preset_recipe` copies (units in the key names, angles in degrees, epochs in TDB)."""


def preset_recipe(kind: str) -> dict:
    """A fresh copy of the built-in recipe of a kind (``montecarlo``, ``sequence``, ``scenes``).

    Parameters
    ----------
    kind : str
        ``montecarlo`` (random scenes), ``sequence`` (a cruise's navigation legs) or ``scenes``
        (a list of scenes).

    Returns
    -------
    dict
        The recipe mapping (units in the key names, angles in degrees), to edit and pass to
        :func:`~skynav.datasets.runner.generate`.

    Raises
    ------
    RecipeError
        An unknown kind.

    Examples
    --------
    >>> from skynav.datasets import preset_recipe
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe["kind"], recipe["frames"], recipe["camera"]
    ('montecarlo', 3000, {'preset': 'paper'})
    """
    if kind not in PRESETS:
        raise RecipeError("kind", kind, "one of: " + ", ".join(KINDS))
    return copy.deepcopy(PRESETS[kind])


# ----------------------------------------------------------------------------- checkers
def _num(d, key, where, *, lo=-math.inf, hi=math.inf, lo_open=False, hi_open=False, integer=False):
    v = d[key]
    name = f"{where}.{key}" if where else key
    lo_s = ("(" if lo_open else "[") + (f"{lo:g}" if math.isfinite(lo) else "-inf")
    hi_s = (f"{hi:g}" if math.isfinite(hi) else "inf") + (")" if hi_open else "]")
    allowed = ("an integer" if integer else "a number") + f" in {lo_s}, {hi_s}"
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise RecipeError(name, v, allowed)
    if integer and int(v) != v:
        raise RecipeError(name, v, allowed)
    if v < lo or v > hi or (lo_open and v == lo) or (hi_open and v == hi):
        raise RecipeError(name, v, allowed)
    return int(v) if integer else float(v)


def _list(d, key, where, n, **kw):
    v = d[key]
    name = f"{where}.{key}"
    if not isinstance(v, (list, tuple)) or len(v) != n:
        raise RecipeError(name, v, f"a list of {n} numbers")
    return [_num({str(i): x}, str(i), name, **kw) for i, x in enumerate(v)]


def _epoch(value, name) -> str:
    try:
        t = to_time(str(value)).tdb
        iso = t.isot
        jd = float(t.jd)
    except Exception:
        raise RecipeError(name, value, "an ISO date in TDB, e.g. 2026-11-01T00:00:00") from None
    if not 2415020.5 <= jd <= 2469807.5:  # DE421 covers 1899-07-29..2053-10-09
        raise RecipeError(name, value, "an epoch inside DE421 (1900..2053)")
    return iso


def _section(recipe, key, defaults):
    sec = recipe.get(key, {})
    if sec is None:
        sec = {}
    if not isinstance(sec, dict):
        raise RecipeError(key, sec, "a mapping")
    for k in sec:
        if k not in defaults:
            raise RecipeError(f"{key}.{k}", sec[k], "no such key; allowed keys: " + ", ".join(sorted(defaults)))
    out = copy.deepcopy(defaults)
    out.update(copy.deepcopy(sec))
    return out


def _validate_montecarlo(recipe) -> dict:
    s = _section(recipe, "montecarlo", _MONTECARLO_DEFAULTS)
    w = "montecarlo"
    s["epoch_start_tdb"] = _epoch(s["epoch_start_tdb"], f"{w}.epoch_start_tdb")
    s["epoch_end_tdb"] = _epoch(s["epoch_end_tdb"], f"{w}.epoch_end_tdb")
    if s["epoch_end_tdb"] < s["epoch_start_tdb"]:
        raise RecipeError(f"{w}.epoch_end_tdb", s["epoch_end_tdb"], f">= epoch_start_tdb ({s['epoch_start_tdb']})")
    s["position_sigma_au"] = _list(s, "position_sigma_au", w, 3, lo=0.0, hi=100.0)
    if s["attitude_frame"] not in ("ecliptic", "icrs"):
        raise RecipeError(f"{w}.attitude_frame", s["attitude_frame"], "one of: ecliptic, icrs")
    s["dec_3sigma_deg"] = _num(s, "dec_3sigma_deg", w, lo=0.0, hi=270.0)
    if s["velocity"] not in ("circular", "zero"):
        raise RecipeError(f"{w}.velocity", s["velocity"], "one of: circular, zero")
    s["min_sun_distance_au"] = _num(s, "min_sun_distance_au", w, lo=0.0, hi=100.0)
    keep = s["keep"]
    if isinstance(keep, str):
        keep = [keep]
    if not isinstance(keep, list) or any(k not in FILTERS for k in keep):
        raise RecipeError(f"{w}.keep", s["keep"], "a list of filters from: " + ", ".join(FILTERS))
    s["keep"] = list(keep)
    s["max_draws_per_frame"] = _num(s, "max_draws_per_frame", w, lo=1, hi=1e7, integer=True)
    return s


def _validate_sequence(recipe) -> dict:
    s = _section(recipe, "sequence", _SEQUENCE_DEFAULTS)
    w = "sequence"
    win = s["departure_window_tdb"]
    if not isinstance(win, (list, tuple)) or len(win) != 2:
        raise RecipeError(f"{w}.departure_window_tdb", win, "a list of two ISO dates (TDB)")
    s["departure_window_tdb"] = [_epoch(win[0], f"{w}.departure_window_tdb[0]"), _epoch(win[1], f"{w}.departure_window_tdb[1]")]
    if s["departure_window_tdb"][1] < s["departure_window_tdb"][0]:
        raise RecipeError(f"{w}.departure_window_tdb", win, "a start before the end")
    s["tof_days"] = _list(s, "tof_days", w, 2, lo=10.0, hi=2000.0)
    if s["tof_days"][1] < s["tof_days"][0]:
        raise RecipeError(f"{w}.tof_days", s["tof_days"], "[min, max] with min <= max")
    s["grid_days"] = _num(s, "grid_days", w, lo=0.1, hi=100.0)
    s["start_offset_days"] = _num(s, "start_offset_days", w, lo=1.0, hi=s["tof_days"][0])
    s["legs"] = _num(s, "legs", w, lo=1, hi=1000, integer=True)
    s["track_s"] = _num(s, "track_s", w, lo=0.0, hi=1e6, lo_open=True)
    s["cadence_s"] = _num(s, "cadence_s", w, lo=0.0, hi=s["track_s"], lo_open=True)
    s["slew_s"] = _num(s, "slew_s", w, lo=0.0, hi=1e6)
    s["propagate_s"] = _num(s, "propagate_s", w, lo=0.0, hi=1e9)
    s["pair_limiting_v_mag"] = _num(s, "pair_limiting_v_mag", w, lo=-30.0, hi=30.0)
    s["pair_elongation_min_deg"] = _num(s, "pair_elongation_min_deg", w, lo=0.0, hi=180.0)
    s["pointing_error_deg"] = _num(s, "pointing_error_deg", w, lo=0.0, hi=10.0)
    s["jitter_rate_deg_s"] = _num(s, "jitter_rate_deg_s", w, lo=0.0, hi=10.0)
    s["angular_velocity_deg_s"] = _list(s, "angular_velocity_deg_s", w, 3, lo=-10.0, hi=10.0)
    s["twist_deg"] = _num(s, "twist_deg", w, lo=-360.0, hi=360.0)
    sc = s["spacecraft"]
    if not isinstance(sc, dict) or set(sc) - {"mass_kg", "area_m2", "reflectivity_coefficient"}:
        raise RecipeError(f"{w}.spacecraft", sc, "a mapping with mass_kg, area_m2, reflectivity_coefficient")
    sc = {**_SEQUENCE_DEFAULTS["spacecraft"], **sc}
    s["spacecraft"] = {
        "mass_kg": _num(sc, "mass_kg", f"{w}.spacecraft", lo=0.0, hi=1e7, lo_open=True),
        "area_m2": _num(sc, "area_m2", f"{w}.spacecraft", lo=0.0, hi=1e4),
        "reflectivity_coefficient": _num(sc, "reflectivity_coefficient", f"{w}.spacecraft", lo=0.0, hi=2.0),
    }
    if not isinstance(s["relativity"], bool):
        raise RecipeError(f"{w}.relativity", s["relativity"], "true or false")
    s["rtol"] = _num(s, "rtol", w, lo=1e-14, hi=1e-6)
    s["trajectory_step_s"] = _num(s, "trajectory_step_s", w, lo=1.0, hi=1e7)
    return s


def validate_recipe(recipe) -> dict:
    """Check a recipe and return its normalised copy (defaults filled, JSON types).

    Parameters
    ----------
    recipe : dict
        A recipe mapping (:func:`preset_recipe`, or a parsed recipe file).

    Returns
    -------
    dict
        A new, normalised recipe; the input is not changed.

    Raises
    ------
    RecipeError
        Naming the dotted key, the value and what is allowed, e.g.
        ``montecarlo.position_sigma_au.2 = -1 is not allowed; expected a number in [0, 100]``.

    Examples
    --------
    >>> from skynav.datasets import RecipeError, preset_recipe, validate_recipe
    >>> sorted(validate_recipe(preset_recipe("sequence")))
    ['camera', 'catalog_limiting_v_mag', 'formats', 'kind', 'seed', 'sequence', 'visibility']
    >>> try:
    ...     validate_recipe({"kind": "survey"})
    ... except RecipeError as exc:
    ...     print(exc)
    kind = 'survey' is not allowed; expected one of: montecarlo, sequence, scenes
    """
    if not isinstance(recipe, dict):
        raise RecipeError("recipe", type(recipe).__name__, "a mapping with a 'kind' key")
    kind = recipe.get("kind")
    if kind not in KINDS:
        raise RecipeError("kind", kind, "one of: " + ", ".join(KINDS))
    allowed = {"kind", "frames", "seed", "camera", "visibility", "catalog_limiting_v_mag", "render", "formats", "name", kind}
    for k in recipe:
        if k == "star_mag_limit":
            raise MovedKeyError(k, recipe[k], "catalog_limiting_v_mag")
        if k not in allowed:
            raise RecipeError(k, recipe[k], "no such key; allowed keys: " + ", ".join(sorted(allowed)))
    out = {"kind": kind}
    if "name" in recipe:
        out["name"] = str(recipe["name"])
    if "seed" not in recipe:
        raise RecipeError("seed", None, "a non-negative integer master seed")
    out["seed"] = _num(recipe, "seed", "", lo=0, hi=2**63 - 1, integer=True)
    cam = recipe.get("camera", {"preset": "paper"})
    camera = camera_from_mapping(cam)  # raises ConfigValueError naming camera.<key>
    out["camera"] = copy.deepcopy(cam)
    vis = recipe.get("visibility", {})
    visibility_from_mapping(vis)  # raises ConfigValueError naming visibility.<key>
    out["visibility"] = {"limiting_v_mag": float(vis.get("limiting_v_mag", 7.0)),
                         "sun_exclusion_deg": float(vis.get("sun_exclusion_deg", 20.0))}
    render = _validate_render(recipe.get("render"), camera)
    render_mag = render.pop("catalog_limiting_v_mag", None)  # the scene file's spelling of the same cut
    mag = recipe.get("catalog_limiting_v_mag", 9.0 if render_mag is None else render_mag)
    out["catalog_limiting_v_mag"] = _num({"catalog_limiting_v_mag": mag}, "catalog_limiting_v_mag", "", lo=-2.0, hi=14.0)
    if render_mag is not None and render_mag != out["catalog_limiting_v_mag"]:
        raise RecipeError("render.catalog_limiting_v_mag", render_mag,
                          f"left out, or equal to catalog_limiting_v_mag ({out['catalog_limiting_v_mag']:g}): "
                          "both name the star catalogue cut")
    render = {k: v for k, v in render.items() if v != RENDER_KEYS[k][0]}
    if render:
        out["render"] = render
    fmts = recipe.get("formats", ["png", "exr", "json"])
    if isinstance(fmts, str):
        fmts = [fmts]
    if not isinstance(fmts, (list, tuple)) or not fmts or any(f not in FORMATS for f in fmts) or len(set(fmts)) != len(fmts):
        raise RecipeError("formats", fmts, "a list of distinct formats from: " + ", ".join(FORMATS))
    if "json" not in fmts:
        raise RecipeError("formats", fmts, "a list that includes json (the ground truth)")
    out["formats"] = [f for f in FORMATS if f in fmts]
    if kind == "montecarlo":
        if "frames" not in recipe:
            raise RecipeError("frames", None, "an integer >= 1 (number of frames)")
        out["frames"] = cap_count(_num(recipe, "frames", "", lo=1, hi=1e9, integer=True), "Monte Carlo frames")
        out["montecarlo"] = _validate_montecarlo(recipe)
    elif kind == "sequence":
        if recipe.get("frames") is not None:
            out["frames"] = _num(recipe, "frames", "", lo=1, hi=1e9, integer=True)
        out["sequence"] = _validate_sequence(recipe)
    else:
        scenes = recipe.get("scenes")
        if not isinstance(scenes, list) or not scenes:
            raise RecipeError("scenes", scenes, "a non-empty list of scene mappings")
        for i, sc in enumerate(scenes):
            try:
                scene_spec_from_mapping(sc)
            except RecipeError:
                raise
            except Exception as exc:  # re-raise naming the list item
                raise RecipeError(f"scenes[{i}]", "...", str(exc)) from None
            render = sc.get("render") or {}
            if "seed" in render:  # frame k's stream is SeedSequence([seed, k]); a scene cannot pick its own
                raise RecipeError(f"scenes[{i}].render.seed", render["seed"],
                                  "no per-scene seed in a dataset (frame k draws from SeedSequence([seed, k])); set the recipe's seed")
        out["scenes"] = copy.deepcopy(scenes)
        if recipe.get("frames") is not None and recipe["frames"] != len(scenes):
            raise RecipeError("frames", recipe["frames"], f"absent or equal to the number of scenes ({len(scenes)})")
        out["frames"] = len(scenes)
    return out


def _validate_render(rd, camera) -> dict:
    """The keys given in a recipe's ``render:`` mapping, validated as a scene file's are."""
    if isinstance(rd, dict) and "seed" in rd:  # frame k's stream is SeedSequence([seed, k])
        raise RecipeError("render.seed", rd["seed"], "no render seed in a recipe (frame k draws from "
                                                     "SeedSequence([seed, k])); set the recipe's top-level seed")
    return render_settings_from_mapping(rd, camera, key="render", fill=False, keys=RECIPE_RENDER_KEYS)


def recipe_render(recipe: dict) -> dict:
    """The render settings of a (validated) recipe, every key but ``seed`` (defaults filled).

    Examples
    --------
    >>> recipe_render({"render": {"cosmic_rays_per_frame": 0.0}})["cosmic_rays_per_frame"]
    0.0
    """
    given = recipe.get("render") or {}
    out = {k: given.get(k, RENDER_KEYS[k][0]) for k in RECIPE_RENDER_KEYS}
    out["catalog_limiting_v_mag"] = recipe.get("catalog_limiting_v_mag", out["catalog_limiting_v_mag"])
    return out


def recipe_camera(recipe: dict):
    """The :class:`~skynav.scenes.camera.Camera` of a (validated) recipe."""
    return camera_from_mapping(recipe.get("camera", {"preset": "paper"}))


def recipe_visibility(recipe: dict):
    """The :class:`~skynav.scenes.visibility.VisibilityCriteria` of a (validated) recipe."""
    return visibility_from_mapping(recipe.get("visibility", {}))


def read_recipe_mapping(path) -> dict:
    """The mapping of a YAML (or JSON) recipe file, or a fresh copy of a preset (``montecarlo``...),
    not yet validated (``--set`` overrides apply to it before :func:`validate_recipe`); relative
    PSF file paths in it are made relative to the recipe's folder.

    Raises
    ------
    RecipeError
        A missing file (naming the presets) or malformed YAML (naming the line).
    """
    if isinstance(path, str) and path in PRESETS and not os.path.isfile(path):
        return preset_recipe(path)
    try:
        with open(path, "rb") as f:
            data = load_yaml(f)
    except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
        raise RecipeError("recipe", str(path), "an existing YAML file or a preset: " + ", ".join(PRESETS)) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        raise RecipeError("recipe", str(path), f"valid YAML ({getattr(exc, 'problem', None) or exc.__class__.__name__}{where})") from None
    # a PSF file named in the recipe is found beside the recipe, wherever it is run from
    return resolve_psf_files(data, os.path.dirname(os.path.abspath(path)))


def load_recipe_file(path) -> dict:
    """Read a YAML (or JSON) recipe file, or a preset name (``montecarlo``...), and validate it.

    Parameters
    ----------
    path : str or os.PathLike
        A recipe file, or the name of a preset kind.

    Returns
    -------
    dict
        The normalised recipe (:func:`validate_recipe`).

    Raises
    ------
    RecipeError
        A bad value (the dotted key, the value, what is allowed).
    SceneFileError
        A missing or malformed file.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> from skynav.datasets import load_recipe_file, recipe_yaml
    >>> load_recipe_file("montecarlo")["frames"]
    3000
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     path = Path(tmp) / "recipe.yaml"
    ...     _ = path.write_text(recipe_yaml("montecarlo").replace("frames: 3000", "frames: 10"))
    ...     print(load_recipe_file(path)["frames"])
    10
    """
    return validate_recipe(read_recipe_mapping(path))


# ----------------------------------------------------------------------------- commented presets
#: One line per key of a recipe file (meaning, unit, allowed values), for :func:`recipe_yaml`.
KEY_COMMENTS = {
    "kind": "recipe kind: montecarlo (random scenes), sequence (a cruise's navigation legs) or scenes (a list)",
    "name": "free text naming the dataset (optional)",
    "frames": "number of frames, an integer >= 1 (sequence: optional, the first N of the plan; scenes: the list length)",
    "seed": "master seed, a non-negative integer: frame k draws from SeedSequence([seed, k])",
    "camera": "the camera, as in scene files: preset: paper (Andreis et al. (2024), Table 4), then any key to change, "
              "e.g. exposure_s: 0.2, width: 256, height: 256, fov_deg: 20, f_number: 2.2, sensor: {read_noise_e: 8}",
    "camera.preset": "starting camera: paper (20 deg, 1024 x 1024 px, f/2.2, 0.4 s, 8-bit)",
    "visibility": "the detection rule that sets each body's visible flag (and the keep-filters)",
    "visibility.limiting_v_mag": "faintest visible body, V mag",
    "visibility.sun_exclusion_deg": "a body this close to the Sun is not visible, deg, in [0, 180)",
    "catalog_limiting_v_mag": "faintest catalogue star rendered, V mag, in [-2, 14] (also written "
                              "render.catalog_limiting_v_mag, the scene file's spelling)",
    "render": "render options, the scene file's render: keys (a key left out keeps the default shown)",
    "formats": "files per frame, from: png (counts), exr (electrons, irradiance), json (ground truth, required), fits",
    "montecarlo": "scene distribution of Andreis et al. (2023a), Sec. V.A (draws in docs/datasets.md)",
    "montecarlo.epoch_start_tdb": "first epoch, ISO date in TDB, inside DE421 (1900..2053)",
    "montecarlo.epoch_end_tdb": "last epoch (uniform in between), ISO date in TDB, >= epoch_start_tdb",
    "montecarlo.position_sigma_au": "sigma of the Gaussian position about the barycentre, ecliptic x y z, AU, each in [0, 100]",
    "montecarlo.attitude_frame": "axes of the random pointing: ecliptic or icrs",
    "montecarlo.dec_3sigma_deg": "3-sigma of the pointing's declination (normal), deg, in [0, 270]",
    "montecarlo.velocity": "observer velocity: circular (heliocentric circular speed, prograde) or zero (at rest w.r.t. the Sun)",
    "montecarlo.min_sun_distance_au": "positions closer to the Sun are redrawn, AU, in [0, 100]",
    "montecarlo.keep": "keep-filters a scene must pass, a list from: " + ", ".join(FILTERS),
    "montecarlo.max_draws_per_frame": "give up on a frame after this many rejected draws, an integer >= 1",
    "sequence": "an Earth-Mars cruise (Lambert transfer) cut into tracking legs (Andreis et al. (2023b), Sec. IV; Andreis et al. (2024), Sec. 4)",
    "sequence.departure_window_tdb": "departure dates searched, [start, end], ISO dates in TDB",
    "sequence.tof_days": "times of flight searched, [min, max], days, in [10, 2000]",
    "sequence.grid_days": "grid step of the departure and time-of-flight search, days, in [0.1, 100]",
    "sequence.start_offset_days": "first leg this long after departure, days, in [1, tof min]",
    "sequence.legs": "number of legs (track A, slew, track B, coast), an integer in 1..1000",
    "sequence.track_s": "length of one tracking window (A or B) of a leg, s, > 0",
    "sequence.cadence_s": "time between frames within a leg, s, in (0, track_s]",
    "sequence.slew_s": "time between legs (slew to the next pair of planets), s, >= 0",
    "sequence.propagate_s": "coast without frames after each leg, s, >= 0",
    "sequence.pair_limiting_v_mag": "a leg's planets must be brighter than this, V mag",
    "sequence.pair_elongation_min_deg": "a leg's planets must be this far from the Sun, deg, in [0, 180]",
    "sequence.pointing_error_deg": "1-sigma pointing error per axis, deg, in [0, 10]",
    "sequence.jitter_rate_deg_s": "1-sigma attitude jitter rate per axis, deg/s, in [0, 10]",
    "sequence.angular_velocity_deg_s": "constant camera rate, camera x y z, deg/s, each in [-10, 10]",
    "sequence.twist_deg": "camera twist about the boresight, deg, in [-360, 360]",
    "sequence.spacecraft": "spacecraft for solar radiation pressure",
    "sequence.spacecraft.mass_kg": "mass, kg, > 0",
    "sequence.spacecraft.area_m2": "area facing the Sun, m^2, >= 0",
    "sequence.spacecraft.reflectivity_coefficient": "radiation-pressure coefficient C_r, in [0, 2]",
    "sequence.relativity": "post-Newtonian term of the Sun in the propagation: true or false",
    "sequence.rtol": "relative tolerance of the integrator, in [1e-14, 1e-6]",
    "sequence.trajectory_step_s": "spacing of the stored trajectory samples, s, in [1, 1e7]",
    "scenes": "a list of scenes, each with a scene file's keys (epoch, observer, attitude, camera, visibility, "
              "render; no render.seed), as in docs/examples/*.yaml",
}
KEY_COMMENTS.update({f"render.{k}": text for k, (_, text) in RENDER_KEYS.items() if k in RECIPE_RENDER_KEYS})


def _flow(value) -> str:
    """One YAML value on one line (flow style)."""
    text = yaml.safe_dump(value, default_flow_style=True, width=10_000, sort_keys=False).strip()
    return text[:-len("\n...")].strip() if text.endswith("...") else text


def _emit(lines: list, mapping: dict, prefix: str, indent: int) -> None:
    pad = " " * indent
    for key, value in mapping.items():
        dotted = f"{prefix}{key}"
        comment = KEY_COMMENTS.get(dotted)
        if comment:
            lines.append(f"{pad}# {comment}")
        if isinstance(value, dict) and value:
            lines.append(f"{pad}{key}:")
            _emit(lines, value, dotted + ".", indent + 2)
        elif dotted == "scenes":
            lines.append(f"{pad}{key}:")
            block = yaml.safe_dump(value, default_flow_style=None, sort_keys=False, width=100)
            lines.extend(pad + "  " + line for line in block.splitlines())
        else:
            lines.append(f"{pad}{key}: {_flow(value)}")


def recipe_yaml(kind: str) -> str:
    """A preset as a commented YAML file to edit: every key, each with a comment line above it.

    The file gives the same normalised recipe as :func:`preset_recipe` (it also writes the
    ``visibility:`` and ``render:`` defaults out, which normalise to the same values).

    Parameters
    ----------
    kind : str
        ``montecarlo``, ``sequence`` or ``scenes``.

    Returns
    -------
    str
        The YAML text, one comment line (meaning, unit, allowed values) above each key.

    Examples
    --------
    >>> import yaml
    >>> from skynav.datasets import preset_recipe, recipe_yaml, validate_recipe
    >>> text = recipe_yaml("montecarlo")
    >>> validate_recipe(yaml.safe_load(text)) == validate_recipe(preset_recipe("montecarlo"))
    True
    """
    recipe = preset_recipe(kind)
    ordered = {"kind": recipe.pop("kind")}
    for key in ("name", "frames", "seed", "camera"):
        if key in recipe:
            ordered[key] = recipe.pop(key)
    ordered["visibility"] = {"limiting_v_mag": 7.0, "sun_exclusion_deg": 20.0}
    ordered["catalog_limiting_v_mag"] = recipe.pop("catalog_limiting_v_mag", 9.0)
    ordered["render"] = {k: RENDER_KEYS[k][0] for k in RECIPE_RENDER_KEYS if k != "catalog_limiting_v_mag"}
    ordered.update(recipe)
    lines = [f"# skynav dataset recipe, kind {kind} (written by: skynav dataset recipe {kind})",
             "# Edit the values, then: skynav dataset generate THIS_FILE -o DATASET_FOLDER",
             "# Any key can also be changed on the command line: --set KEY.SUB=VALUE, e.g. --set render.cosmic_rays_per_frame=0", ""]
    _emit(lines, ordered, "", 0)
    return "\n".join(lines) + "\n"
