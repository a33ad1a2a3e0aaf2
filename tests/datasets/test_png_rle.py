"""The PNG writer's fast path (``datasets/png_rle.py``) against its reference, Pillow's writer:
other bytes, the same decoded pixels and the same ``sBIT`` and ``tEXt`` chunks, for 8- and
16-bit frames (a dark noisy sky with stars, a flat field, full-range noise, one pixel)."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from skynav.datasets.frame_files import PNG_SCALING, PNG_SCALING_KEY, png_bytes, read_png, scale_dn_to_png
from skynav.datasets.png_rle import png_rle_bytes, reference_png_bytes


def _frames(rng, dtype, top):
    h, w = 96, 130
    sky = rng.poisson(3.0, (h, w)).astype(dtype)
    for _ in range(12):
        y, x = rng.integers(2, h - 2), rng.integers(2, w - 2)
        sky[y - 2:y + 3, x - 2:x + 3] = rng.integers(0, top + 1, (5, 5))
    return [sky, np.full((h, w), top, dtype), rng.integers(0, top + 1, (h, w)).astype(dtype), np.zeros((1, 1), dtype)]


def _decoded(data: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(data)) as im:
        a = np.array(im)
    return a.astype(np.uint16) if a.dtype.itemsize > 2 else a


@pytest.mark.parametrize("dtype, top", [(np.uint8, 255), (np.uint16, 65535)])
@pytest.mark.parametrize("level", [1, 6])
def test_the_same_pixels_as_pillows_writer(rng, dtype, top, level):
    for a in _frames(rng, dtype, top):
        fast, ref = png_rle_bytes(a, level), reference_png_bytes(a, level)
        np.testing.assert_array_equal(_decoded(fast), a)
        np.testing.assert_array_equal(_decoded(ref), a)


def test_the_same_chunks_and_dn_as_pillows_writer_for_a_12_bit_frame(rng):
    dn = rng.integers(0, 4096, (40, 50)).astype(np.uint16)
    stored = scale_dn_to_png(dn, 12)
    text = ((PNG_SCALING_KEY, PNG_SCALING),)
    fast, ref = png_rle_bytes(stored, 6, sbit=12, text=text), reference_png_bytes(stored, 6, sbit=12, text=text)
    assert fast == png_bytes(dn, bit_depth=12)  # what the writer writes
    for data in (fast, ref):
        with Image.open(io.BytesIO(data)) as im:
            assert im.info[PNG_SCALING_KEY] == PNG_SCALING
        assert b"sBIT\x0c" in data
        np.testing.assert_array_equal(read_png(io.BytesIO(data)), dn)
