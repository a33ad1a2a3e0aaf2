"""SPICE kernels in scene files: an SPK (Type 13, written here with spiceypy from an analytic
motion) as the observer, the kernel pool isolated between scenes, and the errors (one line
naming the kernels, exit 2)."""

import numpy as np
import pytest

sp = pytest.importorskip("spiceypy")

from skynav.cli import main  # noqa: E402
from skynav.infra.errors import ConfigValueError  # noqa: E402
from skynav.scenes.config import scene_spec_from_mapping  # noqa: E402
from skynav.scenes.mission_spice import spice_state  # noqa: E402
from skynav.scenes.scene_files import load_scene_file  # noqa: E402
from skynav.scenes.timescales import tdb_seconds  # noqa: E402
from .spice_texts import FK, SCLK  # noqa: E402

T0 = float(tdb_seconds("2027-02-01T00:00:00"))
R0 = np.array([1.2e8, -4.0e7, 2.5e7])
V0 = np.array([10.0, 20.0, -5.0])


def _spk(path, r0=R0, v=V0, body=-999, span_s=6 * 3600.0):
    """A Type 13 (Hermite) SPK of uniform motion r0 + v (t - T0): Hermite is exact on it."""
    t = T0 + np.arange(0.0, span_s + 1.0, 600.0)
    states = np.hstack([r0 + np.outer(t - T0, v), np.tile(v, (len(t), 1))])
    handle = sp.spkopn(str(path), "skynav test", 0)
    sp.spkw13(handle, body, 0, "J2000", t[0], t[-1], "uniform", 3, len(t), states, t)
    sp.spkcls(handle)


def _scene(tmp_path, kernels, body="-999", epoch="2027-02-01T01:15:00"):
    path = tmp_path / "scene.yaml"
    ks = ", ".join(kernels)
    path.write_text(f"epoch: {epoch}\nobserver: {{spice: {{kernels: [{ks}], body: '{body}'}}}}\n"
                    f"attitude: {{ra_deg: 10, dec_deg: 5}}\n")
    return path


def test_spk_type_13_is_the_observer(tmp_path):
    _spk(tmp_path / "craft.bsp")
    spec = load_scene_file(_scene(tmp_path, ["craft.bsp"]))
    dt = float(tdb_seconds("2027-02-01T01:15:00")) - T0
    # SPICE ET is TDB seconds past J2000: exact; 1 mm (double rounding of 1e8 km)
    np.testing.assert_allclose(spec.position_km, R0 + V0 * dt, rtol=0, atol=1e-6)
    np.testing.assert_allclose(spec.velocity_km_s, V0, rtol=0, atol=1e-12)
    # the pool holds the scene's kernel alone (kept loaded for the next scene of the same set)
    assert [sp.kdata(i, "ALL")[0] for i in range(sp.ktotal("ALL"))] == [str(tmp_path / "craft.bsp")]


def test_two_scenes_never_see_each_others_kernels(tmp_path):
    """The same NAIF id in two SPKs: each scene gets its own (CSPICE would give the last loaded
    one to both if the pool were shared)."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    _spk(tmp_path / "a" / "craft.bsp")
    _spk(tmp_path / "b" / "craft.bsp", r0=R0 + 1000.0)
    sa = load_scene_file(_scene(tmp_path / "a", ["craft.bsp"]))
    sb = load_scene_file(_scene(tmp_path / "b", ["craft.bsp"]))
    sa2 = load_scene_file(_scene(tmp_path / "a", ["craft.bsp"]))
    np.testing.assert_allclose(np.subtract(sb.position_km, sa.position_km), [1000.0] * 3, atol=1e-6)
    assert sa2.position_km == sa.position_km


def test_a_mapping_from_elsewhere_cannot_name_a_kernel():
    d = {"epoch": "2027-02-01T00:20:00", "observer": {"spice": {"kernels": ["/tmp/x.bsp"], "body": "-999"}},
         "attitude": {"ra_deg": 0, "dec_deg": 0}}
    with pytest.raises(ConfigValueError, match="observer.spice.kernels"):
        scene_spec_from_mapping(d)


@pytest.mark.parametrize("kernels, body, epoch, expected", [
    (["missing.bsp"], "-999", "2027-02-01T01:15:00", "no such SPICE kernel"),
    (["craft.bsp"], "-555", "2027-02-01T01:15:00", "SPICE(SPKINSUFFDATA)"),  # a body with no data
    (["craft.bsp"], "-999", "2027-02-02T01:15:00", "SPICE(SPKINSUFFDATA)"),  # outside the coverage
    (["broken.bsp"], "-999", "2027-02-01T01:15:00", "SPICE("),  # not a kernel
])
def test_errors_are_one_line_exit_2(tmp_path, capsys, kernels, body, epoch, expected):
    _spk(tmp_path / "craft.bsp")
    (tmp_path / "broken.bsp").write_bytes(b"DAF/SPK " + b"\0" * 100)
    path = _scene(tmp_path, kernels, body=body, epoch=epoch)
    assert main(["render", str(path), "-o", str(tmp_path / "out"), "--backend", "numpy", "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and expected in err and kernels[0] in err and "Traceback" not in err
    assert "=====" not in err  # never CSPICE's dump
    assert "broken.bsp" not in [sp.kdata(i, "ALL")[0].rsplit("/", 1)[-1] for i in range(sp.ktotal("ALL"))]


def test_spice_state_against_the_analytic_motion_at_many_epochs(tmp_path):
    _spk(tmp_path / "craft.bsp")
    for dt in np.linspace(0.0, 6 * 3600.0, 7):
        r, v = spice_state([str(tmp_path / "craft.bsp")], "-999", T0 + dt)
        np.testing.assert_allclose(r, R0 + V0 * dt, rtol=0, atol=1e-6)


# ----------------------------------------------------------------------------- attitude from a CK
W_CAM = np.array([1e-3, -2e-3, 5e-4])  # rad/s, camera frame


def _R_true(dt):
    from skynav.scenes import frames

    R0 = frames.radec_twist_to_dcm(0.3, -0.2, 0.1)
    return frames.propagate_attitude(R0, W_CAM, dt)


def _ck(tmp_path):
    """A Type 3 CK of a constant body rate, with its SCLK (TDB ticks of 1/65536 s) and FK."""
    (tmp_path / "craft.tsc").write_text(SCLK.format(et0=repr(T0)))
    (tmp_path / "craft.tf").write_text(FK)
    dts = np.arange(0.0, 600.0 + 1.0, 10.0)
    sp.furnsh(str(tmp_path / "craft.tsc"))
    try:
        ticks = np.array([sp.sce2c(-999, T0 + dt) for dt in dts])
    finally:
        sp.kclear()
    R = [_R_true(dt) for dt in dts]
    quats = np.array([sp.m2q(r) for r in R])
    av = np.array([r.T @ W_CAM for r in R])  # CK rates are in the reference frame (J2000)
    handle = sp.ckopn(str(tmp_path / "craft.bc"), "skynav test", 0)
    sp.ckw03(handle, ticks[0], ticks[-1], -999000, "J2000", True, "spin", len(ticks), ticks, quats, av, 1,
             ticks[:1])
    sp.ckcls(handle)


def test_ck_with_sclk_and_fk_is_the_attitude(tmp_path):
    from skynav.scenes import frames

    _ck(tmp_path)
    _spk(tmp_path / "craft.bsp")
    path = tmp_path / "scene.yaml"
    path.write_text("epoch: 2027-02-01T00:04:05\nobserver: {spice: {kernels: [craft.bsp], body: '-999'}}\n"
                    "attitude: {spice: {kernels: [craft.bc, craft.tsc, craft.tf], frame: SKYNAV_CAM}}\n")
    spec = load_scene_file(path)
    dt = float(tdb_seconds("2027-02-01T00:04:05")) - T0
    # CK Type 3 interpolates linearly in rotation between the 10-s samples of a constant rate:
    # exact up to the SCLK's 1/65536-s ticks (1e-3 rad/s x 15 us = 1.5e-8 rad)
    R = frames.quat_to_dcm(spec.attitude.q_cam_icrs)
    assert np.max(np.abs(R - _R_true(dt))) < 5e-8
    # through the scene file's deg/s and back: 1e-12 rad/s
    np.testing.assert_allclose(spec.attitude.angular_velocity_rad_s, W_CAM, rtol=0, atol=1e-12)


def test_a_ck_without_its_sclk_is_one_line(tmp_path, capsys):
    _ck(tmp_path)
    _spk(tmp_path / "craft.bsp")
    path = tmp_path / "scene.yaml"
    path.write_text("epoch: 2027-02-01T00:04:05\nobserver: {spice: {kernels: [craft.bsp], body: '-999'}}\n"
                    "attitude: {spice: {kernels: [craft.bc, craft.tf], frame: SKYNAV_CAM}}\n")
    assert main(["render", str(path), "-o", str(tmp_path / "out"), "--backend", "numpy", "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "craft.bc" in err and "SPICE(" in err and "Traceback" not in err


def test_de421_through_cspice_matches_the_jplephem_path():
    """CSPICE (an independent SPK reader) and skynav's jplephem path agree on every body of
    DE421 at 1000 epochs over 1990-2050: 1 m and 1 mm/s (both evaluate the same Chebyshev
    coefficients; the budget is float64 rounding of ~1e9 km and Julian-date splitting)."""
    from skynav.infra.data_files import de421_path
    from skynav.scenes.ephemeris_jpl import BODY_NAIF_IDS, default_ephemeris
    from skynav.scenes.mission_spice import kernel_pool

    eph = default_ephemeris()
    t = np.sort(np.random.default_rng(5).uniform(tdb_seconds("1990-01-01T00:00:00"),
                                                  tdb_seconds("2050-01-01T00:00:00"), 1000))
    worst_r = worst_v = 0.0
    with kernel_pool([str(de421_path())]) as cspice:
        for body, naif in BODY_NAIF_IDS.items():
            r, v = eph.position_velocity(body, t)
            s = np.array([cspice.spkgeo(naif, float(ti), "J2000", 0)[0] for ti in t])
            worst_r = max(worst_r, float(np.max(np.abs(s[:, :3] - r))))
            worst_v = max(worst_v, float(np.max(np.abs(s[:, 3:] - v))))
    assert worst_r < 1e-3 and worst_v < 1e-6, (worst_r, worst_v)
