"""Cosmic-ray hits on the detector: how many, where, how much charge, which pixels.

Model
-----
- **Count per frame**: ``mode="poisson"``: ``N ~ Poisson(rate_per_frame)`` (independent arrivals);
  ``mode="fixed"``: exactly ``rate_per_frame`` hits (Andreis et al. (2024), Table 4: "1" single pixel turned
  on per image).
- **Where**: uniform over the sensor area (pixel edges at -0.5 and W - 0.5, docs/conventions.md).
- **Shape**: by default a single pixel (Andreis et al. (2024), and Andreis et al. (2023a), section on spikes: "cosmic rays ...
  hit only single pixels" in under-sampled images). With probability ``track_prob`` a hit is a
  short straight track (an oblique particle): uniform direction, projected length uniform in
  ``[1, max_track_length_px]``; its charge is spread over the pixels the segment crosses, in
  proportion to the length of segment inside each pixel (sampled on a fine grid along the
  segment), and the parts outside the sensor are lost (only charge on the sensor is recorded).
- **Charge**: energy loss of a minimum-ionising particle in a thin silicon layer follows a
  Landau distribution; :class:`ChargeModel` ``kind="moyal"`` uses Moyal's closed-form
  approximation of it (J. E. Moyal 1955, Phil. Mag. 46, 263), sampled exactly as
  ``X = -ln(Z^2)``, ``Z ~ N(0, 1)``, charge ``= mpv_e + width_e X`` (mode at ``mpv_e``, long
  high-energy tail), floored at 0; ``kind="lognormal"``: median ``mpv_e``, log-standard deviation
  ``width_e / mpv_e``. The default ``mpv_e = 1600`` e- is ~80 e-h pairs per um of silicon
  (3.6 eV per pair, ~290 eV/um for a MIP) over a ~20 um sensitive depth. A track's charge is the
  draw times its projected length in px (>= 1).

Where the charge goes in the chain
----------------------------------
:func:`deposit` adds the charge to an electrons image (in place). Hand that image to the sensor as
``extra_charge_e`` (``Sensor.expose(..., extra_charge_e=deposit(np.zeros(shape), hits))``): it
is added AFTER the shot noise and before the full-well clipping, because a particle's charge has
its own (Landau) statistics and is not Poisson-scaled with the optical signal, while it does
saturate and bloom like any other charge.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from skynav.infra.errors import ConfigValueError

_SUBSAMPLES_PER_PX = 32  # points per px of track length used to share charge between pixels


@dataclass(frozen=True, kw_only=True)
class ChargeModel:
    """Distribution of the charge one cosmic ray deposits (per px of projected track length).

    Parameters
    ----------
    kind : {"moyal", "lognormal"}
        ``moyal``: Moyal (1955) approximation of the Landau distribution; ``lognormal``.
    mpv_e : float
        Most probable value (moyal) or median (lognormal), e-.
    width_e : float
        Moyal scale, or ``mpv_e`` x log-standard deviation for the lognormal, e-.

    References
    ----------
    Moyal, J. E. (1955), Phil. Mag. 46, 263 (the approximation of the Landau distribution).

    Examples
    --------
    >>> from skynav.renderer import ChargeModel
    >>> q = ChargeModel().sample(20000, np.random.default_rng(0))
    >>> bool(1500 < np.median(q) < 1900), bool(q.min() >= 0)   # e-: the mode is mpv_e = 1600
    (True, True)
    """

    kind: str = "moyal"
    mpv_e: float = 1600.0
    width_e: float = 250.0

    def __post_init__(self):
        if self.kind not in ("moyal", "lognormal"):
            raise ConfigValueError("cosmic_rays.charge_model.kind", self.kind, "one of: moyal, lognormal")
        if not (math.isfinite(self.mpv_e) and self.mpv_e > 0):
            raise ConfigValueError("cosmic_rays.charge_model.mpv_e", self.mpv_e, "> 0 (electrons)")
        if not (math.isfinite(self.width_e) and self.width_e >= 0):
            raise ConfigValueError("cosmic_rays.charge_model.width_e", self.width_e, ">= 0 (electrons)")

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """Draw ``n`` charges.

        Parameters
        ----------
        n : int
            Number of charges.
        rng : numpy.random.Generator
            The stream to draw from.

        Returns
        -------
        numpy.ndarray, shape (n,)
            Charges, e- (>= 0).
        """
        if self.kind == "moyal":
            z = rng.standard_normal(n)
            x = -np.log(z * z)  # Moyal variate: pdf exp(-(x + e^-x)/2) / sqrt(2 pi)
            return np.maximum(self.mpv_e + self.width_e * x, 0.0)
        return self.mpv_e * np.exp((self.width_e / self.mpv_e) * rng.standard_normal(n))


@dataclass(frozen=True, kw_only=True, eq=False)
class CosmicRayHits:
    """The hits of one frame and the pixels they charge.

    Attributes
    ----------
    shape : tuple (H, W)
    xy : ndarray, shape (N, 2), px
        Impact point of each hit (x = column, y = row, pixel centres at integers); the pixel
        centre for single-pixel hits, the track midpoint for tracks.
    electrons : ndarray, shape (N,), e-
        Charge each hit deposits on the sensor (sum of its pixels).
    track_start_xy, track_end_xy : ndarray, shape (N, 2), px
        Track endpoints (both equal ``xy`` for a single-pixel hit).
    is_track : ndarray, shape (N,), bool
        True for a track, False for a single-pixel hit.
    pixel_hit : ndarray, shape (M,), int
        Index of the hit each charged pixel belongs to.
    pixel_rows, pixel_cols : ndarray, shape (M,), int
        Row and column of each charged pixel.
    pixel_electrons : ndarray, shape (M,), e-
        Charge of each charged pixel.

    Examples
    --------
    >>> from skynav.renderer import draw_cosmic_rays
    >>> hits = draw_cosmic_rays((64, 64), 3, np.random.default_rng(1), mode="fixed", track_prob=1.0)
    >>> len(hits), hits.is_track.tolist()
    (3, [True, True, True])
    >>> bool(np.allclose(np.bincount(hits.pixel_hit, hits.pixel_electrons), hits.electrons))
    True
    """

    shape: tuple
    xy: np.ndarray
    electrons: np.ndarray
    track_start_xy: np.ndarray
    track_end_xy: np.ndarray
    is_track: np.ndarray
    pixel_hit: np.ndarray
    pixel_rows: np.ndarray
    pixel_cols: np.ndarray
    pixel_electrons: np.ndarray = field(repr=False)

    def __len__(self) -> int:
        return len(self.electrons)

    def _fields(self):
        return (self.xy, self.electrons, self.track_start_xy, self.track_end_xy, self.is_track, self.pixel_hit, self.pixel_rows, self.pixel_cols, self.pixel_electrons)

    def __eq__(self, other) -> bool:
        return isinstance(other, CosmicRayHits) and tuple(self.shape) == tuple(other.shape) and all(np.array_equal(a, b) for a, b in zip(self._fields(), other._fields()))

    def __hash__(self) -> int:
        return hash((tuple(self.shape),) + tuple(np.ascontiguousarray(a).tobytes() for a in self._fields()))

    def to_ground_truth(self) -> list[dict]:
        """The ``cosmic_rays`` list of the frame ground truth (docs/conventions.md), one record per hit.

        Each record holds ``xy`` and ``electrons`` (the fixed names) and the whole track:
        ``track`` (bool), ``track_start_xy``, ``track_end_xy``, ``length_px`` (projected track
        length, 0 for a single-pixel hit) and ``pixels``: ``[row, col, electrons]`` of every
        charged pixel on the sensor, whose electrons sum to the hit's ``electrons``.

        Returns
        -------
        list of dict

        Examples
        --------
        >>> hits = draw_cosmic_rays((8, 8), 1, np.random.default_rng(0), mode="fixed")
        >>> sorted(hits.to_ground_truth()[0])
        ['electrons', 'length_px', 'pixels', 'track', 'track_end_xy', 'track_start_xy', 'xy']
        """
        order = np.argsort(self.pixel_hit, kind="stable")
        bounds = np.searchsorted(self.pixel_hit[order], np.arange(len(self) + 1))
        rows = self.pixel_rows[order].tolist()
        cols = self.pixel_cols[order].tolist()
        charge = self.pixel_electrons[order].tolist()
        length = np.hypot(*(self.track_end_xy - self.track_start_xy).T) if len(self) else np.zeros(0)
        return [
            {
                "xy": [float(v) for v in self.xy[i]],
                "electrons": float(self.electrons[i]),
                "track": bool(self.is_track[i]),
                "track_start_xy": [float(v) for v in self.track_start_xy[i]],
                "track_end_xy": [float(v) for v in self.track_end_xy[i]],
                "length_px": float(length[i]),
                "pixels": [[rows[m], cols[m], charge[m]] for m in range(bounds[i], bounds[i + 1])],
            }
            for i in range(len(self))
        ]


def _track_pixels(start, end, shape):
    """Pixels crossed by the segment and the fraction of its length in each (on-sensor only)."""
    length = float(np.hypot(*(end - start)))
    m = max(int(math.ceil(length * _SUBSAMPLES_PER_PX)), 1)
    s = (np.arange(m) + 0.5) / m  # midpoints of m equal sub-segments
    pts = start[None, :] + s[:, None] * (end - start)[None, :]
    cols = np.floor(pts[:, 0] + 0.5).astype(np.int64)
    rows = np.floor(pts[:, 1] + 0.5).astype(np.int64)
    inside = (rows >= 0) & (rows < shape[0]) & (cols >= 0) & (cols < shape[1])
    lin = rows[inside] * shape[1] + cols[inside]
    uniq, counts = np.unique(lin, return_counts=True)
    return uniq // shape[1], uniq % shape[1], counts / m


def draw_cosmic_rays(
    shape,
    rate_per_frame: float,
    rng: np.random.Generator,
    *,
    mode: str = "poisson",
    charge_model: ChargeModel | None = None,
    track_prob: float = 0.0,
    max_track_length_px: float = 8.0,
) -> CosmicRayHits:
    """Cosmic-ray hits of one frame.

    Parameters
    ----------
    shape : tuple (H, W)
        Sensor size, px.
    rate_per_frame : float
        Mean number of hits (``mode="poisson"``) or the exact number (``mode="fixed"``, an
        integer).
    rng : numpy.random.Generator
        The frame's stream (the count, positions, directions and charges are drawn from it).
    mode : {"poisson", "fixed"}
        Poisson count of mean ``rate_per_frame``, or exactly that many.
    charge_model : ChargeModel, optional
        Default ``ChargeModel()`` (Moyal, mpv 1600 e-).
    track_prob : float
        Probability that a hit is a short track rather than a single pixel (default 0).
    max_track_length_px : float
        Longest projected track, px (>= 1).

    Returns
    -------
    CosmicRayHits
        The hits (impact points, px; charges, e-) and the pixels they charge.

    Examples
    --------
    >>> from skynav.renderer import draw_cosmic_rays
    >>> hits = draw_cosmic_rays((64, 64), 1, np.random.default_rng(0), mode="fixed")
    >>> len(hits), hits.pixel_rows.size
    (1, 1)
    """
    shape = tuple(int(s) for s in shape)
    if len(shape) != 2 or min(shape) < 1:
        raise ConfigValueError("cosmic_rays.shape", shape, "(H, W) with H, W >= 1")
    if not (math.isfinite(rate_per_frame) and rate_per_frame >= 0):
        raise ConfigValueError("render.cosmic_rays_per_frame", rate_per_frame, ">= 0")
    if not 0.0 <= track_prob <= 1.0:
        raise ConfigValueError("cosmic_rays.track_prob", track_prob, "in [0, 1]")
    if not max_track_length_px >= 1.0:
        raise ConfigValueError("cosmic_rays.max_track_length_px", max_track_length_px, ">= 1")
    if mode == "poisson":
        n = int(rng.poisson(rate_per_frame))
    elif mode == "fixed":
        if float(rate_per_frame) != int(rate_per_frame):
            raise ConfigValueError("render.cosmic_rays_per_frame", rate_per_frame, "an integer when mode='fixed'")
        n = int(rate_per_frame)
    else:
        raise ConfigValueError("cosmic_rays.mode", mode, "one of: poisson, fixed")
    model = charge_model or ChargeModel()
    H, W = shape

    # Draw order is fixed (positions, shapes, charges) so a seed always gives the same hits.
    pos = np.column_stack([rng.uniform(-0.5, W - 0.5, n), rng.uniform(-0.5, H - 0.5, n)])
    is_track = rng.random(n) < track_prob
    angle = rng.uniform(0.0, 2.0 * math.pi, n)
    length = rng.uniform(1.0, max_track_length_px, n)
    charge_per_px = model.sample(n, rng)

    return _hits(shape, pos, is_track, angle, length, charge_per_px)


def _hits(shape, pos, is_track, angle, length, charge_per_px) -> CosmicRayHits:
    """The hits of drawn positions (n, 2), kinds, angles, lengths and charges per px: a single
    pixel's hit at the centre of the struck pixel, a track's spread over the pixels it crosses
    (:func:`_track_pixels`) in proportion to its length in each."""
    n = pos.shape[0]
    xy = np.floor(pos + 0.5)  # single pixel: the centre of the struck pixel
    start = xy.copy()
    end = xy.copy()
    electrons = np.zeros(n)
    pr, pc, pe, ph = [], [], [], []
    for i in range(n):
        if is_track[i]:
            half = 0.5 * length[i] * np.array([math.cos(angle[i]), math.sin(angle[i])])
            start[i], end[i], xy[i] = pos[i] - half, pos[i] + half, pos[i]
            rows, cols, frac = _track_pixels(start[i], end[i], shape)
            q = charge_per_px[i] * length[i] * frac
        else:
            rows = np.array([int(xy[i, 1])])
            cols = np.array([int(xy[i, 0])])
            q = np.array([charge_per_px[i]])
        electrons[i] = float(np.sum(q))
        pr.append(rows)
        pc.append(cols)
        pe.append(q)
        ph.append(np.full(len(rows), i))
    cat = lambda parts, dt: np.concatenate(parts).astype(dt) if parts else np.zeros(0, dt)  # noqa: E731
    return CosmicRayHits(
        shape=shape,
        xy=xy,
        electrons=electrons,
        track_start_xy=start,
        track_end_xy=end,
        is_track=is_track,
        pixel_hit=cat(ph, np.int64),
        pixel_rows=cat(pr, np.int64),
        pixel_cols=cat(pc, np.int64),
        pixel_electrons=cat(pe, np.float64),
    )


def deposit(image_e: np.ndarray, hits: CosmicRayHits) -> np.ndarray:
    """Add the cosmic-ray charge to an electrons image, IN PLACE, and return that image.

    The intended use is the sensor's ``extra_charge_e`` (added after the shot noise; see the
    module notes): ``Sensor.expose(signal, t, rng, extra_charge_e=deposit(np.zeros(shape), hits))``.

    Parameters
    ----------
    image_e : ndarray, shape (H, W), float, e-
        Modified in place (pass a copy to keep the original).
    hits : CosmicRayHits
        The hits (:func:`draw_cosmic_rays`) of a sensor of the image's shape.

    Returns
    -------
    ndarray, shape (H, W), e-
        ``image_e`` itself.

    Raises
    ------
    ConfigValueError
        Not a writeable float array, or not the hits' shape.

    Examples
    --------
    >>> from skynav.renderer import deposit, draw_cosmic_rays
    >>> hits = draw_cosmic_rays((64, 64), 2, np.random.default_rng(0), mode="fixed")
    >>> image = deposit(np.zeros((64, 64)), hits)
    >>> bool(np.isclose(image.sum(), hits.electrons.sum()))   # charge conserved, e-
    True
    """
    if not isinstance(image_e, np.ndarray) or image_e.dtype.kind != "f" or not image_e.flags.writeable:
        raise ConfigValueError("cosmic_rays.image", type(image_e).__name__, "a writeable float numpy array (charge is added in place)")
    if image_e.shape != tuple(hits.shape):
        raise ConfigValueError("cosmic_rays.image_shape", image_e.shape, f"the hits' sensor shape {tuple(hits.shape)}")
    np.add.at(image_e, (hits.pixel_rows, hits.pixel_cols), hits.pixel_electrons)
    return image_e
