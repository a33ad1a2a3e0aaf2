"""The facility file's schema (``skynav.facility/1``): JSON Schema draft 2020-12, and its checker.

:data:`FACILITY_SCHEMA` is the one statement of what a facility file may hold: every key, its
type, unit (in the name and the description), range, the grids' and spectra's sizes; unknown keys
are refused (``additionalProperties: false``). It is published, written out verbatim, as
``skynav/datasets/schemas/facility.schema.json`` beside the frame schemas (a test keeps the file
equal to this mapping and checks it against the draft 2020-12 meta-schema with ``jsonschema``).

:func:`validate_facility_mapping` checks a mapping against it without ``jsonschema`` (the sky
model imports no other room and no validation library): the keywords used here (``type``,
``const``, ``enum``, ``properties``, ``required``, ``additionalProperties``, ``minimum``,
``maximum``, ``exclusiveMinimum``, ``exclusiveMaximum``, ``items``, ``minItems``, ``maxItems``)
are interpreted as JSON Schema defines them, and the first violation is raised as one
:class:`~skynav.infra.errors.ConfigValueError` naming the dotted key (``geometric.parameters.k1``,
``spectra.screen_emission.relative[3]``), the value and what is allowed; an unknown key names the
closest valid one (``difflib``). What JSON Schema cannot say is checked after it, in the same
words: grids strictly increasing, 2-D tables of the grid's shape, the screen's pixel count, a
non-zero spectrum, and the collimator's focal length agreeing with the geometric model's.
Camera keys are those of a scene file's ``camera:`` section and are checked by
:func:`skynav.scenes.config.camera_from_mapping`.

>>> validate_facility_mapping({"schema": "skynav.facility/1"})
Traceback (most recent call last):
...
skynav.infra.errors.ConfigValueError: screen = None is not allowed; expected a value (missing)
"""

from __future__ import annotations

import difflib
import json
import math

from skynav.infra.errors import ConfigValueError

__all__ = ["FACILITY_SCHEMA", "SCHEMA_ID", "MAX_SCREEN_SIDE_PX", "MAX_SCREEN_PIXELS", "MAX_GRID_NODES",
           "MAX_SPECTRUM_SAMPLES", "validate_facility_mapping", "schema_json"]

SCHEMA_ID = "skynav.facility/1"
#: a screen side, px: 8192 is beyond every microdisplay made (4K: 3840 px)
MAX_SCREEN_SIDE_PX = 8192
#: a screen frame is drawn in float64 (8 B/px, a few arrays): 2**25 px is ~270 MB per array
MAX_SCREEN_PIXELS = 1 << 25
#: nodes per axis of the residual and flat-field grids (the fit uses ~10)
MAX_GRID_NODES = 512
#: samples of a spectrum (1 nm over 300-1200 nm is 901)
MAX_SPECTRUM_SAMPLES = 20000


def _num(description, *, minimum=None, maximum=None, exclusive_minimum=None, exclusive_maximum=None, integer=False):
    s = {"type": "integer" if integer else "number", "description": description}
    for k, v in (("minimum", minimum), ("maximum", maximum), ("exclusiveMinimum", exclusive_minimum),
                 ("exclusiveMaximum", exclusive_maximum)):
        if v is not None:
            s[k] = v
    return s


def _array(items, description, *, min_items=None, max_items=None):
    s = {"type": "array", "description": description, "items": items}
    if min_items is not None:
        s["minItems"] = min_items
    if max_items is not None:
        s["maxItems"] = max_items
    return s


def _object(properties, description, *, required=(), additional=False):
    s = {"type": "object", "description": description, "properties": properties}
    if required:
        s["required"] = list(required)
    if not additional:
        s["additionalProperties"] = False
    return s


_ANGLE_DEG = dict(minimum=-180, maximum=180)
_GRID = _array(_num("grid node, screen px (strictly increasing)", minimum=-1e6, maximum=1e6), "grid nodes, screen px, "
               "strictly increasing", min_items=2, max_items=MAX_GRID_NODES)
_RESIDUAL_TABLE = _array(_array(_num("offset, arcsec", minimum=-36000, maximum=36000), "one row of the grid (x nodes)",
                                min_items=4, max_items=MAX_GRID_NODES),
                         "rows (ny) of nx values, arcsec", min_items=4, max_items=MAX_GRID_NODES)


def _spectrum(what):
    return _object({
        "wavelengths_nm": _array(_num("wavelength, nm", exclusive_minimum=0, maximum=100000), "wavelengths, nm, strictly "
                                 "increasing", min_items=2, max_items=MAX_SPECTRUM_SAMPLES),
        "relative": _array(_num("relative value (>= 0)", minimum=0, maximum=1e30), "relative values at those wavelengths",
                           min_items=2, max_items=MAX_SPECTRUM_SAMPLES),
    }, f"{what}: relative values on strictly increasing wavelengths (same length), not all zero, overlapping the "
       "camera's response band", required=("wavelengths_nm", "relative"))


_RECORD = {"type": "object", "description": "written by skynav calibrate (a report; free-form inside)"}

FACILITY_SCHEMA = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "$id": "https://skynav.invalid/schemas/facility.schema.json",
    "title": f"{SCHEMA_ID}: a hardware-in-the-loop bench (screen, collimator, camera, geometric and radiometric models)",
    "description": "What `skynav hil facility` writes and `skynav calibrate geometric|radiometric` update. Units are in "
                   "the names (px, um, mm, deg, arcsec, nm, W/m^2). Every number is finite; unknown keys are refused. "
                   "Beyond this schema skynav checks: grids strictly increasing, tables of the grid's shape, "
                   f"screen.width_px * screen.height_px <= {MAX_SCREEN_PIXELS}, spectra not all zero and overlapping "
                   "the camera's band, collimator.focal_length_mm equal to geometric.parameters.focal_length_mm "
                   "(the model uses the latter), radiometric peak_w_m2 > black_w_m2.",
    "type": "object",
    "required": ["schema", "screen", "collimator", "camera"],
    "additionalProperties": False,
    "properties": {
        "schema": {"const": SCHEMA_ID, "description": "the file format and its version"},
        "name": {"type": "string", "description": "the bench's name (printed, recorded in exports)", "maxLength": 200},
        "screen": _object({
            "width_px": _num("screen width, px", minimum=16, maximum=MAX_SCREEN_SIDE_PX, integer=True),
            "height_px": _num("screen height, px", minimum=16, maximum=MAX_SCREEN_SIDE_PX, integer=True),
            "pixel_pitch_um": _num("screen pixel pitch, micrometres", exclusive_minimum=0, maximum=10000),
            "bit_depth": _num("bits per screen pixel (default 10)", minimum=1, maximum=16, integer=True),
        }, "the microdisplay in the collimator's focal plane", required=("width_px", "height_px", "pixel_pitch_um")),
        "collimator": _object({
            "focal_length_mm": _num("collimator focal length, mm (nominal; must equal geometric.parameters."
                                    "focal_length_mm when that is given, which the model uses)",
                                    exclusive_minimum=0, maximum=100000),
        }, "the collimator", required=("focal_length_mm",)),
        "camera": {"type": "object", "description": "the flight camera: the keys of a scene file's camera: section "
                   "(checked by skynav's camera reader)"},
        "spectra": _object({
            "screen_emission": _spectrum("the screen's relative emission spectrum"),
            "power_meter_responsivity": _spectrum("the power meter's relative spectral responsivity"),
        }, "spectra (defaults: a colour OLED's grey; a flat meter)"),
        "geometric": _object({
            "model": {"const": "physical/1", "description": "the geometric model"},
            "parameters": _object({
                "focal_length_mm": _num("collimator focal length the model uses, mm (fitted by calibrate geometric)",
                                        exclusive_minimum=0, maximum=100000),
                "decentre_x_mm": _num("screen decentre, mm", minimum=-1000, maximum=1000),
                "decentre_y_mm": _num("screen decentre, mm", minimum=-1000, maximum=1000),
                "tilt_x_deg": _num("screen tilt about x, deg", minimum=-60, maximum=60),
                "tilt_y_deg": _num("screen tilt about y, deg", minimum=-60, maximum=60),
                "roll_deg": _num("screen roll, deg", **_ANGLE_DEG),
                "k1": _num("radial distortion k1", minimum=-100, maximum=100),
                "k2": _num("radial distortion k2", minimum=-1e4, maximum=1e4),
                "p1": _num("tangential distortion p1", minimum=-10, maximum=10),
                "p2": _num("tangential distortion p2", minimum=-10, maximum=10),
                "misalignment_deg": _array(_num("rotation-vector component, deg", **_ANGLE_DEG),
                                           "camera misalignment, rotation vector (x, y, z), deg", min_items=3, max_items=3),
            }, "the physical model's parameters (missing: 0; focal length: the collimator's)"),
            "residual_field": _object({"x_px": _array(_GRID["items"], _GRID["description"], min_items=4, max_items=MAX_GRID_NODES),
                                       "y_px": _array(_GRID["items"], _GRID["description"], min_items=4, max_items=MAX_GRID_NODES),
                                       "dx_arcsec": _RESIDUAL_TABLE, "dy_arcsec": _RESIDUAL_TABLE},
                                      "line-of-sight correction on a grid (bicubic spline): dx, dy (arcsec) of shape "
                                      "(len(y_px), len(x_px))", required=("x_px", "y_px", "dx_arcsec", "dy_arcsec")),
            "status": {"type": "string", "description": "'nominal (not calibrated)' before a fit"},
            "fit": _RECORD, "provenance": _RECORD,
        }, "the geometric model (and its calibration record: fit, provenance)"),
        "radiometric": _object({
            "model": {"const": "gamma/1", "description": "the radiometric model"},
            "parameters": _object({
                "black_w_m2": _num("irradiance at DN 0 per lit pixel, W/m^2", minimum=0, maximum=1e6),
                "peak_w_m2": _num("irradiance at full scale per lit pixel, W/m^2 (> black_w_m2)", exclusive_minimum=0,
                                  maximum=1e6),
                "gamma": _num("curve exponent", exclusive_minimum=0.2, exclusive_maximum=10),
            }, "the curve E(d) = black + (peak - black) (d / max_dn)^gamma (missing: the nominal curve)"),
            "flat_field": _object({"x_px": _GRID, "y_px": _GRID,
                                   "relative": _array(_array(_num("relative transmission", exclusive_minimum=0, maximum=1000),
                                                             "one row (x nodes)", min_items=2, max_items=MAX_GRID_NODES),
                                                      "rows (ny) of nx values", min_items=2, max_items=MAX_GRID_NODES)},
                                  "relative transmission on a grid, (len(y_px), len(x_px)) values > 0",
                                  required=("x_px", "y_px", "relative")),
            "status": {"type": "string", "description": "'nominal (not calibrated)' before a fit"},
            "samples": _RECORD, "fit": _RECORD, "usable_range": _RECORD, "provenance": _RECORD,
            "electrons_per_s_per_w_m2": _num("recorded by the fit (camera electrons per s per W/m^2)", minimum=0),
        }, "the radiometric model (and its calibration record)"),
    },
}


def schema_json() -> str:
    """The schema as the published file holds it."""
    return json.dumps(FACILITY_SCHEMA, indent=1) + "\n"


# ----------------------------------------------------------------------------- checker
def _short(value):
    """A value as an error line shows it (long lists and mappings abridged)."""
    if isinstance(value, (list, tuple)):
        return value if len(value) <= 4 else f"[{', '.join(repr(v) for v in value[:3])}, ... ({len(value)} items)]"
    if isinstance(value, dict):
        return "{" + ", ".join(map(str, list(value)[:4])) + (", ..." if len(value) > 4 else "") + "}"
    if isinstance(value, str) and len(value) > 60:
        return value[:57] + "..."
    return value


def _type_ok(value, t) -> bool:
    if t == "object":
        return isinstance(value, dict)
    if t == "array":
        return isinstance(value, list)
    if t == "string":
        return isinstance(value, str)
    if t == "integer":
        return (isinstance(value, int) and not isinstance(value, bool)) or (isinstance(value, float) and math.isfinite(value)
                                                                            and value == int(value))
    if t == "number":
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    return True


_TYPE_WORDS = {"object": "a mapping of keys to values", "array": "a list", "string": "a string",
               "integer": "an integer", "number": "a finite number"}


def _range_words(s) -> str:
    parts = []
    if "minimum" in s:
        parts.append(f">= {s['minimum']:g}")
    if "exclusiveMinimum" in s:
        parts.append(f"> {s['exclusiveMinimum']:g}")
    if "maximum" in s:
        parts.append(f"<= {s['maximum']:g}")
    if "exclusiveMaximum" in s:
        parts.append(f"< {s['exclusiveMaximum']:g}")
    return " and ".join(parts)


def _allowed_number(s) -> str:
    words = _TYPE_WORDS[s["type"]]
    rng = _range_words(s)
    return f"{words} {rng}" if rng else words


def _check_node(value, s, key):
    if "const" in s:
        if value != s["const"] or isinstance(value, bool):
            raise ConfigValueError(key, _short(value), repr(s["const"]))
        return
    t = s.get("type")
    if t is not None:
        if not _type_ok(value, t) or (t in ("number", "integer") and not math.isfinite(value)):
            raise ConfigValueError(key, _short(value), _allowed_number(s) if t in ("number", "integer") else _TYPE_WORDS[t])
    if t in ("number", "integer"):
        lo, hi = s.get("minimum"), s.get("maximum")
        xlo, xhi = s.get("exclusiveMinimum"), s.get("exclusiveMaximum")
        if (lo is not None and value < lo) or (hi is not None and value > hi) or (xlo is not None and value <= xlo) \
                or (xhi is not None and value >= xhi):
            raise ConfigValueError(key, value, _allowed_number(s))
    elif t == "string":
        if "maxLength" in s and len(value) > s["maxLength"]:
            raise ConfigValueError(key, _short(value), f"a string of at most {s['maxLength']} characters")
    elif t == "array":
        n = len(value)
        lo, hi = s.get("minItems"), s.get("maxItems")
        if (lo is not None and n < lo) or (hi is not None and n > hi):
            what = f"exactly {lo}" if lo == hi else f"{lo} to {hi}" if lo is not None and hi is not None else \
                f"at least {lo}" if lo is not None else f"at most {hi}"
            raise ConfigValueError(key, _short(value), f"a list of {what} items ({s.get('description', '')})")
        if "items" in s:
            for i, v in enumerate(value):
                _check_node(v, s["items"], f"{key}[{i}]")
    elif t == "object":
        props = s.get("properties", {})
        if s.get("additionalProperties", True) is False:
            for k in value:
                if k not in props:
                    name = str(k) if str(k).isprintable() and str(k).strip() and " " not in str(k) else repr(k)
                    where = f"{key}.{name}" if key else name
                    close = difflib.get_close_matches(str(k), list(props), n=1, cutoff=0.5)
                    hint = f"did you mean {key + '.' if key else ''}{close[0]}? " if close else ""
                    raise ConfigValueError(where, _short(value[k]), f"no such key; {hint}allowed keys"
                                           f"{' in ' + key if key else ''}: {', '.join(props)}")
        for k in s.get("required", ()):
            if k not in value:
                raise ConfigValueError(f"{key}.{k}" if key else k, None, "a value (missing)")
        for k, sub in props.items():
            if k in value:
                _check_node(value[k], sub, f"{key}.{k}" if key else k)


def _increasing(values, key):
    for i in range(1, len(values)):
        if not values[i] > values[i - 1]:
            raise ConfigValueError(f"{key}[{i}]", values[i], f"> {key}[{i - 1}] = {values[i - 1]:g} (the grid must be "
                                   "strictly increasing)")


def _table(rows, nx, ny, key):
    if len(rows) != ny:
        raise ConfigValueError(key, f"{len(rows)} rows", f"{ny} rows (one per y_px node)")
    for j, row in enumerate(rows):
        if len(row) != nx:
            raise ConfigValueError(f"{key}[{j}]", f"{len(row)} values", f"{nx} values (one per x_px node)")


def validate_facility_mapping(d) -> None:
    """Raise :class:`ConfigValueError` (one line, the dotted key) unless ``d`` is a valid facility file form.

    The checks of :data:`FACILITY_SCHEMA`, then the rules a schema cannot state (module docstring).
    The camera's own keys and the spectra's overlap with the camera's band are checked where the
    camera is built (:func:`skynav.scenes.facility.facility_from_mapping`).
    """
    if not isinstance(d, dict):
        raise ConfigValueError("facility", type(d).__name__, "a mapping (a facility YAML file)")
    if "schema" not in d:
        raise ConfigValueError("schema", None, f"{SCHEMA_ID!r} (missing: is this a facility file?)")
    _check_node(d["schema"], FACILITY_SCHEMA["properties"]["schema"], "schema")
    for k in FACILITY_SCHEMA["required"]:
        if k not in d:
            raise ConfigValueError(k, None, "a value (missing)")
    _check_node(d, FACILITY_SCHEMA, "")
    sc = d["screen"]
    if sc["width_px"] * sc["height_px"] > MAX_SCREEN_PIXELS:
        raise ConfigValueError("screen.width_px x screen.height_px", f"{sc['width_px']}x{sc['height_px']}",
                               f"at most {MAX_SCREEN_PIXELS} pixels (a screen frame is drawn in memory in float64)")
    for section, name in (("geometric", "residual_field"), ("radiometric", "flat_field")):
        grid = (d.get(section) or {}).get(name)
        if grid is None:
            continue
        key = f"{section}.{name}"
        _increasing(grid["x_px"], f"{key}.x_px")
        _increasing(grid["y_px"], f"{key}.y_px")
        for table in (("dx_arcsec", "dy_arcsec") if name == "residual_field" else ("relative",)):
            _table(grid[table], len(grid["x_px"]), len(grid["y_px"]), f"{key}.{table}")
    for name, spec in (d.get("spectra") or {}).items():
        key = f"spectra.{name}"
        wl, rel = spec["wavelengths_nm"], spec["relative"]
        _increasing(wl, f"{key}.wavelengths_nm")
        if len(rel) != len(wl):
            raise ConfigValueError(f"{key}.relative", f"{len(rel)} values", f"{len(wl)} values (one per wavelength)")
        if not max(rel) > 0:
            raise ConfigValueError(f"{key}.relative", _short(rel), "non-negative values, not all zero")
    rp = (d.get("radiometric") or {}).get("parameters") or {}
    if "black_w_m2" in rp and "peak_w_m2" in rp and not rp["peak_w_m2"] > rp["black_w_m2"]:
        raise ConfigValueError("radiometric.parameters.peak_w_m2", rp["peak_w_m2"],
                               f"> radiometric.parameters.black_w_m2 = {rp['black_w_m2']:g}")
    geo = d.get("geometric") or {}
    fitted = (geo.get("parameters") or {}).get("focal_length_mm")
    nominal = d["collimator"]["focal_length_mm"]
    if fitted is not None and not math.isclose(fitted, nominal, rel_tol=1e-12):
        if geo.get("fit"):
            raise ConfigValueError("collimator.focal_length_mm", nominal,
                                   f"the fitted geometric.parameters.focal_length_mm = {fitted!r}, which the model uses: "
                                   "in a calibrated facility edit geometric.parameters.focal_length_mm (and this key to the "
                                   "same value), or calibrate again")
        raise ConfigValueError("collimator.focal_length_mm", nominal,
                               f"the same value as geometric.parameters.focal_length_mm = {fitted!r} (the model uses "
                               "that key): edit both, or delete geometric.parameters.focal_length_mm")


if __name__ == "__main__":  # python -m skynav.scenes.facility_schema > datasets/schemas/facility.schema.json
    import sys

    sys.stdout.write(schema_json())
