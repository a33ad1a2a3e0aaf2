"""Quick look at digital counts: zscale limits and an asinh stretch, as an 8-bit image for the eye.

Core module (no files). A frame's PNG holds its physical DN (docs/conventions.md "Files"): a
star field is a dark sky a few DN above the black level with a handful of bright points, so an
image viewer shows it black. The quick look is what astronomers' viewers show (SAOImage DS9's
"zscale" and "asinh" settings, ``astropy.visualization``): display limits from the zscale
algorithm (IRAF's, ``ZScaleInterval``) on the frame's own values, which brackets the sky and its
noise, then an asinh stretch (``AsinhStretch``), linear near the sky and
logarithmic for the stars, so that the sky's noise is a visible grey, faint stars stand out and
bright ones keep their cores. It is for the eye only: nothing reads DN back from it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["display_limits", "quicklook_u8"]


def quicklook_u8(dn, *, asinh_a: float = 0.1, contrast: float = 0.25) -> np.ndarray:
    """8-bit quick look of an image: zscale limits, then an asinh stretch.

    Parameters
    ----------
    dn : array_like, shape (H, W)
        Digital counts (or any real image).
    asinh_a : float
        The asinh stretch's ``a`` (``astropy.visualization.AsinhStretch``): the fraction of the
        zscale range that stays nearly linear; 0.1 is astropy's default.
    contrast : float
        The zscale algorithm's contrast (astropy's default 0.25, IRAF's).

    Returns
    -------
    ndarray, shape (H, W), uint8
        0 at and below the lower zscale limit, 255 at and above the upper one. An image of one
        value gives all 0.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> sky = rng.normal(10.0, 2.0, (64, 64))
    >>> sky[32, 32] = 250.0  # a star
    >>> q = quicklook_u8(sky)
    >>> bool(np.median(q) > 60), int(q[32, 32])
    (True, 255)
    """
    from astropy.visualization import AsinhStretch  # local: astropy's visualization loads on first use

    raw = np.asarray(dn)
    step = 1.0 if raw.dtype.kind in "iub" else 0.0  # one DN: the quantum of digital counts
    a = raw.astype(np.float64)
    finite = a[np.isfinite(a)]
    if finite.size == 0:
        return np.zeros(a.shape, np.uint8)
    lo, hi = display_limits(finite, step=step, contrast=contrast)
    if not hi > lo:
        return np.zeros(a.shape, np.uint8)
    x = np.clip((np.nan_to_num(a, nan=lo) - lo) / (hi - lo), 0.0, 1.0)
    y = AsinhStretch(a=asinh_a)(x, clip=True)
    return np.round(255.0 * y).astype(np.uint8)


def display_limits(values, *, step: float = 1.0, contrast: float = 0.25) -> tuple:
    """``(low, high)`` display limits of an image's finite values.

    The zscale limits (``astropy.visualization.ZScaleInterval``), unless the sky's noise is below
    one DN ``step`` (its robust standard deviation, 1.4826 times the median absolute deviation):
    a frame whose sky reads one value, the black level, as an 8-bit camera's often does, where
    zscale's line is fitted to the stars alone. There the high limit is the 90th percentile of the
    pixels above the sky (the faint stars bright, the brightest clipped) and the low one below the
    median by a twentieth of that span, one step at least: the sky then shows a dark grey (about
    40 of 255 after the stretch), so the frame's extent shows. An image of one value gives
    ``low == high``.
    """
    from astropy.visualization import ZScaleInterval  # local: astropy's visualization loads on first use

    values = np.asarray(values, dtype=np.float64)
    if values.min() == values.max():
        return float(values.min()), float(values.max())
    med = float(np.median(values))
    sigma = 1.4826 * float(np.median(np.abs(values - med)))
    if step and sigma < step:
        above = values[values > med + 0.5 * step]
        hi = max(float(np.percentile(above, 90.0)), med + step) if above.size else med + step
        return med - max(step, (hi - med) / 20.0), hi
    lo, hi = (float(v) for v in ZScaleInterval(contrast=contrast).get_limits(values))
    if not hi > lo:  # zscale's degenerate fit: the image's own range
        lo, hi = float(values.min()), float(values.max())
    return lo, hi
