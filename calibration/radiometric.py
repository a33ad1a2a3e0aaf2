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
from scipy.optimize import least_squares

from skynav.renderer.radiometry import Radiometry
from skynav.scenes.facility import Facility, RadiometricModel

from .errors import MeasurementError

MIN_ROWS = 8


#: the most rows a measurement table may hold (a bench sweep has one per DN step: 65536 at 16 bits)
MAX_ROWS = 1_000_000
HEADER = ["digital_count", "lit_pixels", "irradiance_w_m2"]


def read_measurements(path, *, max_dn: int | None = None):
    """(digital_count, lit_pixels, irradiance_w_m2) arrays from the CSV, checked.

    UTF-8 text (a byte-order mark before the header is allowed), the header
    ``digital_count,lit_pixels,irradiance_w_m2``, then at least :data:`MIN_ROWS` rows of three
    finite numbers: whole digital counts in ``0..max_dn`` (when given), whole ``lit_pixels`` > 0,
    ``irradiance_w_m2`` >= 0; the irradiance per lit pixel must not fall as the count rises.

    Raises
    ------
    MeasurementError
        One line naming the file, the row and the column.
    """
    p = Path(path)
    if not p.is_file():
        raise MeasurementError(f"{path}: no such measurement file" + (" (a folder)" if p.is_dir() else ""))
    try:
        with open(p, newline="", encoding="utf-8-sig") as f:
            rows = list(csv.reader(f))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise MeasurementError(f"{path}: not a UTF-8 CSV table ({exc.__class__.__name__}); expected the header "
                               f"{','.join(HEADER)}") from None
    if not rows or [c.strip() for c in rows[0]] != HEADER:
        raise MeasurementError(f"{path}: header must be {','.join(HEADER)}")
    rows = [r for r in rows[1:] if r and any(c.strip() for c in r)]
    if len(rows) > MAX_ROWS:
        raise MeasurementError(f"{path}: {len(rows)} measurements; at most {MAX_ROWS}")
    for i, r in enumerate(rows):
        if len(r) != 3:
            raise MeasurementError(f"{path}: row {i + 2} has {len(r)} values; expected 3 ({','.join(HEADER)})")
    try:
        data = np.array([[float(c) for c in r] for r in rows], dtype=float).reshape(-1, 3)
    except ValueError as exc:
        raise MeasurementError(f"{path}: not a number ({exc})") from None
    for j, name in enumerate(HEADER):
        col = data[:, j]
        bad = ~np.isfinite(col) | (col < 0)
        if name == "digital_count":
            bad |= col != np.round(col)
            if max_dn is not None:
                bad |= col > max_dn
            allowed = f"a whole number in 0..{max_dn}" if max_dn is not None else "a whole number >= 0"
        elif name == "lit_pixels":
            bad |= (col <= 0) | (col != np.round(col)) | (col > 1e9)
            allowed = "a whole number of pixels > 0"
        else:
            bad |= col > 1e6
            allowed = "a finite irradiance in [0, 1e6] W/m^2"
        if np.any(bad):
            k = int(np.flatnonzero(bad)[0])
            raise MeasurementError(f"{path}: row {k + 2}: {name} = {rows[k][j].strip()}; expected {allowed}")
    if data.shape[0] < MIN_ROWS:
        raise MeasurementError(f"{path}: {data.shape[0]} measurements; need >= {MIN_ROWS} rows of 3 values")
    d, n, e = data.T
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
    if not per.max() > 0:
        raise MeasurementError(f"{path}: every irradiance_w_m2 is 0; the meter saw no light")
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
    rad = Radiometry.for_camera(facility.camera)
    rm = facility.radiometric
    e_per_s = (rm.irradiance_w_m2(dn) - rm.black_w_m2) * facility.electrons_per_s_per_w_m2() * psf_pixels
    with np.errstate(divide="ignore"):
        return -2.5 * np.log10(e_per_s / rad.zero_point_e_per_s)


def calibrate_radiometric(facility: Facility, csv_path, *, psf_pixels: float = 20.0) -> RadiometricResult:
    d, n, e = read_measurements(csv_path, max_dn=facility.screen.max_dn)
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
