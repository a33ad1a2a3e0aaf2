"""Ground truth on disk: canonical JSON bytes, reading, and validation against JSON Schema.

Adapter module. The contracts are published as JSON Schema (draft 2020-12) files inside the
package, ``skynav/datasets/schemas/frame.schema.json`` (``skynav.frame/2``, one frame's truth)
and ``manifest.schema.json`` (``skynav.dataset/1``, a dataset's ``manifest.json``); outside
tools can validate against them without skynav. Their required keys are the fixed names of
docs/conventions.md "Files"; every object allows more keys, so new fields never break a reader.

- :func:`truth_json_bytes` / :func:`write_truth_json`: canonical bytes (insertion order, ASCII,
  shortest round-trip floats, NaN as ``null``, one star or body per line), written atomically;
- :func:`read_truth_json`: the dict back (checks the schema name only: cheap);
- :func:`validate_truth`, :func:`validate_manifest`, :func:`schema_problems`: every violation
  as one line ``<JSON path>: <what is wrong>``, e.g. ``$.attitude.q_cam_icrs: missing``.

The typed view of a truth file is :class:`skynav.datasets.frame_truth.FrameTruth`.
"""

from __future__ import annotations

import functools
import json
import math
import os
from collections.abc import Mapping
from importlib.resources import files

import numpy as np
import orjson

from skynav.infra.atomic_files import atomic_write_bytes, open_binary

from .errors import TruthSchemaError
from .layout import MANIFEST_SCHEMA

__all__ = [
    "FRAME_SCHEMA",
    "MANIFEST_SCHEMA",
    "TruthSchemaError",
    "load_schema",
    "schema_problems",
    "truth_to_jsonable",
    "truth_json_bytes",
    "write_truth_json",
    "read_truth_json",
    "validate_truth",
    "validate_manifest",
]

FRAME_SCHEMA = "skynav.frame/2"
#: Frame schema versions read (version 2 added ``camera.psf`` and ``centre_of_light_xy``; a
#: version 1 file is a version 2 file without them). One JSON Schema file covers both.
FRAME_SCHEMAS_READ = ("skynav.frame/1", FRAME_SCHEMA)
_SCHEMA_FILES = {FRAME_SCHEMA: "frame.schema.json", "skynav.frame/1": "frame.schema.json",
                 MANIFEST_SCHEMA: "manifest.schema.json"}


# ----------------------------------------------------------------------------- ground truth
class _Slow(Exception):
    """Internal: the fast conversion met something it leaves to the checked one."""


def _fast_jsonable(obj):
    tp = type(obj)
    if tp is float:
        if obj != obj:
            return None
        if obj - obj != 0.0:  # inf - inf is NaN
            raise _Slow
        return obj
    if tp is int or tp is str or tp is bool or obj is None:
        return obj
    if tp is dict:
        out = {}
        for k, v in obj.items():
            if type(k) is not str:
                raise _Slow
            out[k] = _fast_jsonable(v)
        return out
    if tp is np.ndarray:
        kind = obj.dtype.kind
        if kind in "iub" or (kind == "f" and np.isfinite(obj).all()):
            return obj.tolist()  # Python numbers in nested lists: nothing left to convert
        return _fast_jsonable(obj.tolist())
    if tp is list or tp is tuple:
        return [_fast_jsonable(v) for v in obj]
    raise _Slow


def truth_to_jsonable(obj, _where: str = "truth"):
    """Plain-JSON copy of ground truth: numpy arrays/scalars to lists/numbers, NaN to None.

    Mappings keep their insertion order; tuples become lists. ``+-inf`` has no JSON form and is
    refused (a truth value must be finite or NaN = "not defined").

    Raises
    ------
    TruthSchemaError
        Non-string keys, infinities or types JSON cannot hold, naming where.
    """
    try:  # plain dicts, lists, Python and numpy numbers: no per-item bookkeeping
        return _fast_jsonable(obj)
    except _Slow:
        return _checked_jsonable(obj, _where)


def _checked_jsonable(obj, _where: str):
    if isinstance(obj, Mapping):
        out = {}
        for k, v in obj.items():
            if not isinstance(k, str):
                raise TruthSchemaError(f"{_where}: key {k!r} is not a string")
            out[k] = _checked_jsonable(v, f"{_where}.{k}")
        return out
    if isinstance(obj, np.ndarray):
        return _checked_jsonable(obj.tolist(), _where)
    if isinstance(obj, (list, tuple)):
        return [_checked_jsonable(v, f"{_where}[{i}]") for i, v in enumerate(obj)]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if obj is None or isinstance(obj, (bool, str, int)):
        return obj
    if isinstance(obj, float):
        obj = float(obj)
        if math.isnan(obj):
            return None
        if math.isinf(obj):
            raise TruthSchemaError(f"{_where} = {obj}: infinity has no JSON form; use NaN (written as null) or a finite value")
        return obj
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    raise TruthSchemaError(f"{_where}: value of type {type(obj).__name__} cannot be written to JSON")


_ENCODE = json.JSONEncoder(ensure_ascii=True, allow_nan=False, separators=(",", ":")).encode


def _encode_line(value) -> bytes:
    """One line of the layout: orjson (compact separators, shortest round-trip floats, 20-30
    times the standard library's C encoder, whose ``float.__repr__`` per number dominated a
    frame's encode); the standard library where orjson cannot hold the value (an integer past
    64 bits) or writes non-ASCII (kept ``\\u`` escaped). Both read back to the same values."""
    try:
        b = orjson.dumps(value)
    except orjson.JSONEncodeError:
        return _ENCODE(value).encode("ascii")
    return b if b.isascii() else _ENCODE(value).encode("ascii")


def _is_leaf(value) -> bool:
    """True for what goes on one line: scalars and lists of scalars or of lists (truth lists are
    homogeneous, so the first item stands for all). Works on the truth as given (tuples, numpy
    arrays) and on its :func:`truth_to_jsonable` copy alike; raises :class:`_Slow` where only
    the copy can say (a mapping that is not a dict, an array of objects)."""
    while True:
        tp = type(value)
        if tp is float or tp is int or tp is str or tp is bool or value is None:
            return True
        if tp is list or tp is tuple:
            if not value:
                return True
            value = value[0]
            continue
        if tp is dict:
            return False
        if (tp is np.ndarray and value.dtype.kind == "O") or isinstance(value, (Mapping, list, tuple)):
            raise _Slow  # an array of objects, a subclass of dict, list or tuple
        return True  # a numeric array or a numpy scalar: one line


def _is_flat_record(value) -> bool:
    return type(value) is dict and all(_is_leaf(v) for v in value.values())


def _line(value) -> bytes:
    """One line, from the value as given: orjson reads plain Python numbers, strings, lists,
    tuples and str-keyed dicts itself and writes what :func:`_encode_line` writes for their
    :func:`truth_to_jsonable` copy (a tuple as a list, NaN as ``null``), so the copy is made
    only for a line orjson refuses (numpy values, keys that are not strings, huge integers) or
    writes ``null`` in (NaN, None, or an infinity that must be refused) or non-ASCII in.
    :class:`_Slow` (the whole truth goes the checked way) where the copy needs the checks."""
    try:
        b = orjson.dumps(value)
    except orjson.JSONEncodeError:
        b = None
    if b is None or b"null" in b or not b.isascii():
        return _encode_line(_fast_jsonable(value))
    return b


def _flat_records_without_null(b: bytes, n: int) -> bool:
    """Whether orjson's bytes ``b`` of a list of ``n`` mappings hold exactly ``n`` "{" (no record
    holds a mapping) and no ``null`` (orjson's NaN and None): ``b.count(b"{") == n and b"null"
    not in b``, by numpy over the bytes (a quarter of their time on a frame's 150 kB of stars)."""
    a = np.frombuffer(b, np.uint8)
    if np.count_nonzero(a == ord("{")) != n:
        return False
    i = np.flatnonzero(a[:-3] == ord("n"))
    return not ((a[i + 1] == ord("u")) & (a[i + 2] == ord("l")) & (a[i + 3] == ord("l"))).any()


def _emit(value, indent: bytes, out: list) -> None:
    """Canonical layout: a mapping has one key per line (2-space indent); lists of numbers,
    matrices and flat records (a star, a body) are written on one line each."""
    if _is_leaf(value):
        out.append(_line(value))
        return
    inner = indent + b"  "
    if type(value) is dict:
        if not value:
            out.append(b"{}")
            return
        out.append(b"{\n")
        last = len(value) - 1
        for i, (k, v) in enumerate(value.items()):
            if type(k) is not str:
                raise _Slow
            out.append(inner + _encode_line(k) + b": ")
            _emit(v, inner, out)
            out.append(b",\n" if i < last else b"\n")
        out.append(indent + b"}")
        return
    # a list holding mappings: one item per line, flat records on one line
    if all(type(v) is dict for v in value):
        # a list of records (the stars, the bodies) in one orjson call: when its bytes hold one
        # "{" per record, no record holds a mapping (each is flat) and every "},{" is a boundary
        # between two records, so that splitting there gives the lines _line writes
        try:
            b = orjson.dumps(value)
        except orjson.JSONEncodeError:
            b = None
        if b is not None and b.isascii() and _flat_records_without_null(b, len(value)):
            # (split and join: the bytes of replace(), in half its time on 150 kB)
            out.append(b"[\n" + inner + (b"},\n" + inner + b"{").join(b[1:-1].split(b"},{")) + b"\n" + indent + b"]")
            return
    out.append(b"[\n")
    last = len(value) - 1
    for i, v in enumerate(value):
        out.append(inner)
        if _is_flat_record(v):
            out.append(_line(v))
        else:
            _emit(v, inner, out)
        out.append(b",\n" if i < last else b"\n")
    out.append(indent + b"]")


def truth_json_bytes(truth: Mapping) -> bytes:
    """Canonical bytes of ground truth: insertion order, ASCII, shortest round-trip floats; one
    key per line (2-space indent), and each list of numbers and each flat record (one star, one
    body) on one line with compact separators, so that a frame with 700 stars is 700 readable
    lines, not 20 000. Every float reads back bit-exact.

    The layout is written from the truth as given (plain Python values: no copy); where that
    meets something only :func:`truth_to_jsonable` handles (numpy values, non-dict mappings,
    infinities to refuse), the whole truth is converted first and written again: the same bytes
    either way, since both walk the same layout with the same line encoder."""
    if not isinstance(truth, Mapping) or truth.get("schema") not in FRAME_SCHEMAS_READ:
        got = truth.get("schema") if isinstance(truth, Mapping) else type(truth).__name__
        raise TruthSchemaError(f'ground truth needs "schema": "{FRAME_SCHEMA}"; got {got!r}', [f"schema: {got!r}"])
    out: list = []
    try:
        if type(truth) is not dict:
            raise _Slow
        _emit(truth, b"", out)
    except _Slow:
        out = []
        _emit(truth_to_jsonable(truth), b"", out)
    out.append(b"\n")
    return b"".join(out)


def write_truth_json(path, truth: Mapping, *, strict: bool = False) -> None:
    """Write one frame's ground truth as canonical JSON, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Destination ``.json``.
    truth : mapping
        Must hold ``"schema": "skynav.frame/2"`` (or ``/1``); numpy values are converted, NaN becomes
        ``null``. Key order is kept as given (callers build it in a fixed order), so equal
        truth gives equal bytes.
    strict : bool
        Also refuse truth for which :func:`validate_truth` finds problems.

    Raises
    ------
    TruthSchemaError
        Missing/wrong schema, infinities, unserialisable values, or (strict) schema problems.
    """
    if strict:
        problems = validate_truth(truth)
        if problems:
            raise TruthSchemaError(f"ground truth has {len(problems)} problem(s): {'; '.join(problems[:5])}", problems)
    atomic_write_bytes(path, truth_json_bytes(truth))


def read_truth_json(source) -> dict:
    """Ground truth of one frame (``null`` comes back as None); checks the schema name."""
    with open_binary(source) as f:
        truth = json.loads(f.read().decode("utf-8"))
    if not isinstance(truth, dict) or truth.get("schema") not in FRAME_SCHEMAS_READ:
        got = truth.get("schema") if isinstance(truth, dict) else type(truth).__name__
        raise TruthSchemaError(f'not a skynav frame file: "schema" is {got!r}, expected "{FRAME_SCHEMA}"')
    return truth


# ----------------------------------------------------------------------------- JSON Schema
@functools.lru_cache(maxsize=None)
def _schema_text(name: str) -> str:
    if name not in _SCHEMA_FILES:
        raise KeyError(f"no published schema {name!r}; known: {', '.join(_SCHEMA_FILES)}")
    return (files("skynav.datasets") / "schemas" / _SCHEMA_FILES[name]).read_text(encoding="utf-8")


def load_schema(name: str = FRAME_SCHEMA) -> dict:
    """The published JSON Schema (draft 2020-12) of the frame truth or of the manifest.

    The files are package data: ``importlib.resources.files("skynav.datasets") / "schemas"``.

    Parameters
    ----------
    name : str
        ``"skynav.frame/2"`` (``"skynav.frame/1"`` reads the same file) or ``"skynav.dataset/1"``.

    Returns
    -------
    dict
        A fresh copy of the schema (the caller may change it).

    Raises
    ------
    KeyError
        No published schema of that name.

    Examples
    --------
    >>> from skynav.datasets import load_schema
    >>> load_schema("skynav.frame/2")["title"]
    'skynav.frame/2: ground truth of one frame'
    >>> load_schema("skynav.dataset/1")["title"]
    'skynav.dataset/1: manifest.json of a dataset folder'
    """
    return json.loads(_schema_text(name))


@functools.lru_cache(maxsize=None)
def _validator(name: str):
    import jsonschema  # adapter-local import: only validation needs it

    schema = load_schema(name)
    cls = jsonschema.validators.validator_for(schema)
    cls.check_schema(schema)
    return cls(schema)


def _json_path(path) -> str:
    """JSONPath of a location: ``$.stars[3].xy``; keys that are not identifiers in brackets,
    ``$.files["frames/000000.png"]``."""
    out = "$"
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else f".{p}" if str(p).isidentifier() else f"[{json.dumps(p)}]"
    return out


def _short(value) -> str:
    text = json.dumps(value) if not isinstance(value, (dict, list)) else type(value).__name__.replace("dict", "object").replace("list", "array")
    return text if len(text) <= 40 else text[:37] + "..."


def _problem_lines(error) -> list:
    """One line per violation: ``<JSON path>: <what>`` (short; never the whole instance)."""
    path = _json_path(error.absolute_path)
    v, want, got = error.validator, error.validator_value, error.instance
    if v == "required":
        return [f"{_json_path([*error.absolute_path, k])}: missing" for k in want if isinstance(got, dict) and k not in got]
    if v == "type":
        kinds = want if isinstance(want, list) else [want]
        return [f"{path}: {_short(got)} is not of type {' or '.join(kinds)}"]
    if v in ("minItems", "maxItems"):
        return [f"{path}: {len(got)} items, expected {'at least' if v == 'minItems' else 'at most'} {want}"]
    if v == "const":
        return [f"{path}: {_short(got)}, expected {json.dumps(want)}"]
    if v == "pattern":
        return [f"{path}: {_short(got)} does not match {want}"]
    if v in ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum"):
        return [f"{path}: {_short(got)} violates {v} {want}"]
    msg = error.message.splitlines()[0] if error.message else v
    return [f"{path}: {msg if len(msg) <= 100 else msg[:97] + '...'}"]


# Keywords whose verdict depends only on a value's skeleton (see _skeleton): where the items of a
# top-level list use no others, validating one item per distinct skeleton is exact.
_STRUCTURAL = frozenset({"type", "required", "properties", "items", "minItems", "maxItems", "$ref", "description"})


def _structural(node, defs) -> bool:
    if isinstance(node, list):
        return all(_structural(x, defs) for x in node)
    if not isinstance(node, dict):
        return True
    if not set(node) <= _STRUCTURAL:
        return False
    if "$ref" in node and not _structural(defs[node["$ref"].rsplit("/", 1)[-1]], defs):
        return False
    return ("items" not in node or _structural(node["items"], defs)) and all(_structural(v, defs) for v in node.get("properties", {}).values())


@functools.lru_cache(maxsize=None)
def _dedupable_lists(name: str) -> frozenset:
    """Top-level list keys of a schema whose item schema is purely structural."""
    schema = load_schema(name)
    defs = schema.get("$defs", {})
    return frozenset(k for k, sub in schema.get("properties", {}).items()
                     if isinstance(sub, dict) and sub.get("type") == "array" and _structural(sub.get("items"), defs))


def _skeleton(v):
    """What the structural keywords see of a JSON value: types, lengths and keys; numbers only as
    integer-valued or not (``"integer"`` accepts 3.0). Leaves become tags, never values, so that
    ``0``, ``0.0`` and ``False`` (equal in Python) stay apart."""
    tp = type(v)
    if tp is dict:
        return ("{", *((k, _skeleton(x)) for k, x in v.items()))
    if tp is list:
        return ("[", *(_skeleton(x) for x in v))
    if tp is float:
        return "f.0" if v.is_integer() else "f"
    return _TAGS.get(tp, "?")


_TAGS = {int: "i", str: "s", bool: "b", type(None): "n"}


def schema_problems(instance, name: str = FRAME_SCHEMA) -> list:
    """Violations of a published schema by a JSON value, one line each, sorted by JSON path.

    Validated with ``jsonschema`` against the schema file. For speed (a frame lists hundreds of
    stars, and ``jsonschema`` takes about a millisecond per star), the items of a top-level list
    whose item schema uses only structural keywords (``type``, ``required``, ``properties``,
    ``items``, ``minItems``, ``maxItems``) are validated once per distinct skeleton (types, lengths,
    keys): exact for such schemas; a violation is reported at the first item that has it.

    Parameters
    ----------
    instance : object
        Plain JSON data (what ``json.loads`` returns).
    name : str
        ``"skynav.frame/2"`` or ``"skynav.dataset/1"``.

    Returns
    -------
    list of str
        Empty when it conforms, else e.g. ``["$.stars[2].xy: 3 items, expected at most 2"]``.
    """
    first_index = {}  # (list key, index in the reduced list) -> index in the instance
    if isinstance(instance, dict):
        reduced = dict(instance)
        for key in _dedupable_lists(name):
            items = instance.get(key)
            if type(items) is not list:
                continue
            seen, kept = {}, []
            for i, item in enumerate(items):
                sk = _skeleton(item)
                if sk not in seen:
                    seen[sk] = len(kept)
                    first_index[(key, len(kept))] = i
                    kept.append(item)
            reduced[key] = kept
        instance = reduced
    lines = []
    for error in _validator(name).iter_errors(instance):
        p = error.absolute_path
        if len(p) >= 2 and (p[0], p[1]) in first_index:
            error.path[1] = first_index[(p[0], p[1])]  # relative == absolute at the top level
        lines.extend(_problem_lines(error))
    return sorted(set(lines))


def validate_truth(truth) -> list:
    """Problems of one frame's ground truth against ``frame.schema.json``; empty when it conforms.

    Works on the in-memory dict (numpy values, NaN) as on what :func:`read_truth_json` returns:
    the dict is converted as :func:`truth_json_bytes` would write it, then validated. Extra keys
    are welcome and not reported.

    Parameters
    ----------
    truth : dict
        One frame's ground truth (``skynav.frame/2``), in memory or as read from its JSON.

    Returns
    -------
    list of str
        E.g. ``["$.attitude.q_cam_icrs: missing", "$.stars[2].xy: 3 items, expected at most 2"]``.

    Examples
    --------
    >>> from skynav.datasets import validate_truth
    >>> validate_truth({"schema": "skynav.frame/2"})[:2]
    ['$.attitude: missing', '$.bodies: missing']
    """
    try:
        plain = truth_to_jsonable(truth)
    except TruthSchemaError as exc:
        return [str(exc)]
    return schema_problems(plain, FRAME_SCHEMA)


def validate_manifest(manifest) -> list:
    """Problems of a dataset's ``manifest.json`` content against ``manifest.schema.json``.

    Parameters
    ----------
    manifest : dict
        The parsed ``manifest.json`` (``skynav.dataset/1``).

    Returns
    -------
    list of str
        One line per problem with its JSON path; empty when the manifest conforms.

    Examples
    --------
    >>> from skynav.datasets import validate_manifest
    >>> validate_manifest({})[:2]
    ['$.camera: missing', '$.complete: missing']
    """
    return schema_problems(manifest, MANIFEST_SCHEMA)
