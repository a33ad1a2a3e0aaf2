"""The sensor chain as one Dr.Jit kernel (the ``"llvm"`` and ``"cuda"`` backends of
:class:`~skynav.renderer.detector.Sensor`): per-pixel random streams keyed by the frame
(TEA-hashed PCG32 seeds, as Mitsuba seeds its samplers), Poisson charge (sequential inversion
below :data:`POISSON_INVERSION_MAX_MEAN`, PTRS above), read noise through an ``erfinv``
polynomial, gain and quantisation; the frozen (recorded and replayed) forms of the kernel, for
the whole frame and for the few pixels cosmic rays hit. The method and its checks are in
:mod:`skynav.renderer.detector`'s notes.
"""

from __future__ import annotations

import functools
import math
import threading

import numpy as np


POISSON_INVERSION_MAX_MEAN = 10.0
"""Below this mean the Dr.Jit path samples Poisson by sequential inversion, above by PTRS."""

_INVERSION_MAX_K = 200  # cap of the inversion loop: P(K > 200 | mean < 10) ~ 1e-200
#: pmf terms per trip of the inversion loop (see _jit_charge); 200 is 25 trips of 8. The terms,
#: their sums and the comparisons are the same whatever the count (so are the bits); fewer trips
#: cost less loop overhead; 8 is among the fastest counts measured (docs/performance.md).
_INVERSION_TERMS_PER_TRIP = 8


def _jit_exposure(sig, gain, dark, extra, t, key, full_well, readout, index, small_dn):
    """The sensor chain without blooming, lazy: PRNU and dark current, Poisson, extra charge,
    full well, read noise, gain, ADC (:func:`_jit_charge`, :func:`_jit_readout`); ``index``:
    the pixels' flat indices (None: all the image's, in order)."""
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    mean = dr.fma(sig, gain, dark * t)
    n, pcg = _jit_charge(mean, extra, key, index)
    return _jit_readout(dr.minimum(n, full_well), pcg, *readout, small_dn=small_dn)


_frozen_lock = threading.Lock()

#: Lanes of the hit pixels' replayed kernel: the next power of two >= their number, at least
#: _HIT_LANES_MIN; above _HIT_LANES_MAX (a frame of particle showers) the chain is traced. At most
#: 11 sizes, each recorded once per process (Dr.Jit warns after _HIT_RECORDINGS_WARN recordings).
_HIT_LANES_MIN = 64
_HIT_LANES_MAX = 1 << 16
_HIT_RECORDINGS_WARN = 16


def _hit_lanes(n: int) -> int:
    """Lanes of the hit pixels' kernel for ``n`` pixels hit; 0: trace it instead."""
    lanes = max(_HIT_LANES_MIN, 1 << max(0, int(n) - 1).bit_length())
    return lanes if lanes <= _HIT_LANES_MAX else 0


@functools.lru_cache(maxsize=8)
def _frozen_exposure(small_dn: bool, backend: str = "llvm", hit_pixels: bool = False):
    """:func:`_jit_exposure` as a Dr.Jit frozen function (``drjit.freeze``).

    The first call of each input layout (image size, extra charge or none) traces the chain and
    records its kernel launch; later calls replay the recording with the new inputs, skipping
    the ~800 operations of Python tracing a frame. The recording is the
    kernel a plain call compiles, so the two give the same bits (``tests/renderer/
    test_detector_emva1288.py``). Every per-frame number is an input (an opaque variable), never a
    constant of the recording. Calls are serialised by ``_frozen_lock`` (a recording is state).
    One instance per Dr.Jit backend (``"llvm"``, ``"cuda"``): a recording holds its backend's
    kernel. ``hit_pixels``: the instance for the pixels cosmic rays hit (one recording per lane count,
    :func:`_hit_lanes`), apart from the image's so that its recordings do not count against it.
    """
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    def exposure(sig, gain, dark, extra, t, key, full_well, readout, index):
        return _jit_exposure(sig, gain, dark, extra, t, key, full_well, readout, index, small_dn)

    return dr.freeze(exposure, warn_after=_HIT_RECORDINGS_WARN) if hit_pixels else dr.freeze(exposure)


# --------------------------------------------------------------------------- per-pixel streams
TEA_DELTA = 0x9E3779B9
"""TEA's round constant, floor(2^32 / golden ratio) (Wheeler & Needham 1994)."""

PIXEL_SEED_TEA_ROUNDS = 4
"""TEA cycles (two Feistel half-rounds each) of the per-pixel stream hash, as Mitsuba's
``sample_tea_32``; see :func:`pixel_stream_seeds`."""

_MASK32 = 0xFFFFFFFF


def tea_encrypt(v0, v1, key, *, rounds: int = 32):
    """Encrypt 64-bit blocks ``(v0, v1)`` with the Tiny Encryption Algorithm (TEA).

    Written with ``+``, ``^``, ``<<`` and ``>>`` only, so it runs unchanged on numpy ``uint32``
    arrays and on Dr.Jit ``UInt32`` arrays (inside a kernel); both wrap around modulo 2^32.

    Parameters
    ----------
    v0, v1 : ndarray of uint32, drjit UInt32, or int in [0, 2^32)
        The two 32-bit halves of each plaintext block (broadcast against each other).
    key : sequence of 4 items, each as ``v0``
        The 128-bit key ``(k0, k1, k2, k3)``.
    rounds : int
        TEA cycles; 32 is the cipher of the reference, fewer give a cheaper hash.

    Returns
    -------
    v0, v1 : same type as the inputs
        The two halves of each ciphertext block.

    References
    ----------
    Wheeler, D. J. and Needham, R. M. (1994), "TEA, a Tiny Encryption Algorithm", Fast Software
    Encryption, LNCS 1008, 363-366. Zafar, F., Olano, M. and Curtis, A. (2010), "GPU random
    numbers via the tiny encryption algorithm", Proc. High Performance Graphics, 133-141 (TEA with
    few rounds as a hash of (seed, index) for parallel random numbers). Mitsuba 3
    ``sample_tea_32`` (``include/mitsuba/core/random.h``), which seeds each lane of its samplers'
    PCG32 this way.

    Examples
    --------
    The published test vector (key 0, plaintext 0, 32 rounds):

    >>> [hex(int(w[0])) for w in tea_encrypt(np.uint32([0]), np.uint32([0]), (0, 0, 0, 0))]
    ['0x41ea3a0a', '0x94baa940']
    """
    k0, k1, k2, k3 = key
    s = 0
    for _ in range(int(rounds)):
        s = (s + TEA_DELTA) & _MASK32
        v0 = v0 + (((v1 << 4) + k0) ^ (v1 + s) ^ ((v1 >> 5) + k1))
        v1 = v1 + (((v0 << 4) + k2) ^ (v0 + s) ^ ((v0 >> 5) + k3))
    return v0, v1


def frame_key(rng: np.random.Generator) -> tuple[int, int, int, int]:
    """The 128-bit key of one frame's sensor noise on the LLVM path, drawn from ``rng``.

    Consumes ``rng`` exactly as before the streams were hashed (two 64-bit words), so that the
    numbers a caller draws after the sensor do not move.

    Returns
    -------
    tuple of 4 int, each in [0, 2^32)
        ``(lo(w0), hi(w0), lo(w1), hi(w1))`` of the two 64-bit words drawn.
    """
    w = rng.integers(0, 2**64, size=2, dtype=np.uint64, endpoint=False)
    w0, w1 = int(w[0]), int(w[1])
    return w0 & _MASK32, w0 >> 32, w1 & _MASK32, w1 >> 32


def pixel_stream_seeds(key, index, *, rounds: int = PIXEL_SEED_TEA_ROUNDS):
    """PCG32 initial state and sequence of each pixel's stream: a keyed hash of its index.

    ``(initstate, initseq) = TEA_key(index, 0)``: the two 32-bit halves of the ciphertext of the
    block ``(index, 0)`` under the frame key. This is what Mitsuba's samplers do
    (``sample_tea_32(seed, lane index)`` seeds each lane's PCG32 state and sequence, 4 rounds),
    with the frame's 128 bits of randomness as the TEA key rather than in the plaintext. For one
    key TEA is a permutation of 64-bit blocks, so no two pixels of a frame share a (state,
    sequence) pair; frames differ by their key. (With 32-bit sequences about a hundred pairs of
    pixels in a megapixel share a sequence, at unrelated points of its 2^64-long cycle, far
    further apart than the few hundred numbers a pixel draws.) Seeding PCG32 with ``state + i`` and
    ``sequence + i`` instead (Dr.Jit's ``PCG32(size, state, sequence)``) gives correlated
    streams: the old LLVM path had a +0.24 autocorrelation of the noise at one lag
    (``tests/renderer/test_noise_independence.py``).

    Parameters
    ----------
    key : sequence of 4 Dr.Jit UInt32 (opaque) or int
        The frame key, :func:`frame_key`.
    index : drjit.llvm.UInt32 or drjit.cuda.UInt32, shape (N,)
        Flat pixel indices (row-major), < 2^32.
    rounds : int
        TEA cycles (:data:`PIXEL_SEED_TEA_ROUNDS`, Mitsuba's choice; each cycle adds to the
        kernel's time in proportion to the pixels).

    Returns
    -------
    initstate, initseq : UInt64 of ``index``'s backend, shape (N,), each < 2^32
        Arguments of ``PCG32.seed`` (which runs two LCG steps, so the 64-bit state depends on
        both).

    References
    ----------
    O'Neill, M. E. (2014), "PCG: A Family of Simple Fast Space-Efficient Statistically Good
    Algorithms for Random Number Generation", Harvey Mudd College HMC-CS-2014-0905.
    Mitsuba 3, ``PCG32Sampler::seed`` (``src/render/sampler.cpp``).
    """
    UInt64 = _module_of(index).UInt64
    v0, v1 = tea_encrypt(index, 0, key, rounds=rounds)
    return UInt64(v0), UInt64(v1)


# --------------------------------------------------------------------------- Dr.Jit kernels
def _jit_module(backend: str):
    """Dr.Jit's array module of a sensor backend: ``drjit.llvm`` or ``drjit.cuda``."""
    if backend == "cuda":
        # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
        import drjit.cuda as jt
    else:
        # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
        import drjit.llvm as jt
    return jt


def _module_of(x):
    """The array module of a Dr.Jit array's backend: the kernels below build their other arrays
    (random streams, masks, results) on the backend of their input, so that one Python body
    traces the LLVM and the CUDA kernel alike."""
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    return _jit_module("cuda" if dr.backend_v(x) == dr.JitBackend.CUDA else "llvm")


def _jit_charge(mean, extra, key, index=None):
    """Poisson(mean) (+ extra) as a lazy Dr.Jit Float, and the advanced PCG32 streams.

    ``key`` is the frame key (:func:`frame_key`) as four opaque Dr.Jit UInt32 (kernel inputs, so
    the kernel does not depend on their values); lane ``j`` of ``mean`` gets the PCG32 stream
    seeded by :func:`pixel_stream_seeds` for the pixel ``index[j]`` (default: ``j``).
    """
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    jt = _module_of(mean)
    PCG32, Float, Float64, UInt32 = jt.PCG32, jt.Float, jt.Float64, jt.UInt32
    if index is None:
        index = dr.arange(UInt32, dr.width(mean))
    initstate, initseq = pixel_stream_seeds(key, index)
    pcg = PCG32(dr.width(mean))
    pcg.seed(initstate, initseq)  # seed() adds no per-lane offset, unlike the constructor
    lam = dr.maximum(mean, 0.0)
    small = lam < POISSON_INVERSION_MAX_MEAN

    # -- sequential inversion (means < 10): smallest k with F(k) >= u.
    # In float64: float32 sums of the pmf can stall a few ulp below 1 and leave the rare u above
    # them stuck until the cap (a spurious tail value ~1e-7 of the time); float64 with a 53-bit u
    # resolves tail probabilities down to ~1e-15.
    # _INVERSION_TERMS_PER_TRIP (T) terms per trip, each p(k + j) = p(k + j - 1) * (lam / (k + j)):
    # the divisions do not depend on p, so they leave the loop-carried chain (one multiply and one
    # add per term instead of a division); a lane's answer is k + 1 + [u > F(k+1)] + ... +
    # [u > F(k+T-1)] when u <= F(k+T), else the search goes on from k + T. The cap stays at
    # _INVERSION_MAX_K.
    u = pcg.next_float64()
    lam64 = Float64(lam)
    p0 = dr.exp(-lam64)
    k0 = Float64(0.0)

    def inv_cond(k, p, f):
        return small & (u > f) & (k < _INVERSION_MAX_K)

    def inv_body(k, p, f):
        ratio = [lam64 / (k + float(j)) for j in range(1, _INVERSION_TERMS_PER_TRIP + 1)]
        step = Float64(1.0)
        for j, r in enumerate(ratio):
            p = p * r
            f = f + p
            if j < len(ratio) - 1:
                step = step + dr.select(u > f, 1.0, 0.0)
        return dr.select(u > f, k + float(len(ratio)), k + step), p, f

    k_small, _, _ = dr.while_loop((k0, p0, p0), inv_cond, inv_body, labels=("k", "p", "f"), label="poisson_inversion")

    pcg, k_big = _jit_poisson_ptrs(pcg, lam, small)
    n = dr.select(small, Float(k_small), k_big)
    if extra is not None:
        n = n + extra
    return n, pcg


def _jit_poisson_ptrs(pcg, lam, small):
    """Poisson(lam) by PTRS transformed rejection (Hoermann 1993), lazy, in the lanes not ``small``
    (the others' draw is 0 and their stream is not advanced): ``(pcg advanced, k)``."""
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    jt = _module_of(lam)
    Bool, Float = jt.Bool, jt.Float
    # As in numpy's random_poisson_ptrs.
    # Its constants are computed inside the loop body: only the few packets of lanes holding a
    # mean >= 10 (stars, bright bodies) enter the loop, so the dark sky does not pay for them.
    big_lam = dr.select(small, POISSON_INVERSION_MAX_MEAN, lam)

    def ptrs_cond(rng, k, done):
        return ~done

    def ptrs_body(rng, k, done):
        slam = dr.sqrt(big_lam)
        log_lam = dr.log(big_lam)
        b = 0.931 + 2.53 * slam
        a = -0.059 + 0.02483 * b
        log_inv_alpha = dr.log(1.1239 + 1.1328 / (b - 3.4))
        vr = 0.9277 - 3.6224 / (b - 2.0)
        half_log_2pi_lam = 0.5 * (log_lam + math.log(2.0 * math.pi))
        uu = rng.next_float32() - 0.5
        v = rng.next_float32()
        us = 0.5 - dr.abs(uu)
        kk = dr.floor((2.0 * a / us + b) * uu + big_lam + 0.43)
        fast = (us >= 0.07) & (v <= vr)
        reject = (kk < 0.0) | ((us < 0.013) & (v > us)) | ~dr.isfinite(kk)
        # log pmf(kk) = -lam + kk log(lam) - lgamma(kk + 1), with lgamma by Stirling's series at
        # x = kk + 1 written around (x - lam) to avoid cancelling two ~kk log kk terms in float32.
        xk = dr.maximum(kk, 0.0) + 1.0
        rx = dr.rcp(xk)
        rx2 = rx * rx
        log_pmf = -(xk - 0.5) * dr.log(xk / big_lam) + (xk - big_lam) - half_log_2pi_lam - rx * (1.0 / 12.0 - rx2 * (1.0 / 360.0 - rx2 * (1.0 / 1260.0)))
        log_lhs = dr.log(v) + log_inv_alpha - dr.log(a / (us * us) + b)
        accept = fast | (~reject & (log_lhs <= log_pmf))
        return rng, dr.select(accept, kk, k), done | accept

    return dr.while_loop((pcg, Float(0.0), Bool(small)), ptrs_cond, ptrs_body, labels=("rng", "k", "done"), label="poisson_ptrs")[:2]


#: Giles (2010) single-precision erfinv: its central polynomial in w - 2.5 (w < 5) and its tail
#: polynomial in sqrt(w) - 3, w = -log(1 - x^2), lowest degree first (the coefficients of the
#: paper's Fig. 2, as Dr.Jit's ``erfinv`` holds them).
_ERFINV_CENTRAL = (1.50140941, 0.246640727, -0.00417768164, -0.00125372503, 0.00021858087, -4.39150654e-06,
                   -3.5233877e-06, 3.43273939e-07, 2.81022636e-08)
_ERFINV_TAIL = (2.83297682, 1.00167406, 0.00943887047, -0.0076224613, 0.00573950773, -0.00367342844,
                0.00134934322, 0.000100950558, -0.000200214257)


def _jit_estrin(x, coeffs):
    """Estrin's scheme for ``sum coeffs[i] x^i`` on Dr.Jit arrays (pairs by fused multiply-add,
    then the same on x^2, as Dr.Jit's ``estrin``); Python-float coefficients are rounded to
    float32 first, as a Float kernel's constants are."""
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    c = [float(np.float32(v)) if isinstance(v, float) else v for v in coeffs]
    while len(c) > 1:
        pairs = [dr.fma(x, c[2 * i + 1], c[2 * i]) for i in range(len(c) // 2)]
        c = pairs + c[len(pairs) * 2:]
        x = x * x
    return c[0]


def _jit_erfinv(x):
    """Inverse error function of a Dr.Jit Float in (-1, 1), lazy: Giles, M. (2010),
    "Approximating the erfinv function", GPU Computing Gems Jade Edition, 109-116 (single
    precision, relative error < 4e-7), as Dr.Jit's ``erfinv``, except that the tail polynomial
    (|x| > 0.9966, 0.3 % of the read-noise draws) is evaluated only in the packets of lanes that
    hold one: a loop that runs at most once, so ~95 % of the packets skip it. Checked against ``math.erf`` (tests/renderer/test_detector_emva1288.py)."""
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    Bool = _module_of(x).Bool
    w = -dr.log((1.0 - x) * (1.0 + x))
    central = _jit_estrin(w - 2.5, _ERFINV_CENTRAL)

    def tail_cond(p, todo):
        return todo

    def tail_body(p, todo):
        return _jit_estrin(dr.sqrt(w) - 3.0, _ERFINV_TAIL), Bool(False)

    p, _ = dr.while_loop((central, Bool(w >= 5.0)), tail_cond, tail_body, labels=("p", "todo"), label="erfinv_tail")
    return p * x


def _jit_readout(n, pcg, sigma_e, gain, offset_plus_half, max_dn, *, small_dn=False):
    """Read + reset noise, gain, offset, ADC (round half up), saturation -> DN (lazy): UInt8
    when ``small_dn`` (``max_dn`` < 256), else UInt32."""
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    jt = _module_of(n)
    UInt8, UInt32 = jt.UInt8, jt.UInt32
    u = pcg.next_float32() + 2.0**-25  # in (0, 1): erfinv(+-1) would be infinite
    z = math.sqrt(2.0) * _jit_erfinv(2.0 * u - 1.0)
    y = dr.floor(dr.fma(gain, dr.fma(sigma_e, z, n), offset_plus_half))
    return (UInt8 if small_dn else UInt32)(dr.clip(y, 0.0, max_dn))
