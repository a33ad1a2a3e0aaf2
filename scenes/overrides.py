"""Overrides of a configuration mapping: ``KEY.SUB=VALUE`` (what ``--set`` takes), parsed and applied.

Part of the configuration layer beside :mod:`skynav.scenes.config` (kept apart from it for the
house's module size): a scene file, a dataset recipe, a facility file or an options dataclass is
read as a mapping, the overrides are set in a copy of it, and the copy goes through the same
validation as the file, so a misspelt key is refused naming the allowed keys. The command line
(``--set``), scripts (``benchmarks/loop_vs_nav.py``) and the Python API share it.

>>> apply_overrides({"camera": {"width": 1024}}, [parse_override("camera.width=256")])
{'camera': {'width': 256}}
"""

from __future__ import annotations

import copy
import dataclasses
import io
import logging
import math
import re

import yaml

from skynav.infra.errors import SkynavError

from .config import camera_from_mapping
from .scene_files import load_yaml

__all__ = ["OverrideError", "parse_override", "apply_overrides", "keep_field_of_view", "dataclass_from_overrides"]

_log = logging.getLogger("skynav.scenes.overrides")

#: camera keys that set the scale of the field: given with a size override, they decide it
_SCALE_KEYS = ("pixel_pitch_um", "pixel_pitch_y_um", "focal_length_mm", "fov_deg", "K")


class OverrideError(SkynavError, ValueError):
    """An override that cannot be parsed or applied (one line, exit 2 on the command line).

    Examples
    --------
    >>> from skynav.scenes import OverrideError, parse_override
    >>> try:
    ...     parse_override("camera.width 256")
    ... except OverrideError as exc:
    ...     print(exc)
    'camera.width 256': expected KEY.SUB=VALUE, e.g. camera.exposure_s=0.2
    """


def parse_override(text: str):
    """``(text, path, value)`` of an override ``KEY.SUB=VALUE``.

    KEY.SUB is a dotted path into the mapping (``camera.exposure_s``; a list item by its index,
    ``scenes.0.epoch`` or ``scenes[0].epoch``); VALUE is parsed as YAML with the scene files'
    loader (``0.2``, ``2e-1``, ``[png, json]``, ``{k: 1}``, ``true``; an empty VALUE is null).

    Parameters
    ----------
    text : str
        The override as typed, ``KEY.SUB=VALUE``.

    Returns
    -------
    tuple
        ``(text, path, value)``: the text, the path as a tuple of keys (str) and list indices
        (int), the parsed value (units as the key's name says).

    Raises
    ------
    OverrideError
        No ``=``, an empty or malformed KEY, or a VALUE that is not YAML.

    Examples
    --------
    >>> from skynav.scenes import parse_override
    >>> parse_override("camera.exposure_s=0.2")[1:]
    (('camera', 'exposure_s'), 0.2)
    >>> parse_override("scenes[1].epoch=2027-03-15T00:00:00")[1]
    ('scenes', 1, 'epoch')
    """
    key, eq, raw = text.partition("=")
    key = key.strip()
    why = "expected KEY.SUB=VALUE, e.g. camera.exposure_s=0.2"
    if not eq or not key:
        raise OverrideError(f"{text!r}: {why}")
    parts = re.sub(r"\[(\d+)\]", r".\1", key).split(".")
    if any(not re.fullmatch(r"[A-Za-z0-9_-]+", p) for p in parts):
        raise OverrideError(f"{text!r}: {why} (KEY: names and list indices joined by dots)")
    try:
        value = load_yaml(io.StringIO(raw)) if raw.strip() else None
    except yaml.YAMLError as exc:
        raise OverrideError(f"{text!r}: the VALUE is not valid YAML "
                            f"({getattr(exc, 'problem', None) or exc.__class__.__name__})") from None
    return text, tuple(int(p) if p.isdigit() else p for p in parts), value


def apply_overrides(mapping, overrides, *, known_keys_only: bool = False, what: str = "the file") -> dict:
    """A deep copy of ``mapping`` with each ``(text, path, value)`` of :func:`parse_override` set in it.

    A missing mapping key on the way is created, so a misspelt key reaches the mapping's own
    validation, which refuses it naming the allowed keys (as for the same key in a file). With
    ``known_keys_only`` (a mapping written out in full, whose reader ignores unknown keys: a
    facility) a key that is not already there is refused here, naming the keys at that level.

    Parameters
    ----------
    mapping : dict or None
        The configuration mapping (a scene file, a recipe, a facility), not changed.
    overrides : iterable of tuple
        :func:`parse_override` results, applied in order.
    known_keys_only : bool
        Refuse a key that the mapping does not already have.
    what : str
        What the mapping is, for the error messages.

    Returns
    -------
    dict
        The new mapping, to validate as the file would be.

    Raises
    ------
    OverrideError
        The path goes through a value that is not a mapping or list, or past a list's end.

    Examples
    --------
    >>> from skynav.scenes import apply_overrides, parse_override
    >>> scene = {"camera": {"preset": "paper"}}
    >>> apply_overrides(scene, [parse_override("camera.exposure_s=0.2"), parse_override("render.seed=3")])
    {'camera': {'preset': 'paper', 'exposure_s': 0.2}, 'render': {'seed': 3}}
    >>> scene
    {'camera': {'preset': 'paper'}}
    """
    out = copy.deepcopy(mapping) if mapping is not None else {}
    if not isinstance(out, dict):
        raise OverrideError(f"--set: the file is not a mapping ({type(out).__name__}); fix the file first")
    for text, path, value in overrides:
        node = out
        for i, part in enumerate(path):
            last = i == len(path) - 1
            where = ".".join(str(p) for p in path[:i]) or "the top level"
            if isinstance(node, list):
                if not isinstance(part, int) or not 0 <= part < len(node):
                    raise OverrideError(f"--set {text}: {where} is a list of {len(node)}; give an index 0..{len(node) - 1}")
            elif isinstance(node, dict):
                if isinstance(part, int) and part not in node:
                    part = str(part)
                if known_keys_only and part not in node:
                    name = ".".join(str(p) for p in path[:i + 1])
                    raise OverrideError(f"--set {text}: {what} has no key {name}; allowed keys"
                                        f"{'' if i == 0 else ' in ' + where}: " + ", ".join(sorted(map(str, node))))
                if not last and (part not in node or node[part] is None):
                    node[part] = {}
            else:
                raise OverrideError(f"--set {text}: {where} is {_kind(node)}, not a mapping")
            if last:
                node[part] = value
            else:
                node = node[part]
    return out


def keep_field_of_view(before, after: dict, overrides, *, section: str = "camera") -> str | None:
    """Make a size override keep the camera's field of view; the one line that says what changed.

    ``--set camera.width=256 --set camera.height=256`` on the paper camera (20 deg, 1024 px) asks
    for a smaller image of the same sky: the pixel pitch follows the width, ``pitch * old / new``
    (the focal length, so the optics, kept), and the field stays 20 x 20 deg instead of shrinking
    to 5 x 5 deg. A height given alone keeps the pitch (the image is cropped or extended
    vertically); a width alone changes the vertical field. The line says the field before and
    after. Nothing is changed (and None returned) when an
    override also gives a key that sets the scale (``pixel_pitch_um``, ``pixel_pitch_y_um``,
    ``focal_length_mm``, ``fov_deg``), replaces the whole ``camera`` mapping, or when the camera
    before or after is not valid (its own validation names the fault). ``after`` (what
    :func:`apply_overrides` returned) is changed in place: ``pixel_pitch_um`` (and
    ``pixel_pitch_y_um`` of rectangular pixels) set, a derived ``K`` dropped.

    Examples
    --------
    >>> before = {"camera": {"preset": "paper"}}
    >>> ov = [parse_override("camera.width=256"), parse_override("camera.height=256")]
    >>> after = apply_overrides(before, ov)
    >>> keep_field_of_view(before, after, ov)
    '--set camera.width=256 camera.height=256: the pixel pitch follows the width (13.78 -> 55.1 um), so the field is 20 x 20 deg (was 20 x 20 deg); give camera.pixel_pitch_um (or focal_length_mm, fov_deg) to set the field yourself'
    """
    paths = [path for _, path, _ in overrides if path and path[0] == section]
    sized = {path[1] for path in paths if len(path) == 2 and path[1] in ("width", "height")}
    if not sized or any(len(path) == 1 or path[1] in _SCALE_KEYS for path in paths):
        return None
    cam = after.get(section)
    try:
        old = camera_from_mapping(copy.deepcopy((before or {}).get(section)), section)
        if "width" in sized and cam.get("width") != old.width:
            ratio = old.width / cam["width"]
            cam["pixel_pitch_um"] = old.pixel_pitch_um * ratio
            if old.pixel_pitch_y_um is not None:
                cam["pixel_pitch_y_um"] = old.pixel_pitch_y_um * ratio
            cam.pop("K", None)
        new = camera_from_mapping(copy.deepcopy(cam), section)
    except (SkynavError, TypeError, AttributeError, ZeroDivisionError):
        return None
    given = " ".join(f"{section}.{k}={cam[k]}" for k in ("width", "height") if k in sized)

    def field(c):
        return f"{math.degrees(c.fov_x_rad):.4g} x {math.degrees(c.fov_y_rad):.4g} deg"

    if new.pixel_pitch_um != old.pixel_pitch_um:
        line = (f"--set {given}: the pixel pitch follows the width ({old.pixel_pitch_um:.4g} -> "
                f"{new.pixel_pitch_um:.4g} um), so the field is {field(new)} (was {field(old)})")
    elif field(new) != field(old):
        line = f"--set {given}: the field is {field(new)} (was {field(old)}; the pixel pitch is kept)"
    else:
        return None
    line += f"; give {section}.pixel_pitch_um (or focal_length_mm, fov_deg) to set the field yourself"
    _log.info(line)
    return line


def _kind(value) -> str:
    if isinstance(value, bool):
        return "true/false"
    if isinstance(value, (int, float)):
        return f"a number ({value!r})"
    if isinstance(value, str):
        return f"a string ({value!r})"
    return type(value).__name__


def dataclass_from_overrides(cls, overrides, *, what: str):
    """An instance of the frozen options dataclass ``cls`` with ``FIELD=VALUE`` overrides applied.

    Each KEY must be a field; each VALUE must have the default's type (an integer for int
    fields, a finite number for float fields, true/false for bool fields).

    Parameters
    ----------
    cls : type
        A frozen dataclass whose fields all have defaults (``ProcessOptions``, ...).
    overrides : iterable of tuple
        :func:`parse_override` results, one field each.
    what : str
        What the options are, for the error messages.

    Returns
    -------
    object
        ``cls(**fields)`` with the defaults and the overrides.

    Raises
    ------
    OverrideError
        An unknown field, or a value of the wrong type (one line naming the field).

    Examples
    --------
    >>> import dataclasses
    >>> from skynav.scenes import dataclass_from_overrides, parse_override
    >>> @dataclasses.dataclass(frozen=True)
    ... class Options:
    ...     threshold: float = 5.0
    ...     steps: int = 3
    >>> dataclass_from_overrides(Options, [parse_override("threshold=4")], what="options")
    Options(threshold=4.0, steps=3)
    """
    defaults = cls()
    fields = {f.name: getattr(defaults, f.name) for f in dataclasses.fields(cls)}
    kw = {}
    for text, path, value in overrides:
        name = ".".join(str(p) for p in path)
        if len(path) != 1 or path[0] not in fields:
            raise OverrideError(f"--set {text}: {what} has no key {name}; allowed keys: " + ", ".join(sorted(fields)))
        default = fields[path[0]]
        if isinstance(default, bool):
            ok, allowed = isinstance(value, bool), "true or false"
        elif isinstance(default, int):
            ok, allowed = isinstance(value, int) and not isinstance(value, bool), "an integer"
        elif isinstance(default, float):
            ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
            allowed = "a finite number"
        else:
            ok, allowed = isinstance(value, type(default)), f"a {type(default).__name__}"
        if not ok:
            raise OverrideError(f"--set {text}: {what}.{name} = {value!r} is not allowed; expected {allowed}")
        kw[path[0]] = float(value) if isinstance(default, float) else value
    return dataclasses.replace(defaults, **kw)
