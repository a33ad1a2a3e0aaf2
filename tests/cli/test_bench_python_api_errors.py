"""The Python API raises skynav's errors (subclasses of the builtin ones) with one-line messages:
``skynav.datasets.open``, ``ds[k]``, ``ds.observation(k)``, ``ds.truth(k)``, the facility and
calibration loaders."""

from __future__ import annotations

import json
import shutil

import pytest
import yaml

from skynav.infra.errors import SkynavError


@pytest.fixture(scope="module")
def ds_root(tmp_path_factory):
    from skynav import datasets

    recipe = datasets.preset_recipe("montecarlo")
    recipe.update(frames=1, formats=["png", "json"], camera={"preset": "paper", "width": 96, "height": 96})
    root = tmp_path_factory.mktemp("api") / "ds"
    datasets.generate(recipe, root, workers=1, progress=False)
    return root


def _damaged(ds_root, tmp_path, edit):
    d = tmp_path / "ds"
    shutil.copytree(ds_root, d)
    p = d / "frames" / "000000.json"
    doc = json.loads(p.read_text())
    edit(doc)
    p.write_text(json.dumps(doc))
    return d


def _one_line(exc_info, builtin, text):
    assert isinstance(exc_info.value, SkynavError) and isinstance(exc_info.value, builtin)
    msg = str(exc_info.value)
    assert "\n" not in msg and text in msg, msg


def test_open_a_folder_that_is_not_a_dataset(tmp_path):
    import skynav.datasets as sd

    with pytest.raises(OSError) as e:
        sd.open(tmp_path)
    _one_line(e, OSError, str(tmp_path))


def test_index_out_of_range_and_of_a_wrong_type(ds_root):
    import skynav.datasets as sd

    ds = sd.open(ds_root)
    with pytest.raises(IndexError) as e:
        ds[5]
    _one_line(e, IndexError, "out of range")
    with pytest.raises(IndexError) as e:
        ds["0"]
    _one_line(e, IndexError, "integer")


@pytest.mark.parametrize("key, call", [("camera", "observation"), ("observer", "truth"), ("attitude", "truth"),
                                       ("epoch", "truth")])
def test_a_truth_without_a_section_gives_one_line(ds_root, tmp_path, key, call):
    import skynav.datasets as sd

    ds = sd.open(_damaged(ds_root, tmp_path, lambda d: d.pop(key)))
    with pytest.raises(ValueError) as e:
        getattr(ds, call)(0) if call == "observation" else ds.truth(0, validate=False)
    _one_line(e, ValueError, "000000.json")


def test_a_truth_with_a_damaged_camera_gives_one_line(ds_root, tmp_path):
    import skynav.datasets as sd

    ds = sd.open(_damaged(ds_root, tmp_path, lambda d: d.update(camera={"width": "wide"})))
    with pytest.raises(ValueError) as e:
        ds.observation(0)
    _one_line(e, ValueError, "000000.json")


def test_the_facility_loader_names_the_file_and_the_key(tmp_path):
    from skynav.calibration.facility_io import load_facility
    from skynav.scenes.facility import screen_small_preset, facility_from_mapping

    m = screen_small_preset().to_mapping()
    m["geometric"]["parameters"]["k_1"] = 0.1
    f = tmp_path / "f.yaml"
    f.write_text(yaml.safe_dump(m))
    with pytest.raises(ValueError) as e:
        load_facility(f)
    _one_line(e, ValueError, "did you mean geometric.parameters.k1")
    assert str(f) in str(e.value)
    with pytest.raises(ValueError) as e:
        facility_from_mapping({**m, "screen": [1, 2]})
    _one_line(e, ValueError, "screen = [1, 2]")


def test_the_calibration_readers_raise_skynav_errors(tmp_path):
    from skynav.calibration.patterns import read_patterns
    from skynav.calibration.radiometric import read_measurements

    (tmp_path / "patterns.json").write_text("[1, 2]")
    with pytest.raises(ValueError) as e:
        read_patterns(tmp_path)
    _one_line(e, ValueError, "patterns.json")
    (tmp_path / "pm.csv").write_bytes(b"\x89PNG\r\n\x1a\n\xff")
    with pytest.raises(ValueError) as e:
        read_measurements(tmp_path / "pm.csv")
    _one_line(e, ValueError, "pm.csv")


def test_a_former_facility_preset_name_is_refused_naming_the_new_one():
    """"bench" means only the benchmark commands: the facility presets are screen and screen_small."""
    from skynav.calibration.errors import FacilityFileError
    from skynav.calibration.facility_io import load_facility

    for old, new in (("bench", "screen"), ("bench_small", "screen_small")):
        with pytest.raises(FacilityFileError, match=f"now named {new} .*; give {new}$"):
            load_facility(old)
        assert load_facility(new).name == new
    import skynav.scenes as S

    with pytest.raises(AttributeError, match="skynav.scenes.bench_small_preset is now screen_small_preset"):
        S.bench_small_preset  # noqa: B018 - the attribute access is the test
