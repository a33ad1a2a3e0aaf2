"""The sparse RLE encoder of EXR files (``datasets/exr_rle.py``) against OpenEXR's own: a lossless
round trip (OpenEXR reads back the very words written), and the header is the one
OpenEXR writes itself, for mostly-zero frames, dense noise, long runs and long literals (the
127-byte literal and 128-byte run limits), rows that do not shrink (stored raw) and uint32
channels."""

from __future__ import annotations

import io

import numpy as np
import pytest

from skynav.datasets.exr_rle import rle_file
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


def _reference_rle_file(head: bytes, channels) -> bytes:
    """The file :func:`rle_file` writes, one scanline at a time in plain code: OpenEXR's RLE
    (internal_rle.c: the bytes split even/odd, d[0] = t[0], d[j] = t[j] - t[j-1] + 128 mod 256,
    literals (-count, bytes) of up to 127 bytes, runs (count - 1, byte) of up to 128), cut where the
    encoder cuts: a literal covers each half's bytes of an island of dirty 4-byte words (word 0,
    a non-zero word and the word after one), islands at most one clean word apart are one, the
    128s between islands are runs; a chunk that does not shrink is stored raw."""
    words = np.concatenate([np.asarray(c).view("<u4") for c in channels], axis=1)
    H, W = words.shape
    chunks = []
    for y in range(H):
        raw = words[y].tobytes()
        t = np.frombuffer(raw[0::2] + raw[1::2], np.uint8).astype(int)
        d = np.concatenate((t[:1], (t[1:] - t[:-1] + 128) % 256)).astype(np.uint8).tobytes()
        islands = []
        for k in range(W):
            if k == 0 or words[y, k] != 0 or words[y, k - 1] != 0:
                if islands and k - islands[-1][1] <= 2:
                    islands[-1][1] = k
                else:
                    islands.append([k, k])
        data = b""
        for half in (0, 2 * W):
            for i, (a, b) in enumerate(islands):
                literal = d[half + 2 * a:half + 2 * b + 2]
                for j in range(0, len(literal), 127):
                    data += bytes([256 - len(literal[j:j + 127])]) + literal[j:j + 127]
                gap = (2 * islands[i + 1][0] if i + 1 < len(islands) else 2 * W) - (2 * b + 2)
                for j in range(0, gap, 128):
                    data += bytes([min(128, gap - j) - 1, 128])
        if len(data) >= len(raw):
            data = raw
        chunks.append(y.to_bytes(4, "little") + len(data).to_bytes(4, "little") + data)
    offsets, at = [], len(head) + 8 * H
    for chunk in chunks:
        offsets.append(at.to_bytes(8, "little"))
        at += len(chunk)
    return head + b"".join(offsets) + b"".join(chunks)


def test_bytes_equal_those_of_a_plain_per_scanline_encoder(rng):
    """The vectorised encoder writes exactly the bytes of the plain one above, for sparse, dense,
    long-island (> 127 bytes), long-gap (> 128 bytes), raw-row, 1-3 channel, odd-width images with
    NaN, inf, -0.0 and uint32 words (OpenEXR reading them back is checked above)."""
    head = b"an EXR header\0"
    specials = np.array([np.nan, np.inf, -np.inf, -0.0, 1.0, 3e-39], np.float32)
    for trial in range(60):
        h, w = int(rng.integers(1, 12)), int(rng.integers(1, 400))
        fill = [0.0, 0.005, 0.03, 0.2, 1.0][trial % 5]
        channels = []
        for c in range(int(rng.integers(1, 4))):
            values = [rng.normal(size=(h, w)).astype(np.float32), rng.choice(specials, (h, w)),
                      rng.integers(0, 2**32, (h, w), dtype=np.uint64).astype(np.uint32)][(trial + c) % 3]
            keep = rng.random((h, w)) < fill
            if trial % 4 == 3:  # a long island
                a = int(rng.integers(0, w))
                keep[:, a:a + int(rng.integers(60, 200))] = True
            channels.append(np.where(keep, values, values.dtype.type(0)).view("<u4"))
        assert rle_file(head, channels) == _reference_rle_file(head, channels), trial
