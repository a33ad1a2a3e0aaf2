"""The sparse RLE encoder of EXR files (``datasets/frame_files.py``, :func:`_exr_rle_file`):
a lossless round trip (OpenEXR reads back the very words written), and the header is the one
OpenEXR writes itself, for mostly-zero frames, dense noise, long runs and long literals (the
127-byte literal and 128-byte run limits), rows that do not shrink (stored raw) and uint32
channels."""

from __future__ import annotations

import io

import numpy as np
import pytest

from skynav.datasets.frame_files import _exr_bytes, read_exr, read_exr_header


def _equal_words(a, b) -> bool:
    """A round trip through a lossless file: the 4-byte words read back equal those written."""
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype.itemsize == b.dtype.itemsize == 4 and np.array_equal(a.view(np.uint32), b.view(np.uint32))


def _check(channels, header=None):
    fast = _exr_bytes(channels, header)
    ref = _exr_bytes(channels, header, sparse=False)  # OpenEXR's own RLE encoder
    back = read_exr(io.BytesIO(fast))
    assert sorted(back) == sorted(channels)
    for name, a in channels.items():
        want = np.asarray(a, np.uint32 if np.asarray(a).dtype.kind in "ui" else np.float32)
        assert _equal_words(back[name], want), name  # round trip
    assert repr(read_exr_header(io.BytesIO(fast))) == repr(read_exr_header(io.BytesIO(ref)))
    return fast, ref


def test_mostly_zero_frame_is_smaller_or_equal_and_decodes_exactly(rng):
    e = np.zeros((64, 200), np.float32)
    for _ in range(30):  # star-like blobs
        y, x = rng.integers(2, 62), rng.integers(2, 198)
        e[y - 2:y + 3, x - 2:x + 3] = rng.gamma(2.0, 50.0, (5, 5))
    fast, ref = _check({"electrons": e, "irradiance_w_m2": e * np.float32(3.1e-17)})
    assert len(fast) <= len(ref) * 1.15  # the same RLE format, cut at other places (whole 4-byte words)


@pytest.mark.parametrize("fill", [0.0, 0.01, 0.2, 0.7, 1.0])
def test_random_fill_and_values(rng, fill):
    for trial in range(8):
        h, w = int(rng.integers(1, 30)), int(rng.integers(1, 300))
        values = [rng.normal(size=(h, w)), np.ones((h, w)), rng.integers(0, 3, (h, w)).astype(float),
                  -np.zeros((h, w))][trial % 4]
        e = np.where(rng.random((h, w)) < fill, values, 0.0).astype(np.float32)
        ids = np.where(rng.random((h, w)) < fill, rng.integers(0, 2**32, (h, w), dtype=np.uint64), 0).astype(np.uint32)
        _check({"b": e, "a_id": ids, "z": np.full((h, w), trial % 2, np.float32)}, {"note": "x", "n": 3})


def test_long_runs_literals_and_raw_rows(rng):
    w = 3000
    e = np.zeros((5, w), np.float32)
    e[0] = rng.normal(size=w)  # dense noise: stored raw
    e[1, 500:900] = 1.5  # a literal of more than 127 bytes, runs of more than 128
    e[2, ::7] = 2.0
    e[3, ::2] = rng.normal(size=w // 2)
    _check({"e": e})
