"""CCSDS OEM/AEM in and out: hand-made KVN files skynav did not write, a second reader (the
``oem`` package) on skynav's OEM, scene files with ``observer: {oem: FILE}`` and
``attitude: {aem: FILE}``, and the errors (one line, the file named, exit 2).

The hand-made files (tests/scenes/data) were typed from the standards (CCSDS 502.0-B-3 and
504.0-B-2), with motions whose truth is analytic: uniform motion (the cubic Hermite between
two states of it is exact) and a uniform spin about the camera's +z axis (slerp is exact).
"""

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ccsds_ndm")

from skynav.cli import main  # noqa: E402
from skynav.infra.errors import ConfigValueError  # noqa: E402
from skynav.scenes import frames  # noqa: E402
from skynav.scenes.config import scene_spec_from_mapping  # noqa: E402
from skynav.scenes.errors import SceneFileError  # noqa: E402
from skynav.scenes.mission_ccsds import (aem_attitude, aem_kvn, oem_kvn, oem_state, read_aem,  # noqa: E402
                                         read_oem)
from skynav.scenes.scene_files import load_scene_file  # noqa: E402

DATA = Path(__file__).parent / "data"
R0 = np.array([1.2e8, -4.0e7, 2.5e7])
V0 = np.array([10.0, 20.0, -5.0])


def _tdb(utc_iso):
    from astropy.time import Time

    t = Time(utc_iso, scale="utc").tdb
    return ((t.jd1 - 2451545.0) + t.jd2) * 86400.0


def test_handmade_oem_two_segments_utc():
    tab = read_oem(DATA / "handmade.oem")
    assert len(tab.t_tdb_s) == 5
    # UTC epochs to TDB by astropy directly: 1 us (float64 seconds past J2000 resolve ~0.1 us)
    assert abs(tab.t_tdb_s[0] - _tdb("2027-02-01T00:00:00")) < 1e-6
    np.testing.assert_array_equal(tab.position_km[1], [120018000.0, -39964000.0, 24991000.0])
    # between samples of each segment: uniform motion, exact for cubic Hermite; the truth is in
    # UTC seconds, TDB runs at 1 + O(1e-8) of it: 1 m over an hour at 22 km/s
    for utc, dt in (("2027-02-01T00:15:00", 900.0), ("2027-02-01T02:30:00", 9000.0), ("2027-02-01T01:00:00", 3600.0)):
        r, v = oem_state(tab, _tdb(utc))
        assert np.max(np.abs(r - (R0 + V0 * dt))) < 1e-3
        assert np.max(np.abs(v - V0)) < 1e-6
    # the gap between the segments holds no data
    with pytest.raises(SceneFileError, match="between segments 1 and 2"):
        oem_state(tab, _tdb("2027-02-01T01:30:00"))


def test_a_segment_may_start_where_the_last_stopped(tmp_path):
    """A manoeuvre: segment 2 starts at segment 1's last epoch with another velocity; from that
    epoch on, segment 2's state holds."""
    text = (DATA / "handmade.oem").read_text()
    text = text.replace("START_TIME = 2027-02-01T02:00:00.000", "START_TIME = 2027-02-01T01:00:00.000")
    text = text.replace("2027-02-01T02:00:00.000 120072000.0 -39856000.0 24964000.0 10.0 20.0 -5.0",
                        "2027-02-01T01:00:00.000 120036000.0 -39928000.0 24982000.0 10.0 21.0 -5.0")
    (tmp_path / "burn.oem").write_text(text)
    tab = read_oem(tmp_path / "burn.oem")
    _, v = oem_state(tab, _tdb("2027-02-01T01:00:00"))
    assert v[1] == 21.0
    _, v = oem_state(tab, _tdb("2027-02-01T00:59:59"))
    assert abs(v[1] - 20.0) < 1e-6


def test_handmade_aem_spin_about_z():
    tab = read_aem(DATA / "handmade_v2.aem")
    assert tab.angular_velocity_rad_s is None  # QUATERNION: no rates in the file
    t0 = _tdb("2027-02-01T00:00:00")
    # a spin of 2 deg/min: q(t) = (cos(w t / 2), 0, 0, sin(w t / 2)), the attitude matrix R3(w t)
    w = math.radians(2.0) / 60.0
    for dt in (0.0, 30.0, 60.0, 95.0):
        q, rate = aem_attitude(tab, t0 + dt)
        expected = frames.quat_to_dcm([math.cos(w * dt / 2), 0, 0, math.sin(w * dt / 2)])
        np.testing.assert_allclose(frames.quat_to_dcm(q), expected, atol=1e-12)
        # the body rate of docs/conventions.md: R(t) = exp(-[w x] t) R0 (frames.propagate_attitude)
        np.testing.assert_allclose(rate, [0.0, 0.0, w], atol=1e-12)
        np.testing.assert_allclose(frames.propagate_attitude(frames.quat_to_dcm(q), rate, 10.0),
                                   frames.quat_to_dcm([math.cos(w * (dt + 10) / 2), 0, 0, math.sin(w * (dt + 10) / 2)]),
                                   atol=1e-12)


@pytest.fixture
def trajectory():
    t = 8.5e8 + np.arange(0.0, 6 * 3600.0, 3600.0)
    rng = np.random.default_rng(3)
    r = 1.5e8 * rng.normal(size=(len(t), 3))
    v = 30.0 * rng.normal(size=(len(t), 3))
    return t, r, v


def test_second_reader_gives_the_same_states(tmp_path, trajectory):
    """The ``oem`` package (another implementation) reads skynav's OEM to the same states."""
    import oem
    from astropy.time import Time

    t, r, v = trajectory
    path = tmp_path / "traj.oem"
    path.write_text(oem_kvn(t, r, v))
    other = oem.OrbitEphemerisMessage.open(str(path))
    states = [s for seg in other for s in seg.states]
    assert len(states) == len(t)
    got_t = np.array([((Time(s.epoch).tdb.jd1 - 2451545.0) + Time(s.epoch).tdb.jd2) * 86400.0 for s in states])
    # the file holds decimal repr of each float: the same doubles back; epochs to 1 us (ISO microseconds)
    np.testing.assert_array_equal(np.array([s.position for s in states]), r)
    np.testing.assert_array_equal(np.array([s.velocity for s in states]), v)
    assert np.max(np.abs(got_t - t)) < 1e-6
    mine = read_oem(path)
    np.testing.assert_array_equal(mine.position_km, r)
    assert np.max(np.abs(mine.t_tdb_s - t)) < 1e-6


def test_aem_round_trip(tmp_path, trajectory):
    t, _, _ = trajectory
    rng = np.random.default_rng(4)
    q = rng.normal(size=(len(t), 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    w = 1e-3 * rng.normal(size=(len(t), 3))
    path = tmp_path / "att.aem"
    path.write_text(aem_kvn(t, q, w))
    tab = read_aem(path)
    np.testing.assert_allclose(tab.q_cam_icrs, q, rtol=0, atol=1e-15)
    np.testing.assert_allclose(tab.angular_velocity_rad_s, w, rtol=0, atol=1e-18)
    for k in range(len(t)):
        qk, wk = aem_attitude(tab, tab.t_tdb_s[k])
        np.testing.assert_allclose(frames.quat_to_dcm(qk), frames.quat_to_dcm(q[k]), atol=1e-14)


def _scene(tmp_path, observer, attitude, epoch="2027-02-01T00:20:00"):
    for name in ("handmade.oem", "handmade_v2.aem"):
        shutil.copy(DATA / name, tmp_path / name)
    path = tmp_path / "scene.yaml"
    path.write_text(f"epoch: {epoch}\nobserver: {observer}\nattitude: {attitude}\n")
    return path


def test_scene_file_reads_oem_and_aem_beside_it(tmp_path):
    path = _scene(tmp_path, "{oem: handmade.oem}", "{aem: handmade_v2.aem}", epoch="2027-02-01T00:01:30.5")
    spec = load_scene_file(path)
    from astropy.time import Time

    t = Time("2027-02-01T00:01:30.5", scale="tdb")
    t_s = ((t.jd1 - 2451545.0) + t.jd2) * 86400.0
    r, v = oem_state(read_oem(tmp_path / "handmade.oem"), t_s)
    np.testing.assert_allclose(spec.position_km, r, rtol=0, atol=1e-6)
    np.testing.assert_allclose(spec.velocity_km_s, v, rtol=0, atol=1e-12)
    q, _ = aem_attitude(read_aem(tmp_path / "handmade_v2.aem"), t_s)
    np.testing.assert_allclose(frames.quat_to_dcm(spec.attitude.q_cam_icrs), frames.quat_to_dcm(q), atol=1e-12)


def test_a_mapping_from_elsewhere_cannot_name_a_file():
    """A service request is a mapping: a path in it is refused, never opened."""
    d = {"epoch": "2027-02-01T00:20:00", "observer": {"oem": "/etc/passwd"}, "attitude": {"ra_deg": 0, "dec_deg": 0}}
    with pytest.raises(ConfigValueError, match="observer.oem"):
        scene_spec_from_mapping(d)


@pytest.mark.parametrize("damage, expected", [
    (lambda p: p.write_text(p.read_text().replace("-39964000.0", "-39964O00.0")), "not a readable CCSDS OEM"),
    (lambda p: p.write_text(p.read_text().replace("META_STOP", "", 1)), "not a readable CCSDS OEM"),
    (lambda p: p.write_text(p.read_text().replace("REF_FRAME = ICRF", "REF_FRAME = EME2000")), "REF_FRAME EME2000"),
    (lambda p: p.write_text(p.read_text().replace("CENTER_NAME = SOLAR SYSTEM BARYCENTER", "CENTER_NAME = EARTH")),
     "CENTER_NAME EARTH"),
    (lambda p: p.unlink(), "no such OEM file"),
])
def test_a_damaged_oem_is_one_line_exit_2(tmp_path, capsys, damage, expected):
    path = _scene(tmp_path, "{oem: handmade.oem}", "{ra_deg: 10, dec_deg: 5}")
    damage(tmp_path / "handmade.oem")
    with pytest.raises(SceneFileError, match=expected):
        load_scene_file(path)
    assert main(["render", str(path), "-o", str(tmp_path / "out"), "--backend", "numpy", "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "handmade.oem" in err and expected in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("epoch, aem, expected", [
    ("2027-02-01T05:00:00", None, "outside the file's"),
    ("2027-02-01T00:01:30", "CCSDS_AEM_VERS = 1.0", "AEM version 1.0"),
])
def test_epoch_outside_and_old_aem_are_one_line(tmp_path, capsys, epoch, aem, expected):
    path = _scene(tmp_path, "{oem: handmade.oem}", "{aem: handmade_v2.aem}", epoch=epoch)
    if aem:
        p = tmp_path / "handmade_v2.aem"
        p.write_text(p.read_text().replace("CCSDS_AEM_VERS = 2.0", aem))
    assert main(["render", str(path), "-o", str(tmp_path / "out"), "--backend", "numpy", "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and expected in err and "Traceback" not in err


def test_xml_messages_are_read_too(tmp_path):
    """The same hand-made messages in XML (the library's conversion) give the same states."""
    import ccsds_ndm

    for name, cls, read in (("handmade.oem", ccsds_ndm.Oem, read_oem), ("handmade_v2.aem", ccsds_ndm.Aem, read_aem)):
        xml = tmp_path / (name + ".xml")
        xml.write_text(cls.from_file(str(DATA / name)).to_str("xml"))
        a, b = read(DATA / name), read(xml)
        np.testing.assert_array_equal(a.t_tdb_s, b.t_tdb_s)
        for field in ("position_km", "velocity_km_s", "q_cam_icrs"):
            if hasattr(a, field):
                np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
