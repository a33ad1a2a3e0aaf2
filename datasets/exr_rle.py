"""OpenEXR's RLE scanline files, written sparsely: the fast path of the EXR writer.

What it computes: the file OpenEXR writes for float32/uint32 channels with ``RLE_COMPRESSION``,
one scanline per chunk (OpenEXRCore ``internal_rle.c``): each scanline's bytes split into the
even-indexed bytes then the odd ones, a byte-wise delta predictor (``d[0] = t[0]``,
``d[j] = t[j] - t[j-1] + 128 mod 256``), then runs (``count - 1 >= 0``, byte) and literals
(``-count``, bytes); a chunk that does not shrink is stored raw. The header and the file layout
are OpenEXR's own: OpenEXR writes a zero image of the same shape, channels and attributes once
per process, and its header is reused (:func:`exr_layout`).

A frame's expected electrons and irradiance are mostly exact zeros (a dark sky with stars). The
encoder touches only the bytes near non-zero pixels: each island of non-zero words becomes one
literal, the zeros between islands runs of 128. OpenEXR's encoder, which scans every byte, is
the reference (:func:`reference_exr_bytes`); the runs and literals may be cut at other places
than OpenEXR cuts them, so the bytes can differ from OpenEXR's while every decoded pixel is the
same (``tests/datasets/test_exr_rle.py`` reads both files back with OpenEXR and compares the
words). ``benchmarks/encoder_bench.py`` measures what it saves of a frame (docs/performance.md).
"""

from __future__ import annotations

import io
import threading

import numpy as np

__all__ = ["exr_layout", "reference_exr_bytes", "rle_file", "sparse_exr_bytes"]

_EXR_LAYOUTS: dict = {}
_RLE_GAP = 3  # runs of this many 128s or more between non-128 bytes end a literal

#: Scanlines the encoder scans at a time: a block of two 1024-px float32 channels is 512 kB, so
#: the scan stays in the core's cache instead of streaming a full copy of the channels.
_RLE_BLOCK_ROWS = 64

_RLE_SCRATCH = threading.local()


def reference_exr_bytes(arrays: dict, hdr: dict, OpenEXR) -> bytes:
    """The file OpenEXR's own encoder writes for ``arrays`` (``{name: (H, W) float32 or uint32}``)
    with the attributes ``hdr``: the reference of :func:`sparse_exr_bytes`."""
    buf = io.BytesIO()
    OpenEXR.File(hdr, arrays).write(buf)
    return buf.getvalue()


def sparse_exr_bytes(arrays: dict, hdr: dict, OpenEXR) -> bytes | None:
    """The RLE scanline file of ``arrays`` with the attributes ``hdr``, written by
    :func:`rle_file` inside OpenEXR's header; None where this encoder does not apply (a
    big-endian machine, an empty channel, or a layout other than the plain one)."""
    if not (np.little_endian and all(a.size for a in arrays.values())):
        return None
    layout = exr_layout(arrays, hdr, OpenEXR)
    if layout is None:
        return None
    head, names = layout
    return rle_file(head, [arrays[n].view("<u4") for n in names])


def exr_layout(arrays: dict, hdr: dict, OpenEXR):
    """``(header bytes, channel names in file order)`` of a RLE scanline file of these channels'
    shape and types with these attributes, written once by OpenEXR; None if the layout is not the
    plain one this encoder writes (single part, one scanline per chunk, 4-byte channels)."""
    shape = next(iter(arrays.values())).shape
    key = (shape, tuple((n, a.dtype.str) for n, a in arrays.items()), tuple(sorted((k, repr(v)) for k, v in hdr.items())))
    if key in _EXR_LAYOUTS:
        return _EXR_LAYOUTS[key]
    data = reference_exr_bytes({n: np.zeros(shape, a.dtype) for n, a in arrays.items()}, hdr, OpenEXR)
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


def _dirty_words(channels: list, S: int):
    """``(p, words)``: the positions ``p`` of the scanlines' dirty 4-byte words in rows of ``S``
    words (each row after 2 zero words, so that rows are 3 or more words apart), and the words.

    d[j] (either half of a scanline) differs from 128 only where t[j] or t[j-1] is not 0: the
    2-byte words 2p, 2p + 1 of a non-zero 4-byte word p, and the word after it; and where a half
    begins. The scan goes a block of scanlines at a time."""
    H = channels[0].shape[0]
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
    return p, np.concatenate(curs)


def _deltas(cur, dp, s, first, last_channel):
    """The delta bytes of the dirty words ``cur`` (modified in place), ``[word][2p, 2p + 1][low,
    high half]``: bytewise ``(t - t_before + 128) mod 256`` on 4 bytes at once, each half's t being
    the low, resp. high bytes of the 2-byte words and t_before those of the word before each (0
    if that word is clean, ``dp`` > 1; before word 0 of a row, at the islands ``s[first]``:
    t[-1] = 128 and t[N - 1] of the row, from the row's last word of ``last_channel``). Per byte,
    (t | 128) - (t_before & 127) is t - t_before + 128 mod 256 but for the top bit."""
    y = np.empty_like(cur)
    y[0] = 0
    np.multiply(cur[:-1], dp == 1, out=y[1:])
    y >>= 16
    y[s[first]] = 128 | (last_channel[:, -1] >> 16 & 0xFF) << 8
    y |= cur << 16  # the 2-byte words 2p - 1, 2p: those before 2p, 2p + 1
    low7 = np.bitwise_and(y, 0x7F7F7F7F)
    y ^= cur
    y &= 0x80808080
    cur |= 0x80808080
    cur -= low7
    cur ^= y
    return cur.view(np.uint8).reshape(-1, 2, 2)


def _write_islands(out, o, p, p_s, lens, n, gap, lit_pieces, dv) -> None:
    """Each island's literal (headers ``-count``, pieces of up to 127 bytes, its delta bytes
    ``dv``) and the runs of 128 after it (``count - 1, 128``, up to 128 bytes each), at ``o`` in
    the low half and in the high one."""
    count, at = _rle_pieces(o, n, 127, 128)
    for every, last in at:
        if every is not last:
            out[every] = 256 - 127
        out[last] = 256 - count
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


def rle_file(head: bytes, channels: list) -> bytes:
    """The RLE scanline file of ``channels`` (each (H, w_c) 4-byte words, little-endian, in file
    order: a scanline is each channel's row in turn), after the header ``head``
    (:func:`exr_layout`)."""
    H = channels[0].shape[0]
    n_words = sum(c.shape[1] for c in channels)
    N = 2 * n_words  # bytes in each half of a scanline: its even-indexed bytes, then its odd ones
    S = n_words + 2
    p, cur = _dirty_words(channels, S)
    # islands of dirty words, cut where 3 or more 128s lie between (2 clean 4-byte words)
    dp = np.diff(p)
    s = np.flatnonzero(dp > 1 + _RLE_GAP // 2) + 1
    lens = np.diff(s, prepend=0, append=p.size)  # words in each island
    s = np.concatenate(([0], s))
    p_s, p_e = p[s].astype(np.int64), p[s + lens - 1].astype(np.int64)
    row = p_s // S
    k_s, k_e = p_s - row * S - 2, p_e - row * S - 2  # first and last word in the row
    first = k_s == 0  # each row's first island: the one at its word 0
    dv = _deltas(cur, dp, s, first, channels[-1])
    del dp
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
    _write_islands(out, o, p, p_s, lens, n, gap, lit_pieces, dv)
    for r in np.flatnonzero(raw):
        out[region[r] + 8:region[r] + 8 + 2 * N] = np.concatenate([c[r] for c in channels]).view(np.uint8)
    hdr = np.empty((H, 2), "<i4")
    hdr[:, 0], hdr[:, 1] = np.arange(H), size
    out[region[:, None] + np.arange(8)] = hdr.view(np.uint8).reshape(H, 8)
    out[:len(head)] = np.frombuffer(head, np.uint8)
    out[len(head):prefix] = region.astype("<u8").view(np.uint8)
    return out[:end].tobytes()
