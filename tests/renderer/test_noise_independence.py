"""Independence of the sensor noise between pixels and between frames, on both backends.

The oracle is the white-noise hypothesis itself: the temporal noise of a flat field is, pixel by
pixel, independent (EMVA 1288 Release 4.0 Linear, Sect. 2: each pixel's shot, dark and
quantisation noise are independent; its spatial non-uniformities are fixed patterns and cancel in
a difference of two frames). Under that hypothesis

- the sample autocorrelation of N independent values has, at every lag k != 0, mean ~0 and
  standard deviation sqrt(N - k) / N <= 1 / sqrt(N) (Bartlett 1946; Box, Jenkins & Reinsel,
  "Time Series Analysis", Sect. 2.1, standard errors of autocorrelation estimates), and is
  close to normal for N = 2^18;
- the periodogram ordinates of white noise of variance s^2 at the Fourier frequencies other than
  the self-conjugate ones are independent, exponentially distributed with mean s^2 (chi-square
  with 2 degrees of freedom, times s^2 / 2): exactly for Gaussian noise, asymptotically for any
  i.i.d. noise of finite variance (Brockwell & Davis 1991, "Time Series: Theory and Methods",
  Sect. 10.3).

These tests were written against a defect: up to package version 0.2 the Dr.Jit LLVM path gave
pixel i the PCG32 stream (state s + i, sequence q + i), and the difference of two flat fields had
an autocorrelation of +0.24 at lag 5721 (11 rows, 89 columns) and about 0.2 at other lags, while
means and variances (the EMVA tests) were right.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from skynav.renderer import jit_backend
from tests.renderer.conftest import llvm_or_skip
from skynav.renderer.detector import Sensor
from skynav.scenes.camera import SensorParams



# The flat field of the defect report: gain 0.8 DN/e-, 1000 e- per pixel; 16 bit, offset and
# full well such that nothing clips (mean 1000 DN, temporal sd ~26 DN, 1 - 2^16 DN of room).
# No PRNU and no dark current, so the expected image is the constant K mu + offset exactly
# and the residual of one frame is pure temporal noise.
FLAT = SensorParams(
    bit_depth=16,
    gain_dn_per_e=0.8,
    offset_dn=200.0,
    full_well_e=60000.0,
    read_noise_e=6.0,
    reset_noise_e=4.0,
    dark_current_e_per_s=0.0,
    dsnu_e_per_s=0.0,
    prnu_fraction=0.0,
    pattern_seed=7,
)
SHAPE = (512, 512)
N_PX = SHAPE[0] * SHAPE[1]
EXPOSURE_S = 0.1
DEFECT_LAG = 11 * SHAPE[1] + 89  # 5721: where the old LLVM path peaked (+0.237)

# Family-wise false-alarm probability of each "every lag" test, for a correct generator.
FAMILY_ALPHA = 1e-3


def _band(n_tests: int, n: int = N_PX) -> float:
    """Half-width of the white-noise band of a sample (auto/cross-)correlation, Bonferroni over
    ``n_tests`` lags: z / sqrt(n) with two-sided P(|Z| > z) = FAMILY_ALPHA / n_tests. For the
    2^18 - 1 lags of one autocorrelation, z = 5.94 and the band is 0.0116."""
    z = stats.norm.isf(FAMILY_ALPHA / (2 * n_tests))
    return float(z) / math.sqrt(n)


def _flat(level_e: float = 1000.0) -> np.ndarray:
    return np.full(SHAPE, level_e)


def _expose(rng, backend, level_e: float = 1000.0) -> np.ndarray:
    return Sensor(FLAT, SHAPE).expose(_flat(level_e), EXPOSURE_S, rng, backend=backend).astype(np.float64)


def _autocorrelation(x: np.ndarray) -> np.ndarray:
    """Sample autocorrelation r(k), k = 0 .. n-1, of a 1-D series (biased estimator, the sum of
    products over the n - k overlapping pairs divided by n times the variance), via a
    zero-padded FFT (Wiener-Khinchin), so it is exact, not circular."""
    d = x - x.mean()
    n = d.size
    f = np.fft.rfft(d, 2 * n)
    acov = np.fft.irfft(f * np.conj(f), 2 * n)[:n]
    return acov / acov[0]


def _cross_correlation(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sample cross-correlation of two 1-D series at every lag -(n-1) .. n-1 (biased
    estimator, normalised by n sd_x sd_y), via a zero-padded FFT."""
    a, b = x - x.mean(), y - y.mean()
    n = a.size
    c = np.fft.irfft(np.fft.rfft(a, 2 * n) * np.conj(np.fft.rfft(b, 2 * n)), 2 * n)
    return c / (n * a.std() * b.std())


# ----------------------------------------------------------------------------- 1. autocorrelation
@pytest.mark.parametrize("level_e", [1000.0, 3.0], ids=["ptrs-1000e", "inversion-3e"])
def test_difference_autocorrelation_inside_white_noise_band_at_every_lag(backend, level_e):
    # 1000 e-: Poisson by transformed rejection (PTRS); 3 e-: by inversion (llvm path).
    rng = np.random.default_rng(20240515)
    diff = (_expose(rng, backend, level_e) - _expose(rng, backend, level_e)).ravel()
    r = _autocorrelation(diff)
    lags = np.arange(1, N_PX)
    band = _band(lags.size)  # every lag 1 .. N-1 tested: Bonferroni over 262143 lags, 5.94 sigma
    worst = int(lags[np.argmax(np.abs(r[lags]))])
    assert abs(r[worst]) < band, f"{backend}: |r| = {r[worst]:+.4f} at lag {worst} = {divmod(worst, SHAPE[1])} (rows, cols) > band {band:.4f}"
    # The lag of the defect report, tested alone (one pre-named lag: 4 sigma, P = 6e-5).
    assert abs(r[DEFECT_LAG]) < 4.0 / math.sqrt(N_PX), f"{backend}: r(5721) = {r[DEFECT_LAG]:+.4f}"


# ----------------------------------------------------------------------------- 2. spectral flatness
def _periodogram_ordinates(residual: np.ndarray) -> np.ndarray:
    """2-D periodogram |FFT|^2 / N at the Fourier frequencies whose ordinates are independent
    and exponential under white noise: ``rfft2`` columns 1 .. W/2 - 1 (all rows). Columns 0 and
    W/2 are left out: they hold conjugate pairs of each other (not independent) and the real,
    chi-square(1) ordinates (0, 0), (0, H/2), (H/2, 0), (H/2, H/2)."""
    p = np.abs(np.fft.rfft2(residual)) ** 2 / residual.size
    return p[:, 1 : residual.shape[1] // 2].ravel()


def test_noise_periodogram_is_exponential_and_flat(backend):
    rng = np.random.default_rng(1288)
    dn = _expose(rng, backend)
    # Expectation of one exposure: K mu + offset (no PRNU, no dark signal; round-half-up ADC is
    # unbiased). The sample mean is used in its place: it differs from it by ~0.05 DN and only
    # the left-out zero frequency sees a constant.
    ords = _periodogram_ordinates(dn - dn.mean())
    n = ords.size  # 512 * 255 = 130560 independent ordinates
    y = ords / ords.mean()

    # Shape: Kolmogorov-Smirnov against Exp(1). The scale estimated from the same ordinates
    # makes the test conservative (Lilliefors 1969, JASA 64, 387: KS for the exponential with
    # unknown mean): a correct generator fails with P < 1e-3.
    ks = stats.kstest(y, "expon")

    # Flatness: Wiener entropy (geometric / arithmetic mean) of exponential ordinates tends to
    # exp(-gamma) = 0.5615 (E[log Y] = -gamma for Y ~ Exp(1)). Its sampling sd, by the delta
    # method on mean(log Y) - log(mean(Y)): exp(-gamma) sqrt((pi^2/6 - 1) / n) = 0.0012 here
    # (Var log Y = pi^2/6, Var Y = 1, Cov(log Y, Y) = 1). Tolerance 5 sd (P = 6e-7).
    flatness = math.exp(np.mean(np.log(ords))) / ords.mean()
    expected = math.exp(-np.euler_gamma)
    sd = expected * math.sqrt((math.pi**2 / 6.0 - 1.0) / n)
    found = f"{backend}: KS D = {ks.statistic:.4f} (p = {ks.pvalue:.2e}), spectral flatness {flatness:.4f} (white: {expected:.4f} +- {sd:.4f})"
    assert ks.pvalue > 1e-3, "periodogram ordinates not exponential; " + found
    assert abs(flatness - expected) < 5.0 * sd, "periodogram not flat; " + found


# ----------------------------------------------------------------------------- 3. across frames
def test_frames_with_different_seeds_have_uncorrelated_noise(backend):
    expected_dn = FLAT.gain_dn_per_e * 1000.0 + FLAT.offset_dn
    r1 = (_expose(np.random.default_rng(101), backend) - expected_dn).ravel()
    r2 = (_expose(np.random.default_rng(102), backend) - expected_dn).ravel()
    c = _cross_correlation(r1, r2)
    band = _band(c.size)  # every lag -(N-1) .. N-1: Bonferroni over 524287 lags, 6.06 sigma
    worst = int(np.argmax(np.abs(c)))
    assert abs(c[worst]) < band, f"{backend}: cross-correlation {c[worst]:+.4f} at lag {worst if worst < N_PX else worst - 2 * N_PX} > band {band:.4f}"
    # Same pixel, other frame (lag 0), tested alone: 4 sigma, P = 6e-5.
    assert abs(c[0]) < 4.0 / math.sqrt(N_PX), f"{backend}: frame-to-frame correlation {c[0]:+.4f}"


def test_same_generator_state_gives_identical_dn(backend):
    sensor = Sensor(FLAT, SHAPE)
    e = _flat()
    a = sensor.expose(e, EXPOSURE_S, np.random.default_rng(7), backend=backend)
    b = sensor.expose(e, EXPOSURE_S, np.random.default_rng(7), backend=backend)
    c = sensor.expose(e, EXPOSURE_S, np.random.default_rng(8), backend=backend)
    assert np.array_equal(a, b)
    assert np.mean(a != c) > 0.9  # sd 26 DN: two independent draws agree ~1.1 % of the time


def test_llvm_path_draws_two_words_from_the_generator():
    # The frame key is two 64-bit words, as before the per-pixel streams were hashed: what a
    # caller draws after the sensor does not move.
    llvm_or_skip()
    used = np.random.default_rng(5)
    Sensor(FLAT, (16, 16)).expose(np.full((16, 16), 100.0), EXPOSURE_S, used, backend="llvm")
    ref = np.random.default_rng(5)
    ref.integers(0, 2**64, size=2, dtype=np.uint64, endpoint=False)
    assert used.integers(0, 2**63) == ref.integers(0, 2**63)


# ----------------------------------------------------------------------------- the hash
@pytest.mark.parametrize(
    ("key", "plain", "cipher"),
    [  # TEA known answers (32 cycles), as published with the reference C code and used by
        # Bouncy Castle's TeaTest: key words, plaintext words (v0, v1), ciphertext words.
        ((0, 0, 0, 0), (0, 0), (0x41EA3A0A, 0x94BAA940)),
        ((0, 0, 0, 0), (0x01020304, 0x05060708), (0x6A2F9CF3, 0xFCCF3C55)),
        ((0x01234567, 0x12345678, 0x23456789, 0x3456789A), (0, 0), (0x34E943B0, 0x900F5DCB)),
        ((0x01234567, 0x12345678, 0x23456789, 0x3456789A), (0x01020304, 0x05060708), (0x773DC179, 0x878A81C0)),
    ],
)
def test_tea_matches_published_test_vectors(key, plain, cipher):
    from skynav.renderer.sensor_jit import tea_encrypt

    got = tea_encrypt(np.uint32([plain[0]]), np.uint32([plain[1]]), key)
    assert [int(w[0]) for w in got] == list(cipher)
    if jit_backend.configure_llvm().available:  # the same code traced into a Dr.Jit kernel
        import drjit as dr
        from drjit.llvm import UInt32

        got = tea_encrypt(UInt32(plain[0]), UInt32(plain[1]), tuple(dr.opaque(UInt32, k) for k in key))
        assert [int(w[0]) for w in got] == list(cipher)
