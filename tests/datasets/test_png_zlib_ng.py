"""PNG frames are deflated by zlib-ng: its run-length stream must be the standard zlib's bytes.

Reference: the Python standard library's ``zlib`` (the zlib that skynav used before, and that
libpng and Pillow use), given the same rows: filter type 0 per row, then the samples
(big-endian for 16 bits, PNG 2nd ed. 7.2), ``compressobj(level, DEFLATED, 15, 9, Z_RLE)``.
Equal bytes mean that the switch changed no file (CHANGELOG.md), and a
zlib-ng release whose stream differs fails here, before a dataset holds files of both.
"""

from __future__ import annotations

import io
import zlib
from pathlib import Path

import numpy as np
import pytest

from skynav.datasets.frame_files import png_bytes, read_png

REF = Path(__file__).parent / "data" / "main_a259a83"


def _idat(data: bytes) -> bytes:
    """The IDAT payloads of a PNG, concatenated."""
    out, i = [], 8
    while i + 8 <= len(data):
        n = int.from_bytes(data[i:i + 4], "big")
        if data[i + 4:i + 8] == b"IDAT":
            out.append(data[i + 8:i + 8 + n])
        i += 12 + n
    return b"".join(out)


def _stdlib_stream(a: np.ndarray, level: int) -> bytes:
    samples = a.astype(">u2") if a.dtype == np.uint16 else a
    rows = np.zeros((a.shape[0], 1 + a.shape[1] * a.dtype.itemsize), np.uint8)
    rows[:, 1:] = samples.view(np.uint8).reshape(a.shape[0], -1)
    z = zlib.compressobj(level, zlib.DEFLATED, 15, 9, zlib.Z_RLE)
    return z.compress(rows.tobytes()) + z.flush()


def _images():
    g = np.random.default_rng(20261126)
    # a 1024 x 1024 dark frame with a bias, shot noise and stars: the default frame's statistics
    dark = np.minimum(g.poisson(2.2, (1024, 1024)), 255).astype(np.uint8)
    ys, xs = g.integers(0, 1024, 700), g.integers(0, 1024, 700)
    dark[ys, xs] = g.integers(3, 256, 700).astype(np.uint8)
    yield "dark 8-bit frame", dark
    # a bright, noisy 16-bit frame: many literals, so several deflate blocks
    yield "bright 16-bit frame", np.minimum(g.poisson(900.0, (600, 700)), 65535).astype(np.uint16)
    yield "flat", np.full((33, 257), 7, np.uint8)
    yield "one pixel", np.array([[200]], np.uint8)
    for lam in (0.3, 30.0, 4000.0):
        dtype = np.uint8 if lam < 100 else np.uint16
        yield f"poisson {lam}", np.minimum(g.poisson(lam, (int(g.integers(1, 300)), int(g.integers(1, 300)))),
                                           np.iinfo(dtype).max).astype(dtype)
    for stem in ("000000", "000001"):  # frames written by main at a259a83, 8 and 12 bits
        for bits in (8, 12):
            yield f"main_a259a83 mc{bits} {stem}", read_png(REF / f"mc{bits}" / f"{stem}.png")


@pytest.mark.parametrize("level", [1, 6, 9])
def test_png_deflate_is_the_standard_zlib_stream(level):
    for name, a in _images():
        got = _idat(png_bytes(a, compress_level=level))
        assert got == _stdlib_stream(a, level), f"{name}, level {level}"
        assert zlib.decompress(got)  # a zlib stream the standard library reads


def test_frame_png_decodes_to_its_dn():
    """The frame's PNG (12 bits: scaled to 16 and marked) still reads back to its DN."""
    a = read_png(REF / "mc12" / "000000.png")
    assert np.array_equal(read_png(io.BytesIO(png_bytes(a, bit_depth=12))), a)
