"""Keys of the data files a reader meets: required ones checked, unknown ones kept and ignored.

Core module (no files). A dataset's ``manifest.json`` and its frames' JSON may come from a newer
skynav or from another program: docs/conventions.md "Files" fixes the required keys (checked with
their types against the published schemas, :mod:`skynav.datasets.truth_schema`) and welcomes more.
A reader keeps every key it does not know in the dict it returns and says so once per dataset
(:func:`note_unknown_keys`, a :class:`~skynav.infra.errors.SkynavWarning`); it never refuses a
file for them. Configuration files (scenes, recipes, facilities) stay strict: that is their
readers' business, not this module's.

The one place a data file's record is read by a strict constructor is its camera
(:meth:`skynav.scenes.camera.Camera.from_dict` refuses a key it does not know, as configuration
must): :func:`camera_from_record` gives it the keys it knows and returns the others.
"""

from __future__ import annotations

import copy
import functools
import os
import warnings

from skynav.infra.errors import ConfigValueError, SkynavWarning
from skynav.scenes.camera import Camera

from .truth_schema import load_schema

__all__ = ["known_keys", "unknown_keys", "note_unknown_keys", "camera_from_record"]


@functools.lru_cache(maxsize=None)
def known_keys(schema: str) -> frozenset:
    """Top-level keys a published schema names (``"skynav.frame/2"``, ``"skynav.dataset/1"``)."""
    return frozenset(load_schema(schema).get("properties", {}))


def unknown_keys(record, schema: str) -> list:
    """Top-level keys of ``record`` that ``schema`` does not name, sorted (empty for a non-dict)."""
    return sorted(k for k in record if k not in known_keys(schema)) if isinstance(record, dict) else []


def note_unknown_keys(where, keys, what: str, *, kind: str | None = None) -> None:
    """One warning naming the keys a reader kept and ignored (nothing when there are none).

    Said once per process for each ``where`` (a dataset folder or a file) and ``kind`` of record
    (default ``what``): a dataset opened again, by another reader or from another call site, is
    not said again. The command line prints it as one ``skynav: warning:`` line.
    """
    keys = sorted(set(keys))
    if not keys:
        return
    said = (os.path.realpath(os.fspath(where)), kind or what)
    if said in _SAID:
        return
    _SAID.add(said)
    shown = ", ".join(keys[:8]) + (f" (+{len(keys) - 8} more)" if len(keys) > 8 else "")
    warnings.warn(f"{where}: {what} has keys this skynav does not know ({shown}); kept and ignored",
                  SkynavWarning, stacklevel=3)


#: (dataset or file, kind of record) already said by :func:`note_unknown_keys` in this process
_SAID: set = set()


def camera_from_record(record, *, max_unknown: int = 64):
    """``(Camera, unknown keys)`` of a data file's camera record.

    Keys :meth:`Camera.from_dict` does not know (``camera.lens_serial``,
    ``camera.sensor.temperature_c``) are left out, and returned as dotted names; every known key
    is checked as :meth:`Camera.from_dict` checks it (a wrong value or type raises its
    :class:`~skynav.infra.errors.ConfigValueError`, naming the key).
    """
    rec, dropped = record, []
    for _ in range(max_unknown + 1):
        try:
            return Camera.from_dict(rec), dropped
        except ConfigValueError as exc:
            path = str(exc.key).split(".")
            if not str(exc.allowed).startswith("no such key") or path[0] != "camera" or len(path) < 2:
                raise
            if not dropped:
                rec = copy.deepcopy(record)  # the caller's record stays as the file has it
            node = rec
            for p in path[1:-1]:
                node = node[p]
            node.pop(path[-1])
            dropped.append(exc.key)
    raise ConfigValueError("camera", f"{len(dropped)} unknown keys", f"at most {max_unknown} keys skynav does not know")
