"""Background levels of a frame: the saturated fraction and the improved mode's robust threshold.

The improved mode thresholds at ``median + T x sigma`` with ``sigma`` the larger of 1.4826 MAD
(the MAD of a Gaussian is 0.6745 sigma) and the standard deviation of the pixels within
``median + 5 sigma``, floored at 0.5 DN (an 8-bit frame's dark background is one or two DN), from
every 8th row and column: a resolved planet or a bright frame does not lift it above the stars,
as the paper's mean + T x standard deviation (Eq. 6) does.
"""

from __future__ import annotations

import numpy as np

from .centroids import detect_spots

__all__ = ["Levels", "robust_level", "detect_robust", "weighted_median"]


class Levels:
    """The frame's sample of every 8th row and column, read once: the saturated fraction and the
    robust level (:func:`robust_level`) of one frame from the same histogram of its counts
    (integer frames; ``histogram=False`` or other frames: counted directly). The levels of each
    ``T`` are kept on the object (one per frame, owned by the caller)."""

    def __init__(self, img, *, histogram: bool):
        self.img = img
        self.sub = img[::8, ::8]
        self.counts = sample_histogram(self.sub) if histogram else None
        self._levels = {}

    def count_at_least(self, value: float) -> int:
        """Number of sample pixels >= ``value``."""
        if self.counts is None:
            return int(np.count_nonzero(self.sub >= value))
        return int(self.counts[max(int(np.ceil(value)), 0):].sum())

    def level(self, T: float):
        """``(background, threshold)`` DN of :func:`robust_level` at ``T``."""
        if T not in self._levels:
            self._levels[T] = robust_level(self.img, T, counts=self.counts)
        return self._levels[T]


def sample_histogram(sub):
    """``np.bincount`` of an integer sample with counts in [0, 2^17), else None."""
    counts_ok = np.issubdtype(sub.dtype, np.integer) and sub.size > 0
    if counts_ok and not (sub.dtype.kind == "u" and sub.dtype.itemsize <= 2):  # 8/16-bit: 0 <= counts < 2^16
        counts_ok = int(sub.min()) >= 0 and int(sub.max()) < 1 << 17
    return np.bincount(sub.ravel()) if counts_ok else None


def robust_level(img, T, *, counts=None):
    """``(background, threshold)`` of the improved mode: median + T x robust sigma (module
    docstring), from every 8th row and column. Integer frames (every camera's) take the same
    statistics from a histogram of the counts (``counts``, :func:`sample_histogram` of that
    sample, when already made): the median and MAD of :func:`numpy.median` (tested against it)."""
    sub = img[::8, ::8]
    if counts is None:
        counts = sample_histogram(sub)
    if counts is not None:
        values = counts.nonzero()[0]
        counts = counts[values]
        values = values.astype(np.float64)
        med = weighted_median(values, counts, ascending=True)
        dev = np.abs(values - med)
        mad = weighted_median(dev, counts) * 1.4826
        inl = counts * (values <= med + 5 * max(mad, 0.5))
        n = inl.sum()
        mean = float((inl * values).sum() / n)
        sd = max(mad, float(np.sqrt((inl * (values - mean) ** 2).sum() / n)), 0.5)
        return med, med + T * sd
    sub = np.asarray(sub, dtype=np.float32)
    med = float(np.median(sub))
    mad = float(np.median(np.abs(sub - med))) * 1.4826
    sd = max(mad, float(np.std(sub[sub <= med + 5 * max(mad, 0.5)])), 0.5)
    return med, med + T * sd


def weighted_median(values, counts, *, ascending=False) -> float:
    """:func:`numpy.median` of the sample holding ``counts[i]`` copies of ``values[i]`` (the mean
    of the two middle order statistics when the sample size is even); ``ascending``: the values
    are sorted already."""
    if not ascending:
        order = np.argsort(values, kind="stable")
        values, counts = values.take(order), counts.take(order)
    cum = np.cumsum(counts)
    n = int(cum[-1])
    lo = values[np.searchsorted(cum, (n - 1) // 2, side="right")]
    hi = values[np.searchsorted(cum, n // 2, side="right")]
    return float(0.5 * (lo + hi))


def detect_robust(img, *, T, max_dn, max_regions, windows_xy=None, window_half_px=0, level=None):
    """Spots above the robust threshold (:func:`robust_level`, or ``level`` = its result)."""
    med, thr = robust_level(img, T) if level is None else level
    return detect_spots(img, T=T, max_dn=max_dn, max_regions=max_regions, background="median",
                        threshold_dn=thr, background_dn=med, stats_stride=8, windows_xy=windows_xy,
                        window_half_px=window_half_px)
