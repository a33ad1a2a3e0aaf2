"""The facility file's schema (skynav.facility/1): the published file is the checker's mapping, a
valid draft 2020-12 schema, and ``jsonschema`` itself agrees with skynav's checker on fuzzed files."""

from __future__ import annotations

import json
import math
from importlib.resources import files

import jsonschema
import pytest
from hypothesis import HealthCheck, given, settings

from skynav.infra.errors import ConfigValueError
from skynav.scenes.facility import PRESETS
from skynav.scenes.facility_schema import FACILITY_SCHEMA, _check_node, schema_json, validate_facility_mapping

from ..cli.test_fuzz_bench_files import facility_docs


def test_the_published_file_is_the_checkers_schema_and_a_valid_draft_2020_12_schema():
    text = (files("skynav.datasets") / "schemas" / "facility.schema.json").read_text(encoding="utf-8")
    assert text == schema_json(), "regenerate: python -m skynav.scenes.facility_schema > datasets/schemas/facility.schema.json"
    jsonschema.Draft202012Validator.check_schema(json.loads(text))


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_what_skynav_writes_follows_the_schema(name):
    m = json.loads(json.dumps(PRESETS[name]().to_mapping()))
    jsonschema.validate(m, FACILITY_SCHEMA)
    validate_facility_mapping(m)


def _finite(v):
    if isinstance(v, float):
        return math.isfinite(v)
    if isinstance(v, dict):
        return all(_finite(x) for x in v.values())
    if isinstance(v, list):
        return all(_finite(x) for x in v)
    return True


@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(doc=facility_docs())
def test_jsonschema_and_the_checker_agree(doc):
    """The keywords the checker interprets mean what JSON Schema says (JSON holds no NaN/inf, so
    documents with them are left to the checker alone, which refuses them)."""
    if not _finite(doc):
        return
    ours = True
    try:
        _check_node(doc, FACILITY_SCHEMA, "")
    except ConfigValueError:
        ours = False
    theirs = jsonschema.Draft202012Validator(FACILITY_SCHEMA).is_valid(doc)
    assert ours == theirs, doc
