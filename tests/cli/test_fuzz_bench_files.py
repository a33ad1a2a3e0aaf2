"""Hypothesis fuzz of the bench's files: facility files, pattern manifests, power-meter tables.

Each generated file goes through the reader its command uses (``load_facility``,
``read_patterns``, ``read_measurements``); the only allowed outcomes are a value or a
:class:`~skynav.infra.errors.SkynavError` with a one-line message, never another exception (the
command line would print a traceback), and never a hang (a per-example deadline). The fast run is
CI-sized; the ``slow`` run tries 1000 files of each kind (``pytest -m slow
tests/cli/test_fuzz_bench_files.py``).
"""

from __future__ import annotations

import json
import math

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skynav.infra.errors import SkynavError

FAST = settings(max_examples=60, deadline=5000, suppress_health_check=list(HealthCheck), derandomize=True)
SLOW = settings(max_examples=1000, deadline=5000, suppress_health_check=list(HealthCheck), derandomize=True)

_scalars = st.one_of(st.none(), st.booleans(), st.integers(-10 ** 6, 10 ** 6), st.floats(allow_nan=True, allow_infinity=True),
                     st.text(max_size=8), st.sampled_from([0, 1, -1, 1e300, 16, 640, 50.0, 2.2, "png"]))
_values = st.recursive(_scalars, lambda inner: st.one_of(st.lists(inner, max_size=5),
                                                         st.dictionaries(st.text(max_size=6), inner, max_size=4)),
                       max_leaves=12)


def _good_facility():
    from skynav.scenes.facility import screen_small_preset

    return json.loads(json.dumps(screen_small_preset().to_mapping()))


def _paths(d, prefix=()):
    out = [prefix] if prefix else []
    if isinstance(d, dict):
        for k, v in d.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(d, list) and len(d) <= 8:
        for i, v in enumerate(d):
            out += _paths(v, prefix + (i,))
    return out


_FAC_PATHS = None


def _mutate(doc, path, value, delete):
    node = doc
    for p in path[:-1]:
        node = node[p]
    if delete and isinstance(node, dict):
        node.pop(path[-1], None)
    else:
        node[path[-1]] = value
    return doc


@st.composite
def facility_docs(draw):
    global _FAC_PATHS
    doc = _good_facility()
    if _FAC_PATHS is None:
        _FAC_PATHS = _paths(doc)
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(_FAC_PATHS))
        try:
            _mutate(doc, path, draw(_values), draw(st.booleans()))
        except (KeyError, IndexError, TypeError):
            pass
    if draw(st.booleans()):  # an unknown key somewhere
        doc[draw(st.text(min_size=1, max_size=6))] = draw(_values)
    return doc


def _check_facility(doc, tmp_path):
    from skynav.calibration.facility_io import load_facility

    f = tmp_path / "f.yaml"
    try:
        f.write_text(yaml.safe_dump(doc))
    except (yaml.YAMLError, UnicodeEncodeError):
        return
    try:
        fac = load_facility(f)
        fac.check_coverage()
    except SkynavError as exc:
        assert "\n" not in str(exc) and str(exc)


def _good_patterns():
    from skynav.calibration.patterns import SCHEMA, design
    from skynav.scenes.facility import screen_small_preset

    fac = screen_small_preset()
    pats = design(fac, phases=1)
    sc = fac.screen
    return {"schema": SCHEMA, "screen": {"width_px": sc.width_px, "height_px": sc.height_px, "bit_depth": sc.bit_depth},
            "png_scaling": "sbit", "significant_bits": sc.bit_depth,
            "patterns": [dict(p.to_json(), dots=p.to_json()["dots"][:6]) for p in pats]}


_GOOD_PATTERNS = None


@st.composite
def pattern_docs(draw):
    global _GOOD_PATTERNS
    if _GOOD_PATTERNS is None:
        _GOOD_PATTERNS = _good_patterns()
    doc = json.loads(json.dumps(_GOOD_PATTERNS))
    paths = _paths(doc)
    for _ in range(draw(st.integers(1, 3))):
        try:
            _mutate(doc, draw(st.sampled_from(paths)), draw(_values | st.sampled_from(["../x.png", "/etc/x.png", "a/b.png"])),
                    draw(st.booleans()))
        except (KeyError, IndexError, TypeError):
            pass
    return doc


def _check_patterns(doc, tmp_path):
    from skynav.calibration.patterns import read_patterns

    d = tmp_path / "p"
    d.mkdir(exist_ok=True)
    (d / "patterns.json").write_text(json.dumps(doc))
    try:
        screen, pats = read_patterns(d)
    except SkynavError as exc:
        assert "\n" not in str(exc)
        return
    for p in pats:  # what was accepted stays in its folder
        assert "/" not in p.file and not p.file.startswith(".") and p.file.endswith(".png")
        assert all(math.isfinite(v) for v in p.dots.ravel())


_cells = st.one_of(st.integers(-5, 1100).map(str), st.floats(allow_nan=True, allow_infinity=True).map(repr),
                   st.sampled_from(["", "nan", "inf", "-0", "1e-9", "x", "\ufeff", " 3 ", "1,2"]), st.text(max_size=4))


@st.composite
def csv_texts(draw):
    header = draw(st.sampled_from(["digital_count,lit_pixels,irradiance_w_m2", "\ufeffdigital_count,lit_pixels,irradiance_w_m2",
                                   "digital_count,lit_pixels", "dn,px,w", ""]))
    rows = draw(st.lists(st.lists(_cells, min_size=0, max_size=4), max_size=20))
    good = [f"{d},{1 + d % 7},{1e-9 * (1 + d) ** 2:.6e}" for d in range(0, 1024, 64)] if draw(st.booleans()) else []
    lines = [header] + good + [",".join(r) for r in rows]
    text = "\n".join(lines) + "\n"
    return text.encode("utf-8", "surrogatepass") if draw(st.booleans()) else text.encode("utf-16")


def _check_csv(data, tmp_path):
    from skynav.calibration.radiometric import read_measurements

    f = tmp_path / "pm.csv"
    f.write_bytes(data)
    try:
        d, n, e = read_measurements(f, max_dn=1023)
    except SkynavError as exc:
        assert "\n" not in str(exc)
        return
    assert len(d) >= 8 and all(math.isfinite(v) for v in (*d, *n, *e))


@FAST
@given(doc=facility_docs())
def test_fuzzed_facility_files_load_or_say_one_line(doc, tmp_path_factory):
    _check_facility(doc, tmp_path_factory.mktemp("fz"))


@FAST
@given(doc=pattern_docs())
def test_fuzzed_pattern_manifests_load_or_say_one_line(doc, tmp_path_factory):
    _check_patterns(doc, tmp_path_factory.mktemp("fz"))


@FAST
@given(data=csv_texts())
def test_fuzzed_power_meter_tables_load_or_say_one_line(data, tmp_path_factory):
    _check_csv(data, tmp_path_factory.mktemp("fz"))


@pytest.mark.slow
@SLOW
@given(doc=facility_docs())
def test_slow_1000_facility_files(doc, tmp_path_factory):
    _check_facility(doc, tmp_path_factory.mktemp("fz"))


@pytest.mark.slow
@SLOW
@given(doc=pattern_docs())
def test_slow_1000_pattern_manifests(doc, tmp_path_factory):
    _check_patterns(doc, tmp_path_factory.mktemp("fz"))


@pytest.mark.slow
@SLOW
@given(data=csv_texts())
def test_slow_1000_power_meter_tables(data, tmp_path_factory):
    _check_csv(data, tmp_path_factory.mktemp("fz"))
