"""What the pipeline may see (Observation, no truth) and what scoring reads (FrameTruth)."""

from __future__ import annotations

import dataclasses
import gc
import json
import math
import pickle
import types

import numpy as np
import pytest

import skynav.datasets as D
from skynav.datasets import CalibrationErrorModel, FrameTruth, Observation
from skynav.datasets.errors import TruthSchemaError
from skynav.infra.errors import ConfigValueError
from skynav.datasets.observation import make_observation
from skynav.scenes.camera import Camera
from skynav.scenes.timescales import tdb_seconds

from .conftest import small_recipe


@pytest.fixture(scope="module")
def small_ds(tmp_path_factory):
    out = tmp_path_factory.mktemp("obs") / "ds"
    D.generate(small_recipe(frames=3), out, workers=1, progress=False)
    return out


def _truth_json(ds_root, k):
    return json.loads((ds_root / "frames" / f"{k:06d}.json").read_text())


# ----------------------------------------------------------------------------- Observation
def test_observation_carries_image_epoch_exposure_and_camera(small_ds):
    ds = D.open(small_ds)
    obs = ds.observation(2)
    raw = _truth_json(small_ds, 2)
    assert isinstance(obs, Observation) and obs.index == 2
    np.testing.assert_array_equal(obs.dn, ds[2].dn)
    assert not obs.dn.flags.writeable
    assert obs.exposure_s == raw["camera"]["exposure_s"]
    assert obs.camera == Camera.from_dict(raw["camera"]) and obs.calibration_error is None
    # epoch: float TDB seconds past J2000 and an astropy Time; the file's ISO string is rounded to 1 ms
    assert obs.epoch_tdb_s == raw["epoch"]["tdb_seconds_past_j2000"]
    assert abs(obs.epoch_tdb_s - tdb_seconds(raw["epoch"]["tdb_iso"])) < 1e-3
    assert obs.epoch.scale == "tdb" and abs(obs.epoch.jd - raw["epoch"]["jd_tdb"]) * 86400.0 < 1e-4
    assert ds.observation(-1).index == 2


# Everything an Observation may hold: the spacecraft's own data, nothing about how it was made.
OBSERVATION_FIELDS = {"index", "dn", "epoch_tdb_s", "exposure_s", "camera", "calibration_error"}


def _reachable(obj, limit=100000):
    """Every object reachable from ``obj`` through references (gc), classes and modules excluded."""
    seen, todo, out = {id(obj)}, [obj], []
    while todo and len(out) < limit:
        o = todo.pop()
        out.append(o)
        for r in gc.get_referents(o):
            if id(r) in seen or isinstance(r, (type, types.ModuleType, types.FunctionType, types.BuiltinFunctionType)):
                continue
            seen.add(id(r))
            todo.append(r)
    assert len(out) < limit
    return out


def test_observation_has_no_path_to_the_truth(small_ds):
    ds = D.open(small_ds)
    obs = ds.observation(0, calibration_error=CalibrationErrorModel(focal_length_rel_sigma=1e-4, seed=3))
    assert {f.name for f in dataclasses.fields(obs)} == OBSERVATION_FIELDS
    assert set(vars(obs)) == OBSERVATION_FIELDS
    raw = _truth_json(small_ds, 0)
    truth_strings = {raw["epoch"]["tdb_iso"], "skynav.frame/2", str(small_ds)}
    for o in _reachable(obs):
        assert not isinstance(o, (D.FrameRecord, D.Dataset, FrameTruth)), type(o)
        if isinstance(o, dict):
            assert "stars" not in o and "bodies" not in o and "attitude" not in o and "schema" not in o
        if isinstance(o, str):
            assert o not in truth_strings and "frames/" not in o
    # and the repr says nothing of it either
    assert "star" not in repr(obs) and "attitude" not in repr(obs)


def test_calibration_error_model_is_deterministic_and_applied(small_ds):
    ds = D.open(small_ds)
    true = ds.observation(1).camera
    m = CalibrationErrorModel(focal_length_rel_sigma=1e-3, principal_point_sigma_px=0.5, distortion_k1_sigma=1e-4, seed=11)
    a, b = ds.observation(1, calibration_error=m), ds.observation(2, calibration_error=m)
    assert a.calibration_error == m and a.camera == b.camera  # one calibration for every frame
    # the draw, by an independent route: the same four normals
    z = np.random.default_rng(11).standard_normal(4)
    K_true, K_cal = true.K, a.camera.K
    assert K_cal[0, 0] == pytest.approx(K_true[0, 0] * (1 + 1e-3 * z[0]), rel=1e-12)
    assert K_cal[1, 1] == pytest.approx(K_true[1, 1] * (1 + 1e-3 * z[0]), rel=1e-12)
    assert K_cal[0, 2] == pytest.approx(K_true[0, 2] + 0.5 * z[1], abs=1e-12)
    assert K_cal[1, 2] == pytest.approx(K_true[1, 2] + 0.5 * z[2], abs=1e-12)
    assert a.camera.distortion.k1 == pytest.approx(true.distortion.k1 + 1e-4 * z[3], abs=1e-15)
    assert dataclasses.replace(a.camera, focal_length_mm=true.focal_length_mm, cx=true.cx, cy=true.cy,
                               distortion=true.distortion) == true  # nothing else changed
    assert m.draw() == m.draw() and dataclasses.replace(m, seed=12).draw() != m.draw()
    assert CalibrationErrorModel().apply(true).K.tolist() == true.K.tolist()  # zero sigmas: exact
    assert pickle.loads(pickle.dumps(m)) == m and eval(repr(m), {"CalibrationErrorModel": CalibrationErrorModel}) == m


@pytest.mark.parametrize("kw", [{"focal_length_rel_sigma": -1e-3}, {"principal_point_sigma_px": math.nan},
                                {"distortion_k1_sigma": "0.1"}, {"seed": -1}, {"seed": 1.5}])
def test_calibration_error_model_refuses_bad_values(kw):
    with pytest.raises(ConfigValueError, match="calibration_error"):
        CalibrationErrorModel(**kw)


def test_make_observation_keeps_no_reference_to_the_dict(small_ds):
    raw = _truth_json(small_ds, 0)
    dn = np.zeros((256, 256), np.uint8)
    obs = make_observation(raw, dn, index=0)
    assert obs.dn is not dn and not obs.dn.flags.writeable and dn.flags.writeable
    assert not any(r is raw or r is raw["camera"] for r in _reachable(obs))


# ----------------------------------------------------------------------------- FrameTruth
def test_typed_truth_matches_the_json(small_ds):
    ds = D.open(small_ds)
    raw = _truth_json(small_ds, 1)
    t = ds.truth(1)
    assert isinstance(t, FrameTruth) and ds[1].truth == raw  # the dict view is unchanged
    assert t.epoch_tdb_iso == raw["epoch"]["tdb_iso"] and t.epoch_tdb_s == raw["epoch"]["tdb_seconds_past_j2000"]
    np.testing.assert_array_equal(t.position_km, raw["observer"]["position_km"])
    np.testing.assert_array_equal(t.R_cam_icrs, raw["attitude"]["R_cam_icrs"])
    assert t.R_cam_icrs.shape == (3, 3) and t.q_cam_icrs.shape == (4,)
    n = len(raw["stars"])
    assert len(t.stars) == n and t.stars.u_icrs.shape == (n, 3) and t.stars.xy.shape == (n, 2)
    assert t.stars.hip.dtype == np.int64 and t.stars.hip.tolist() == [s["hip"] for s in raw["stars"]]
    np.testing.assert_array_equal(t.stars.xy, [s["xy"] for s in raw["stars"]])
    np.testing.assert_array_equal(t.stars.electrons, [s["electrons"] for s in raw["stars"]])
    assert [b.name for b in t.bodies] == [b["name"] for b in raw["bodies"]]
    mars, raw_mars = t.body("mars"), next(b for b in raw["bodies"] if b["name"] == "mars")
    assert mars.phase_angle_rad == pytest.approx(math.radians(raw_mars["phase_angle_deg"]), rel=1e-15)
    assert mars.in_fov is raw_mars["in_fov"] and mars.distance_km == raw_mars["distance_km"]
    assert t.cosmic_rays.xy.shape == (len(raw["cosmic_rays"]), 2)
    assert t.seeds == raw["seeds"] and t.camera == raw["camera"] and t.raw["schema"] == "skynav.frame/2"
    assert not t.stars.xy.flags.writeable and not t.position_km.flags.writeable
    with pytest.raises(dataclasses.FrozenInstanceError):
        t.epoch_tdb_s = 0.0
    with pytest.raises(KeyError, match="bodies"):
        t.body("pluto")


def test_typed_truth_nulls_empty_lists_and_schema_errors():
    base = {
        "schema": "skynav.frame/2", "epoch": {"tdb_iso": "2030-01-01T00:00:00.000", "jd_tdb": 2462502.5},
        "observer": {"position_km": [1.0, 2.0, 3.0], "velocity_km_s": [0.0, 0.0, 0.0]},
        "attitude": {"R_cam_icrs": np.eye(3).tolist(), "q_cam_icrs": [1.0, 0, 0, 0], "angular_velocity_rad_s": [0, 0, 0]},
        "camera": {"K": np.eye(3).tolist(), "width": 4, "height": 4, "focal_length_mm": 1.0, "pixel_pitch_um": 1.0,
                   "f_number": 2.0, "exposure_s": 0.1, "bit_depth": 8},
        "stars": [], "bodies": [{"name": "mars", "xy": [None, None], "xy_geometric": None, "u_icrs": [1.0, 0.0, 0.0],
                                 "light_time_s": 1.0, "distance_km": 3e5, "v_mag": None, "phase_angle_deg": 10.0,
                                 "angular_diameter_px": 0.1, "in_fov": False, "visible": False, "resolved": False,
                                 "electrons": 0.0}],
        "cosmic_rays": [], "seeds": {"frame": 1},
    }
    t = FrameTruth.from_dict(base)
    assert t.stars.xy.shape == (0, 2) and t.stars.u_icrs.shape == (0, 3) and t.cosmic_rays.xy.shape == (0, 2)
    assert np.isnan(t.bodies[0].xy).all() and np.isnan(t.bodies[0].xy_geometric).all() and math.isnan(t.bodies[0].v_mag)
    # no tdb_seconds_past_j2000: the ISO string in TDB
    assert t.epoch_tdb_s == pytest.approx(tdb_seconds("2030-01-01T00:00:00.000"), abs=1e-6)
    bad = json.loads(json.dumps(base))
    del bad["attitude"]["q_cam_icrs"]
    with pytest.raises(TruthSchemaError, match=r"^x\.json: does not follow skynav\.frame/2: \$\.attitude\.q_cam_icrs: missing$"):
        FrameTruth.from_dict(bad, source="x.json")
