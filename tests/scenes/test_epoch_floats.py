"""One meaning for a float epoch: TDB seconds past J2000 everywhere (names end in ``_tdb_s``)."""

import numpy as np
import pytest
from astropy.time import Time

from skynav.scenes import timescales


def test_a_float_epoch_is_tdb_seconds_past_j2000():
    # independent reference: astropy's own JD arithmetic, 10 days and 1.5 s after J2000 TDB
    t_tdb_s = 10 * 86400.0 + 1.5
    want = Time(2451545.0 + 10.0, 1.5 / 86400.0, format="jd", scale="tdb")
    got = timescales.to_time(t_tdb_s)
    assert abs((got.tdb - want).to_value("s")) < 1e-9
    assert timescales.tdb_seconds(t_tdb_s) == t_tdb_s  # passed through unchanged: the same code, exact
    assert timescales.tdb_seconds("2000-01-11T12:00:01.5") == pytest.approx(t_tdb_s, abs=1e-6)
    arr = np.array([0.0, t_tdb_s])
    assert np.array_equal(timescales.tdb_seconds(arr), arr)
    assert timescales.tdb_seconds(timescales.time_from_tdb_seconds(t_tdb_s)) == pytest.approx(t_tdb_s, abs=1e-6)


def test_build_scene_and_to_time_agree_on_a_float_epoch():
    """build_scene's float epoch and to_time's float epoch have the same meaning."""
    from skynav.scenes import presets
    from skynav.scenes.scene import build_scene, resolve_spec

    spec = presets.default_scene_spec()
    t, r, v, R, sky = resolve_spec(spec)
    a = build_scene(t, position_km=r, velocity_km_s=v, R_cam_icrs=R, camera=spec.camera, sky=sky)
    b = build_scene(timescales.to_time(t), position_km=r, velocity_km_s=v, R_cam_icrs=R, camera=spec.camera, sky=sky)
    assert a.epoch_tdb_s == t and b.epoch_tdb_s == pytest.approx(t, abs=1e-6)
