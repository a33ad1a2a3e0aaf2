"""The recipe schema: the keys each kind of recipe takes, their defaults and ranges, and
:func:`validate_recipe`, which checks a recipe and returns its normalised copy.

The normalised recipe (defaults filled, plain JSON types, angles in degrees as in files) is what
``manifest.json`` stores and what a resumed run is compared with; errors are
:class:`~skynav.datasets.errors.RecipeError` naming the dotted key and the allowed range. The
presets, the recipe files and the commented YAML live in :mod:`skynav.datasets.recipes`.
"""

from __future__ import annotations

import copy
import math

from skynav.infra.count_cap import cap_count
from skynav.scenes.config import (
    RENDER_KEYS,
    camera_from_mapping,
    render_settings_from_mapping,
    scene_spec_from_mapping,
    visibility_from_mapping,
)
from skynav.scenes.errors import MovedKeyError
from skynav.scenes.mission_spice import KernelName
from skynav.scenes.timescales import to_time

from .errors import RecipeError

__all__ = ["KINDS", "SEQUENCE_KERNEL_SOURCES", "validate_recipe", "RECIPE_RENDER_OPTIONS", "RECIPE_RENDER_KEYS"]

#: The ``render:`` keys that set :class:`~skynav.renderer.render.RenderOptions` fields of the same name.
RECIPE_RENDER_OPTIONS = ("cosmic_rays_per_frame", "mitsuba_spp")
#: The ``render:`` keys a recipe takes: the scene file's but ``seed`` (frame k's stream is fixed by the recipe's seed).
RECIPE_RENDER_KEYS = tuple(k for k in RENDER_KEYS if k != "seed")

#: The kinds of recipe.
KINDS = ("montecarlo", "sequence", "scenes")
#: The file formats a dataset can write (``json``, the ground truth, always).
FORMATS = ("png", "exr", "json", "fits")
#: The keep-filters of a Monte Carlo recipe (``montecarlo.keep``).
FILTERS = ("visible_planet", "sun_outside_exclusion", "body_in_fov")

#: The ``montecarlo:`` section's keys and defaults.
MONTECARLO_DEFAULTS = {
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

#: The ``sequence:`` keys that take the cruise from a mission's SPICE kernels (absent: the
#: built-in ballistic cruise and pointing rule): section key -> the key naming what to read.
SEQUENCE_KERNEL_SOURCES = {"observer": "body", "attitude": "frame"}

#: The ``sequence:`` section's keys and defaults.
SEQUENCE_DEFAULTS = {
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


def _section(recipe, key, defaults, optional=()):
    sec = recipe.get(key, {})
    if sec is None:
        sec = {}
    if not isinstance(sec, dict):
        raise RecipeError(key, sec, "a mapping")
    for k in sec:
        if k not in defaults and k not in optional:
            raise RecipeError(f"{key}.{k}", sec[k], "no such key; allowed keys: " + ", ".join(sorted([*defaults, *optional])))
    out = copy.deepcopy(defaults)
    out.update(copy.deepcopy(sec))
    return out


def _kernel_source(value, name: str, want: str) -> dict:
    """A sequence's ``observer`` or ``attitude`` from kernels, ``{spice: {kernels, body|frame}}``
    (the scene file's spelling); each kernel kept as a :class:`KernelName` (the name as written,
    the file beside the recipe file or in the current folder)."""
    spec = value.get("spice") if isinstance(value, dict) and set(value) == {"spice"} else None
    if not isinstance(spec, dict) or set(spec) != {"kernels", want}:
        raise RecipeError(name, value, f"a mapping {{spice: {{kernels: [FILE, ...], {want}: ...}}}}")
    ks = spec["kernels"]
    if not isinstance(ks, list) or not ks or not all(isinstance(k, str) and k for k in ks):
        raise RecipeError(f"{name}.spice.kernels", ks, "a non-empty list of kernel files (read beside the recipe file)")
    if not isinstance(spec[want], (str, int)) or isinstance(spec[want], bool) or not str(spec[want]).strip():
        raise RecipeError(f"{name}.spice.{want}", spec[want], "a NAIF name or integer id")
    return {"spice": {"kernels": [k if isinstance(k, KernelName) else KernelName(k) for k in ks], want: str(spec[want])}}


def _validate_montecarlo(recipe) -> dict:
    s = _section(recipe, "montecarlo", MONTECARLO_DEFAULTS)
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
    s = _section(recipe, "sequence", SEQUENCE_DEFAULTS, optional=tuple(SEQUENCE_KERNEL_SOURCES))
    w = "sequence"
    for key, want in SEQUENCE_KERNEL_SOURCES.items():
        if key in s:
            s[key] = _kernel_source(s[key], f"{w}.{key}", want)
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
    sc = {**SEQUENCE_DEFAULTS["spacecraft"], **sc}
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
    kind = _check_top_level_keys(recipe)
    out = {"kind": kind}
    if "name" in recipe:
        out["name"] = str(recipe["name"])
    if "seed" not in recipe:
        raise RecipeError("seed", None, "a non-negative integer master seed")
    out["seed"] = _num(recipe, "seed", "", lo=0, hi=2**63 - 1, integer=True)
    out.update(_validate_sky(recipe))
    out["formats"] = _validate_formats(recipe.get("formats", ["png", "exr", "json"]))
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
        out["scenes"] = _validate_scenes(recipe.get("scenes"))
        if recipe.get("frames") is not None and recipe["frames"] != len(out["scenes"]):
            raise RecipeError("frames", recipe["frames"], f"absent or equal to the number of scenes ({len(out['scenes'])})")
        out["frames"] = len(out["scenes"])
    return out


def _check_top_level_keys(recipe) -> str:
    """The recipe's kind, after refusing a non-mapping, an unknown kind and any key it does not take."""
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
    return kind


def _validate_sky(recipe) -> dict:
    """What every kind shares: the camera, the visibility rule, the render keys and the catalogue cut."""
    out = {}
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
    return out


def _validate_formats(fmts) -> list:
    """The formats in :data:`FORMATS` order; distinct, known, and with ``json`` among them."""
    if isinstance(fmts, str):
        fmts = [fmts]
    if not isinstance(fmts, (list, tuple)) or not fmts or any(f not in FORMATS for f in fmts) or len(set(fmts)) != len(fmts):
        raise RecipeError("formats", fmts, "a list of distinct formats from: " + ", ".join(FORMATS))
    if "json" not in fmts:
        raise RecipeError("formats", fmts, "a list that includes json (the ground truth)")
    return [f for f in FORMATS if f in fmts]


def _validate_scenes(scenes) -> list:
    """A copy of a ``scenes`` recipe's list, each item checked as a scene file's mapping."""
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
    return copy.deepcopy(scenes)


def _validate_render(rd, camera) -> dict:
    """The keys given in a recipe's ``render:`` mapping, validated as a scene file's are."""
    if isinstance(rd, dict) and "seed" in rd:  # frame k's stream is SeedSequence([seed, k])
        raise RecipeError("render.seed", rd["seed"], "no render seed in a recipe (frame k draws from "
                                                     "SeedSequence([seed, k])); set the recipe's top-level seed")
    return render_settings_from_mapping(rd, camera, key="render", fill=False, keys=RECIPE_RENDER_KEYS)
