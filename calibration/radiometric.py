"""Radiometric calibration of a bench from power-meter readings.

CSV header ``digital_count,lit_pixels,irradiance_w_m2`` (the meter at the collimator exit, with
``lit_pixels`` screen pixels showing ``digital_count``). The per-pixel irradiance
``irradiance_w_m2 / lit_pixels`` is fitted by the monotone curve of
:class:`~skynav.scenes.facility.RadiometricModel` (black level, peak, gamma) by weighted least
squares in relative error (so the dense low counts weigh as much as the bright ones). The usable
range is where one digital-count step changes the signal by less than 10 % and the signal is
above twice the black level; its magnitudes are those of a Vega-like (A0V) star whose whole flux,
spread over ``psf_pixels`` screen pixels, gives the same camera electrons.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skynav.scenes.facility import Facility, RadiometricModel

from .errors import MeasurementError

MIN_ROWS = 8


def read_measurements(path):
    """(digital_count, lit_pixels, irradiance_w_m2) arrays from the CSV, checked."""
    p = Path(path)
    if not p.is_file():
        raise MeasurementError(f"{path}: no such measurement file")
    with open(p, newline="") as f:
        rows = list(csv.reader(f))
    if not rows or [c.strip() for c in rows[0]] != ["digital_count", "lit_pixels", "irradiance_w_m2"]:
        raise MeasurementError(f"{path}: header must be digital_count,lit_pixels,irradiance_w_m2")
    try:
        data = np.array([[float(c) for c in r] for r in rows[1:] if r], dtype=float)
    except ValueError as exc:
        raise MeasurementError(f"{path}: not a number ({exc})") from None
    if data.ndim != 2 or data.shape[0] < MIN_ROWS or data.shape[1] != 3:
        raise MeasurementError(f"{path}: {0 if data.ndim != 2 else data.shape[0]} measurements; need >= {MIN_ROWS} rows of 3 values")
    d, n, e = data.T
    if np.any(n <= 0) or np.any(~np.isfinite(e)) or np.any(e < 0):
        raise MeasurementError(f"{path}: lit_pixels must be > 0 and irradiance_w_m2 finite and >= 0")
    order = np.argsort(d, kind="stable")
    d, n, e = d[order], n[order], e[order]
    per = e / n
    # monotone within the meter noise (1 %)
    drop = per[1:] < per[:-1] * (1.0 - 0.01)
    if np.any(drop):
        k = int(np.flatnonzero(drop)[0])
        raise MeasurementError(f"{path}: irradiance per lit pixel falls from {per[k]:.4g} at DN {d[k]:g} to {per[k + 1]:.4g} at DN {d[k + 1]:g}; "
                               "the curve must be monotone")
    if len(np.unique(d)) < MIN_ROWS:
        raise MeasurementError(f"{path}: only {len(np.unique(d))} distinct digital counts; need >= {MIN_ROWS}")
    return d, n, e


@dataclass(frozen=True)
class RadiometricResult:
    facility: Facility
    dn: np.ndarray
    per_pixel_w_m2: np.ndarray
    rms_relative: float
    usable_dn: tuple
    usable_v_mag: tuple


def v_mag_of_dn(facility: Facility, dn, *, psf_pixels: float) -> np.ndarray:
    """V magnitude of an A0V star whose camera electrons equal ``psf_pixels`` screen pixels at
    ``dn`` above black (flat field 1), via the renderer's radiometry zero point."""
    from skynav.renderer.radiometry import Radiometry

    rad = Radiometry.for_camera(facility.camera)
    rm = facility.radiometric
    e_per_s = (rm.irradiance_w_m2(dn) - rm.black_w_m2) * facility.electrons_per_s_per_w_m2() * psf_pixels
    with np.errstate(divide="ignore"):
        return -2.5 * np.log10(e_per_s / rad.zero_point_e_per_s)


def calibrate_radiometric(facility: Facility, csv_path, *, psf_pixels: float = 20.0) -> RadiometricResult:
    from scipy.optimize import least_squares

    d, n, e = read_measurements(csv_path)
    per = e / n
    m = facility.screen.max_dn
    black0 = max(float(per[d == d.min()].mean()), 1e-30) if d.min() == 0 else per.min() * 0.5
    peak0 = float(per.max())

    def model(q):
        black, peak, gamma = math.exp(q[0]), math.exp(q[1]), q[2]
        return black + (peak - black) * (d / m) ** gamma

    def resid(q):
        return model(q) / per - 1.0

    r = least_squares(resid, [math.log(black0), math.log(peak0), 2.2], method="lm")
    black, peak, gamma = math.exp(r.x[0]), math.exp(r.x[1]), float(r.x[2])
    rm = RadiometricModel(black_w_m2=black, peak_w_m2=peak, gamma=gamma, max_dn=m)
    rms = float(np.sqrt(np.mean(resid(r.x) ** 2)))
    grid = np.arange(1, m + 1)
    E = rm.irradiance_w_m2(grid)
    step = np.diff(rm.irradiance_w_m2(np.arange(0, m + 1))) / np.maximum(E - black, 1e-300)
    ok = (step < 0.10) & (E - black > black)
    lo = int(grid[ok][0]) if ok.any() else m
    new = facility.replace(radiometric=rm)
    v = v_mag_of_dn(new, np.array([lo, m], dtype=float), psf_pixels=psf_pixels)
    cal = {
        "samples": {"digital_count": [int(x) for x in d], "irradiance_per_px_w_m2": [float(x) for x in per]},
        "fit": {"rms_relative": round(rms, 6), "n": int(len(d))},
        "usable_range": {"dn_min": lo, "dn_max": m, "v_mag_faintest": round(float(v[0]), 3), "v_mag_brightest": round(float(v[1]), 3),
                         "psf_pixels": psf_pixels},
        "electrons_per_s_per_w_m2": facility.electrons_per_s_per_w_m2(),
        "provenance": {"measurements": str(csv_path), "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())},
    }
    new = dataclasses.replace(new, calibrated_radiometric=cal)
    return RadiometricResult(facility=new, dn=d, per_pixel_w_m2=per, rms_relative=rms, usable_dn=(lo, m),
                             usable_v_mag=(float(v[0]), float(v[1])))
