"""The sensor model against the EMVA 1288 (Release 4.0 Linear) measurement methods.

The oracle is the standard's own characterisation procedure, run on simulated frames: the
photon-transfer method on flat-field pairs gives the system gain K, dark pairs at two exposure
times give the dark noise and the dark current, and averaged stacks give PRNU and DSNU. Exact
distributions are checked against scipy's Poisson pmf and chi-square laws.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy import stats

from skynav.renderer.detector import Sensor, SensorInputError, bloom_columns, fixed_patterns
from skynav.scenes.camera import SensorParams
from tests.renderer.conftest import cuda_or_skip, llvm_or_skip



# 16 bit and K < 1 DN/e-, so the ADC quantisation (1/12 DN^2) is negligible next to the
# dark noise (K sigma_d ~ 5.8 DN), and the full well sits below 2^16 - 1.
PTC = SensorParams(
    bit_depth=16,
    gain_dn_per_e=0.8,
    offset_dn=200.0,
    full_well_e=60000.0,
    read_noise_e=6.0,
    reset_noise_e=4.0,
    dark_current_e_per_s=40.0,
    dsnu_e_per_s=8.0,
    prnu_fraction=0.02,
    pattern_seed=7,
)
SHAPE = (256, 256)  # 65536 px: a variance from one pair is good to sqrt(2/65536) = 0.55 %


def _pair(sensor, level_e, t, rng, backend):
    e = np.full(sensor.shape, float(level_e))
    y1 = sensor.expose(e, t, rng, backend=backend).astype(np.float64)
    y2 = sensor.expose(e, t, rng, backend=backend).astype(np.float64)
    return 0.5 * (y1.mean() + y2.mean()), 0.5 * np.var(y1 - y2)  # EMVA 1288 mean and temporal variance


def test_photon_transfer_gain_read_noise_dark_current(backend):
    rng = np.random.default_rng(1288)
    s = Sensor(PTC, SHAPE)
    t = 0.05
    mu_d, var_d = _pair(s, 0.0, t, rng, backend)
    xs, ys = [], []
    for level in (500, 1000, 2000, 4000, 8000, 16000, 30000):  # < 70 % of the full well
        mu, var = _pair(s, level, t, rng, backend)
        xs.append(mu - mu_d)
        ys.append(var - var_d)
    xs, ys = np.array(xs), np.array(ys)
    K = float(np.sum(xs * ys) / np.sum(xs * xs))  # photon transfer: var_y - var_dark = K (mu_y - mu_dark)
    assert abs(K / PTC.gain_dn_per_e - 1) < 0.02  # EMVA gain accuracy asked for: 2 %
    # linearity of the mean: mu_y - mu_dark = K * mu_e (PRNU has mean 1)
    mean_gain = float(np.mean(fixed_patterns(PTC, SHAPE)[0]))
    levels = np.array([500, 1000, 2000, 4000, 8000, 16000, 30000.0])
    assert np.allclose(xs, PTC.gain_dn_per_e * levels * mean_gain, rtol=2e-3)

    # dark pairs at two exposure times: var_dark(t) = K^2 (sigma_d^2 + D t) + 1/12
    t1, t2 = 0.001, 1.0
    mu1, v1 = _pair(s, 0.0, t1, rng, backend)
    mu2, v2 = _pair(s, 0.0, t2, rng, backend)
    v0 = v1 - (v2 - v1) * t1 / (t2 - t1)  # extrapolated to zero exposure
    sigma_d = math.sqrt(v0 - 1.0 / 12.0) / K
    assert abs(sigma_d / math.hypot(PTC.read_noise_e, PTC.reset_noise_e) - 1) < 0.05
    dark_rate = (mu2 - mu1) / (K * (t2 - t1))
    assert abs(dark_rate / PTC.dark_current_e_per_s - 1) < 0.05
    # dark-current shot noise: the variance grows by K^2 D (t2 - t1)
    assert abs((v2 - v1) / (K * K * (t2 - t1)) / PTC.dark_current_e_per_s - 1) < 0.1


def _stack(sensor, level_e, t, L, rng, backend):
    e = np.full(sensor.shape, float(level_e))
    frames = np.stack([sensor.expose(e, t, rng, backend=backend).astype(np.float64) for _ in range(L)])
    mean_img = frames.mean(axis=0)
    temporal_var = float(np.mean(frames.var(axis=0, ddof=1)))
    # EMVA 1288: spatial variance of the averaged image, less the temporal part left after averaging
    return float(mean_img.mean()), float(np.var(mean_img, ddof=1)) - temporal_var / L


def test_prnu_and_dsnu_from_averaged_stacks(backend):
    rng = np.random.default_rng(8)
    s = Sensor(PTC, (128, 128))
    L, t = 16, 1.0
    mu_dark, s2_dark = _stack(s, 0.0, t, L, rng, backend)
    mu_bright, s2_bright = _stack(s, 20000.0, t, L, rng, backend)
    K = PTC.gain_dn_per_e
    dsnu = math.sqrt(s2_dark) / K / t
    prnu = math.sqrt(s2_bright - s2_dark) / (mu_bright - mu_dark)
    assert abs(dsnu / PTC.dsnu_e_per_s - 1) < 0.10
    assert abs(prnu / PTC.prnu_fraction - 1) < 0.10


def test_fixed_patterns_have_configured_moments():
    gain, dark = fixed_patterns(PTC, SHAPE)
    assert gain.dtype == np.float32 and not gain.flags.writeable
    n = gain.size  # sample moments of n iid draws: relative std of a std is ~ 1/sqrt(2n) = 0.3 %
    assert abs(gain.mean() - 1) < 5 * PTC.prnu_fraction / math.sqrt(n)
    assert abs(gain.std() / PTC.prnu_fraction - 1) < 0.015
    assert abs(dark.mean() / PTC.dark_current_e_per_s - 1) < 0.005
    assert abs(dark.std() / PTC.dsnu_e_per_s - 1) < 0.015
    assert dark.min() >= 0
    # same seed -> same pattern; another seed -> another pattern
    assert np.array_equal(fixed_patterns(dataclasses.replace(PTC, read_noise_e=1.0), SHAPE)[0], gain)
    assert not np.array_equal(fixed_patterns(dataclasses.replace(PTC, pattern_seed=8), SHAPE)[0], gain)


def test_per_pixel_variance_chi_square(backend):
    # (N-1) s^2 / sigma^2 summed over pixels ~ chi2(P (N-1)), sigma^2 = K^2 (mu_e + sigma_d^2) + 1/12
    rng = np.random.default_rng(99)
    shape, N, t = (24, 24), 150, 0.1
    s = Sensor(PTC, shape)
    e = np.exp(np.random.default_rng(3).uniform(0, np.log(20000), shape)) - 1  # 0 .. 20000 e-
    frames = np.stack([s.expose(e, t, rng, backend=backend).astype(np.float64) for _ in range(N)])
    mean_e = e * s.prnu_gain + s.dark_e_per_s * t
    K = PTC.gain_dn_per_e
    sigma2 = K * K * (mean_e + s.dark_noise_e**2) + 1.0 / 12.0
    stat = float(np.sum((N - 1) * frames.var(axis=0, ddof=1) / sigma2))
    dof = e.size * (N - 1)
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], dof)
    assert lo < stat < hi, (stat, dof)
    # and the means: E[DN] = K mu_e + offset (round half up is unbiased)
    z = (frames.mean(axis=0) - (K * mean_e + PTC.offset_dn)) / np.sqrt(sigma2 / N)
    assert abs(z.mean()) < 4 / math.sqrt(e.size) and 0.85 < z.std() < 1.15


PURE = SensorParams(bit_depth=16, gain_dn_per_e=1.0, offset_dn=0.0, full_well_e=60000.0, read_noise_e=0.0, reset_noise_e=0.0, dark_current_e_per_s=0.0, dsnu_e_per_s=0.0, prnu_fraction=0.0)


@pytest.mark.parametrize("lam", [0.3, 2.5, 9.9, 10.0, 17.3, 150.0, 4000.0])
def test_shot_noise_against_scipy_poisson_pmf(backend, lam):
    # noise-free readout, K = 1: DN is the Poisson charge itself. Pearson chi-square goodness of
    # fit against scipy.stats.poisson; bins with expected count < 5 are pooled into the tails.
    s = Sensor(PURE, (256, 256))
    dn = s.expose(np.full(s.shape, lam), 1.0, np.random.default_rng(int(lam * 10)), backend=backend).ravel()
    n = dn.size
    k = np.arange(int(stats.poisson.ppf(1e-9, lam)), int(stats.poisson.isf(1e-9, lam)) + 1)
    expected = n * stats.poisson.pmf(k, lam)
    keep = expected >= 5
    lo_k, hi_k = k[keep][0], k[keep][-1]
    obs = np.array([np.sum(dn < lo_k + 1) if kk == lo_k else np.sum(dn >= hi_k) if kk == hi_k else np.sum(dn == kk) for kk in k[keep]], float)
    exp = expected[keep].copy()
    exp[0] = n * stats.poisson.cdf(lo_k, lam)
    exp[-1] = n * stats.poisson.sf(hi_k - 1, lam)
    chi2 = float(np.sum((obs - exp) ** 2 / exp))
    p = stats.chi2.sf(chi2, len(obs) - 1)
    assert p > 1e-4, (lam, chi2, len(obs))


def test_jit_read_noise_erfinv_against_math_erf(jit_backend_name):
    """The read noise's inverse error function (Giles 2010, its tail polynomial only in the packets
    that need it) inverts ``math.erf``: over 200,000 points of (-1, 1) and 4,000 in the tails down
    to 1 - x = 6e-8, erf(erfinv(x)) is within 2e-7 of x, and z within 4e-7 (relative) of the exact
    inverse, the single-precision accuracy the paper states (a wrong tail branch or coefficient
    is off by 1e-3 or more). On each Dr.Jit backend: the CUDA kernel takes the GPU's log."""
    import drjit as dr

    from skynav.renderer.sensor_jit import _jit_erfinv, _jit_module

    Float = _jit_module(jit_backend_name).Float

    tails = 1.0 - np.logspace(-7.2, -1.0, 2000)
    x = np.concatenate([np.linspace(-0.999999, 0.999999, 200001), tails, -tails]).astype(np.float32)
    z = _jit_erfinv(Float(x))
    dr.eval(z)
    z = z.numpy().astype(np.float64)
    err = np.array([math.erf(v) for v in z]) - x.astype(np.float64)
    assert np.abs(err).max() < 2e-7
    dz = np.abs(err) / (2.0 / math.sqrt(math.pi) * np.exp(-z * z))  # error of z: d erf / dz
    assert np.max(dz / np.maximum(np.abs(z), 1e-12)) < 4e-7


@pytest.mark.gpu
def test_cuda_and_llvm_kernels_draw_the_same_streams():
    """Two implementations of one kernel (Dr.Jit traces the same Python for the CPU and the GPU)
    with the same frame key: the PCG32 streams are the same integers, so a DN can differ only
    where the GPU's log/exp/sqrt round differently from the CPU's and the difference crosses an
    ADC step or flips a Poisson acceptance. At dark, shot-noise-dominated and bright levels (the
    inversion and PTRS paths both), at least 99.9 % of the pixels carry the same DN and the frames'
    means agree to 0.01 DN; a tolerance, as between any two implementations."""
    llvm_or_skip()
    cuda_or_skip()
    params = dataclasses.replace(PTC, gain_dn_per_e=0.25, read_noise_e=2.0, reset_noise_e=1.0)
    s = Sensor(params, (256, 256))
    for i, level in enumerate((0.0, 4.0, 60.0, 3000.0)):
        e = np.full(s.shape, level)
        a = s.expose(e, 0.2, np.random.default_rng(40 + i), backend="llvm").astype(np.int64)
        b = s.expose(e, 0.2, np.random.default_rng(40 + i), backend="cuda").astype(np.int64)
        same = float(np.mean(a == b))
        assert same >= 0.999, (level, same)
        assert abs(a.mean() - b.mean()) < 0.01, (level, a.mean(), b.mean())


def test_numpy_and_jit_statistics_agree(jit_backend_name):
    # two-sample chi-square homogeneity test on DN histograms of the full chain at several levels
    params = dataclasses.replace(PTC, gain_dn_per_e=0.25, read_noise_e=2.0, reset_noise_e=1.0)
    s = Sensor(params, (128, 128))
    for i, level in enumerate((0.0, 4.0, 60.0, 3000.0)):
        a = s.expose(np.full(s.shape, level), 0.2, np.random.default_rng(10 + i), backend="numpy").ravel()
        b = s.expose(np.full(s.shape, level), 0.2, np.random.default_rng(20 + i), backend=jit_backend_name).ravel()
        edges = np.unique(np.quantile(np.concatenate([a, b]), np.linspace(0, 1, 41)))
        edges[-1] += 1
        ca, _ = np.histogram(a, edges)
        cb, _ = np.histogram(b, edges)
        table = np.array([ca, cb])
        table = table[:, table.sum(axis=0) > 0]
        p = stats.chi2_contingency(table).pvalue
        assert p > 1e-4, (level, p)


def test_saturation_and_full_well(backend):
    # paper camera: 8 bit, K = 255/20000 DN/e-: a full well maps above 255 -> exactly 255
    s = Sensor(SensorParams(), (32, 32))
    e = np.zeros(s.shape)
    e[:16] = 1e6
    dn = s.expose(e, 0.4, np.random.default_rng(5), backend=backend)
    assert dn.dtype == np.uint8
    assert np.all(dn[:16] == 255)
    assert dn.max() <= 255
    # 12 bit with headroom: clipped pixels hold exactly the full well; their DN carries only the
    # dark noise (no shot noise left) around K FW + offset
    p12 = SensorParams(bit_depth=12, gain_dn_per_e=0.05, offset_dn=10.0, full_well_e=20000.0, read_noise_e=8.0, reset_noise_e=0.0)
    s = Sensor(p12, (64, 64))
    d = s.expose_details(np.full(s.shape, 1e7), 0.1, np.random.default_rng(6), backend=backend)
    assert np.all(d.charge_e == p12.full_well_e)
    assert d.dn.dtype == np.uint16
    y = d.dn.astype(float)
    assert abs(y.mean() - (0.05 * 20000 + 10)) < 0.05  # 4096 px, sigma = 0.4 DN -> 4 sigma = 0.025
    # DN never exceeds 2^bits - 1 even far above the full well / with a large gain
    p_hot = dataclasses.replace(p12, gain_dn_per_e=5.0)
    dn = Sensor(p_hot, (8, 8)).expose(np.full((8, 8), 1e9), 1.0, np.random.default_rng(0), backend=backend)
    assert np.all(dn == 4095)


def test_blooming_conserves_charge(backend):
    fw = 1000.0
    p = SensorParams(bit_depth=16, gain_dn_per_e=1.0, offset_dn=0.0, full_well_e=fw, read_noise_e=0.0, reset_noise_e=0.0, dark_current_e_per_s=0.0, dsnu_e_per_s=0.0, prnu_fraction=0.0, blooming=True)
    s = Sensor(p, (40, 6))
    e = np.zeros(s.shape)
    extra = np.zeros(s.shape)
    extra[20, 2] = 7.5 * fw  # deterministic charge (no shot noise on extra charge)
    extra[1, 4] = 3.2 * fw  # near the top edge
    extra[:, 5] = 2 * fw  # a full column: the excess is lost, every pixel full
    d = s.expose_details(e, 1.0, np.random.default_rng(0), backend=backend, extra_charge_e=extra)
    c = d.charge_e
    assert c.max() <= fw
    assert c[:, 2].sum() == pytest.approx(7.5 * fw) and c[:, 4].sum() == pytest.approx(3.2 * fw)
    assert np.all(c[:, 5] == fw)
    full = np.flatnonzero(c[:, 2] == fw)
    assert len(full) == 7 and np.all(np.diff(full) == 1) and full[0] <= 20 <= full[-1]
    assert np.array_equal(d.dn, np.floor(c + 0.5).astype(np.uint16))
    # without blooming the same input is clipped
    d2 = Sensor(dataclasses.replace(p, blooming=False), s.shape).expose_details(e, 1.0, np.random.default_rng(0), backend=backend, extra_charge_e=extra)
    assert d2.charge_e[:, 2].sum() == fw


def test_bloom_columns_against_direct_count():
    rng = np.random.default_rng(4)
    charge = rng.uniform(0, 900, (50, 30))
    charge[rng.integers(0, 50, 40), rng.integers(0, 30, 40)] += rng.uniform(0, 8000, 40)
    out = bloom_columns(charge, 1000.0)
    assert out.max() <= 1000.0
    np.testing.assert_allclose(out.sum(axis=0), charge.sum(axis=0), rtol=1e-12)  # no column fills up
    untouched = ~(charge > 1000.0).any(axis=0)
    assert np.array_equal(out[:, untouched], charge[:, untouched])


def test_same_seed_same_bits(backend):
    s = Sensor(PTC, (64, 48))
    e = np.random.default_rng(2).uniform(0, 50000, s.shape)
    a = s.expose(e, 0.3, np.random.default_rng(11), backend=backend)
    b = s.expose(e, 0.3, np.random.default_rng(11), backend=backend)
    c = s.expose(e, 0.3, np.random.default_rng(12), backend=backend)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    d = s.expose_details(e, 0.3, np.random.default_rng(11), backend=backend)
    assert np.array_equal(d.dn, a) and d.backend == backend


def test_replayed_kernel_gives_the_traced_bits(jit_backend_name):
    """Without blooming the LLVM chain is one Dr.Jit frozen function: its first call of an input
    layout records the kernel, the later ones replay it with new inputs. Each must give the bits
    of the same chain traced afresh (``expose_details`` traces it every call; same code, same
    seed), across bit depths (UInt8 or UInt32 out), sizes, exposures, gains and extra charge,
    on each Dr.Jit backend."""
    rng = np.random.default_rng(4)
    for bits, shape in ((8, (64, 48)), (12, (64, 48)), (8, (30, 70)), (12, (30, 70))):
        for k in range(3):  # the first call records, the next ones replay
            params = dataclasses.replace(PTC, bit_depth=bits, gain_dn_per_e=float(rng.uniform(0.01, 0.3)))
            s = Sensor(params, shape)
            e = rng.uniform(0, 300 * (k + 1), shape)
            extra = None if k == 1 else np.where(rng.random(shape) < 0.01, 5000.0, 0.0)
            t = float(rng.uniform(0.05, 1.0))
            a = s.expose(e, t, np.random.default_rng(100 + k), backend=jit_backend_name, extra_charge_e=extra)
            d = s.expose_details(e, t, np.random.default_rng(100 + k), backend=jit_backend_name, extra_charge_e=extra)
            assert a.dtype == s.dtype and np.array_equal(a, d.dn), (bits, shape, k)


@pytest.mark.parametrize("bits", [8, 12])
def test_pixel_charge_is_its_image(backend, bits):
    """Extra charge given as a few pixels (``PixelCharge``: repeated pixels, corners, a pixel at
    full well) is the frame its image gives, to the bit: the numpy path adds the same image; the
    LLVM path runs the same chain on the pixels hit, from their own streams (same code, same
    seed). ``expose_details`` (the traced path) agrees too."""
    from skynav.renderer.detector import PixelCharge

    s = Sensor(dataclasses.replace(PTC, bit_depth=bits, gain_dn_per_e=0.05 if bits == 8 else 0.8, offset_dn=10.0), (40, 56))
    e = np.random.default_rng(1).uniform(0, 400, s.shape)
    index = np.array([0, 57, 57, 2239, 1000, 1000, 1000, 56 * 20 + 7])
    charge = np.array([300.0, 1e3, 2.5e3, 7.0, 1e5, 0.5, 3.0, 0.0])
    pc = PixelCharge(index=index, electrons=charge)
    image = np.zeros(s.shape)
    np.add.at(image.reshape(-1), index, charge)
    assert np.array_equal(pc.dense(s.shape), image)
    a = s.expose(e, 0.2, np.random.default_rng(9), backend=backend, extra_charge_e=pc)
    b = s.expose(e, 0.2, np.random.default_rng(9), backend=backend, extra_charge_e=image)
    c = s.expose_details(e, 0.2, np.random.default_rng(9), backend=backend, extra_charge_e=pc).dn
    assert np.array_equal(a, b) and np.array_equal(a, c)
    assert not np.array_equal(a, s.expose(e, 0.2, np.random.default_rng(9), backend=backend))  # the charge shows
    assert np.array_equal(s.expected_dn(e, 0.2, extra_charge_e=pc), s.expected_dn(e, 0.2, extra_charge_e=image))
    for bad, match in ((PixelCharge(index=np.array([2240]), electrons=np.array([1.0])), r"index must be in \[0, 2240\)"),
                       (PixelCharge(index=np.array([-1]), electrons=np.array([1.0])), r"index must be in"),
                       (PixelCharge(index=np.array([3]), electrons=np.array([np.nan])), "finite and >= 0"),
                       (PixelCharge(index=np.array([3.0]), electrons=np.array([1.0])), "index integer"),
                       (PixelCharge(index=np.array([3, 4]), electrons=np.array([1.0])), "one length")):
        with pytest.raises(SensorInputError, match=match):
            s.expose(e, 0.2, np.random.default_rng(9), backend=backend, extra_charge_e=bad)


def test_bad_inputs():
    s = Sensor(PTC, (4, 4))
    rng = np.random.default_rng(0)
    with pytest.raises(SensorInputError, match="shape"):
        s.expose(np.zeros((4, 5)), 0.1, rng)
    with pytest.raises(SensorInputError, match="exposure_s"):
        s.expose(np.zeros((4, 4)), -1.0, rng)
    with pytest.raises(SensorInputError, match=">= 0"):
        s.expose(np.full((4, 4), -1.0), 0.1, rng)
    for bad in (np.nan, np.inf, -np.inf):  # one bad pixel among good ones, in either input
        img = np.ones((4, 4))
        img[2, 1] = bad
        with pytest.raises(SensorInputError, match="^electrons must be finite and >= 0"):
            s.expose(img, 0.1, rng)
        with pytest.raises(SensorInputError, match="^extra_charge_e must be finite and >= 0"):
            s.expose(np.ones((4, 4)), 0.1, rng, extra_charge_e=img)
    with pytest.raises(SensorInputError, match="backend"):
        s.expose(np.zeros((4, 4)), 0.1, rng, backend="opencl")
    with pytest.raises(SensorInputError, match="Generator"):
        s.expose(np.zeros((4, 4)), 0.1, 42)


def test_sensor_value_semantics():
    import pickle

    s = Sensor(PTC, (4, 6))
    assert eval(repr(s), {"Sensor": Sensor, "SensorParams": SensorParams}) == s
    t = pickle.loads(pickle.dumps(s))
    assert t == s and hash(t) == hash(s)
    assert s != Sensor(PTC, (6, 4))


def test_expected_dn_is_the_mean_of_the_noisy_chain():
    s = Sensor(PTC, (32, 32))
    e = np.random.default_rng(1).uniform(0, 40000, s.shape)
    e[0, :4] = 1e6  # above the full well
    exp_dn = s.expected_dn(e, 0.2)
    assert exp_dn.dtype == np.uint16
    frames = np.stack([s.expose(e, 0.2, np.random.default_rng(k), backend="numpy").astype(float) for k in range(40)])
    K = PTC.gain_dn_per_e
    mean_e = np.minimum(e * s.prnu_gain + s.dark_e_per_s * 0.2, PTC.full_well_e)
    sd = np.sqrt((K * K * (mean_e + s.dark_noise_e**2) + 1 / 12) / 40)  # standard error of the mean
    assert np.all(np.abs(frames.mean(axis=0) - exp_dn) < 5 * sd + 0.5)  # +0.5: expected_dn is rounded
    assert np.all(exp_dn[0, :4] == np.floor(K * PTC.full_well_e + PTC.offset_dn + 0.5))
