"""PNGs that follow the PNG standard: DN of fewer bits than the sample are scaled to the full range
with an ``sBIT`` chunk (PNG 2nd ed., section 12.4), so every viewer shows the image; skynav reads
back the DN of these files and of the unscaled ones skynav <= 0.3.0 wrote.

The independent reader is Pillow (what a viewer or an outside script sees) and a chunk walker
written here from the PNG specification (``sBIT``, ``tEXt``); skynav's reader is checked against
the DN that were written."""

import json
import struct

import numpy as np
import pytest
from PIL import Image, PngImagePlugin

from skynav.datasets.frame_files import (
    PNG_SCALING_KEY,
    read_png,
    read_png_layout,
    scale_dn_to_png,
    unscale_png_to_dn,
    write_png,
)


def _chunks(path):
    b = open(path, "rb").read()
    assert b[:8] == b"\x89PNG\r\n\x1a\n"
    i, out = 8, {}
    while i < len(b):
        (n,) = struct.unpack(">I", b[i:i + 4])
        out.setdefault(b[i + 4:i + 8], []).append(b[i + 8:i + 8 + n])
        i += 12 + n
    return out


def _pillow(path):
    with Image.open(path) as im:
        return np.array(im), dict(im.text)


def _write_like_0_3_0(path, dn, bit_depth=None):
    """What skynav 0.3.0 wrote: the DN unscaled, an sBIT chunk with the bit depth, no marker."""
    info = None
    if bit_depth is not None:
        info = PngImagePlugin.PngInfo()
        info.add(b"sBIT", bytes([bit_depth]))
    Image.fromarray(np.ascontiguousarray(dn)).save(path, format="PNG", pnginfo=info)


@pytest.mark.parametrize("bits", range(1, 17))
def test_scaling_is_exactly_invertible_for_every_value(bits):
    container = 8 if bits <= 8 else 16
    dn = np.arange(1 << bits, dtype=np.uint8 if container == 8 else np.uint16)
    stored = scale_dn_to_png(dn, bits)
    # the spec's recommended scaling, in floats, as an independent check (values < 2**16: exact)
    want = np.floor(dn.astype(float) * ((1 << container) - 1) / ((1 << bits) - 1) + 0.5)
    np.testing.assert_array_equal(stored, want)
    assert stored[0] == 0 and stored[-1] == (1 << container) - 1  # full range
    np.testing.assert_array_equal(unscale_png_to_dn(stored, bits), dn)
    # a decoder that follows the spec's sBIT advice (a right shift) gets the DN back too
    np.testing.assert_array_equal(stored >> (container - bits), dn)


@pytest.mark.parametrize("bits", [6, 10, 12])
def test_written_png_is_full_range_with_sbit_and_round_trips(tmp_path, rng, bits):
    dtype = np.uint8 if bits <= 8 else np.uint16
    dn = rng.integers(0, 1 << bits, (33, 47)).astype(dtype)
    dn[0, :2] = (0, (1 << bits) - 1)
    p = tmp_path / "a.png"
    write_png(p, dn, bit_depth=bits)
    seen, text = _pillow(p)  # what a viewer decodes
    top = np.iinfo(dtype).max
    assert seen.max() == top and seen.min() == 0
    np.testing.assert_array_equal(seen.astype(np.int64), np.floor(dn * (top / ((1 << bits) - 1)) + 0.5))
    c = _chunks(p)
    assert c[b"sBIT"] == [bytes([bits])]
    assert c[b"IHDR"][0][8] == (8 if bits <= 8 else 16)  # the PNG sample depth
    assert text[PNG_SCALING_KEY] == "sbit"
    got = read_png(p)
    assert got.dtype == dtype
    np.testing.assert_array_equal(got, dn)
    assert read_png_layout(p) == {"png_scaling": "sbit", "significant_bits": bits}


def test_a_dark_scaled_png_still_reads_as_scaled(tmp_path):
    # values that would fit the unscaled range: the marker, not the values, says which
    dn = np.zeros((8, 8), np.uint16)
    dn[3, 3] = 5
    write_png(tmp_path / "a.png", dn, bit_depth=10)
    assert _pillow(tmp_path / "a.png")[0][3, 3] == 320
    np.testing.assert_array_equal(read_png(tmp_path / "a.png"), dn)


@pytest.mark.parametrize("with_sbit", [True, False])
def test_png_of_skynav_0_3_0_reads_unchanged(tmp_path, rng, with_sbit):
    dn = rng.integers(0, 1024, (20, 30)).astype(np.uint16)
    p = tmp_path / "old.png"
    _write_like_0_3_0(p, dn, 10 if with_sbit else None)
    np.testing.assert_array_equal(read_png(p), dn)
    assert read_png_layout(p) == {"png_scaling": "raw", "significant_bits": 10 if with_sbit else 16}


def test_foreign_png_scaled_by_bit_replication_is_unscaled(tmp_path, rng):
    """Another encoder's spec-conforming file: sBIT 12, left-bit replication, no skynav marker;
    its values exceed 4095, so it cannot be unscaled DN."""
    dn = rng.integers(0, 4096, (16, 16)).astype(np.uint16)
    dn[0, 0] = 4095
    stored = (dn << 4) | (dn >> 8)
    _write_like_0_3_0(tmp_path / "f.png", stored, 12)
    np.testing.assert_array_equal(read_png(tmp_path / "f.png"), dn)


def test_dataset_camera_png_is_scaled_and_reads_the_same_dn(tmp_path, rng):
    """A 12-bit camera frame: Pillow sees the full 16-bit range, skynav's reader the DN."""
    from types import SimpleNamespace

    from skynav.datasets.frame_files import write_frame

    dn = rng.integers(0, 4096, (12, 14)).astype(np.uint16)
    dn[0, 0] = 4095
    frame = SimpleNamespace(dn=dn, truth={"camera": {"bit_depth": 12}})
    paths = write_frame(frame, tmp_path, "000000", formats=("png",))
    seen, _ = _pillow(paths["png"])
    assert seen.max() == 65535 and _chunks(paths["png"])[b"sBIT"] == [bytes([12])]
    np.testing.assert_array_equal(read_png(paths["png"]), dn)


def test_image_reader_of_the_pipeline_gives_dn_of_both_layouts(tmp_path, rng):
    from skynav.datasets.reader import read_image_dn

    dn = rng.integers(0, 4096, (10, 10)).astype(np.uint16)
    write_png(tmp_path / "new.png", dn, bit_depth=12)
    _write_like_0_3_0(tmp_path / "old.png", dn, 12)
    for name in ("new.png", "old.png"):
        np.testing.assert_array_equal(read_image_dn(tmp_path / name), dn)


# ----------------------------------------------------------------------------- screen frames
@pytest.fixture(scope="module")
def screen(tmp_path_factory):
    from skynav.datasets.hil_export import write_screen_frame
    from skynav.renderer.display import screen_frame
    from skynav.scenes import config, presets
    from skynav.scenes.facility import screen_small_preset
    from skynav.scenes.scene import build_from_spec

    fac = screen_small_preset()
    scene = build_from_spec(config.scene_spec_from_mapping(presets.preset_mapping("default")))
    out = tmp_path_factory.mktemp("screen")
    rec = write_screen_frame(fac, scene, out, "f", source={"scene": "default"}, seed=3)
    # the same draw in memory (seed = the frame's seed): the screen DN the file must give back
    sf = screen_frame(scene, fac, rng=np.random.default_rng(3))
    return fac, out / "frames" / "f.png", rec, sf.dn


def test_screen_frame_png_shows_the_stars_to_any_viewer(screen):
    fac, png, rec, dn = screen
    bits = fac.screen.bit_depth
    assert bits < 16
    seen, text = _pillow(png)
    # the brightest star, at full screen scale or close, is near the top of the 16-bit range
    # (unscaled it would sit at <= 1023 of 65535, 1.6 %: black in a viewer)
    assert seen.max() > 32768 and seen.max() == scale_dn_to_png(dn, bits).max()
    star = max(rec["stars"], key=lambda s: s["peak_dn"] if s["on_screen"] else -1)
    x, y = (int(round(v)) for v in star["screen_xy"])
    assert seen[y - 1:y + 2, x - 1:x + 2].max() >= 64 * star["peak_dn"] // 2  # the star is where it was put
    assert _chunks(png)[b"sBIT"] == [bytes([bits])] and text[PNG_SCALING_KEY] == "sbit"
    assert rec["schema"] == "skynav.hil_frame/2"
    assert rec["png_scaling"] == "sbit" and rec["significant_bits"] == bits
    np.testing.assert_array_equal(read_png(png), dn)


def test_screen_frame_of_0_3_0_reads_the_same_screen_dn(screen, tmp_path):
    fac, png, _, dn = screen
    _write_like_0_3_0(tmp_path / "old.png", dn, fac.screen.bit_depth)
    np.testing.assert_array_equal(read_png(tmp_path / "old.png"), read_png(png))


# ----------------------------------------------------------------------------- calibration patterns
@pytest.fixture(scope="module")
def small_facility():
    from skynav.scenes.facility import screen_small_preset

    return screen_small_preset()


@pytest.fixture(scope="module")
def small_patterns(tmp_path_factory, small_facility):
    from skynav.calibration.bench_files import write_patterns

    d = tmp_path_factory.mktemp("patterns")
    write_patterns(small_facility, d)
    return d


def _as_0_3_0(patterns_dir, out_dir):
    """The pattern folder as skynav 0.3.0 wrote it: unscaled PNGs, patterns.json version 1."""
    out_dir.mkdir()
    doc = json.loads((patterns_dir / "patterns.json").read_text())
    bits = doc["screen"]["bit_depth"]
    for p in doc["patterns"]:
        _write_like_0_3_0(out_dir / p["file"], read_png(patterns_dir / p["file"]), bits)
    old = {"schema": "skynav.patterns/1", "screen": doc["screen"], "patterns": doc["patterns"]}
    (out_dir / "patterns.json").write_text(json.dumps(old, indent=1))


def test_patterns_are_visible_and_say_how_they_are_stored(small_facility, small_patterns):
    from skynav.calibration.patterns import draw, read_patterns

    doc = json.loads((small_patterns / "patterns.json").read_text())
    bits = small_facility.screen.bit_depth
    assert doc["schema"] == "skynav.patterns/2"
    assert doc["png_scaling"] == "sbit" and doc["significant_bits"] == bits
    _, pats = read_patterns(small_patterns)
    dots = next(p for p in pats if p.kind == "dots")
    seen, _ = _pillow(small_patterns / dots.file)
    # the dots are drawn at level_dn (~0.1 of a 10-bit screen's range): scaled, a viewer sees them
    assert seen.max() == scale_dn_to_png(np.array([dots.level_dn], np.uint16), bits)[0] > 64 * dots.level_dn - 1
    assert _chunks(small_patterns / dots.file)[b"sBIT"] == [bytes([bits])]
    sc = small_facility.screen
    np.testing.assert_array_equal(read_png(small_patterns / dots.file), draw(dots, sc.width_px, sc.height_px, bits))


def test_bench_reads_old_and_new_patterns_alike(small_facility, small_patterns, tmp_path):
    """The virtual bench captures the same images from 0.3.0's pattern files and from today's."""
    from skynav.calibration.bench_files import simulate

    _as_0_3_0(small_patterns, tmp_path / "old")
    a = simulate(small_facility, small_patterns, tmp_path / "cap_new", frames=1, seed=5)
    b = simulate(small_facility, tmp_path / "old", tmp_path / "cap_old", frames=1, seed=5)
    assert a == b
    for f in sorted(p.name for p in (tmp_path / "cap_new").glob("*.png")):
        np.testing.assert_array_equal(read_png(tmp_path / "cap_new" / f), read_png(tmp_path / "cap_old" / f))
