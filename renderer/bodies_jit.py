"""The ray-traced bodies of a batch of frames blurred and composited by Dr.Jit: each body's
Mitsuba crop convolved with its PSF and added into the batch's sensor input on the device.

What it computes: the resolved bodies of :func:`~skynav.renderer.expected.expected_image`
after their ray tracing. The host traces them as the reference does (the same bodies, the same
``rng`` draws: ``expected_image``'s ``traced_out``) and hands each crop over with the kernel
its blur convolves it with (:meth:`~skynav.renderer.kernels.GaussianKernel.blur_stamp`: the
Gaussian's normalised erf kernel, or a table kernel's stamp of a point at the body's pixel
centre), as :class:`BodyCrops`. The device then convolves, directly: one lane per (non-zero
crop pixel, stamp pixel), its product scatter-added in float64 into the body's blurred crop
(the crop padded by the stamp's half size; a crop is mostly its disc, the dark pixels around
it are skipped). One lane per pixel of the blurred crops then adds it, rounded to float32, into
the (N * H * W) sensor input (the pixels off the image dropped, as the reference drops them),
and scatter-adds the crop's total and first moments, over the whole blurred crop (off-image
pixels included, as the reference sums them), into a small float64 array the host reads back
for the truth (:func:`bodies_truth`: centre of light, fraction drawn, electrons, recorded by
the reference's :func:`~skynav.renderer.expected.record_resolved_body`).

The result differs from the numpy reference by roundings: the reference blurs a Gaussian
separably and a table kernel by FFT (whose ringing it clamps at zero, as the device clamps
its sums) and sums in another order; the device's sums are float64 like the reference's, and
rounded once to float32 as the reference's image is (tested to 1e-5 relative per pixel,
tests/renderer/test_batch_bodies.py). The sums' order is the device's (atomic additions), so
the truth's centres of light repeat to float64 roundings, not bit for bit. One Python body is
traced for Dr.Jit's LLVM and CUDA backends.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .expected import record_resolved_body
from .sensor_jit import _module_of

__all__ = ["BodyCrops", "body_crops", "composite_bodies", "bodies_truth"]

#: Lanes of one launch of the convolution at most (its lane index is a 32-bit integer).
_MAX_LANES = 1 << 30


@dataclasses.dataclass(frozen=True, kw_only=True, eq=False)
class BodyCrops:
    """A frame's ray-traced bodies as the device composites them.

    Attributes
    ----------
    bodies : tuple of TracedBody
        Each body's Mitsuba crop (``image.electrons``, e-; top-left pixel ``image.x0``,
        ``image.y0``) and kernel, in the order the frame traced them.
    stamps : tuple of ndarray, each shape (2p + 1, 2p + 1)
        The kernel each crop is convolved with (its blur stamp; ``p``: the blurred crop's pad, px).
    """

    bodies: tuple
    stamps: tuple

    @property
    def pads(self) -> tuple:
        """Each blurred crop's pad (the stamp's half size), px."""
        return tuple(s.shape[0] // 2 for s in self.stamps)


def body_crops(traced, flux_fraction_lost: float) -> BodyCrops:
    """A frame's traced bodies (``traced``: the :class:`~skynav.renderer.expected.TracedBody`
    list of :func:`~skynav.renderer.expected.expected_image`'s ``traced_out``) with the stamps
    their blur convolves them with, as the reference's :func:`~skynav.renderer.expected.blur_crop`
    does (``flux_fraction_lost``: the render's)."""
    bodies = tuple(traced)
    stamps = tuple(np.asarray(t.kernel.blur_stamp(flux_fraction_lost, at_xy=t.at_xy), dtype=float) for t in bodies)
    return BodyCrops(bodies=bodies, stamps=stamps)


def _upload(jt_type, values):
    """A numpy array as a Dr.Jit array of at least two elements (a one-element array would be
    gathered as a constant of the kernel, one compilation per value: its last element repeated;
    the lanes read only the first)."""
    v = np.asarray(values)
    if v.size < 2:
        v = np.concatenate([v, np.repeat(v[-1:] if v.size else np.zeros(1, v.dtype), 2 - v.size)])
    return jt_type(np.ascontiguousarray(v))


@dataclasses.dataclass(frozen=True)
class _Packed:
    """A batch's bodies as flat arrays (host): per non-zero crop pixel (``pix_*``), per body
    (the rest), and the stamps padded to the largest, ``(M, K, K)``."""

    pix_e: np.ndarray      # electrons of each non-zero crop pixel (float64)
    pix_body: np.ndarray   # its body (uint32)
    pix_at: np.ndarray     # its flat index in its crop (uint32)
    width: np.ndarray      # each crop's width, px
    pad: np.ndarray        # each blurred crop's pad, px
    shift: np.ndarray      # K // 2 - pad: where its stamp lies in the padded one
    base: np.ndarray       # each blurred crop's first element in the blurred buffer
    end: np.ndarray        # and one past its last
    origin: np.ndarray     # (M, 2): each blurred crop's top-left pixel in its frame (column, row)
    frame: np.ndarray      # each body's frame in the batch
    stamps: np.ndarray     # (M * K * K,) float64
    k: int                 # the padded stamps' side, px


def _pack(crops) -> _Packed | None:
    """The bodies of ``crops`` (one :class:`BodyCrops` or None per frame) packed for the device;
    None when no frame has one."""
    items = [(f, b, s) for f, c in enumerate(crops) if c is not None for b, s in zip(c.bodies, c.stamps)]
    if not items:
        return None
    k = max(s.shape[0] for _, _, s in items)
    stamps = np.zeros((len(items), k, k))
    pix_e, pix_body, pix_at = [], [], []
    shape = np.zeros((len(items), 2), np.int64)  # (h, w) of each crop
    for j, (_, b, s) in enumerate(items):
        d = (k - s.shape[0]) // 2
        stamps[j, d:d + s.shape[0], d:d + s.shape[0]] = s
        e = np.asarray(b.image.electrons, dtype=float)
        shape[j] = e.shape
        at = np.flatnonzero(e)
        pix_e.append(e.reshape(-1)[at])
        pix_body.append(np.full(at.size, j, np.uint32))
        pix_at.append(at.astype(np.uint32))
    pad = np.array([s.shape[0] // 2 for _, _, s in items], np.int64)
    area = (shape[:, 0] + 2 * pad) * (shape[:, 1] + 2 * pad)
    end = np.cumsum(area)
    origin = np.array([[b.image.x0, b.image.y0] for _, b, _ in items], np.int64) - pad[:, None]
    return _Packed(pix_e=np.concatenate(pix_e), pix_body=np.concatenate(pix_body), pix_at=np.concatenate(pix_at),
                   width=shape[:, 1], pad=pad, shift=k // 2 - pad, base=end - area, end=end, origin=origin,
                   frame=np.array([f for f, _, _ in items], np.int64), stamps=stamps.reshape(-1), k=k)


def composite_bodies(sig, crops, shape):
    """Blur each frame's ray-traced bodies (``crops``: one :class:`BodyCrops` or None per
    frame) and add them into the batch's sensor input ``sig`` (a Dr.Jit Float of N * H * W,
    frame-major; ``shape`` = (H, W)).

    Returns
    -------
    sig : drjit Float, lazy
        The new input.
    moments : drjit Float64 of 3 M, lazy, or None
        Each body's (total, sum x, sum y) over its whole blurred crop (x, y: column and row
        within it), in the order of ``crops``' bodies (e-, e- px); None without a body.
    """
    packed = _pack(crops)
    if packed is None:
        return sig, None
    jt = _module_of(sig)
    blurred = _convolve(jt, packed)
    return _add_blurred(jt, jt.Float(sig), blurred, packed, shape)


def _convolve(jt, p: _Packed):
    """The blurred crops, one after the other (float64, lazy): one lane per (non-zero crop
    pixel, stamp pixel), its product scatter-added where the full convolution puts it."""
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    per_pixel = p.k * p.k
    blurred = dr.zeros(jt.Float64, max(int(p.end[-1]), 2))
    stamps = _upload(jt.Float64, p.stamps)
    width, pad, shift, base = (_upload(jt.Int32, a.astype(np.int32)) for a in (p.width, p.pad, p.shift, p.base))
    step = max(1, _MAX_LANES // per_pixel)
    for first in range(0, p.pix_e.size, step):  # launches of at most _MAX_LANES lanes
        sel = slice(first, min(first + step, p.pix_e.size))
        n = sel.stop - sel.start
        lane = dr.arange(jt.UInt32, n * per_pixel)
        pix, cell = lane // per_pixel, lane % per_pixel
        body = dr.gather(jt.UInt32, _upload(jt.UInt32, p.pix_body[sel]), pix)
        w = dr.gather(jt.Float64, stamps, body * per_pixel + cell)
        on = w != 0.0  # the pad around a smaller stamp, and a kernel's own zeros
        at = jt.Int32(dr.gather(jt.UInt32, _upload(jt.UInt32, p.pix_at[sel]), pix))
        # a divisor at least 1: the idle lanes of LLVM's last packet gather 0 (and would trap)
        wid, d = dr.maximum(dr.gather(jt.Int32, width, body), 1), dr.gather(jt.Int32, shift, body)
        two_p = 2 * dr.gather(jt.Int32, pad, body)
        row = at // wid + jt.Int32(cell // p.k) - d  # the product's pixel in the blurred crop
        col = at % wid + jt.Int32(cell % p.k) - d
        e = dr.gather(jt.Float64, _upload(jt.Float64, p.pix_e[sel]), pix, on) * w
        index = dr.gather(jt.Int32, base, body) + row * (wid + two_p) + col
        dr.scatter_add(blurred, e, jt.UInt32(index), on)
    return blurred


def _add_blurred(jt, sig, blurred, p: _Packed, shape):
    """One lane per pixel of the blurred crops: clamped at zero (as the reference clamps its
    FFT's ringing), rounded to float32 and added into ``sig`` where on the image; its moments
    scatter-added into each body's (total, sum x, sum y). Returns ``(sig, moments)``."""
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    h_img, w_img = shape
    n_bodies = p.frame.size
    lane = dr.arange(jt.UInt32, int(p.end[-1]))
    end = _upload(jt.UInt32, p.end.astype(np.uint32))
    body = dr.binary_search(0, n_bodies - 1, lambda j: dr.gather(jt.UInt32, end, j) <= lane)
    width = dr.maximum(dr.gather(jt.UInt32, _upload(jt.UInt32, (p.width + 2 * p.pad).astype(np.uint32)), body), 1)
    local = lane - dr.gather(jt.UInt32, _upload(jt.UInt32, p.base.astype(np.uint32)), body)
    row, col = jt.Int32(local // width), jt.Int32(local % width)
    e = dr.maximum(dr.gather(jt.Float64, blurred, lane), 0.0)
    moments = dr.zeros(jt.Float64, 3 * n_bodies)
    for k, value in enumerate((e, e * jt.Float64(col), e * jt.Float64(row))):
        dr.scatter_add(moments, value, 3 * body + k)
    col = col + dr.gather(jt.Int32, _upload(jt.Int32, p.origin[:, 0].astype(np.int32)), body)
    row = row + dr.gather(jt.Int32, _upload(jt.Int32, p.origin[:, 1].astype(np.int32)), body)
    inside = (e > 0.0) & (row >= 0) & (row < h_img) & (col >= 0) & (col < w_img)
    frame = dr.gather(jt.UInt32, _upload(jt.UInt32, p.frame.astype(np.uint32)), body)
    index = frame * (h_img * w_img) + jt.UInt32(row * w_img + col)
    # atomics straight into the input: a copy of the whole batch per thread and its reduction
    # (the LLVM backend's choice for a large target) would cost more than these few lanes
    dr.scatter_add(sig, jt.Float(e), index, inside, mode=dr.ReduceMode.Direct)
    return sig, moments


def bodies_truth(expected, crops, moments):
    """The frames' expected images (``expected``: one per frame, made with ``traced_out``) with
    their ray-traced bodies' truth recorded as the reference records it: centre of light,
    fraction drawn and electrons from the device's ``moments`` (:func:`composite_bodies`'s,
    as numpy or Dr.Jit, 3 per body in the order of ``crops``; None without a body)."""
    out = []
    m = None if moments is None else np.asarray(moments, dtype=float).reshape(-1, 3)
    j = 0
    for ex, c in zip(expected, crops):
        if c is None or not c.bodies:
            out.append(ex)
            continue
        body_e, centre = dict(ex.body_electrons), dict(ex.body_centre_of_light or {})
        fraction = None if ex.body_fraction_drawn is None else dict(ex.body_fraction_drawn)
        for body, pad in zip(c.bodies, c.pads):
            record_resolved_body(body, (float(m[j, 0]), float(m[j, 1]), float(m[j, 2])), pad, body_e, centre, fraction)
            j += 1
        out.append(dataclasses.replace(ex, body_electrons=body_e, body_centre_of_light=centre,
                                       body_fraction_drawn=fraction))
    return out
