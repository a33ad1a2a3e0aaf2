"""``ephemeris: {spk: FILE}``: a planetary SPK read through CSPICE in place of DE421, checked
against jplephem's DE421 (the same file: 1 m) and with a small SPK of another type (Type 13,
written here with spiceypy from DE421 states); and UTC epochs through a leapseconds kernel,
against astropy's UTC -> TDB."""

import numpy as np
import pytest

sp = pytest.importorskip("spiceypy")

from skynav.infra.data_files import de421_path  # noqa: E402
from skynav.infra.errors import ConfigValueError  # noqa: E402
from skynav.scenes.ephemeris_jpl import BODIES, BODY_NAIF_IDS, default_ephemeris  # noqa: E402
from skynav.scenes.mission_files import SceneFilePath  # noqa: E402
from skynav.scenes.mission_spice import SpiceEphemeris  # noqa: E402
from skynav.scenes.scene import build_from_spec  # noqa: E402
from skynav.scenes.scene_files import load_scene_file  # noqa: E402
from skynav.scenes.timescales import tdb_seconds  # noqa: E402

EPOCH = "2027-02-01T00:00:00"
SCENE = ("epoch: {epoch}\n"
         "observer: {{position_km: [-128731399.4, 113269566.7, 51647643.2], velocity_km_s: [-19.9093, -18.773, -8.1391]}}\n"
         "attitude: {{point_at: mars}}\ncamera: {{preset: paper, width: 256, height: 256, fov_deg: 20.0}}\n{extra}")


def test_de421_through_the_spk_path_is_the_jplephem_path_within_1_m():
    """The same DE421 read by CSPICE (SpiceEphemeris, what ``ephemeris: {spk: de421.bsp}``
    uses) and by jplephem, every body at 1000 epochs 1990-2050, light-time offsets included:
    1 m and 1 mm/s (the same Chebyshev coefficients; float64 rounding of 1e9 km and of the
    epoch plus its offset, 2e-7 s)."""
    eph, ref = SpiceEphemeris(SceneFilePath(str(de421_path()), "de421.bsp")), default_ephemeris()
    t = np.sort(np.random.default_rng(7).uniform(tdb_seconds("1990-01-01T00:00:00"), tdb_seconds("2050-01-01T00:00:00"), 1000))
    off = -np.random.default_rng(8).uniform(0.0, 3000.0, t.size)
    worst_r = worst_v = 0.0
    for body in BODIES:
        r, v = eph.position_velocity(body, t, offset_s=off)
        r0, v0 = ref.position_velocity(body, t, offset_s=off)
        worst_r = max(worst_r, float(np.max(np.abs(r - r0))))
        worst_v = max(worst_v, float(np.max(np.abs(v - v0))))
        # one epoch (the light-time iterations' call) and the position alone: the array's values
        np.testing.assert_array_equal(eph.position(body, float(t[3]), offset_s=float(off[3])), r[3])
    assert worst_r < 1e-3 and worst_v < 1e-6, (worst_r, worst_v)


def _type13_planets(path, t_mid, half_span_s=2 * 86400.0, step_s=1800.0):
    """Every body of BODIES about the barycentre, Type 13 (Hermite, degree 7) on DE421 states
    every ``step_s``: a planetary SPK of another type than DE421's Chebyshev Type 2."""
    ref = default_ephemeris()
    t = t_mid + np.arange(-half_span_s, half_span_s + 1.0, step_s)
    h = sp.spkopn(str(path), "skynav planets", 0)
    for body in BODIES:
        r, v = ref.position_velocity(body, t)
        sp.spkw13(h, BODY_NAIF_IDS[body], 0, "J2000", t[0], t[-1], body, 7, len(t),
                  np.ascontiguousarray(np.hstack([r, v])), t)
    sp.spkcls(h)


def test_a_scene_with_a_type_13_planetary_spk_sees_the_de421_sky(tmp_path):
    _type13_planets(tmp_path / "planets.bsp", float(tdb_seconds(EPOCH)))
    (tmp_path / "de421.yaml").write_text(SCENE.format(epoch=EPOCH, extra=""))
    (tmp_path / "spk.yaml").write_text(SCENE.format(epoch=EPOCH, extra="ephemeris: {spk: planets.bsp}\n"))
    a, b = load_scene_file(tmp_path / "spk.yaml"), load_scene_file(tmp_path / "de421.yaml")
    assert isinstance(a.ephemeris, SpiceEphemeris) and b.ephemeris is None
    assert [(f["key"], f["name"]) for f in a.data_files] == [("ephemeris.spk", "planets.bsp")]
    sa, sb = build_from_spec(a), build_from_spec(b)
    # Hermite on half-hourly DE421 states: the Moon (the fastest turning) within 1 m, so the
    # bodies' apparent directions within 1 m / 1e8 km = 1e-11 rad = 2e-9 px of this camera
    for ba, bb in zip(sa.bodies, sb.bodies):
        assert ba.name == bb.name and ba.in_fov == bb.in_fov
        assert abs(ba.light_time_s - bb.light_time_s) < 1e-8
        np.testing.assert_allclose(ba.u_icrs, bb.u_icrs, rtol=0, atol=1e-10)
        if ba.in_fov:
            np.testing.assert_allclose(ba.xy, bb.xy, rtol=0, atol=1e-6)
    assert "mars" in [b.name for b in sa.bodies_in_fov()]
    eph = a.ephemeris
    for body in BODIES:
        r, _ = eph.position_velocity(body, float(tdb_seconds(EPOCH)) + 1234.5)
        r0, _ = default_ephemeris().position_velocity(body, float(tdb_seconds(EPOCH)) + 1234.5)
        assert np.max(np.abs(r - r0)) < 1e-3, body


def test_a_scene_epoch_outside_the_planetary_spk_is_one_line(tmp_path, capsys):
    from skynav.cli import main

    _type13_planets(tmp_path / "planets.bsp", float(tdb_seconds(EPOCH)))
    (tmp_path / "s.yaml").write_text(SCENE.format(epoch="2027-03-01T00:00:00", extra="ephemeris: {spk: planets.bsp}\n"))
    assert main(["render", str(tmp_path / "s.yaml"), "-o", str(tmp_path / "out"), "--backend", "numpy", "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "planets.bsp: SPICE(SPKINSUFFDATA)" in err and "Traceback" not in err


# ----------------------------------------------------------------------------- UTC epochs
#: A leapseconds kernel: NAIF's LSK format and constants (DELTET), the leap seconds of the IERS
#: Bulletin C up to 2017-01-01 (TAI - UTC = 37 s from then on), typed here: no download.
LSK = """KPL/LSK
\\begindata
DELTET/DELTA_T_A = 32.184
DELTET/K         = 1.657D-3
DELTET/EB        = 1.671D-2
DELTET/M         = ( 6.239996D0 1.99096871D-7 )
DELTET/DELTA_AT  = ( 10, @1972-JAN-1 11, @1972-JUL-1 12, @1973-JAN-1 13, @1974-JAN-1 14, @1975-JAN-1
                     15, @1976-JAN-1 16, @1977-JAN-1 17, @1978-JAN-1 18, @1979-JAN-1 19, @1980-JAN-1
                     20, @1981-JUL-1 21, @1982-JUL-1 22, @1983-JUL-1 23, @1985-JUL-1 24, @1988-JAN-1
                     25, @1990-JAN-1 26, @1991-JAN-1 27, @1992-JUL-1 28, @1993-JUL-1 29, @1994-JUL-1
                     30, @1996-JAN-1 31, @1997-JUL-1 32, @1999-JAN-1 33, @2006-JAN-1 34, @2009-JAN-1
                     35, @2012-JUL-1 36, @2015-JUL-1 37, @2017-JAN-1 )
\\begintext
"""


def _spk(path, t0):
    t = t0 + np.arange(-86400.0, 86400.0 + 1.0, 3600.0)
    r0, v = np.array([1.2e8, -4.0e7, 2.5e7]), np.array([10.0, 20.0, -5.0])
    h = sp.spkopn(str(path), "skynav test", 0)
    sp.spkw13(h, -999, 0, "J2000", t[0], t[-1], "uniform", 3, len(t), np.hstack([r0 + np.outer(t - t0, v),
                                                                                np.tile(v, (len(t), 1))]), t)
    sp.spkcls(h)


@pytest.mark.parametrize("utc", ["2027-02-01T00:00:00", "2017-01-01T00:00:00", "2024-06-30T23:59:59.5"])
def test_a_utc_epoch_with_a_leapseconds_kernel_is_astropys_tdb(tmp_path, utc):
    """CSPICE's UTC -> ET (TDB) against astropy's UTC -> TDB (ERFA's leap seconds and its full
    TDB - TT series): 50 us, the budget of SPICE's two-term TDB - TT (NAIF: about 30 us)."""
    from astropy.time import Time

    (tmp_path / "leap.tls").write_text(LSK)
    t = Time(utc, scale="utc").tdb
    expected = ((t.jd1 - 2451545.0) + t.jd2) * 86400.0
    _spk(tmp_path / "craft.bsp", expected)
    (tmp_path / "s.yaml").write_text(f"epoch: {utc} UTC\n"
                                     "observer: {spice: {kernels: [leap.tls, craft.bsp], body: '-999'}}\n"
                                     "attitude: {ra_deg: 10, dec_deg: 5}\n")
    spec = load_scene_file(tmp_path / "s.yaml")
    assert abs(float(tdb_seconds(spec.epoch_tdb_iso)) - expected) < 50e-6
    assert [f["name"] for f in spec.data_files] == ["leap.tls", "craft.bsp"]


def test_a_utc_epoch_without_a_leapseconds_kernel_names_what_is_missing(tmp_path):
    _spk(tmp_path / "craft.bsp", float(tdb_seconds("2027-02-01T00:00:00")))
    (tmp_path / "s.yaml").write_text("epoch: 2027-02-01T00:00:00 UTC\n"
                                     "observer: {spice: {kernels: [craft.bsp], body: '-999'}}\n"
                                     "attitude: {ra_deg: 10, dec_deg: 5}\n")
    with pytest.raises(ConfigValueError, match="leapseconds kernel"):
        load_scene_file(tmp_path / "s.yaml")


# ----------------------------------------------------------------------------- meta-kernels
META = """KPL/MK
\\begindata
PATH_VALUES     = ( 'time' )
PATH_SYMBOLS    = ( 'T' )
KERNELS_TO_LOAD = ( '$T/leap.tls', 'cra+'
                    'ft.bsp' )
\\begintext
"""


def test_a_meta_kernel_stands_for_its_list_read_beside_it(tmp_path, monkeypatch):
    """Its relative entries (after PATH_SYMBOLS, ``+`` continuations joined) are read beside the
    meta-kernel, wherever skynav runs from; the truth's records follow it with each kernel."""
    import hashlib

    from astropy.time import Time

    (tmp_path / "kernels" / "time").mkdir(parents=True)
    (tmp_path / "kernels" / "time" / "leap.tls").write_text(LSK)
    t = Time("2027-02-01T00:00:00", scale="utc").tdb
    _spk(tmp_path / "kernels" / "craft.bsp", ((t.jd1 - 2451545.0) + t.jd2) * 86400.0)
    (tmp_path / "kernels" / "mission.tm").write_text(META)
    (tmp_path / "s.yaml").write_text("epoch: 2027-02-01T00:00:00 UTC\n"
                                     "observer: {spice: {kernels: [kernels/mission.tm], body: '-999'}}\n"
                                     "attitude: {ra_deg: 10, dec_deg: 5}\n")
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    spec = load_scene_file(tmp_path / "s.yaml")
    np.testing.assert_allclose(spec.position_km, [1.2e8, -4.0e7, 2.5e7], rtol=0, atol=1e-3)  # the SPK's t0, 1 m
    sha = {n: hashlib.sha256((tmp_path / "kernels" / n).read_bytes()).hexdigest()
           for n in ("mission.tm", "time/leap.tls", "craft.bsp")}
    assert [(f["name"], f["sha256"], f.get("via")) for f in spec.data_files] == [
        ("kernels/mission.tm", sha["mission.tm"], None), ("$T/leap.tls", sha["time/leap.tls"], "kernels/mission.tm"),
        ("craft.bsp", sha["craft.bsp"], "kernels/mission.tm")]


def test_a_meta_kernel_naming_a_missing_file_is_one_line(tmp_path, capsys):
    from skynav.cli import main

    (tmp_path / "mission.tm").write_text(META)
    (tmp_path / "s.yaml").write_text("epoch: 2027-02-01T00:00:00\n"
                                     "observer: {spice: {kernels: [mission.tm], body: '-999'}}\n"
                                     "attitude: {ra_deg: 10, dec_deg: 5}\n")
    assert main(["scene", str(tmp_path / "s.yaml")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "mission.tm: KERNELS_TO_LOAD names $T/leap.tls, no such file" in err
