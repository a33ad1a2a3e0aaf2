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
  (:func:`~skynav.renderer.sensor_jit.pixel_stream_seeds`, as Mitsuba seeds its samplers): the frame key is 128 bits drawn
  from the caller's ``numpy.random.Generator`` (:func:`~skynav.renderer.sensor_jit.frame_key`), the hash is the TEA block
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
from dataclasses import dataclass

import numpy as np

from skynav.scenes.camera import SensorParams

from . import jit_backend
from .errors import SensorInputError  # noqa: F401  (re-exported: the sensor raises it)
from .sensor_jit import (_frozen_exposure, _frozen_lock, _hit_lanes, _jit_charge, _jit_exposure, _jit_module, _jit_readout,
                         frame_key)

JIT_BACKENDS = ("llvm", "cuda")
"""The sensor backends that run the fused Dr.Jit kernel (CPU and GPU)."""


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
