"""The camera sensor: expected electrons -> digital numbers (EMVA 1288 linear model, extended).

The chain (EMVA Standard 1288, Release 4.0 Linear, Sect. 2 "Sensor model"; notation there:
``mu_p`` photons, ``mu_e`` electrons, ``mu_d`` dark electrons, ``K`` system gain, ``sigma_d``
dark noise, ``sigma_q`` quantisation noise):

1. **Response non-uniformity (PRNU)**: ``mu_e = electrons * g``, with a fixed gain map
   ``g = 1 + prnu_fraction * N(0, 1)`` (EMVA 1288 Sect. 8, "spatial non-uniformity": PRNU is the
   relative standard deviation of the photo-response).
2. **Dark current with DSNU**: ``mu_d = D * exposure_s``, with a fixed per-pixel dark-current
   map ``D`` of mean ``dark_current_e_per_s`` and spatial standard deviation ``dsnu_e_per_s``. ``D``
   is drawn from a gamma distribution with exactly that mean and standard deviation: it is
   non-negative and right-skewed like real dark-current maps (warm pixels), unlike a clipped
   normal. DSNU is quoted in e-/s so it scales with exposure, as in EMVA 1288 Sect. 8.
3. **Shot noise**: collected charge ``n ~ Poisson(mu_e + mu_d)`` (EMVA 1288 Sect. 2.1: photon and
   dark-current shot noise, variance = mean).
4. **Extra charge** (optional, e.g. cosmic rays, :mod:`skynav.renderer.cosmic_rays`): added here,
   after the shot noise, because a particle's deposit has its own statistics and is not
   Poisson-scaled with the optical signal.
5. **Full well**: ``n = min(n, full_well_e)``; with ``blooming=True`` the excess charge spills
   along the column, half up and half down, conserving charge until the whole column is full
   (:func:`bloom_columns`).
6. **Dark (read + reset) noise**: ``+ N(0, sigma_d)``, ``sigma_d^2 = read_noise_e^2 +
   reset_noise_e^2``: the kTC reset noise and the read-out noise are independent zero-mean
   Gaussians added in quadrature (EMVA 1288 Sect. 2.2 lumps them into ``sigma_d``).
7. **Gain and offset**: ``y = K (n + noise) + offset_dn`` (EMVA 1288 Eq. for ``mu_y``).
8. **ADC**: round half up, ``DN = floor(y + 0.5)``, so that the mean DN is unbiased,
   ``E[DN] = K mu + offset`` and the quantisation noise is the uniform ``sigma_q^2 = 1/12 DN^2`` of
   EMVA 1288 Sect. 2.3; then clipped to ``[0, 2^bit_depth - 1]`` (saturation).

Two interchangeable implementations with identical statistics (not identical bits):

- ``backend="numpy"``: ``Generator.poisson`` (exact; PTRS above mean 10) and
  ``Generator.normal``; float64.
- ``backend="llvm"`` or ``"cuda"``: one fused Dr.Jit kernel (float32), traced from the same
  Python code for Dr.Jit's LLVM (CPU) or CUDA (GPU) backend. Poisson exact too: sequential
  inversion for means < 10 and Hoermann's PTRS transformed rejection (Hoermann 1993, "The
  transformed rejection method for generating Poisson random variables", Insurance: Mathematics
  and Economics 12, 39-45) above -- the same split numpy uses -- with the log-pmf of the
  acceptance test in Stirling form (error < 3e-4 in log-probability at k = 0, < 1e-7 for k > 10).
  Gaussians by inverse-erf of one uniform. Random streams: PCG32 (O'Neill 2014), one stream
  per pixel, whose state and sequence are both a hash of (frame key, pixel index)
  (:func:`pixel_stream_seeds`, as Mitsuba seeds its samplers): the frame key is 128 bits drawn
  from the caller's ``numpy.random.Generator`` (:func:`frame_key`), the hash is the TEA block
  cipher keyed with it, computed inside the kernel. The same Generator state gives
  bit-identical frames on the same backend (LLVM and CUDA draw the same PCG32 integers, but
  their transcendental functions may round differently), and the pixels' streams are unrelated. (Up to
  package version 0.2, pixel ``i`` had state ``s + i`` and sequence ``q + i``, Dr.Jit's
  ``PCG32(size, s, q)``: those streams are correlated, and the difference of two flat fields
  had an autocorrelation of +0.24 at lag 11 rows + 89 columns of a 512-px-wide image.) Every
  per-frame number (gain, frame key, exposure ...) enters the kernel as an opaque variable, so
  the kernel is compiled once and reused across frames, sensors and exposures. The inversion
  runs in float64 (the rest in float32): float32 pmf sums stall a few ulp below 1 and would
  return a spurious far-tail value about once per 10^7 pixels. A normal approximation above a
  threshold was not needed: PTRS costs a constant ~2 draws per pixel whatever the mean, and is
  exact.
"""

from __future__ import annotations

import functools
import math
import threading
from dataclasses import dataclass

import numpy as np

from skynav.scenes.camera import SensorParams

from . import jit_backend
from .errors import SensorInputError  # noqa: F401  (re-exported: the sensor raises it)

POISSON_INVERSION_MAX_MEAN = 10.0
"""Below this mean the Dr.Jit path samples Poisson by sequential inversion, above by PTRS."""

JIT_BACKENDS = ("llvm", "cuda")
"""The sensor backends that run the fused Dr.Jit kernel (CPU and GPU)."""

_INVERSION_MAX_K = 200  # cap of the inversion loop: P(K > 200 | mean < 10) ~ 1e-200
#: pmf terms per trip of the inversion loop (see _jit_charge); 200 is 25 trips of 8. The terms,
#: their sums and the comparisons are the same whatever the count (so are the bits); fewer trips
#: cost less loop overhead; 8 is among the fastest counts measured (docs/performance.md).
_INVERSION_TERMS_PER_TRIP = 8


@dataclass(frozen=True, kw_only=True)
class ExposureDetails:
    """Intermediates of one exposure.

    Attributes
    ----------
    dn : ndarray, shape (H, W), uint8 or uint16
        Digital numbers.
    mean_e : ndarray, shape (H, W), float
        Expected collected charge ``electrons * PRNU + dark_rate * exposure_s``, e-.
    charge_e : ndarray, shape (H, W), float
        Collected charge after shot noise, extra charge and full-well clipping / blooming, e-.
    backend : str
        ``"numpy"``, ``"llvm"`` or ``"cuda"``.

    Examples
    --------
    >>> from skynav.renderer import Sensor
    >>> from skynav.scenes import SensorParams
    >>> sensor = Sensor(SensorParams(bit_depth=12, gain_dn_per_e=0.1), (4, 5))
    >>> d = sensor.expose_details(np.full((4, 5), 1000.0), 0.1, np.random.default_rng(0), backend="numpy")
    >>> d.backend, d.dn.dtype.name, d.charge_e.shape
    ('numpy', 'uint16', (4, 5))
    >>> bool(abs(d.mean_e.mean() - 1000.5) < 15)   # 1000 e- x PRNU (1 %) + 5 e-/s x 0.1 s
    True
    """

    dn: np.ndarray
    mean_e: np.ndarray
    charge_e: np.ndarray
    backend: str


@dataclass(frozen=True, eq=False)
class PixelCharge:
    """Charge on a few pixels, for :meth:`Sensor.expose`'s ``extra_charge_e`` (cosmic-ray hits).

    The same charge as the image ``np.add.at(np.zeros(shape).ravel(), index, electrons)`` (a
    repeated index adds up, in order), without the full-size image: the LLVM path then reads no
    charge image and computes the few pixels hit in a kernel of their own.

    Attributes
    ----------
    index : ndarray of int, shape (M,)
        Flat (row-major) pixel indices.
    electrons : ndarray of float, shape (M,)
        Charge added to each, e-.
    """

    index: np.ndarray
    electrons: np.ndarray

    def per_pixel(self) -> tuple[np.ndarray, np.ndarray]:
        """(distinct pixel indices, ascending; their charge summed in order from 0.0, float64)."""
        u, inv = np.unique(np.asarray(self.index, dtype=np.int64), return_inverse=True)
        total = np.zeros(u.size)
        np.add.at(total, inv.ravel(), np.asarray(self.electrons, dtype=float))
        return u, total

    def dense(self, shape) -> np.ndarray:
        """The charge image, shape ``shape``, float64."""
        out = np.zeros(int(np.prod(shape)))
        u, total = self.per_pixel()
        out[u] = total
        return out.reshape(shape)


# --------------------------------------------------------------------------- fixed patterns
@functools.lru_cache(maxsize=4)
def fixed_patterns(params: SensorParams, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """PRNU gain map and dark-current map of a sensor, drawn once from ``params.pattern_seed``.

    Parameters
    ----------
    params : SensorParams
        The sensor (``prnu_fraction``, ``dark_current_e_per_s``, ``dsnu_e_per_s``,
        ``pattern_seed``).
    shape : tuple (H, W)
        Image size, px.

    Returns
    -------
    prnu_gain : ndarray, shape (H, W), float32, read-only
        Relative response, mean 1, standard deviation ``prnu_fraction`` (clipped at 0).
    dark_e_per_s : ndarray, shape (H, W), float32, read-only
        Dark current, e-/s: gamma distributed with mean ``dark_current_e_per_s`` and standard
        deviation ``dsnu_e_per_s`` (constant if either is 0).

    References
    ----------
    EMVA Standard 1288 (release 4.0, 2021), Sect. 8 (spatial non-uniformity: PRNU, DSNU).

    Examples
    --------
    >>> from skynav.renderer import fixed_patterns
    >>> from skynav.scenes import SensorParams
    >>> gain, dark = fixed_patterns(SensorParams(), (64, 64))   # 1 % PRNU, 5 +- 1 e-/s
    >>> round(float(gain.mean()), 2), round(float(gain.std()), 3), round(float(dark.mean()), 1)
    (1.0, 0.01, 5.0)
    >>> fixed_patterns(SensorParams(), (64, 64))[0] is gain   # drawn once per sensor
    True
    """
    prnu_ss, dsnu_ss = np.random.SeedSequence(params.pattern_seed).spawn(2)
    gain = 1.0 + params.prnu_fraction * np.random.default_rng(prnu_ss).standard_normal(shape)
    np.maximum(gain, 0.0, out=gain)
    mu, sd = params.dark_current_e_per_s, params.dsnu_e_per_s
    if mu > 0 and sd > 0:
        k_shape = (mu / sd) ** 2  # gamma: mean = k theta, var = k theta^2
        dark = np.random.default_rng(dsnu_ss).gamma(k_shape, sd * sd / mu, shape)
    else:
        dark = np.full(shape, mu)
    gain = gain.astype(np.float32)
    dark = dark.astype(np.float32)
    gain.flags.writeable = False
    dark.flags.writeable = False
    return gain, dark


@functools.lru_cache(maxsize=2)
def _fixed_patterns_f64(params: SensorParams, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """:func:`fixed_patterns` as float64 (the numpy path's), read-only, converted once."""
    out = tuple(a.astype(np.float64) for a in fixed_patterns(params, shape))
    for a in out:
        a.flags.writeable = False
    return out


# --------------------------------------------------------------------------- blooming
def bloom_columns(charge_e: np.ndarray, full_well_e: float) -> np.ndarray:
    """Spill charge above the full well along columns, conserving it until a column is full.

    A run of full pixels holding excess charge passes the excess to the pixels just above and
    below the run, half each (all of it to one side at the sensor edge); the run grows until the
    excess is absorbed. Charge is lost only when an entire column is full.

    Parameters
    ----------
    charge_e : ndarray, shape (H, W)
        Collected charge, e- (not modified).
    full_well_e : float

    Returns
    -------
    ndarray, shape (H, W), float64
        Charge after blooming; every pixel <= ``full_well_e``.
    """
    out = np.array(charge_e, dtype=np.float64, copy=True)
    fw = float(full_well_e)
    cols = np.flatnonzero((out > fw).any(axis=0))
    for c in cols:
        v = out[:, c].copy()
        n = v.size
        while True:
            over = np.flatnonzero(v > fw)
            if over.size == 0:
                break
            lo = hi = int(over[0])
            while lo > 0 and v[lo - 1] >= fw:
                lo -= 1
            while hi < n - 1 and v[hi + 1] >= fw:
                hi += 1
            excess = float(np.sum(v[lo : hi + 1] - fw))
            v[lo : hi + 1] = fw
            up, down = lo > 0, hi < n - 1
            if up and down:
                v[lo - 1] += 0.5 * excess
                v[hi + 1] += 0.5 * excess
            elif up:
                v[lo - 1] += excess
            elif down:
                v[hi + 1] += excess
            else:
                break  # the whole column is full: the excess drains away
        out[:, c] = v
    return out


# --------------------------------------------------------------------------- the sensor
class Sensor:
    """An image sensor with its fixed patterns.

    Parameters
    ----------
    params : SensorParams
        EMVA 1288 parameters (``skynav.scenes.camera``).
    shape : tuple (H, W)
        Image size, px.

    References
    ----------
    EMVA Standard 1288 (release 4.0, 2021), Sect. 2 (the linear sensor model; the chain is in
    the module's docstring).

    Examples
    --------
    >>> from skynav.renderer import Sensor
    >>> from skynav.scenes import SensorParams
    >>> sensor = Sensor(SensorParams(bit_depth=12, gain_dn_per_e=0.1), (4, 5))
    >>> dn = sensor.expose(np.full((4, 5), 1000.0), 0.1, np.random.default_rng(1), backend="numpy")
    >>> dn.dtype, dn.shape
    (dtype('uint16'), (4, 5))
    """

    def __init__(self, params: SensorParams, shape: tuple[int, int]):
        if not isinstance(params, SensorParams):
            raise SensorInputError(f"params must be a SensorParams, got {type(params).__name__}")
        shape = tuple(int(s) for s in shape)
        if len(shape) != 2 or min(shape) < 1:
            raise SensorInputError(f"shape must be (H, W) with H, W >= 1, got {shape}")
        self.params = params
        self.shape: tuple[int, int] = shape
        self._jit_patterns = {}   # per Dr.Jit backend: the PRNU and dark-current images

    def __repr__(self) -> str:
        return f"Sensor({self.params!r}, {self.shape!r})"

    def __eq__(self, other) -> bool:
        return isinstance(other, Sensor) and (self.params, self.shape) == (other.params, other.shape)

    def __hash__(self) -> int:
        return hash((self.params, self.shape))

    def __getstate__(self):
        return {"params": self.params, "shape": self.shape}

    def __setstate__(self, state):
        self.__init__(state["params"], state["shape"])

    @property
    def prnu_gain(self) -> np.ndarray:
        """PRNU gain map, shape (H, W), float32 (see :func:`fixed_patterns`)."""
        return fixed_patterns(self.params, self.shape)[0]

    @property
    def dark_e_per_s(self) -> np.ndarray:
        """Dark-current map, e-/s, shape (H, W), float32 (see :func:`fixed_patterns`)."""
        return fixed_patterns(self.params, self.shape)[1]

    @property
    def dark_noise_e(self) -> float:
        """``sigma_d = sqrt(read_noise_e^2 + reset_noise_e^2)``, e-."""
        return math.hypot(self.params.read_noise_e, self.params.reset_noise_e)

    @property
    def dtype(self):
        """uint8 for bit depth <= 8, else uint16 (docs/conventions.md PNG rule)."""
        return np.uint8 if self.params.bit_depth <= 8 else np.uint16

    # ----------------------------------------------------------------- public entry points
    def expose(self, electrons, exposure_s: float, rng: np.random.Generator, *, backend: str = "auto", extra_charge_e=None) -> np.ndarray:
        """Digital numbers of one exposure.

        Parameters
        ----------
        electrons : array_like, shape (H, W)
            Expected photo-electrons per pixel (noise-free, before PRNU), e-.
        exposure_s : float
            Exposure time (scales the dark current), s.
        rng : numpy.random.Generator
            Source of all randomness; the same state gives the same frame on one backend.
        backend : {"auto", "llvm", "cuda", "numpy"}
            ``auto``: :func:`jit_backend.auto_sensor_backend` (the Dr.Jit LLVM kernel where
            that backend works here, else the CUDA one where a GPU works, else numpy).
        extra_charge_e : array_like, shape (H, W), or PixelCharge, optional
            Charge added after the shot noise (cosmic rays), e-: an image, or the charge of a
            few pixels (:class:`PixelCharge`; the same frame as its image, bit for bit).

        Returns
        -------
        ndarray, shape (H, W), uint8 (bit depth <= 8) or uint16
        """
        return self._run(electrons, exposure_s, rng, backend, extra_charge_e, details=False).dn

    def expose_details(self, electrons, exposure_s: float, rng: np.random.Generator, *, backend: str = "auto", extra_charge_e=None) -> ExposureDetails:
        """Like :meth:`expose`, also returning the expected and the collected charge.

        Consumes ``rng`` exactly as :meth:`expose` does, and gives the same ``dn``.

        Parameters
        ----------
        electrons : array_like, shape (H, W)
            Expected photo-electrons per pixel (noise-free, before PRNU), e-.
        exposure_s : float
            Exposure time (scales the dark current), s.
        rng : numpy.random.Generator
            Source of all randomness.
        backend : {"auto", "llvm", "cuda", "numpy"}
            The sensor backend (:meth:`expose`).
        extra_charge_e : array_like, shape (H, W), or PixelCharge, optional
            Charge added after the shot noise (cosmic rays), e-.

        Returns
        -------
        ExposureDetails
            ``dn``, the expected charge ``mean_e`` and the collected ``charge_e`` (e-), the backend.
        """
        return self._run(electrons, exposure_s, rng, backend, extra_charge_e, details=True)

    def expected_dn(self, electrons, exposure_s: float, *, extra_charge_e=None) -> np.ndarray:
        """Noise-free digital numbers: the same chain with every noise term at its mean.

        ``mean_e = electrons * PRNU + dark * exposure_s (+ extra)``, full well (or blooming),
        ``floor(K mean_e + offset + 0.5)`` clipped to ``[0, 2^bits - 1]``. Fixed patterns are
        included (they are not noise from frame to frame).

        Parameters
        ----------
        electrons : array_like, shape (H, W)
            Expected photo-electrons per pixel (before PRNU), e-.
        exposure_s : float
            Exposure time (scales the dark current), s.
        extra_charge_e : array_like, shape (H, W), or PixelCharge, optional
            Charge added to the mean, e-.

        Returns
        -------
        ndarray, shape (H, W), uint8 (bit depth <= 8) or uint16
            Digital counts, DN.
        """
        e, t, x = self._check_inputs(electrons, exposure_s, extra_charge_e)
        if isinstance(x, PixelCharge):
            x = x.dense(self.shape)
        p = self.params
        gain, dark = _fixed_patterns_f64(p, self.shape)
        mean = e * gain + dark * t
        if x is not None:
            mean = mean + x
        mean = bloom_columns(mean, p.full_well_e) if p.blooming else np.minimum(mean, p.full_well_e)
        return self._quantise_numpy(mean)

    # ----------------------------------------------------------------- plumbing
    def _check_inputs(self, electrons, exposure_s, extra_charge_e):
        e = np.asarray(electrons)
        if e.shape != self.shape:
            raise SensorInputError(f"electrons has shape {e.shape}; this sensor is {self.shape}")
        if not (isinstance(exposure_s, (int, float, np.floating, np.integer)) and math.isfinite(exposure_s) and exposure_s >= 0):
            raise SensorInputError(f"exposure_s = {exposure_s!r}; expected a finite number >= 0 (seconds)")
        # min and max propagate NaN, and +-inf shows in one of them: two reductions, no
        # temporary array (this runs on every frame)
        if e.size and not (e.min() >= 0 and np.isfinite(e.max())):
            raise SensorInputError("electrons must be finite and >= 0 everywhere")
        x = None
        if isinstance(extra_charge_e, PixelCharge):
            idx = np.asarray(extra_charge_e.index)
            val = np.asarray(extra_charge_e.electrons)
            if idx.ndim != 1 or val.shape != idx.shape or (idx.size and idx.dtype.kind not in "iu"):
                raise SensorInputError(f"extra_charge_e: index and electrons must be 1-D of one length, index integer; got {idx.shape} {idx.dtype}, {val.shape}")
            if idx.size and not (idx.min() >= 0 and idx.max() < e.size):
                raise SensorInputError(f"extra_charge_e.index must be in [0, {e.size}) for this {self.shape} sensor")
            if val.size and not (val.min() >= 0 and np.isfinite(val.max())):
                raise SensorInputError("extra_charge_e must be finite and >= 0 everywhere")
            return e, float(exposure_s), extra_charge_e
        if extra_charge_e is not None:
            x = np.asarray(extra_charge_e)
            if x.shape != self.shape:
                raise SensorInputError(f"extra_charge_e has shape {x.shape}; this sensor is {self.shape}")
            if x.size and not (x.min() >= 0 and np.isfinite(x.max())):
                raise SensorInputError("extra_charge_e must be finite and >= 0 everywhere")
        return e, float(exposure_s), x

    def _run(self, electrons, exposure_s, rng, backend, extra_charge_e, *, details):
        if not isinstance(rng, np.random.Generator):
            raise SensorInputError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        e, t, x = self._check_inputs(electrons, exposure_s, extra_charge_e)
        if backend == "auto":
            backend = jit_backend.auto_sensor_backend()
        if backend == "numpy":
            return self._expose_numpy(e, t, rng, x)
        if backend in JIT_BACKENDS:
            jit_backend.require(backend)
            return self._expose_jit(e, t, rng, x, backend, details=details)
        raise SensorInputError(f"backend = {backend!r}; expected one of 'auto', 'llvm', 'cuda', 'numpy'")

    def _quantise_numpy(self, v_e: np.ndarray) -> np.ndarray:
        p = self.params
        y = p.gain_dn_per_e * v_e  # the operations of floor(K v + (offset + 0.5)), in place
        y += p.offset_dn + 0.5
        np.floor(y, out=y)
        np.clip(y, 0, p.max_dn, out=y)
        return y.astype(self.dtype)

    def _expose_numpy(self, e, t, rng, x) -> ExposureDetails:
        p = self.params
        gain, dark = _fixed_patterns_f64(p, self.shape)
        mean = dark * t
        mean += e * gain  # e gain + dark t (IEEE addition commutes)
        n = rng.poisson(mean).astype(np.float64)
        if isinstance(x, PixelCharge):  # n + its image: n + 0 = n off the pixels hit
            idx, charge = x.per_pixel()
            n.reshape(-1)[idx] += charge
        elif x is not None:
            n += x
        n = bloom_columns(n, p.full_well_e) if p.blooming else np.minimum(n, p.full_well_e, out=n)
        if self.dark_noise_e > 0:
            v = rng.normal(0.0, self.dark_noise_e, self.shape)
            v += n  # n + noise (n is returned as the charge)
        else:
            v = n
        return ExposureDetails(dn=self._quantise_numpy(v), mean_e=mean, charge_e=n, backend="numpy")

    # ----------------------------------------------------------------- Dr.Jit path (LLVM or CUDA)
    def _patterns_jit(self, backend: str):
        if backend not in self._jit_patterns:
            Float = _jit_module(backend).Float
            gain, dark = fixed_patterns(self.params, self.shape)
            self._jit_patterns[backend] = (Float(gain.ravel()), Float(dark.ravel()))
        return self._jit_patterns[backend]

    def _expose_jit(self, e, t, rng, x, backend: str, *, details) -> ExposureDetails:
        # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
        import drjit as dr

        jt = _jit_module(backend)
        Float, UInt32 = jt.Float, jt.UInt32
        p = self.params
        gain, dark = self._patterns_jit(backend)
        key = tuple(dr.opaque(UInt32, k) for k in frame_key(rng))
        sig32 = np.ascontiguousarray(e, dtype=np.float32).ravel()
        sig = Float(sig32)
        op = functools.partial(dr.opaque, Float)
        readout = (op(self.dark_noise_e), op(p.gain_dn_per_e), op(p.offset_dn + 0.5), op(float(p.max_dn)))
        small_dn = p.bit_depth <= 8  # DN leave the kernel as bytes
        if not (p.blooming or details):  # the whole chain in one kernel, replayed (see _frozen_exposure)
            hit = x.per_pixel() if isinstance(x, PixelCharge) else None
            extra = None if x is None or hit is not None else Float(np.ascontiguousarray(x, dtype=np.float32).ravel())
            args = (op(t), key, op(p.full_well_e), readout)
            with _frozen_lock:
                dn = _frozen_exposure(small_dn, backend)(sig, gain, dark, extra, *args, None)
                dr.eval(dn)
                out = dn.numpy()
                if hit is not None and hit[0].size:
                    # the pixels hit: the same chain on their own, with their charge, from their
                    # own streams (a stream is a hash of the frame key and the pixel index). Their
                    # number changes from frame to frame, and a recording is replayed only on
                    # inputs of its own size: the lanes are padded to a power of two (the spare
                    # ones repeat the first pixel and are dropped), so a few recordings serve
                    # every frame; beyond _HIT_LANES_MAX the chain is traced
                    idx, charge = hit
                    lanes = _hit_lanes(idx.size)
                    if lanes:
                        idx = np.concatenate([idx, np.full(lanes - idx.size, idx[0])])
                        charge = np.concatenate([charge, np.full(lanes - charge.size, charge[0])])
                    g32, d32 = fixed_patterns(p, self.shape)
                    sub_in = (Float(sig32[idx]), Float(g32.ravel()[idx]), Float(d32.ravel()[idx]),
                              Float(charge.astype(np.float32)), *args, UInt32(idx.astype(np.uint32)))
                    sub = _frozen_exposure(small_dn, backend, True)(*sub_in) if lanes else _jit_exposure(*sub_in, small_dn)
                    dr.eval(sub)
                    out = out.copy() if not out.flags.writeable else out
                    out[hit[0]] = sub.numpy()[:hit[0].size]
            return ExposureDetails(dn=out.reshape(self.shape).astype(self.dtype, copy=False), mean_e=None,
                                   charge_e=None, backend=backend)
        if isinstance(x, PixelCharge):
            x = x.dense(self.shape)
        extra = Float(np.ascontiguousarray(x, dtype=np.float32).ravel()) if x is not None else None
        mean = dr.fma(sig, gain, dark * op(t))
        n, pcg = _jit_charge(mean, extra, key)
        if p.blooming:
            dr.eval(n, pcg)
            n = Float(bloom_columns(n.numpy().reshape(self.shape), p.full_well_e).astype(np.float32).ravel())
        else:
            n = dr.minimum(n, op(p.full_well_e))
        dn = _jit_readout(n, pcg, *readout, small_dn=small_dn)
        if details:
            dr.eval(dn, n, mean)
            mean_np = mean.numpy().reshape(self.shape).astype(np.float64)
            n_np = n.numpy().reshape(self.shape).astype(np.float64)
        else:
            dr.eval(dn)
            mean_np = n_np = None
        out = dn.numpy().reshape(self.shape).astype(self.dtype, copy=False)
        return ExposureDetails(dn=out, mean_e=mean_np, charge_e=n_np, backend=backend)


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
    PCG32, Bool, Float, Float64, UInt32 = jt.PCG32, jt.Bool, jt.Float, jt.Float64, jt.UInt32
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

    # -- PTRS transformed rejection (means >= 10), Hoermann (1993), as in numpy's random_poisson_ptrs.
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

    pcg, k_big, _ = dr.while_loop((pcg, Float(0.0), Bool(small)), ptrs_cond, ptrs_body, labels=("rng", "k", "done"), label="poisson_ptrs")
    n = dr.select(small, Float(k_small), k_big)
    if extra is not None:
        n = n + extra
    return n, pcg


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
