"""Frame files: OpenEXR, PNG, FITS with a TAN WCS.

Adapter module: the one place that talks to OpenEXR, Pillow and
``astropy.io.fits`` for frames. The renderer returns frames in memory
(:class:`skynav.renderer.render.Frame`) and does no file I/O; :func:`write_frame` turns one into
files, for ``skynav render`` and for the dataset runner alike. Nothing here imports the
renderer. File contracts are those of docs/conventions.md "Files":

- **EXR**: float32 named channels (``electrons``, ``irradiance_w_m2``, ...), optional uint32
  ``source_id``. Compression is RLE (run-length on bytes, EXR 1.0): lossless for float32 and
  uint32, deterministic, and read by every EXR tool. Chosen by measurement on the default
  frame's two float32 maps (the fastest lossless compression that shrinks them; the figures are
  in docs/performance.md). The Python binding holds the GIL while it writes,
  so a writer thread would not overlap it with rendering. The RLE chunks of files whose channels
  are all 4-byte (float32, uint32) are written by :func:`_exr_rle_file`, which touches only the
  bytes near non-zero pixels (5 % larger files; OpenEXR reads the same
  bits back), inside OpenEXR's own header; ``_exr_bytes(..., sparse=False)`` is OpenEXR's encoder.
- **PNG**: greyscale, uint8 for bit depth <= 8, uint16 for 9-16 bit; DN of fewer bits than the
  sample (a 12-bit sensor, a 10-bit screen) are scaled to the full range with an ``sBIT`` chunk
  naming the significant bits (the PNG specification's way, section 12.4), so viewers show them;
  :func:`read_png` returns the DN, of these files and of the raw ones of skynav <= 0.3.0.
- **FITS**: primary HDU, the image as given (uint8/uint16/int/float, DN not rescaled), plus an
  optional TAN WCS of the *apparent* sky from :func:`tan_wcs_header` and, for frames, the
  standard keywords a FITS user expects (:func:`fits_frame_header`: ``DATE-OBS`` UTC, ``MJD-OBS``,
  ``EXPTIME``, ``BUNIT``, ``GAIN``, ``SATURATE``, the observer's state...).
- **JSON** ground truth: :mod:`skynav.datasets.truth_schema`.

Atomicity: each writer encodes to memory and hands the bytes to
:func:`~skynav.infra.atomic_files.atomic_write_bytes` (temp file in the same directory, ``fsync``,
``os.replace``, directory ``fsync``), so a reader sees either the old file or the complete new one,
never a partial file, and a failure leaves no temp file behind.

Determinism: identical inputs give identical bytes (same library versions): no writer embeds
a date, a host name or a random value. Tests pin this by SHA-256.

Readers accept a path or a binary file object, so a caller may read from memory as well as from disk.
"""

from __future__ import annotations

import io
import math
import os
import threading
import warnings
import zlib
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from PIL import Image
from zlib_ng import zlib_ng

from skynav.infra.atomic_files import atomic_write_bytes, open_binary
from skynav.infra.errors import ConfigValueError
from skynav.infra.threads import thread_budget
from skynav.scenes.camera import Camera
from skynav.scenes.timescales import time_from_tdb_seconds

from .errors import OutputFormatError, OutputPathError
from .frame_truth import epoch_tdb_seconds
from .truth_schema import truth_json_bytes

__all__ = [
    "FRAME_FORMATS",
    "check_output_dir",
    "check_stem",
    "OutputFormatError",
    "write_exr",
    "read_exr",
    "read_exr_header",
    "PNG_SCALING",
    "PNG_SCALING_KEY",
    "scale_dn_to_png",
    "unscale_png_to_dn",
    "write_png",
    "read_png",
    "read_png_layout",
    "tan_wcs_header",
    "fits_frame_header",
    "write_fits",
    "read_fits",
    "write_frame",
    "encode_frame",
    "write_files",
    "frame_file_bytes",
    "png_bytes",
    "exr_bytes",
]

#: File formats :func:`write_frame` knows, by file extension.
FRAME_FORMATS = ("png", "exr", "json", "fits")


_SYSTEM_DIRS = ("/proc", "/sys", "/dev")


def check_output_dir(directory, *, what: str = "output folder") -> Path:
    """Refuse an output folder that cannot hold files, with one line naming it.

    Checked before any work: the path (or one of its parents) is an existing file, lies in a
    kernel file system (``/proc``, ``/sys``, ``/dev``), or its nearest existing folder is not
    writable.

    Raises
    ------
    OutputPathError
    """
    d = Path(os.path.abspath(os.fspath(directory)))
    for sysdir in _SYSTEM_DIRS:
        if str(d) == sysdir or str(d).startswith(sysdir + "/"):
            raise OutputPathError(f"{directory}: {what} is in a kernel file system ({sysdir}); choose a folder on disk")
    probe = d
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if probe.exists() and not probe.is_dir():
        where = "is an existing file" if probe == d else f"lies under a file ({probe})"
        raise OutputPathError(f"{directory}: {what} {where}; give a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise OutputPathError(f"{directory}: {what} is not writable (no write permission on {probe})")
    return d


def check_stem(stem, *, what: str = "file name") -> str:
    """Refuse a file stem that is not a plain visible name (empty, ``..``, a path, hidden).

    Raises
    ------
    OutputPathError
    """
    if not isinstance(stem, str) or not stem.strip() or "/" in stem or os.sep in stem or stem.startswith(".") \
            or "\0" in stem:
        raise OutputPathError(f"{what} {stem!r}: expected a plain file name (not empty, no '/', "
                              f"not starting with '.')")
    return stem


# ----------------------------------------------------------------------------- OpenEXR
# Attributes OpenEXR manages itself; a caller's header must not override them.
_EXR_RESERVED = frozenset(
    {"channels", "compression", "dataWindow", "displayWindow", "lineOrder", "pixelAspectRatio",
     "screenWindowCenter", "screenWindowWidth", "type", "tiles", "name", "version", "chunkCount"}
)


def _exr_channel(name, array, shape):
    a = np.asarray(array)
    if a.ndim != 2:
        raise OutputFormatError(f"EXR channel {name!r} has shape {a.shape}; expected a 2-D (H, W) array")
    if shape is not None and a.shape != shape:
        raise OutputFormatError(f"EXR channel {name!r} has shape {a.shape}; other channels are {shape}")
    if a.dtype.kind == "f":
        return np.ascontiguousarray(a, dtype=np.float32)
    if a.dtype.kind in "iub":
        if a.size and (a.min() < 0 or a.max() > np.iinfo(np.uint32).max):
            raise OutputFormatError(f"EXR channel {name!r}: integer values must fit uint32 (0..4294967295)")
        return np.ascontiguousarray(a, dtype=np.uint32)
    raise OutputFormatError(f"EXR channel {name!r} has dtype {a.dtype}; expected float or unsigned integer")


_exr_threads_set = False


def _exr_threads(OpenEXR) -> None:
    """OpenEXR's global pool: ``SKYNAV_THREADS`` (default: the cores) when >= 2, else none (a
    single helper thread is slower than compressing in the caller)."""
    global _exr_threads_set
    if not _exr_threads_set:
        n = thread_budget() or (os.cpu_count() or 1)
        OpenEXR.set_global_thread_count(n if n >= 2 else 0)
        _exr_threads_set = True


def _exr_bytes(channels: Mapping, header: Mapping | None, *, sparse: bool = True) -> bytes:
    """The EXR file's bytes; ``sparse=False``: OpenEXR's own RLE encoder for the pixels (the
    reference of :func:`_exr_rle_file`)."""
    import OpenEXR  # adapter-local import: the library is heavy and only needed here

    _exr_threads(OpenEXR)

    if not channels:
        raise OutputFormatError("write_exr needs at least one channel")
    arrays, shape = {}, None
    for name, array in channels.items():
        if not isinstance(name, str) or not name:
            raise OutputFormatError(f"EXR channel name {name!r} must be a non-empty string")
        arrays[name] = _exr_channel(name, array, shape)
        shape = arrays[name].shape
    hdr = {"compression": OpenEXR.RLE_COMPRESSION, "type": OpenEXR.scanlineimage}
    for key, value in (header or {}).items():
        if key in _EXR_RESERVED:
            raise OutputFormatError(f"EXR header key {key!r} is managed by the writer; choose another name")
        if isinstance(value, (bool, np.bool_)):
            value = int(value)
        elif isinstance(value, (int, np.integer)):
            value = int(value)
        elif isinstance(value, (float, np.floating)):
            # OpenEXR's Python binding stores a float attribute as 32-bit; keep the double exactly.
            value = repr(float(value))
        elif not isinstance(value, str):
            raise OutputFormatError(f"EXR header {key!r}: value of type {type(value).__name__}; expected str, int or float")
        hdr[str(key)] = value
    if sparse and np.little_endian and all(a.size for a in arrays.values()):
        layout = _exr_layout(arrays, hdr, OpenEXR)
        if layout is not None:
            head, names = layout
            return _exr_rle_file(head, [arrays[n].view("<u4") for n in names])
    buf = io.BytesIO()
    OpenEXR.File(hdr, arrays).write(buf)
    return buf.getvalue()


# OpenEXR's RLE scanline chunk (one scanline per chunk), encoded sparsely. The frames are mostly
# exact zeros (the expected electrons and irradiance of a dark sky with stars), where OpenEXR's
# byte-by-byte encoder walks every byte; this one
# touches only the bytes near non-zero pixels. Same transform as OpenEXR (OpenEXRCore
# internal_rle.c): the scanline's bytes split into even- then odd-indexed bytes, a byte-wise
# delta predictor (d[0] = t[0], d[j] = t[j] - t[j-1] + 128 mod 256), then runs (count - 1 >= 0,
# byte) and literals (-count, bytes); a chunk that does not shrink is stored raw. The runs and
# literals may be cut at other places than OpenEXR's own encoder cuts them, so the file's bytes
# can differ from OpenEXR's while every decoded pixel is the same (tests/datasets/test_exr_rle.py
# reads the files back with OpenEXR). The header (and the file layout) is OpenEXR's own: it writes
# a zero image of the same shape, channels and attributes once per process, and its
# header is reused.
_EXR_LAYOUTS: dict = {}
_RLE_GAP = 3  # runs of this many 128s or more between non-128 bytes end a literal


def _exr_layout(arrays: dict, hdr: dict, OpenEXR):
    """``(header bytes, channel names in file order)`` of a RLE scanline file of these channels'
    shape and types with these attributes, written once by OpenEXR; None if the layout is not the
    plain one this encoder writes (single part, one scanline per chunk, 4-byte channels)."""
    shape = next(iter(arrays.values())).shape
    key = (shape, tuple((n, a.dtype.str) for n, a in arrays.items()), tuple(sorted((k, repr(v)) for k, v in hdr.items())))
    if key in _EXR_LAYOUTS:
        return _EXR_LAYOUTS[key]
    buf = io.BytesIO()
    OpenEXR.File(hdr, {n: np.zeros(shape, a.dtype) for n, a in arrays.items()}).write(buf)
    data = buf.getvalue()
    layout = None
    if data[:4] == b"\x76\x2f\x31\x01" and data[4] == 2 and not data[5] & 0x1e:  # v2, scanline, single part
        pos, names = 8, None
        while data[pos] != 0:
            name_end = data.index(b"\0", pos)
            type_end = data.index(b"\0", name_end + 1)
            size = int.from_bytes(data[type_end + 1:type_end + 5], "little")
            value = data[type_end + 5:type_end + 5 + size]
            if data[pos:name_end] == b"channels":
                names, p = [], 0
                while value[p] != 0:
                    end = value.index(b"\0", p)
                    names.append(value[p:end].decode())
                    p = end + 1 + 16
            pos = type_end + 5 + size
        head = pos + 1
        first = int.from_bytes(data[head:head + 8], "little")
        if (names is not None and sorted(names) == sorted(arrays) and first == head + 8 * shape[0]
                and int.from_bytes(data[first:first + 4], "little", signed=True) == 0):
            layout = (data[:head], names)
    if len(_EXR_LAYOUTS) > 16:
        _EXR_LAYOUTS.clear()
    _EXR_LAYOUTS[key] = layout
    return layout


#: Scanlines the encoder scans at a time: a block of two 1024-px float32 channels is 512 kB, so
#: the scan stays in the core's cache instead of streaming a full copy of the channels.
_RLE_BLOCK_ROWS = 64


_RLE_SCRATCH = threading.local()


def _rle_scratch(B: int, S: int):
    """The scan's (B, S) block buffers (words, non-zero, dirty), kept by each thread from one file
    to the next: fresh pages cost about as much as scanning them."""
    bufs = getattr(_RLE_SCRATCH, "bufs", None)
    if bufs is None or bufs[0].size < B * S:
        bufs = _RLE_SCRATCH.bufs = (np.empty(B * S, np.uint32), np.empty(B * S, bool), np.empty(B * S, bool))
    return [a[:B * S].reshape(B, S) for a in bufs]


def _rle_pieces(starts, length, size: int, step: int):
    """Each owner's literal or run of ``length`` bytes cut into pieces of ``size`` bytes but the
    last, piece m's header at ``start + step * m`` for each array ``start`` of ``starts``: ``(length
    of each owner's last piece, [(header positions of all pieces, those of each owner's last
    piece) for each start])``. The common case, at most one piece per owner, is the same formula
    with m = 0."""
    count = -(-length // size)
    has = count > 0
    count = count[has]
    at = []
    several = count.max(initial=0) > 1
    if several:  # the positions as the running sum of the steps between them
        first = np.cumsum(count) - count
        steps = np.full(int(first[-1] + count[-1]), step, np.int64)
    for start in starts:
        start = start[has]
        last = start + step * (count - 1)
        if several:
            steps[first[1:]] = start[1:] - last[:-1]
            steps[0] = start[0]
            at.append((np.cumsum(steps), last))
        else:
            at.append((last, last))
    return length[has] - size * (count - 1), at


def _exr_rle_file(head: bytes, channels: list) -> bytes:
    """The RLE scanline file of ``channels`` (each (H, w_c) 4-byte words, little-endian, in file
    order: a scanline is each channel's row in turn), after the header ``head`` (see above)."""
    H = channels[0].shape[0]
    n_words = sum(c.shape[1] for c in channels)
    N = 2 * n_words  # bytes in each half of a scanline: its even-indexed bytes, then its odd ones
    # the scanlines' dirty words, a block of scanlines at a time, each row after 2 zero words (so
    # that rows are 3 or more words apart; p: the word's index in these padded rows): d[j] (either
    # half) differs from 128 only where t[j] or t[j-1] is not 0: words 2p, 2p + 1 of a non-zero
    # 4-byte word p, and the word after it; and where a half begins
    S = n_words + 2
    B = min(_RLE_BLOCK_ROWS, H)
    buf, nz, dirty = _rle_scratch(B, S)
    buf[:, :2] = 0
    ps, curs = [], []
    for y0 in range(0, H, B):
        b = min(B, H - y0)
        block, nzb, db = buf[:b], nz[:b], dirty[:b]
        x = 2
        for c in channels:
            block[:, x:x + c.shape[1]] = c[y0:y0 + b]
            x += c.shape[1]
        np.not_equal(block, 0, out=nzb)
        flat = nzb.reshape(-1)
        np.logical_or(flat[1:], flat[:-1], out=db.reshape(-1)[1:])
        db[:, :2] = False
        db[:, 2] = True
        q = np.flatnonzero(db)
        curs.append(block.reshape(-1)[q])
        q += y0 * S
        ps.append(q)
    # (p in 4 bytes where it fits, as it nearly always does: half the memory to fill)
    p = np.concatenate(ps, dtype=np.int32 if 2 * H * S < 2**31 else np.int64, casting="same_kind")
    cur = np.concatenate(curs)
    # islands of dirty words, cut where 3 or more 128s lie between (2 clean 4-byte words)
    dp = np.diff(p)
    s = np.flatnonzero(dp > 1 + _RLE_GAP // 2) + 1
    lens = np.diff(s, prepend=0, append=p.size)  # words in each island
    s = np.concatenate(([0], s))
    p_s, p_e = p[s].astype(np.int64), p[s + lens - 1].astype(np.int64)
    row = p_s // S
    k_s, k_e = p_s - row * S - 2, p_e - row * S - 2  # first and last word in the row
    first = k_s == 0  # each row's first island: the one at its word 0
    # d of the word's 2-byte words 2p, 2p + 1, bytewise (t - t_before + 128) mod 256 on 4 bytes at
    # once: bytes [d_low(2p), d_high(2p), d_low(2p + 1), d_high(2p + 1)], each half's t being the
    # low, resp. high bytes of the 2-byte words and t_before those of the word before each (0 if
    # that word is clean; before word 0: t[-1] = 128 and t[N - 1] of the row). Per byte,
    # (t | 128) - (t_before & 127) is t - t_before + 128 mod 256 but for the top bit.
    y = np.empty_like(cur)
    y[0] = 0
    np.multiply(cur[:-1], dp == 1, out=y[1:])
    del dp
    y >>= 16
    y[s[first]] = 128 | (channels[-1][:, -1] >> 16 & 0xFF) << 8
    y |= cur << 16  # the 2-byte words 2p - 1, 2p: those before 2p, 2p + 1
    low7 = np.bitwise_and(y, 0x7F7F7F7F)
    y ^= cur
    y &= 0x80808080
    cur |= 0x80808080
    cur -= low7
    cur ^= y
    dv = cur.view(np.uint8).reshape(-1, 2, 2)  # d: [word][2p, 2p + 1][low, high half]
    n = 2 * (k_e - k_s + 1)  # the island's bytes in each half
    k_next = np.append(k_s[1:], 0)
    gap = 2 * (np.where(k_next == 0, n_words, k_next) - k_e - 1)  # the 128s after it in the half
    lit_pieces = -(-n // 127)
    unit = n + lit_pieces + 2 * (-(-gap // 128))
    unit_at = np.cumsum(unit) - unit
    row_at = unit_at[first]
    half = np.diff(row_at, append=unit_at[-1] + unit[-1])
    raw = half >= N  # a row that does not shrink is stored raw
    size = np.where(raw, 2 * N, 2 * half)
    prefix = len(head) + 8 * H
    region = prefix + np.cumsum(size + 8) - (size + 8)
    end = prefix + int(size.sum()) + 8 * H
    # each island's unit in the low half and in the high one; those of a raw row are encoded into
    # scratch space after the file's end, thrown away
    o = np.where(raw, end, region + 8)[row] + unit_at - row_at[row]
    o = (o, o + half[row])
    out = np.full(end + int(2 * half[raw].max(initial=0)), 128, np.uint8)
    # literal headers (-count), each island's literal cut in pieces of up to 127 bytes
    count, at = _rle_pieces(o, n, 127, 128)
    for every, last in at:
        if every is not last:
            out[every] = 256 - 127
        out[last] = 256 - count
    # runs of 128 (count - 1, 128) after each island, up to 128 bytes each
    count, at = _rle_pieces([o_half + lit_pieces + n for o_half in o], gap, 128, 2)
    for every, last in at:
        out[every] = 128 - 1
        out[last] = count - 1
    # literal bytes: the island's bytes b = 2k - 2k_s and b + 1, after their piece's header
    b = np.left_shift(p, 1, out=p)  # (p is not needed any more)
    lo, hi = (np.repeat(o_half + 1 - 2 * p_s, lens) for o_half in o)
    lo += b
    hi += b
    if n.max() <= 127:
        out[lo], out[hi] = dv[:, 0, 0], dv[:, 0, 1]
        lo += 1
        hi += 1
    else:
        b -= np.repeat(2 * p_s, lens)
        out[lo + b // 127], out[hi + b // 127] = dv[:, 0, 0], dv[:, 0, 1]
        b = 1 + (b + 1) // 127
        lo += b
        hi += b
    out[lo], out[hi] = dv[:, 1, 0], dv[:, 1, 1]
    for r in np.flatnonzero(raw):
        out[region[r] + 8:region[r] + 8 + 2 * N] = np.concatenate([c[r] for c in channels]).view(np.uint8)
    hdr = np.empty((H, 2), "<i4")
    hdr[:, 0], hdr[:, 1] = np.arange(H), size
    out[region[:, None] + np.arange(8)] = hdr.view(np.uint8).reshape(H, 8)
    out[:len(head)] = np.frombuffer(head, np.uint8)
    out[len(head):prefix] = region.astype("<u8").view(np.uint8)
    return out[:end].tobytes()


def exr_bytes(channels: Mapping, *, header: Mapping | None = None) -> bytes:
    """Named image channels as the bytes of an OpenEXR file (what :func:`write_exr` writes)."""
    return _exr_bytes(channels, header)


def write_exr(path, channels: Mapping, *, header: Mapping | None = None) -> None:
    """Write named image channels to an OpenEXR file (RLE compression), atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Destination ``.exr``.
    channels : mapping of str to ndarray, shape (H, W)
        E.g. ``{"electrons": e, "irradiance_w_m2": irr, "source_id": ids}``. Floating arrays are
        written as float32 (float64 is rounded to float32); integer arrays as uint32 (values
        must be in 0..2**32-1). All channels share one shape.
    header : mapping of str to (str, int, float), optional
        Extra header attributes. Floats are stored as their ``repr`` string (OpenEXR's Python
        binding would round them to float32), so they come back from
        :func:`read_exr_header` as ``str``. Structural keys (``compression``, ``channels``...)
        are refused.

    Raises
    ------
    OutputFormatError
        Empty channel set, wrong shapes or dtypes, or a reserved header key.
    """
    atomic_write_bytes(path, _exr_bytes(channels, header))


def read_exr(source) -> dict:
    """Channels of an OpenEXR file, ``{name: ndarray (H, W)}`` (float32 or uint32)."""
    # OpenEXR only for EXR files: the reader imports this module for PNGs
    import OpenEXR

    with open_binary(source) as f:
        exr = OpenEXR.File(f, separate_channels=True)
        return {name: np.array(ch.pixels) for name, ch in exr.channels().items()}


def read_exr_header(source) -> dict:
    """Header attributes of an OpenEXR file (including OpenEXR's own structural ones)."""
    # OpenEXR only for EXR files: the reader imports this module for PNGs
    import OpenEXR

    with open_binary(source) as f:
        return dict(OpenEXR.File(f, header_only=True).header())


# ----------------------------------------------------------------------------- PNG
#: How DN of fewer bits than the PNG sample (e.g. 10 or 12 bit in a 16-bit PNG) are stored: scaled
#: to the PNG's full range with the PNG specification's recommended linear scaling (PNG 2nd ed.,
#: section 12.4 "Sample depth scaling"), ``stored = floor(dn * MAX / m + 1/2)`` with
#: ``m = 2**bits - 1`` and ``MAX`` = 255 or 65535, and an ``sBIT`` chunk naming the significant
#: bits. Recorded in each file by a ``tEXt`` chunk :data:`PNG_SCALING_KEY` = ``"sbit"`` and in the
#: JSON beside the files (``png_scaling``, ``significant_bits``).
PNG_SCALING = "sbit"
#: ``tEXt`` keyword of the marker (skynav's files of 0.3.0 and before have none: their DN are raw).
PNG_SCALING_KEY = "skynav.png_scaling"


def _png_container_bits(bit_depth: int) -> int:
    return 8 if bit_depth <= 8 else 16


def scale_dn_to_png(dn, bit_depth: int) -> np.ndarray:
    """DN of ``bit_depth`` bits scaled to the full range of their PNG sample (8 or 16 bit).

    ``stored = floor(dn * MAX / m + 1/2)`` (PNG specification, section 12.4, the recommended
    linear scaling), ``m = 2**bit_depth - 1``, ``MAX = 2**8 - 1`` or ``2**16 - 1``; exact integer
    arithmetic. 8- and 16-bit DN are returned unchanged. :func:`unscale_png_to_dn` inverts it
    exactly, and so does the right shift by ``container - bit_depth`` that the specification
    names for decoders (``tests/datasets/test_png_scaling.py`` checks both for every value).

    Examples
    --------
    >>> scale_dn_to_png(np.array([0, 1, 512, 1023], np.uint16), 10).tolist()
    [0, 64, 32800, 65535]
    """
    a = np.asarray(dn)
    c = _png_container_bits(bit_depth)
    if bit_depth == c:
        return a
    m, top = (1 << bit_depth) - 1, (1 << c) - 1
    return ((2 * a.astype(np.int64) * top + m) // (2 * m)).astype(a.dtype)


def unscale_png_to_dn(stored, bit_depth: int) -> np.ndarray:
    """Inverse of :func:`scale_dn_to_png`: ``dn = floor(stored * m / MAX + 1/2)``.

    Exact for every value :func:`scale_dn_to_png` writes (the rounding error of the scaling,
    at most 1/2 of a stored step, is less than 1/2 DN after division by ``MAX / m`` > 1); it
    also recovers DN scaled by left-bit replication (another spec-conforming encoder's choice).

    Examples
    --------
    >>> unscale_png_to_dn(np.array([0, 64, 32800, 65535], np.uint16), 10).tolist()
    [0, 1, 512, 1023]
    """
    a = np.asarray(stored)
    c = _png_container_bits(bit_depth)
    if bit_depth == c:
        return a
    m, top = (1 << bit_depth) - 1, (1 << c) - 1
    return ((2 * a.astype(np.int64) * m + top) // (2 * top)).astype(a.dtype)


def write_png(path, dn, *, bit_depth: int | None = None, compress_level: int = 6) -> None:
    """Write digital counts as a greyscale PNG, atomically: the bytes of :func:`png_bytes`."""
    atomic_write_bytes(path, png_bytes(dn, bit_depth=bit_depth, compress_level=compress_level))


def png_bytes(dn, *, bit_depth: int | None = None, compress_level: int = 6) -> bytes:
    """Digital counts as the bytes of a greyscale PNG file (what :func:`write_png` writes).

    Parameters
    ----------
    dn : ndarray, shape (H, W), uint8 or uint16
        Digital counts, DN. uint8 gives an 8-bit PNG, uint16 a 16-bit PNG.
    bit_depth : int, optional
        Significant bits of the DN, 1..16 (a 12-bit sensor, a 10-bit screen). When given, the
        dtype must match (uint8 for <= 8, uint16 for 9..16), every value must be
        <= ``2**bit_depth - 1``, the DN are scaled to the PNG's full range
        (:func:`scale_dn_to_png`: a 12-bit 4095 is stored as 65535, so every viewer shows the
        image), and the file carries an ``sBIT`` chunk with ``bit_depth`` and a ``tEXt``
        :data:`PNG_SCALING_KEY` = ``"sbit"``. Without it the values are stored as they are.
        :func:`read_png` gives the DN back either way.
    compress_level : int
        zlib level, 0..9 (the pixels are the same at every level). The rows are unfiltered and
        compressed with zlib's run-length strategy (:func:`_png_bytes`), for which the level
        changes little.

    Raises
    ------
    OutputFormatError
        Wrong shape or dtype, or a value above the bit depth.
    """
    return _png_file_bytes(dn, bit_depth, compress_level)


def _png_file_bytes(dn, bit_depth, compress_level) -> bytes:
    """The checked bytes of :func:`write_png`."""
    a = np.asarray(dn)
    if a.ndim != 2:
        raise OutputFormatError(f"PNG image has shape {a.shape}; expected a 2-D (H, W) array of DN")
    if a.dtype not in (np.uint8, np.uint16):
        raise OutputFormatError(f"PNG image has dtype {a.dtype}; expected uint8 (bit depth <= 8) or uint16 (9-16)")
    sbit = None
    if bit_depth is not None:
        if not (isinstance(bit_depth, (int, np.integer)) and 1 <= bit_depth <= 16):
            raise OutputFormatError(f"PNG bit_depth = {bit_depth!r}; expected an integer in 1..16")
        want = np.uint8 if bit_depth <= 8 else np.uint16
        if a.dtype != want:
            raise OutputFormatError(f"PNG of bit depth {bit_depth} needs {np.dtype(want).name} DN, got {a.dtype}")
        if a.size and int(a.max()) > (1 << bit_depth) - 1:
            raise OutputFormatError(f"PNG DN max {int(a.max())} exceeds {(1 << bit_depth) - 1} for bit depth {bit_depth}")
        a = scale_dn_to_png(a, int(bit_depth))
        sbit = int(bit_depth)
    if not (isinstance(compress_level, (int, np.integer)) and 0 <= compress_level <= 9):
        raise OutputFormatError(f"PNG compress_level = {compress_level!r}; expected an integer in 0..9 (zlib's levels)")
    return _png_bytes(a, sbit, int(compress_level))


def _png_chunk(kind: bytes, payload: bytes) -> bytes:
    return len(payload).to_bytes(4, "big") + kind + payload + zlib.crc32(payload, zlib.crc32(kind)).to_bytes(4, "big")


def _png_bytes(a: np.ndarray, sbit: int | None, level: int) -> bytes:
    """A greyscale PNG (PNG 2nd ed., ISO/IEC 15948): IHDR, ``sBIT`` and the ``tEXt`` marker when
    ``sbit`` is given, one IDAT, IEND. Filter type 0 (None) on every row (the frames are a dark,
    noisy, flat background with a few stars: a predictor finds nothing the entropy coder does
    not), deflated with zlib's run-length strategy ``Z_RLE`` (runs only, no string matching); no
    time stamp. The deflate is zlib-ng's (``zlib-ng``, the zlib of its SIMD compare and checksum):
    its ``Z_RLE`` stream is the bytes of the standard library's zlib for the same rows and level
    (a run-length coder hashes nothing; tests/datasets/test_png_zlib_ng.py compares the two),
    faster (docs/performance.md). ISA-L was tried and left: its bytes for the same rows were not
    always the same from one process to the next (the DN were), so a dataset's files were not
    reproducible (CHANGELOG.md)."""
    h, w = a.shape
    if a.dtype == np.uint16:
        a = a.astype(">u2", copy=False)  # PNG samples are big-endian
    rows = np.zeros((h, 1 + w * a.dtype.itemsize), np.uint8)  # column 0: filter type 0 per row
    rows[:, 1:] = np.ascontiguousarray(a).view(np.uint8).reshape(h, -1)
    z = zlib_ng.compressobj(level, zlib_ng.DEFLATED, 15, 9, zlib_ng.Z_RLE)
    idat = z.compress(rows) + z.flush()
    ihdr = w.to_bytes(4, "big") + h.to_bytes(4, "big") + bytes([8 * a.dtype.itemsize, 0, 0, 0, 0])
    out = [b"\x89PNG\r\n\x1a\n", _png_chunk(b"IHDR", ihdr)]
    if sbit is not None:
        out += [_png_chunk(b"sBIT", bytes([sbit])),  # greyscale sBIT: one byte, significant bits
                _png_chunk(b"tEXt", PNG_SCALING_KEY.encode("latin-1") + b"\0" + PNG_SCALING.encode("latin-1"))]
    out += [_png_chunk(b"IDAT", idat), _png_chunk(b"IEND", b"")]
    return b"".join(out)


def _png_header_chunks(data: bytes) -> dict:
    """``{chunk type: [payload, ...]}`` of the chunks before the first IDAT."""
    out, i = {}, 8
    while i + 8 <= len(data):
        n = int.from_bytes(data[i:i + 4], "big")
        kind = data[i + 4:i + 8]
        if kind == b"IDAT":
            break
        out.setdefault(kind, []).append(data[i + 8:i + 8 + n])
        i += 12 + n
    return out


def _png_layout(data: bytes, stored_max) -> dict:
    chunks = _png_header_chunks(data)
    ihdr = chunks.get(b"IHDR", [b""])[0]
    container = ihdr[8] if len(ihdr) > 8 else None
    sbit = chunks.get(b"sBIT", [b""])[0]
    bits = sbit[0] if len(sbit) == 1 else None  # greyscale sBIT is one byte
    marker = None
    for t in chunks.get(b"tEXt", []):
        key, _, value = t.partition(b"\0")
        if key == PNG_SCALING_KEY.encode():
            marker = value.decode("latin-1")
    if marker == PNG_SCALING or (marker is None and bits and container and bits < container and stored_max is not None
                                 and stored_max > (1 << bits) - 1):
        # skynav's marker, or a foreign file whose values exceed its sBIT range: by the PNG
        # specification such a file is scaled (a file written raw could not hold them)
        if not bits or not container or bits > container:
            raise OutputFormatError(f"PNG says {PNG_SCALING_KEY} = {marker!r} but has no valid sBIT chunk")
        return {"png_scaling": PNG_SCALING, "significant_bits": int(bits)}
    # no marker: skynav <= 0.3.0 (raw DN, sBIT naming the camera's bits) or a plain PNG
    return {"png_scaling": "raw", "significant_bits": int(bits) if bits else container}


def read_png_layout(source) -> dict:
    """How a PNG stores its DN: ``{"png_scaling": "sbit" | "raw", "significant_bits": int}``.

    ``"sbit"``: scaled to the full range (:func:`scale_dn_to_png`), written by skynav after 0.3.0
    (``tEXt`` :data:`PNG_SCALING_KEY`), or a foreign file with an ``sBIT`` chunk whose values
    exceed ``2**sBIT - 1``. ``"raw"``: the values are the DN (files of skynav <= 0.3.0, whose
    ``sBIT`` named the bit depth of unscaled DN, and PNGs without ``sBIT``).
    """
    with open_binary(source) as f:
        data = f.read()
    with Image.open(io.BytesIO(data)) as image:
        stored_max = int(np.asarray(image).max()) if image.width and image.height else 0
    return _png_layout(data, stored_max)


def read_png(source) -> np.ndarray:
    """DN of a greyscale PNG, shape (H, W): uint8 for 8-bit files, uint16 for 16-bit ones.

    Scaled files (:func:`read_png_layout` ``"sbit"``) are unscaled (:func:`unscale_png_to_dn`);
    raw ones (skynav <= 0.3.0, plain PNGs) are returned as stored. Either way the DN are those
    that were written.
    """
    with open_binary(source) as f:
        data = f.read()
    with Image.open(io.BytesIO(data)) as image:
        if image.mode not in ("L", "I;16", "I;16B", "I"):
            raise OutputFormatError(f"PNG mode {image.mode!r}; expected greyscale (L or I;16)")
        a = np.array(image)
    if a.dtype.kind in "iu" and a.dtype.itemsize > 2:  # mode "I": 16-bit data in int32
        a = a.astype(np.uint16)
    layout = _png_layout(data, int(a.max()) if a.size else 0)
    if layout["png_scaling"] == PNG_SCALING:
        a = unscale_png_to_dn(a, layout["significant_bits"])
    return a


# ----------------------------------------------------------------------------- FITS + WCS
def tan_wcs_header(camera_K, width: int, height: int, R_cam_icrs) -> dict:
    """FITS TAN (gnomonic) WCS of the apparent sky for an undistorted pinhole camera.

    With the camera at ``R_cam_icrs`` (passive, ``v_cam = R_cam_icrs @ u_icrs``) a direction ``u``
    lands at ``[x, y, 1] ~ K v_cam`` (docs/conventions.md pixels, top-left pixel centre at (0, 0)).
    Writing the tangent-plane (standard) coordinates at the boresight as
    ``xi = u.e / u.b``, ``eta = u.n / u.b`` (``b`` boresight, ``e`` east, ``n`` north unit
    vectors), the rows ``r0, r1`` of ``R_cam_icrs`` lie in that plane, so
    ``[x - cx, y - cy] = K2 M [xi, eta]`` with ``K2 = K[:2, :2]`` and
    ``M = [[r0.e, r0.n], [r1.e, r1.n]]``. FITS TAN (Calabretta & Greisen 2002, LONPOLE = 180)
    defines intermediate world coordinates ``(xi, eta)`` in degrees = ``CD @ (p - CRPIX)``, hence
    ``CD = deg(inv(K2 M))`` and ``CRPIX = (cx + 1, cy + 1)`` (FITS pixels are 1-based; image row 0
    is FITS row 1, no flip).

    Lens distortion is not represented; the WCS describes the *apparent* directions (after
    light-time and aberration) the renderer projects, so it matches the rendered stars.

    Parameters
    ----------
    camera_K : array_like, shape (3, 3)
        Intrinsic matrix ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``, px.
    width, height : int
        Image size, px (``NAXIS1``, ``NAXIS2``).
    R_cam_icrs : array_like, shape (3, 3)
        Attitude, passive, ICRS to camera.

    Returns
    -------
    dict
        FITS keywords (``WCSAXES``, ``CTYPE1/2``, ``CUNIT1/2``, ``CRPIX1/2``, ``CRVAL1/2`` (deg),
        ``CD1_1`` ... ``CD2_2`` (deg/px), ``LONPOLE``, ``RADESYS`` = ``ICRS``, ``NAXIS1/2``).

    References
    ----------
    Calabretta & Greisen (2002), A&A 395, 1077: eqs. 54-55 (TAN), section 2.3 (LONPOLE).
    """
    K = np.asarray(camera_K, dtype=float)
    R = np.asarray(R_cam_icrs, dtype=float)
    if K.shape != (3, 3) or R.shape != (3, 3):
        raise OutputFormatError(f"tan_wcs_header needs K and R_cam_icrs of shape (3, 3); got {K.shape}, {R.shape}")
    b = R[2] / np.linalg.norm(R[2])
    ra0 = math.atan2(b[1], b[0]) % (2.0 * math.pi)
    dec0 = math.atan2(b[2], math.hypot(b[0], b[1]))
    east = np.array([-math.sin(ra0), math.cos(ra0), 0.0])
    north = np.array([-math.sin(dec0) * math.cos(ra0), -math.sin(dec0) * math.sin(ra0), math.cos(dec0)])
    M = np.array([[R[0] @ east, R[0] @ north], [R[1] @ east, R[1] @ north]])
    CD = np.degrees(np.linalg.inv(K[:2, :2] @ M))
    return {
        "WCSAXES": 2,
        "NAXIS1": int(width),
        "NAXIS2": int(height),
        "CTYPE1": "RA---TAN",
        "CTYPE2": "DEC--TAN",
        "CUNIT1": "deg",
        "CUNIT2": "deg",
        "CRPIX1": float(K[0, 2]) + 1.0,
        "CRPIX2": float(K[1, 2]) + 1.0,
        "CRVAL1": math.degrees(ra0),
        "CRVAL2": math.degrees(dec0),
        "CD1_1": float(CD[0, 0]),
        "CD1_2": float(CD[0, 1]),
        "CD2_1": float(CD[1, 0]),
        "CD2_2": float(CD[1, 1]),
        "LONPOLE": 180.0,
        "RADESYS": "ICRS",
    }


#: Instrument and telescope names of skynav's frames (FITS ``INSTRUME`` / ``TELESCOP``).
FITS_INSTRUME = "skynav simulated camera"
FITS_TELESCOP = "skynav simulated spacecraft"


def fits_frame_header(truth: Mapping) -> dict:
    """The standard FITS keywords of a frame, from its ground truth: ``{key: (value, comment)}``.

    Time (FITS 4.0 standard, section 9; Rots et al. 2015, A&A 574, A36): the truth's epoch is
    mid-exposure, TDB; the header gives UTC (``TIMESYS = 'UTC'``), ``DATE-OBS`` and ``MJD-OBS``
    at the *start* of the exposure (the standard's meaning), ``DATE-AVG``/``MJD-AVG`` at
    mid-exposure (the epoch of the WCS and of the truth) and ``DATE-END``/``MJD-END``; ISO 8601 with
    microseconds. TDB to UTC by astropy/ERFA with its installed leap-second table; an epoch
    after the table (the future) assumes no further leap second.
    ``EXPTIME`` (s); ``BUNIT = 'adu'`` (the DN); ``INSTRUME``, ``TELESCOP``, ``ORIGIN``;
    ``GAIN`` (e-/DN, the inverse of the sensor's ``gain_dn_per_e``), ``RDNOISE`` (e-),
    ``SATURATE`` (DN: the full-well charge read out, ``floor(K full_well + offset + 1/2)``,
    at most ``2**bit_depth - 1``).

    The observer (a spacecraft: ``OBSGEO-*`` are for Earth-fixed observatories) in short keys
    of this project: ``OBSFRAME = 'ICRS'`` (axes ICRS, origin the solar-system barycentre, as
    the truth's ``observer``), ``OBSPOS-X/Y/Z`` (km) and ``OBSVEL-X/Y/Z`` (km/s).

    Parameters
    ----------
    truth : mapping
        A ``skynav.frame/2`` dict (``epoch``, ``observer``, ``camera`` with its ``sensor``).
    """
    # astropy (~0.2-0.7 s to import) only for FITS files: the reader imports this module for PNGs
    from astropy.time import TimeDelta

    cam = Camera.from_dict(dict(truth["camera"]))
    sp = cam.sensor
    mid = time_from_tdb_seconds(epoch_tdb_seconds(truth["epoch"]))
    half = TimeDelta(cam.exposure_s / 2.0, format="sec")
    with warnings.catch_warnings():
        # UTC after the installed leap-second table (ERFA: "dubious year") assumes no further
        # leap second: TAI - UTC stays at its last value (37 s since 2017)
        warnings.filterwarnings("ignore", message=".*dubious year.*")
        utc = [t.utc for t in (mid - half, mid, mid + half)]
        for t in utc:
            t.precision = 6
        (start_iso, mid_iso, end_iso), (start_mjd, mid_mjd, end_mjd) = [t.isot for t in utc], [float(t.mjd) for t in utc]

    pos = [float(v) for v in np.asarray(truth["observer"]["position_km"], dtype=float)]
    vel = [float(v) for v in np.asarray(truth["observer"]["velocity_km_s"], dtype=float)]
    saturate = min(sp.max_dn, math.floor(sp.gain_dn_per_e * sp.full_well_e + sp.offset_dn + 0.5))
    h = {
        "TIMESYS": ("UTC", "time scale of DATE-*, MJD-*"),
        "DATE-OBS": (start_iso, "start of exposure"),
        "MJD-OBS": (start_mjd, "[d] start of exposure, UTC"),
        "DATE-AVG": (mid_iso, "mid-exposure: truth, WCS"),
        "MJD-AVG": (mid_mjd, "[d] mid-exposure, UTC"),
        "DATE-END": (end_iso, "end of exposure"),
        "MJD-END": (end_mjd, "[d] end of exposure, UTC"),
        "EXPTIME": (float(cam.exposure_s), "[s] exposure time"),
        "BUNIT": ("adu", "digital counts (DN) of the camera"),
        "INSTRUME": (FITS_INSTRUME, "rendered, not observed"),
        "TELESCOP": (FITS_TELESCOP, "rendered, not observed"),
        "ORIGIN": ("skynav", "software that wrote this file"),
        "GAIN": (1.0 / float(sp.gain_dn_per_e), "[e-/DN] system gain"),
        "RDNOISE": (float(sp.read_noise_e), "[e-] read noise"),
        "SATURATE": (int(saturate), "[DN] saturation level"),
        "BITDEPTH": (int(sp.bit_depth), "sensor bit depth"),
        "OBSFRAME": ("ICRS", "OBSPOS/OBSVEL: ICRS, barycentric"),
    }
    for axis, p in zip("XYZ", pos):
        h[f"OBSPOS-{axis}"] = (p, f"[km] observer position {axis}")
    for axis, v in zip("XYZ", vel):
        h[f"OBSVEL-{axis}"] = (v, f"[km/s] observer velocity {axis}")
    return h


# Keywords astropy derives from the data array; a caller's header must not contradict them.
_FITS_STRUCTURAL = frozenset({"SIMPLE", "BITPIX", "NAXIS", "NAXIS1", "NAXIS2", "EXTEND", "BZERO", "BSCALE"})


def write_fits(path, image, *, wcs_header: Mapping | None = None, header: Mapping | None = None) -> None:
    """Write an image (DN or float) to a single-HDU FITS file with an optional WCS, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Destination ``.fits``.
    image : ndarray, shape (H, W)
        uint8, uint16 (stored as int16 with ``BZERO = 32768``, read back as uint16 by astropy),
        int16/int32, float32 or float64. Row 0 of the array is FITS row 1 (no flip), so pixel
        ``(x, y)`` of docs/conventions.md is FITS ``(x + 1, y + 1)``.
    wcs_header : mapping, optional
        Output of :func:`tan_wcs_header`; ``NAXIS1/2`` in it must match the image.
    header : mapping, optional
        Extra keywords (<= 8 characters), e.g. ``{"EXPTIME": 0.4}`` or ``{"EXPTIME": (0.4,
        "[s] exposure time")}`` (value, comment); :func:`fits_frame_header` gives a frame's.

    Raises
    ------
    OutputFormatError
        Wrong shape or dtype, or a WCS made for another image size.
    """
    atomic_write_bytes(path, _fits_bytes(image, wcs_header, header))


def _fits_bytes(image, wcs_header, header) -> bytes:
    """The checked bytes of :func:`write_fits`."""
    # astropy (~0.2-0.7 s to import) only for FITS files: the reader imports this module for PNGs
    from astropy.io import fits

    a = np.asarray(image)
    if a.ndim != 2:
        raise OutputFormatError(f"FITS image has shape {a.shape}; expected a 2-D (H, W) array")
    if a.dtype.kind not in "uif" or a.dtype.itemsize > 8 or a.dtype == np.uint64:
        raise OutputFormatError(f"FITS image has dtype {a.dtype}; expected uint8/uint16/int16/int32/float32/float64")
    hdu = fits.PrimaryHDU(np.ascontiguousarray(a))
    for source in (wcs_header or {}), (header or {}):
        for key, value in source.items():
            key = str(key).upper()
            if key in ("NAXIS1", "NAXIS2"):
                n = a.shape[1] if key == "NAXIS1" else a.shape[0]
                if int(value) != n:
                    raise OutputFormatError(f"FITS {key} = {value} in the header but the image has {n}; was the WCS made for another camera?")
                continue
            if key in _FITS_STRUCTURAL:
                raise OutputFormatError(f"FITS keyword {key} is set from the data; remove it from the header")
            if isinstance(value, np.generic):
                value = value.item()
            hdu.header[key] = value
    buf = io.BytesIO()
    fits.HDUList([hdu]).writeto(buf)
    return buf.getvalue()


def read_fits(source):
    """(image ndarray (H, W), header as ``astropy.io.fits.Header``) of the primary HDU."""
    # astropy (~0.2-0.7 s to import) only for FITS files: the reader imports this module for PNGs
    from astropy.io import fits

    with open_binary(source) as f, fits.open(f, memmap=False) as hdul:
        return np.array(hdul[0].data), hdul[0].header.copy()


# ----------------------------------------------------------------------------- one frame
def write_frame(frame, directory, stem: str, *, formats=("png", "exr", "json"), fits: bool = False) -> dict:
    """Write one in-memory frame's files atomically: ``<directory>/<stem>.<format>``.

    Parameters
    ----------
    frame : skynav.renderer.render.Frame
        Or any object with ``dn`` (H, W) uint8/uint16 DN, ``electrons`` and
        ``irradiance_w_m2`` (H, W) float32 (e-, W/m^2) and ``truth`` (the ``skynav.frame/2``
        dict).
    directory : str or os.PathLike
        Created if missing.
    stem : str
        File name without extension (``"frame"``, ``"000042"``).
    formats : sequence of str
        Any of ``png`` (DN, with the camera's bit depth in ``sBIT``), ``exr`` (``electrons``,
        ``irradiance_w_m2``), ``json`` (ground truth, canonical bytes) and ``fits`` (DN with
        the TAN WCS of the truth's ``camera.K`` and ``attitude.R_cam_icrs``).
    fits : bool
        Also write FITS when ``formats`` does not name it.

    Returns
    -------
    dict of str to pathlib.Path
        ``{format: path}`` in the order written.

    Raises
    ------
    ConfigValueError
        An unknown format.
    OutputFormatError, TruthSchemaError
        Data the format cannot hold.

    Examples
    --------
    Any object with the four fields will do (here a 12-bit image; the PNG's bit depth comes
    from the truth's camera):

    >>> import tempfile
    >>> from types import SimpleNamespace
    >>> from skynav.datasets import write_frame
    >>> from skynav.datasets.frame_files import read_png
    >>> frame = SimpleNamespace(dn=np.array([[0, 4095]], dtype=np.uint16),
    ...                         electrons=np.zeros((1, 2), np.float32),
    ...                         irradiance_w_m2=np.zeros((1, 2), np.float32),
    ...                         truth={"camera": {"bit_depth": 12}})
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     paths = write_frame(frame, tmp, "frame", formats=("png", "exr"))
    ...     print(sorted(paths), read_png(paths["png"]).tolist())
    ['exr', 'png'] [[0, 4095]]
    """
    check_stem(stem)
    directory = Path(directory)
    if not directory.is_dir():  # an existing folder (a dataset's frames/) needs no more checks per frame
        check_output_dir(directory)
        try:
            directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputPathError(f"{directory}: cannot create the output folder "
                                  f"({exc.strerror or exc.__class__.__name__})") from None
    # encode everything first: an unknown format or bad data writes nothing
    blobs = {fmt: (directory / f"{stem}.{fmt}", data) for fmt, data in encode_frame(frame, formats, fits=fits).items()}
    write_files(blobs.values())
    return {fmt: path for fmt, (path, _) in blobs.items()}


def encode_frame(frame, formats=("png", "exr", "json"), *, fits: bool = False) -> dict:
    """``{format: bytes}``: the files :func:`write_frame` writes for a frame, in memory (the
    dataset runner encodes a frame, then writes it on another thread while it renders the next).
    Raises what :func:`write_frame` raises for an unknown format or data a format cannot hold."""
    blobs = {}
    for fmt in tuple(formats) + (("fits",) if fits and "fits" not in formats else ()):
        if fmt in ("png", "exr", "json"):
            blobs[fmt] = frame_file_bytes(frame, fmt)
        elif fmt == "fits":
            t = frame.truth
            hdr = tan_wcs_header(np.array(t["camera"]["K"]), t["camera"]["width"], t["camera"]["height"],
                                 np.array(t["attitude"]["R_cam_icrs"]))
            blobs[fmt] = _fits_bytes(frame.dn, hdr, fits_frame_header(t))
        else:
            raise ConfigValueError("formats", fmt, "png, exr, json or fits")
    return blobs


def write_files(files) -> None:
    """Write ``(path, bytes)`` pairs, each atomically (temp file, fsync, rename, folder fsync)
    on its own thread: the fsyncs wait on the disk with the GIL released, so they overlap even
    on one core (what :func:`write_frame` does with a frame's encoded files)."""
    files = list(files)
    if len(files) > 1:
        with ThreadPoolExecutor(len(files), thread_name_prefix="skynav-write") as pool:
            for job in [pool.submit(atomic_write_bytes, path, data) for path, data in files]:
                job.result()
    else:
        for path, data in files:
            atomic_write_bytes(path, data)


def frame_file_bytes(frame, fmt: str) -> bytes:
    """The bytes :func:`write_frame` writes for one format of a frame (``png``, ``exr`` or ``json``).

    One encoder for the files and for programs that take frames in memory (the render service
    answers with these bytes, so they equal the files of ``skynav render``).
    """
    if fmt == "png":
        return png_bytes(frame.dn, bit_depth=frame.truth["camera"]["bit_depth"])
    if fmt == "exr":
        return exr_bytes({"electrons": frame.electrons, "irradiance_w_m2": frame.irradiance_w_m2})
    if fmt == "json":
        return truth_json_bytes(frame.truth)
    raise ConfigValueError("formats", fmt, "png, exr or json")
