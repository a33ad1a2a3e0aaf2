"""Dataset recipes: validated, YAML-able mappings, each kind with a built-in preset.

A recipe is a plain mapping (parsed YAML or a Python dict).
:func:`~skynav.datasets.recipe_checks.validate_recipe` checks every key, fills defaults and
returns the *normalised* mapping (plain JSON types, angles in degrees as in files) that is stored
in ``manifest.json`` and compared on resume; errors are
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
import os

import yaml

from skynav.scenes.mission_spice import KernelName
from skynav.scenes.config import RENDER_KEYS, camera_from_mapping, visibility_from_mapping
from skynav.scenes.psf_measured import resolve_psf_files
from skynav.scenes.scene_files import load_yaml

from .errors import RecipeError
from .recipe_checks import (FILTERS, KINDS, MONTECARLO_DEFAULTS, RECIPE_RENDER_KEYS, SEQUENCE_DEFAULTS,
                            SEQUENCE_KERNEL_SOURCES, validate_recipe)

__all__ = ["PRESETS", "preset_recipe", "recipe_camera", "recipe_visibility", "load_recipe_file",
           "read_recipe_mapping", "recipe_render", "recipe_yaml"]

#: The planets a sequence recipe's legs may point at.
PLANETS = ("mercury", "venus", "earth", "mars", "jupiter", "saturn", "uranus", "neptune")

PRESETS = {
    "montecarlo": {
        "kind": "montecarlo",
        "frames": 3000,
        "seed": 20230214,
        "camera": {"preset": "paper"},
        "catalog_limiting_v_mag": 9.0,
        "formats": ["png", "exr", "json"],
        "montecarlo": copy.deepcopy(MONTECARLO_DEFAULTS),
    },
    "sequence": {
        "kind": "sequence",
        "seed": 20240101,
        "camera": {"preset": "paper"},
        "catalog_limiting_v_mag": 9.0,
        "formats": ["png", "exr", "json"],
        "sequence": copy.deepcopy(SEQUENCE_DEFAULTS),
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
    not yet validated (``--set`` overrides apply to it before :func:`~skynav.datasets.recipe_checks.validate_recipe`); relative
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
    # a PSF file or a kernel named in the recipe is found beside the recipe, wherever it is run from
    folder = os.path.dirname(os.path.abspath(path))
    return _mark_kernels(resolve_psf_files(data, folder), folder)


def _mark_kernels(data, folder: str):
    """The recipe with its ``sequence.observer|attitude.spice.kernels`` names kept as written
    and read beside the recipe (:class:`~skynav.scenes.mission_spice.KernelName`)."""
    seq = data.get("sequence") if isinstance(data, dict) else None
    if not isinstance(seq, dict):
        return data
    seq = dict(seq)
    for key in SEQUENCE_KERNEL_SOURCES:
        spec = seq.get(key, {}).get("spice") if isinstance(seq.get(key), dict) else None
        if isinstance(spec, dict) and isinstance(spec.get("kernels"), list):
            kernels = [KernelName(k, os.path.join(folder, k)) if isinstance(k, str) and k else k for k in spec["kernels"]]
            seq[key] = {**seq[key], "spice": {**spec, "kernels": kernels}}
    return {**data, "sequence": seq}


def load_recipe_file(path) -> dict:
    """Read a YAML (or JSON) recipe file, or a preset name (``montecarlo``...), and validate it.

    Parameters
    ----------
    path : str or os.PathLike
        A recipe file, or the name of a preset kind.

    Returns
    -------
    dict
        The normalised recipe (:func:`~skynav.datasets.recipe_checks.validate_recipe`).

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
    "sequence.observer": "optional: the cruise from SPICE kernels, {spice: {kernels: [FILE, ...], body: NAME_OR_ID}} "
                         "(files beside the recipe); the legs start where the kernels' coverage of the body starts",
    "sequence.attitude": "optional: the frames' attitudes from SPICE kernels, {spice: {kernels: [FILE, ...], "
                         "frame: CAMERA_FRAME}} (a CK with its SCLK and FK), in place of the pointing rule",
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
