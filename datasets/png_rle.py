"""Greyscale PNG files with unfiltered rows deflated run-length: the fast path of the PNG writer.

What it computes: a greyscale PNG (PNG 2nd ed., ISO/IEC 15948): ``IHDR``, an optional ``sBIT``
chunk and ``tEXt`` chunks, one ``IDAT``, ``IEND``; no time stamp. Every row has filter type 0
(None): the frames are a dark, noisy, flat background with a few stars, where a predictor finds
nothing the entropy coder does not. The rows are deflated with zlib's run-length strategy
``Z_RLE`` (runs only, no string matching) by zlib-ng (``zlib-ng``, the zlib of its SIMD compare
and checksum), whose ``Z_RLE`` stream is the bytes of the standard library's zlib for the same
rows and level (a run-length coder hashes nothing; ``tests/datasets/test_png_zlib_ng.py``
compares the two). ISA-L's deflate was tried and left: its bytes for the same rows were not
always the same from one process to the next, so a dataset's files were not reproducible.

The reference is Pillow's PNG writer (:func:`reference_png_bytes`: adaptive filters, zlib's
default strategy): other bytes, the same decoded pixels (``tests/datasets/test_png_rle.py``).
``benchmarks/encoder_bench.py`` measures what this path saves of a frame (docs/performance.md).
"""

from __future__ import annotations

import io
import zlib

import numpy as np
from PIL import Image, PngImagePlugin
from zlib_ng import zlib_ng

__all__ = ["png_rle_bytes", "reference_png_bytes"]


def _chunk(kind: bytes, payload: bytes) -> bytes:
    return len(payload).to_bytes(4, "big") + kind + payload + zlib.crc32(payload, zlib.crc32(kind)).to_bytes(4, "big")


def png_rle_bytes(a: np.ndarray, level: int, *, sbit: int | None = None, text=()) -> bytes:
    """The PNG file of the greyscale samples ``a`` ((H, W) uint8 or uint16), deflated at zlib
    ``level`` (0..9); ``sbit``: the significant bits (an ``sBIT`` chunk); ``text``: ``(keyword,
    value)`` pairs, each a ``tEXt`` chunk (Latin-1)."""
    h, w = a.shape
    if a.dtype == np.uint16:
        a = a.astype(">u2", copy=False)  # PNG samples are big-endian
    rows = np.zeros((h, 1 + w * a.dtype.itemsize), np.uint8)  # column 0: filter type 0 per row
    rows[:, 1:] = np.ascontiguousarray(a).view(np.uint8).reshape(h, -1)
    z = zlib_ng.compressobj(level, zlib_ng.DEFLATED, 15, 9, zlib_ng.Z_RLE)
    idat = z.compress(rows) + z.flush()
    ihdr = w.to_bytes(4, "big") + h.to_bytes(4, "big") + bytes([8 * a.dtype.itemsize, 0, 0, 0, 0])
    out = [b"\x89PNG\r\n\x1a\n", _chunk(b"IHDR", ihdr)]
    if sbit is not None:
        out.append(_chunk(b"sBIT", bytes([sbit])))  # greyscale sBIT: one byte, significant bits
    out += [_chunk(b"tEXt", key.encode("latin-1") + b"\0" + value.encode("latin-1")) for key, value in text]
    out += [_chunk(b"IDAT", idat), _chunk(b"IEND", b"")]
    return b"".join(out)


def reference_png_bytes(a: np.ndarray, level: int, *, sbit: int | None = None, text=()) -> bytes:
    """The same image written by Pillow (its adaptive filters and zlib's default strategy at
    ``level``), with the same ``sBIT`` and ``tEXt`` chunks: the reference of
    :func:`png_rle_bytes`."""
    info = PngImagePlugin.PngInfo()
    if sbit is not None:
        info.add(b"sBIT", bytes([sbit]))
    for key, value in text:
        info.add_text(key, value)
    image = Image.fromarray(np.ascontiguousarray(a))  # mode L for uint8, I;16 for uint16
    buf = io.BytesIO()
    image.save(buf, format="PNG", compress_level=level, pnginfo=info)
    return buf.getvalue()
