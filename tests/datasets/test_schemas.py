"""The published JSON Schemas (package data), checked with jsonschema itself, and `dataset verify`."""

from __future__ import annotations

import copy
import json
import shutil
import tomllib
from importlib.resources import files
from pathlib import Path

import jsonschema
import pytest

import skynav.datasets as D
from skynav.datasets.truth_schema import (
    FRAME_SCHEMA,
    MANIFEST_SCHEMA,
    load_schema,
    schema_problems,
    validate_manifest,
    validate_truth,
)

from .conftest import small_recipe

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def small_ds(tmp_path_factory):
    out = tmp_path_factory.mktemp("schemas") / "ds"
    D.generate(small_recipe(frames=3), out, workers=1, progress=False)
    return out


def test_schema_files_are_package_data_and_valid_json_schema():
    with open(REPO / "pyproject.toml", "rb") as f:
        data = tomllib.load(f)["tool"]["setuptools"]["package-data"]
    assert "schemas/*.json" in data["skynav.datasets"]
    for name, file in ((FRAME_SCHEMA, "frame.schema.json"), (MANIFEST_SCHEMA, "manifest.schema.json")):
        text = (files("skynav.datasets") / "schemas" / file).read_text(encoding="utf-8")
        schema = json.loads(text)
        assert schema == load_schema(name)
        jsonschema.Draft202012Validator.check_schema(schema)  # against the meta-schema
        assert name == schema["properties"]["schema"]["enum"][0] if name == FRAME_SCHEMA else schema["properties"]["schema"] == {"const": name}


def test_written_frames_and_manifest_follow_the_schemas(small_ds):
    # the reference is jsonschema's own validate on the whole file (no shortcut)
    for p in sorted((small_ds / "frames").glob("*.json")):
        truth = json.loads(p.read_text())
        jsonschema.validate(truth, load_schema(FRAME_SCHEMA))
        assert validate_truth(truth) == []
    manifest = json.loads((small_ds / "manifest.json").read_text())
    jsonschema.validate(manifest, load_schema(MANIFEST_SCHEMA))
    assert validate_manifest(manifest) == []


def _full_paths(instance, name):
    """JSON paths of every violation, by jsonschema alone (no shortcut)."""
    v = jsonschema.Draft202012Validator(load_schema(name))
    out = set()
    for e in v.iter_errors(instance):
        base = "$" + "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in e.absolute_path)  # identifiers only here
        if e.validator == "required":
            out.update(f"{base}.{k}" for k in e.validator_value if k not in e.instance)
        else:
            out.add(base)
    return out


def test_shortcut_over_repeated_records_finds_what_jsonschema_finds(small_ds):
    truth = json.loads((small_ds / "frames" / "000001.json").read_text())
    assert len(truth["stars"]) > 20
    bad = copy.deepcopy(truth)
    bad["stars"][3]["xy"] = [1.0, 2.0, 3.0]
    del bad["stars"][7]["hip"]
    bad["stars"][9]["hip"] = 2.5
    bad["stars"][11]["u_icrs"] = None  # null vector: allowed (NaN written as null)
    bad["bodies"][2]["in_fov"] = None
    bad["cosmic_rays"].append({"xy": [1.0], "electrons": "many"})
    bad["bodies"][3]["visible"] = 0  # equal to False in Python, not a JSON boolean
    bad["bodies"][4]["electrons"] = True  # a boolean is not a number in JSON Schema
    got = schema_problems(bad, FRAME_SCHEMA)
    assert {line.split(": ")[0] for line in got} == _full_paths(bad, FRAME_SCHEMA)
    assert "$.stars[3].xy: 3 items, expected at most 2" in got and "$.stars[7].hip: missing" in got
    assert "$.stars[9].hip: 2.5 is not of type integer" in got
    # the same violation in many records is reported at the first one
    twice = copy.deepcopy(truth)
    del twice["stars"][4]["hip"], twice["stars"][6]["hip"]
    assert [p for p in schema_problems(twice) if "hip" in p] == ["$.stars[4].hip: missing"]


def test_unknown_keys_are_welcome_everywhere(small_ds):
    truth = json.loads((small_ds / "frames" / "000000.json").read_text())
    truth["sun"]["elongation_deg"] = 3.0
    truth["render"]["backend_ran"] = "numpy"
    for cr in truth["cosmic_rays"]:
        cr["track"] = {"start_xy": [0.0, 0.0], "end_xy": [1.0, 1.0]}
    truth["bodies"][0]["sun_angle_deg"] = {"renamed": True}
    assert validate_truth(truth) == []
    m = json.loads((small_ds / "manifest.json").read_text())
    m["render_options"] = {"noise": True}
    assert validate_manifest(m) == []


def test_manifest_violations_name_the_json_path(small_ds):
    m = json.loads((small_ds / "manifest.json").read_text())
    bad = copy.deepcopy(m)
    del bad["master_seed"]
    bad["files"]["frames/000000.png"] = "not-a-sha"
    bad["counts"]["frames"] = -1
    got = validate_manifest(bad)
    assert "$.master_seed: missing" in got
    assert '$.files["frames/000000.png"]: "not-a-sha" does not match ^[0-9a-f]{64}$' in got
    assert any(line.startswith("$.counts.frames:") for line in got)


def test_verify_reports_a_schema_violation_as_one_line_with_file_and_path(small_ds, tmp_path):
    copy_ = tmp_path / "ds"
    shutil.copytree(small_ds, copy_)
    js = copy_ / "frames" / "000002.json"
    truth = json.loads(js.read_text())
    del truth["attitude"]["q_cam_icrs"]
    js.write_text(json.dumps(truth))
    mp = copy_ / "manifest.json"
    m = json.loads(mp.read_text())
    m["master_seed"] = "seven"
    mp.write_text(json.dumps(m))
    report = D.verify(copy_)
    assert not report.ok
    assert "frames/000002.json: does not follow skynav.frame/2: $.attitude.q_cam_icrs: missing" in report.problems
    assert 'manifest.json: does not follow skynav.dataset/1: $.master_seed: "seven" is not of type integer' in report.problems
    assert len(report.problems) == 2, report.problems
    # and the command line prints it (exit 1: a damaged dataset, not a usage error)
    from skynav.cli import main

    assert main(["dataset", "verify", "-q", str(copy_)]) == 1
