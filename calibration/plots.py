"""Calibration figures (matplotlib Figures on an Agg canvas, no pyplot): the line-of-sight residual
CDF and PDF (as in Andreis et al. (2023b), Fig. 2), DN <-> irradiance and DN <-> magnitude
(their Fig. 3).

The functions return Figures; ``skynav calibrate`` writes them as PNG through
:func:`skynav.datasets.plots.figure_png` (the file side lives in ``datasets``). Axis labels end
with their unit in parentheses; legends are words.
"""

from __future__ import annotations

import numpy as np

from .radiometric import v_mag_of_dn

__all__ = ["residual_figure", "radiometric_figure"]


def _figure(width_in: float, height_in: float, dpi: int = 100):
    # matplotlib only when a figure is drawn
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def residual_figure(holdout_arcsec, fit_arcsec):
    """CDF and PDF of the geometric fit's line-of-sight residuals, fit and held-out points."""
    fig = _figure(10, 4)
    a, b = fig.subplots(1, 2)
    for data, label in ((fit_arcsec, "fit points"), (holdout_arcsec, "held-out points")):
        x = np.sort(np.asarray(data, dtype=float))
        a.plot(x, 100.0 * np.arange(1, len(x) + 1) / max(len(x), 1), label=f"{label} (n = {len(x)})")
        b.hist(x, bins=50, density=True, histtype="step", label=label)
    a.axhline(99.0, color="grey", ls=":", label="99 %")
    a.set_xlabel("line-of-sight residual (arcsec)")
    a.set_ylabel("cumulative share of points (%)")
    p99 = np.percentile(holdout_arcsec, 99) if len(holdout_arcsec) else float("nan")
    a.set_title(f"CDF: held-out 99th percentile {p99:.3f} arcsec")
    a.legend()
    b.set_xlabel("line-of-sight residual (arcsec)")
    b.set_ylabel("probability density (1/arcsec)")
    b.set_title("probability density")
    b.legend()
    return fig


def radiometric_figure(result):
    """The fitted screen curve (DN -> pupil irradiance) with the power-meter readings, and the V
    magnitude each DN stands for."""
    fac = result.facility
    rm = fac.radiometric
    dn = np.arange(0, rm.max_dn + 1)
    fig = _figure(10, 4)
    a, b = fig.subplots(1, 2)
    a.loglog(np.maximum(result.dn, 0.5), result.per_pixel_w_m2, "o", ms=3, label="power-meter reading per lit pixel")
    a.loglog(np.maximum(dn, 0.5), rm.irradiance_w_m2(dn), "-", label=f"fit, gamma {rm.gamma:.3f}")
    a.axvspan(result.usable_dn[0], result.usable_dn[1], color="green", alpha=0.1, label="usable range")
    a.set_xlabel("screen digital count (DN)")
    a.set_ylabel("pupil irradiance per lit pixel (W/m²)")
    a.legend()
    v = v_mag_of_dn(fac, dn[1:].astype(float), psf_pixels=fac.calibrated_radiometric["usable_range"]["psf_pixels"])
    b.plot(dn[1:], v, label="A0V star giving the same camera electrons")
    b.invert_yaxis()
    b.set_xscale("log")
    b.set_xlabel("screen digital count (DN)")
    b.set_ylabel("V magnitude (mag)")
    b.set_title(f"usable V {result.usable_v_mag[1]:.2f} .. {result.usable_v_mag[0]:.2f}")
    b.legend()
    return fig
