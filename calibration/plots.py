"""Calibration plots (matplotlib, Agg): residual CDF/PDF (paper 001 Fig. 2), DN <-> irradiance and
DN <-> magnitude (paper 001 Fig. 3)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def residual_plot(holdout_arcsec, fit_arcsec, path) -> Path:
    plt = _plt()
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    for data, label in ((fit_arcsec, "fit points"), (holdout_arcsec, "held-out points")):
        x = np.sort(data)
        a.plot(x, np.arange(1, len(x) + 1) / len(x), label=f"{label} (n={len(x)})")
        b.hist(data, bins=50, density=True, histtype="step", label=label)
    a.axhline(0.99, color="grey", ls=":")
    a.set_xlabel("line-of-sight residual, arcsec")
    a.set_ylabel("cumulative fraction")
    a.set_title(f"CDF: held-out p99 = {np.percentile(holdout_arcsec, 99):.3f} arcsec")
    a.legend()
    b.set_xlabel("line-of-sight residual, arcsec")
    b.set_ylabel("probability density")
    b.set_title("PDF")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def radiometric_plots(result, path) -> Path:
    from .radiometric import v_mag_of_dn

    plt = _plt()
    fac = result.facility
    rm = fac.radiometric
    dn = np.arange(0, rm.max_dn + 1)
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    a.loglog(np.maximum(result.dn, 0.5), result.per_pixel_w_m2, "o", ms=3, label="power meter / lit pixels")
    a.loglog(np.maximum(dn, 0.5), rm.irradiance_w_m2(dn), "-", label=f"fit: gamma {rm.gamma:.3f}")
    a.axvspan(result.usable_dn[0], result.usable_dn[1], color="green", alpha=0.1, label="usable")
    a.set_xlabel("screen digital count")
    a.set_ylabel("pupil irradiance per lit pixel, W/m^2")
    a.legend()
    v = v_mag_of_dn(fac, dn[1:].astype(float), psf_pixels=fac.calibrated_radiometric["usable_range"]["psf_pixels"])
    b.plot(dn[1:], v)
    b.invert_yaxis()
    b.set_xscale("log")
    b.set_xlabel("screen digital count")
    b.set_ylabel("V magnitude (A0V, same camera electrons)")
    b.set_title(f"usable V {result.usable_v_mag[1]:.2f} .. {result.usable_v_mag[0]:.2f}")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
