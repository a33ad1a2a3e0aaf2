"""Frame files: round trips, deterministic bytes, atomicity, FITS WCS against astropy.wcs, and
the published truth schema (moved from tests/renderer/test_outputs.py with the writers)."""

from __future__ import annotations

import copy
import hashlib
import json
import math
import os
import struct
import zlib

import numpy as np
import pytest
from astropy.wcs import WCS

from skynav.datasets.fits_files import read_fits, tan_wcs_header, write_fits
from skynav.datasets.frame_files import (
    OutputFormatError,
    read_exr,
    read_exr_header,
    read_png,
    write_exr,
    write_png,
)
from skynav.datasets.truth_schema import (
    FRAME_SCHEMA,
    TruthSchemaError,
    read_truth_json,
    validate_truth,
    write_truth_json,
)
from skynav.infra.atomic_files import atomic_path, atomic_write_bytes, sha256_file
from skynav.infra.errors import SkynavError
from skynav.scenes.camera import paper_camera
from skynav.scenes.frames import radec_twist_to_dcm, unit_to_radec


@pytest.fixture
def rng():
    return np.random.default_rng(20240515)


def _sha(path) -> str:
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


def _leftovers(directory):
    return sorted(n for n in os.listdir(directory) if n.endswith(".tmp"))


# ----------------------------------------------------------------------------- atomicity
def test_atomic_write_bytes_writes_and_replaces(tmp_path):
    p = tmp_path / "a.bin"
    atomic_write_bytes(p, b"first")
    atomic_write_bytes(p, b"second")
    assert p.read_bytes() == b"second"
    assert _leftovers(tmp_path) == []


def test_atomic_path_temp_is_hidden_unique_and_beside_target(tmp_path):
    with atomic_path(tmp_path / "f.exr") as t1, atomic_path(tmp_path / "f.exr") as t2:
        for t in (t1, t2):
            assert os.path.dirname(t) == str(tmp_path)
            name = os.path.basename(t)
            assert name.startswith(f".f.exr.{os.getpid()}.") and name.endswith(".tmp")
        assert t1 != t2
        open(t1, "wb").write(b"1")
        open(t2, "wb").write(b"2")
    assert (tmp_path / "f.exr").read_bytes() == b"1"  # t1 committed last (outer context)
    assert _leftovers(tmp_path) == []


def test_failure_inside_atomic_path_leaves_no_file_and_no_temp(tmp_path):
    p = tmp_path / "new.png"
    with pytest.raises(RuntimeError, match="boom"):
        with atomic_path(p) as tmp:
            open(tmp, "wb").write(b"partial")
            raise RuntimeError("boom")
    assert not p.exists()
    assert os.listdir(tmp_path) == []


def test_failure_leaves_existing_file_untouched(tmp_path):
    p = tmp_path / "old.json"
    p.write_bytes(b"complete old content")
    with pytest.raises(KeyboardInterrupt):  # BaseException too: Ctrl-C mid-write
        with atomic_path(p) as tmp:
            open(tmp, "wb").write(b"half")
            raise KeyboardInterrupt
    assert p.read_bytes() == b"complete old content"
    assert os.listdir(tmp_path) == ["old.json"]


def test_writer_failure_leaves_existing_file_untouched(tmp_path):
    p = tmp_path / "frame.exr"
    write_exr(p, {"electrons": np.ones((4, 5), np.float32)})
    before = _sha(p)
    with pytest.raises(OutputFormatError):
        write_exr(p, {"electrons": np.ones((4, 5)), "source_id": np.ones((5, 4))})
    assert _sha(p) == before
    assert _leftovers(tmp_path) == []


def test_sha256_file_matches_hashlib(tmp_path, rng):
    data = rng.bytes(3 * 1024 + 17)
    p = tmp_path / "x"
    p.write_bytes(data)
    assert sha256_file(p) == hashlib.sha256(data).hexdigest()
    assert sha256_file(p, chunk_bytes=1000) == hashlib.sha256(data).hexdigest()


# ----------------------------------------------------------------------------- EXR
def test_exr_round_trip_exact(tmp_path, rng):
    electrons = rng.gamma(2.0, 1e3, (48, 64)).astype(np.float32)
    electrons[0, 0] = np.float32(1e-42)  # a float32 denormal must survive (no half, no rounding)
    electrons[1, 1] = np.nan
    electrons[2, 2] = np.inf
    irr = rng.random((48, 64)) * 1e-12  # float64 input: rounded once to float32
    ids = rng.integers(0, 2**32, (48, 64), dtype=np.uint64).astype(np.uint32)
    ids[0, 0] = 2**32 - 1
    p = tmp_path / "f.exr"
    write_exr(p, {"electrons": electrons, "irradiance_w_m2": irr, "source_id": ids})
    got = read_exr(p)
    assert set(got) == {"electrons", "irradiance_w_m2", "source_id"}
    assert got["electrons"].dtype == np.float32 and got["source_id"].dtype == np.uint32
    np.testing.assert_array_equal(got["electrons"], electrons)  # NaN == NaN here
    np.testing.assert_array_equal(got["irradiance_w_m2"], irr.astype(np.float32))
    np.testing.assert_array_equal(got["source_id"], ids)
    with open(p, "rb") as f:  # file objects too, not only paths
        np.testing.assert_array_equal(read_exr(f)["source_id"], ids)


def test_exr_deterministic_bytes_and_zip(tmp_path, rng):
    ch = {"electrons": rng.random((300, 257)).astype(np.float32), "source_id": np.arange(300 * 257, dtype=np.uint32).reshape(300, 257)}
    write_exr(tmp_path / "a.exr", ch, header={"skynav_frame": "000001", "exposure_s": 0.1})
    write_exr(tmp_path / "b.exr", ch, header={"skynav_frame": "000001", "exposure_s": 0.1})
    assert _sha(tmp_path / "a.exr") == _sha(tmp_path / "b.exr")
    hdr = read_exr_header(tmp_path / "a.exr")
    assert "RLE_COMPRESSION" in str(hdr["compression"])
    assert hdr["skynav_frame"] == "000001"
    assert float(hdr["exposure_s"]) == 0.1  # stored as repr, not rounded to float32


def test_exr_refuses_bad_input(tmp_path):
    with pytest.raises(OutputFormatError, match="compression"):
        write_exr(tmp_path / "x.exr", {"e": np.zeros((2, 2))}, header={"compression": "none"})
    with pytest.raises(OutputFormatError, match="uint32"):
        write_exr(tmp_path / "x.exr", {"source_id": -np.ones((2, 2), np.int64)})
    with pytest.raises(OutputFormatError, match="2-D"):
        write_exr(tmp_path / "x.exr", {"e": np.zeros((2, 2, 3))})
    with pytest.raises(SkynavError):
        write_exr(tmp_path / "x.exr", {})
    assert os.listdir(tmp_path) == []


# ----------------------------------------------------------------------------- PNG
def _ihdr(path):
    """(width, height, bit depth, colour type) parsed from the PNG bytes (PNG spec 11.2.2)."""
    b = open(path, "rb").read()
    assert b[:8] == b"\x89PNG\r\n\x1a\n" and b[12:16] == b"IHDR"
    w, h, depth, colour = struct.unpack(">IIBB", b[16:26])
    return w, h, depth, colour


def _png_chunks(path):
    b = open(path, "rb").read()
    i, out = 8, {}
    while i < len(b):
        (n,) = struct.unpack(">I", b[i : i + 4])
        out.setdefault(b[i + 4 : i + 8], []).append(b[i + 8 : i + 8 + n])
        i += 12 + n
    return out


def test_png_uint8_round_trip(tmp_path, rng):
    dn = rng.integers(0, 256, (37, 53), dtype=np.uint8)
    dn[0, :2] = (0, 255)
    write_png(tmp_path / "a.png", dn, bit_depth=8)
    got = read_png(tmp_path / "a.png")
    assert got.dtype == np.uint8
    np.testing.assert_array_equal(got, dn)
    assert _ihdr(tmp_path / "a.png") == (53, 37, 8, 0)  # greyscale, 8 bit


def test_png_uint16_raw_dn_round_trip(tmp_path, rng):
    dn = rng.integers(0, 65536, (41, 29), dtype=np.uint16)
    dn[0, :6] = (0, 255, 256, 4095, 65534, 65535)
    write_png(tmp_path / "a.png", dn)
    got = read_png(tmp_path / "a.png")
    assert got.dtype == np.uint16
    np.testing.assert_array_equal(got, dn)
    assert _ihdr(tmp_path / "a.png") == (29, 41, 16, 0)
    # independent decoder: zlib + PNG filter 0 rows are big-endian uint16 (Pillow uses filter 0
    # for 16-bit greyscale; if it changes, this check is skipped rather than wrong)
    raw = zlib.decompress(b"".join(_png_chunks(tmp_path / "a.png")[b"IDAT"]))
    rows = np.frombuffer(raw, np.uint8).reshape(41, 1 + 2 * 29)
    if np.all(rows[:, 0] == 0):
        np.testing.assert_array_equal(rows[:, 1:].copy().view(">u2"), dn)


def test_png_12_bit_dn_come_back_and_sbit(tmp_path, rng):
    # stored scaled to 16 bits (tests/datasets/test_png_scaling.py); read back as DN
    dn = rng.integers(0, 4096, (16, 16), dtype=np.uint16)
    dn[0, 0] = 4095
    p = tmp_path / "a.png"
    write_png(p, dn, bit_depth=12)
    assert read_png(p).max() == 4095
    np.testing.assert_array_equal(read_png(p), dn)
    assert _png_chunks(p)[b"sBIT"] == [bytes([12])]
    with pytest.raises(OutputFormatError, match="exceeds 4095"):
        write_png(tmp_path / "b.png", dn + 1, bit_depth=12)
    with pytest.raises(OutputFormatError, match="uint16"):
        write_png(tmp_path / "b.png", dn.astype(np.uint8), bit_depth=12)
    with pytest.raises(OutputFormatError, match="dtype"):
        write_png(tmp_path / "b.png", dn.astype(np.int32))
    assert not (tmp_path / "b.png").exists()


def test_png_deterministic_bytes(tmp_path, rng):
    for dtype in (np.uint8, np.uint16):
        dn = rng.integers(0, np.iinfo(dtype).max + 1, (64, 80), dtype=dtype)
        write_png(tmp_path / "a.png", dn, bit_depth=np.iinfo(dtype).bits)
        write_png(tmp_path / "b.png", dn.copy(), bit_depth=np.iinfo(dtype).bits)
        assert _sha(tmp_path / "a.png") == _sha(tmp_path / "b.png")


# ----------------------------------------------------------------------------- FITS + WCS
@pytest.mark.parametrize(
    "ra_deg, dec_deg, twist_deg, overrides",
    [
        (30.0, 20.0, 0.0, {}),
        (201.3, -47.9, 123.4, {}),
        (359.9, 89.5, 300.0, {}),  # near the pole: RA varies fast across the field
        (95.0, -10.0, 45.0, {"width": 640, "height": 480, "cx": 300.25, "cy": 250.75}),  # off-centre
    ],
)
def test_tan_wcs_against_astropy_wcs(ra_deg, dec_deg, twist_deg, overrides, rng):
    """astropy.wcs (WCSLIB) world_to_pixel agrees with Camera.project of R_cam_icrs @ u.

    Tolerance 1e-6 px: both are double-precision gnomonic projections of the same direction;
    the residual is round-off (~1e-12 px) far below it.
    """
    from astropy.coordinates import SkyCoord
    import astropy.units as u

    cam = paper_camera(**overrides)
    R = radec_twist_to_dcm(math.radians(ra_deg), math.radians(dec_deg), math.radians(twist_deg))
    header = tan_wcs_header(cam.K, cam.width, cam.height, R)
    wcs = WCS(header)
    # random directions filling the field (and a bit past it)
    xy_true = rng.uniform(-10.0, [cam.width + 10.0, cam.height + 10.0], (200, 2))
    u_icrs = cam.back_project(xy_true) @ R  # v_icrs = R^T v_cam
    xy_cam = cam.project(u_icrs @ R.T)
    ra, dec = unit_to_radec(u_icrs)
    sky = SkyCoord(np.degrees(ra) * u.deg, np.degrees(dec) * u.deg, frame="icrs")
    px, py = wcs.world_to_pixel(sky)  # astropy pixels are 0-based: FITS pixel minus 1
    np.testing.assert_allclose(np.stack([px, py], -1), xy_cam, rtol=0, atol=1e-6)
    # boresight at CRPIX, and the inverse direction
    assert header["CRPIX1"] == cam.cx + 1 and header["CRPIX2"] == cam.cy + 1
    back = wcs.pixel_to_world(xy_cam[:, 0], xy_cam[:, 1])
    assert np.max(back.separation(sky).to_value(u.rad)) * cam.focal_length_px < 1e-6  # px


def test_fits_round_trip_wcs_and_deterministic(tmp_path, rng):
    cam = paper_camera(width=96, height=64)
    R = radec_twist_to_dcm(1.0, 0.2, 0.3)
    dn = rng.integers(0, 65536, (64, 96), dtype=np.uint16)
    wcs_h = tan_wcs_header(cam.K, cam.width, cam.height, R)
    write_fits(tmp_path / "a.fits", dn, wcs_header=wcs_h, header={"EXPTIME": 0.4})
    write_fits(tmp_path / "b.fits", dn, wcs_header=wcs_h, header={"EXPTIME": 0.4})
    assert _sha(tmp_path / "a.fits") == _sha(tmp_path / "b.fits")
    data, header = read_fits(tmp_path / "a.fits")
    assert data.dtype == np.uint16
    np.testing.assert_array_equal(data, dn)  # row 0 stays row 0 (no flip)
    assert header["EXPTIME"] == 0.4 and header["CTYPE1"] == "RA---TAN"
    for k in ("CRPIX1", "CRVAL1", "CD1_1", "CD2_1"):
        # a FITS card holds 20 characters (16 significant digits): 1 ulp may go, ~1e-13 px
        assert header[k] == pytest.approx(wcs_h[k], rel=4e-16, abs=0.0)
    img = rng.random((64, 96)).astype(np.float32)
    write_fits(tmp_path / "c.fits", img)
    np.testing.assert_array_equal(read_fits(tmp_path / "c.fits")[0], img)
    with pytest.raises(OutputFormatError, match="NAXIS1"):
        write_fits(tmp_path / "d.fits", dn[:, :50], wcs_header=wcs_h)
    assert not (tmp_path / "d.fits").exists()


# ----------------------------------------------------------------------------- ground truth
def _truth():
    cam = paper_camera()
    R = radec_twist_to_dcm(0.5, 0.1, 0.2)
    return {
        "schema": FRAME_SCHEMA,
        "epoch": {"tdb_iso": "2030-01-01T00:00:00.000", "jd_tdb": 2462502.5},
        "observer": {"position_km": np.array([1.4e8, -2.2e7, 3.3e6]), "velocity_km_s": np.array([1.0, 29.5, 0.1])},
        "attitude": {"R_cam_icrs": R, "q_cam_icrs": np.array([1.0, 0.0, 0.0, 0.0]), "angular_velocity_rad_s": np.zeros(3)},
        "camera": cam.to_dict(),
        "stars": [{"hip": np.int64(32349), "v_mag": -1.46, "u_icrs": np.array([0.0, 0.6, 0.8]), "xy": np.array([511.25, 3.0]), "electrons": np.float32(1.5e6)}],
        "bodies": [{"name": "mars", "xy": [1.0, 2.0], "xy_geometric": [1.1, 2.1], "u_icrs": [1.0, 0.0, 0.0], "light_time_s": 600.0,
                    "distance_km": 1.8e8, "v_mag": 0.3, "phase_angle_deg": 12.0, "angular_diameter_px": 0.02,
                    "in_fov": np.bool_(True), "visible": True, "resolved": False, "electrons": float("nan")}],
        "cosmic_rays": [{"xy": (100.5, 200.25), "electrons": 3000.0}],
        "seeds": {"master": 7, "frame": [7, 0]},
    }


def test_truth_round_trip_and_nan_to_null(tmp_path):
    truth = _truth()
    p = tmp_path / "000000.json"
    write_truth_json(p, truth, strict=True)
    got = read_truth_json(p)
    assert list(got) == list(truth)  # insertion order kept
    assert got["bodies"][0]["electrons"] is None  # NaN -> null
    assert got["stars"][0]["hip"] == 32349 and got["bodies"][0]["in_fov"] is True
    assert got["attitude"]["R_cam_icrs"] == truth["attitude"]["R_cam_icrs"].tolist()  # repr floats: bit exact
    assert got["stars"][0]["electrons"] == float(np.float32(1.5e6))
    assert got["cosmic_rays"][0]["xy"] == [100.5, 200.25]
    assert validate_truth(got) == []
    assert b'"electrons":null' in p.read_bytes()


def test_truth_deterministic_bytes(tmp_path):
    write_truth_json(tmp_path / "a.json", _truth())
    write_truth_json(tmp_path / "b.json", _truth())
    assert _sha(tmp_path / "a.json") == _sha(tmp_path / "b.json")


def test_truth_schema_required_and_infinity_refused(tmp_path):
    t = _truth()
    del t["schema"]
    with pytest.raises(TruthSchemaError, match="schema"):
        write_truth_json(tmp_path / "a.json", t)
    t = _truth()
    t["bodies"][0]["distance_km"] = float("inf")
    with pytest.raises(TruthSchemaError, match=r"truth\.bodies\[0\]\.distance_km"):
        write_truth_json(tmp_path / "a.json", t)
    (tmp_path / "b.json").write_text('{"schema": "other/1"}')
    with pytest.raises(TruthSchemaError, match="other/1"):
        read_truth_json(tmp_path / "b.json")
    assert sorted(os.listdir(tmp_path)) == ["b.json"]


def test_validate_truth_catches_missing_keys_and_shapes():
    assert validate_truth(_truth()) == []
    t = _truth()
    del t["attitude"]["q_cam_icrs"]
    del t["bodies"][0]["xy_geometric"]
    del t["seeds"]
    t["stars"][0]["xy"] = [1.0, 2.0, 3.0]
    t["camera"].pop("bit_depth")
    problems = validate_truth(t)
    assert set(problems) == {
        "$.attitude.q_cam_icrs: missing",
        "$.bodies[0].xy_geometric: missing",
        "$.seeds: missing",
        "$.stars[0].xy: 3 items, expected at most 2",
        "$.camera.bit_depth: missing",
    }
    t = _truth()
    del t["cosmic_rays"]
    t["epoch"] = "2030"
    assert set(validate_truth(t)) == {"$.cosmic_rays: missing", '$.epoch: "2030" is not of type object'}
    with pytest.raises(TruthSchemaError) as err:
        write_truth_json("/nonexistent-dir/x.json", {**_truth(), "seeds": None} | {"observer": {}}, strict=True)
    assert "$.observer.position_km: missing" in err.value.problems


# docs/conventions.md "Per-frame ground truth", copied by hand: the independent reference the published
# schema must require (section -> keys; the lists' keys are per item).
CONVENTIONS_FIXED_KEYS = {
    "epoch": ["tdb_iso", "jd_tdb"],
    "observer": ["position_km", "velocity_km_s"],
    "attitude": ["R_cam_icrs", "q_cam_icrs", "angular_velocity_rad_s"],
    "camera": ["K", "width", "height", "focal_length_mm", "pixel_pitch_um", "f_number", "exposure_s", "bit_depth"],
    "stars": ["hip", "v_mag", "u_icrs", "xy", "electrons"],
    "bodies": ["name", "xy", "xy_geometric", "u_icrs", "light_time_s", "distance_km", "v_mag", "phase_angle_deg",
               "angular_diameter_px", "in_fov", "visible", "resolved", "electrons"],
    "cosmic_rays": ["xy", "electrons"],
}


def test_every_required_key_of_conventions_is_checked():
    """Removing any one fixed key of docs/conventions.md is reported, with its JSON path (the schema
    cannot be vacuous), and an extra key anywhere is welcome."""
    base = _truth()
    for section, keys in CONVENTIONS_FIXED_KEYS.items():
        for key in keys:
            t = _truth()
            target = t[section][0] if isinstance(t[section], list) else t[section]
            del target[key]
            probs = validate_truth(t)
            where = f"$.{section}[0].{key}" if isinstance(t[section], list) else f"$.{section}.{key}"
            assert probs == [f"{where}: missing"], (section, key, probs)
    for top in ("schema", "seeds", *CONVENTIONS_FIXED_KEYS):
        t = _truth()
        del t[top]
        assert f"$.{top}: missing" in validate_truth(t)
    t = _truth()
    t["new_section"] = {"anything": [1, 2]}
    t["stars"][0]["colour_index"] = 0.3
    t["bodies"][0]["elongation_deg"] = 40.0
    t["cosmic_rays"][0]["track"] = {"length_px": 3.0}
    assert validate_truth(base) == [] and validate_truth(t) == []


def test_truth_layout_parses_like_stdlib_json_and_one_record_per_line(tmp_path):
    # Oracle: the standard library's own encoder (pure-Python, indent mode) on the same plain data;
    # the canonical layout must decode to exactly the same object, and write each star on one line.
    import json

    from skynav.datasets.truth_schema import truth_json_bytes, truth_to_jsonable

    truth = _truth()
    truth["stars"] = truth["stars"] * 50
    text = truth_json_bytes(truth).decode("ascii")
    reference = json.loads(json.dumps(truth_to_jsonable(truth), indent=2))
    assert json.loads(text) == reference
    star_lines = [ln for ln in text.splitlines() if ln.lstrip().startswith('{"hip"')]
    assert len(star_lines) == 50
    assert text.endswith("}\n") and "NaN" not in text and "Infinity" not in text


def test_truth_bytes_of_the_truth_as_given_equal_those_of_its_plain_copy():
    # truth_json_bytes writes the layout from the values as given (tuples, whole lists of records
    # in one orjson call) and falls back to the truth_to_jsonable copy where only it can say; the
    # copy is the reference: the same bytes for records with NaN, numpy values, tuples, nested
    # mappings, braces and "},{" inside strings, non-ASCII text, and a non-dict mapping
    from collections import OrderedDict

    from skynav.datasets.truth_schema import truth_json_bytes, truth_to_jsonable

    truth = _truth()
    truth["stars"] = [copy.deepcopy(s) for s in truth["stars"] * 4]
    cases = [truth]
    for change in (
        lambda t: t["stars"][1].update(v_mag=float("nan")),
        lambda t: t["stars"][2].update(xy=np.array([1.5, 2.25]), hip=np.int64(7)),
        lambda t: t["stars"][0].update(xy=(1.0, 2)),
        lambda t: t["stars"][3].update(note="a {b},{c} d"),
        lambda t: t["stars"][3].update(note="x},{y"),
        lambda t: t["stars"][2].update(track={"length_px": 3.0}),
        lambda t: t["stars"][1].update(note="\u00e9toile"),
        lambda t: t.update(extra=OrderedDict(a=[1.0, None])),
        lambda t: t.update(cosmic_rays=[]),
    ):
        t = copy.deepcopy(truth)
        change(t)
        cases.append(t)
    for t in cases:
        assert truth_json_bytes(t) == truth_json_bytes(truth_to_jsonable(t))
        assert json.loads(truth_json_bytes(t)) == json.loads(json.dumps(truth_to_jsonable(t)))
    bad = copy.deepcopy(truth)
    bad["stars"][2]["v_mag"] = float("inf")
    with pytest.raises(TruthSchemaError, match=r"truth\.stars\[2\]\.v_mag = inf"):
        truth_json_bytes(bad)


def test_truth_numpy_nan_and_inf_inside_arrays(tmp_path):
    from skynav.datasets.truth_schema import truth_to_jsonable

    assert truth_to_jsonable({"a": np.array([1.0, np.nan])}) == {"a": [1.0, None]}
    assert truth_to_jsonable({"a": np.array([[1, 2]], dtype=np.uint16)}) == {"a": [[1, 2]]}
    assert truth_to_jsonable({"a": (np.float32(0.5), np.int64(3), np.bool_(False))}) == {"a": [0.5, 3, False]}
    with pytest.raises(TruthSchemaError, match=r"truth\.a\[1\]"):
        truth_to_jsonable({"a": np.array([1.0, -np.inf])})
    with pytest.raises(TruthSchemaError, match="key 3"):
        truth_to_jsonable({"a": {3: 1.0}})
    with pytest.raises(TruthSchemaError, match=r"truth\.a: value of type set"):
        truth_to_jsonable({"a": {1, 2}})


def test_thread_budget_reads_skynav_threads_without_the_renderer(monkeypatch):
    # the file side reads SKYNAV_THREADS itself (it may not import the renderer); same meaning
    from skynav.infra.threads import thread_budget
    from skynav.infra.errors import ConfigValueError

    monkeypatch.delenv("SKYNAV_THREADS", raising=False)
    assert thread_budget() is None
    monkeypatch.setenv("SKYNAV_THREADS", " 3 ")
    assert thread_budget() == 3
    for bad in ("0", "-2", "two", "1.5"):
        monkeypatch.setenv("SKYNAV_THREADS", bad)
        with pytest.raises(ConfigValueError, match="SKYNAV_THREADS"):
            thread_budget()


def test_write_frame_writes_each_format_and_refuses_unknown_ones(tmp_path, rng):
    from types import SimpleNamespace

    from skynav.datasets.frame_files import write_frame

    truth = _truth()
    cam = truth["camera"]
    dn = rng.integers(0, 256, (cam["height"], cam["width"]), dtype=np.uint8)
    e = rng.random(dn.shape).astype(np.float32)
    frame = SimpleNamespace(dn=dn, electrons=e, irradiance_w_m2=e * 1e-12, truth=truth)
    paths = write_frame(frame, tmp_path / "out", "f", formats=("png", "json"), fits=True)
    assert list(paths) == ["png", "json", "fits"] and all(p.is_file() for p in paths.values())
    np.testing.assert_array_equal(read_png(paths["png"]), dn)
    assert read_truth_json(paths["json"])["stars"][0]["hip"] == 32349
    data, header = read_fits(paths["fits"])
    np.testing.assert_array_equal(data, dn)
    assert header["CRPIX1"] == cam["K"][0][2] + 1.0
    with pytest.raises(SkynavError, match="formats"):
        write_frame(frame, tmp_path / "out", "g", formats=("tiff",))


def test_atomic_write_many_writes_all_and_leaves_no_temp_files(tmp_path):
    from skynav.infra.atomic_files import atomic_write_many

    (tmp_path / "b.json").write_bytes(b"old")
    atomic_write_many([(tmp_path / "a.exr", b"\x00" * 10), (tmp_path / "b.json", b"{}")])
    assert (tmp_path / "a.exr").read_bytes() == b"\x00" * 10 and (tmp_path / "b.json").read_bytes() == b"{}"
    with pytest.raises(FileNotFoundError):  # a folder that does not exist: nothing renamed, no temp left
        atomic_write_many([(tmp_path / "c.png", b"1"), (tmp_path / "missing" / "d.png", b"2")])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.exr", "b.json"]
