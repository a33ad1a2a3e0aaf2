"""FITS frames: the image as given with a TAN WCS of the apparent sky and the keywords a FITS
user expects; written through ``astropy.io.fits``, atomically.

The primary HDU holds the image as given (uint8/uint16/int/float, DN not rescaled), plus an
optional TAN WCS of the *apparent* sky from :func:`tan_wcs_header` and, for frames, the standard
keywords of :func:`fits_frame_header` (``DATE-OBS`` UTC, ``MJD-OBS``, ``EXPTIME``, ``BUNIT``,
``GAIN``, ``SATURATE``, the observer's state...). Identical inputs give identical bytes.
"""

from __future__ import annotations

import io
import math
import warnings
from collections.abc import Mapping

import numpy as np

from skynav.infra.atomic_files import atomic_write_bytes, open_binary
from skynav.scenes.camera import Camera
from skynav.scenes.timescales import time_from_tdb_seconds

from .errors import OutputFormatError
from .frame_truth import epoch_tdb_seconds

__all__ = ["fits_frame_header", "fits_bytes", "read_fits", "tan_wcs_header", "write_fits"]


def tan_wcs_header(camera_K, width: int, height: int, R_cam_icrs) -> dict:
    """FITS TAN (gnomonic) WCS of the apparent sky for an undistorted pinhole camera.

    With the camera at ``R_cam_icrs`` (passive, ``v_cam = R_cam_icrs @ u_icrs``) a direction ``u``
    lands at ``[x, y, 1] ~ K v_cam`` (docs/conventions.md pixels, top-left pixel centre at (0, 0)).
    Writing the tangent-plane (standard) coordinates at the boresight as
    ``xi = u.e / u.b``, ``eta = u.n / u.b`` (``b`` boresight, ``e`` east, ``n`` north unit
    vectors), the rows ``r0, r1`` of ``R_cam_icrs`` lie in that plane, so
    ``[x - cx, y - cy] = K2 M [xi, eta]`` with ``K2 = K[:2, :2]`` and
    ``M = [[r0.e, r0.n], [r1.e, r1.n]]``. FITS TAN (Calabretta & Greisen 2002, LONPOLE = 180)
    defines intermediate world coordinates ``(xi, eta)`` in degrees = ``CD @ (p - CRPIX)``, hence
    ``CD = deg(inv(K2 M))`` and ``CRPIX = (cx + 1, cy + 1)`` (FITS pixels are 1-based; image row 0
    is FITS row 1, no flip).

    Lens distortion is not represented; the WCS describes the *apparent* directions (after
    light-time and aberration) the renderer projects, so it matches the rendered stars.

    Parameters
    ----------
    camera_K : array_like, shape (3, 3)
        Intrinsic matrix ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``, px.
    width, height : int
        Image size, px (``NAXIS1``, ``NAXIS2``).
    R_cam_icrs : array_like, shape (3, 3)
        Attitude, passive, ICRS to camera.

    Returns
    -------
    dict
        FITS keywords (``WCSAXES``, ``CTYPE1/2``, ``CUNIT1/2``, ``CRPIX1/2``, ``CRVAL1/2`` (deg),
        ``CD1_1`` ... ``CD2_2`` (deg/px), ``LONPOLE``, ``RADESYS`` = ``ICRS``, ``NAXIS1/2``).

    References
    ----------
    Calabretta & Greisen (2002), A&A 395, 1077: eqs. 54-55 (TAN), section 2.3 (LONPOLE).
    """
    K = np.asarray(camera_K, dtype=float)
    R = np.asarray(R_cam_icrs, dtype=float)
    if K.shape != (3, 3) or R.shape != (3, 3):
        raise OutputFormatError(f"tan_wcs_header needs K and R_cam_icrs of shape (3, 3); got {K.shape}, {R.shape}")
    b = R[2] / np.linalg.norm(R[2])
    ra0 = math.atan2(b[1], b[0]) % (2.0 * math.pi)
    dec0 = math.atan2(b[2], math.hypot(b[0], b[1]))
    east = np.array([-math.sin(ra0), math.cos(ra0), 0.0])
    north = np.array([-math.sin(dec0) * math.cos(ra0), -math.sin(dec0) * math.sin(ra0), math.cos(dec0)])
    M = np.array([[R[0] @ east, R[0] @ north], [R[1] @ east, R[1] @ north]])
    CD = np.degrees(np.linalg.inv(K[:2, :2] @ M))
    return {
        "WCSAXES": 2,
        "NAXIS1": int(width),
        "NAXIS2": int(height),
        "CTYPE1": "RA---TAN",
        "CTYPE2": "DEC--TAN",
        "CUNIT1": "deg",
        "CUNIT2": "deg",
        "CRPIX1": float(K[0, 2]) + 1.0,
        "CRPIX2": float(K[1, 2]) + 1.0,
        "CRVAL1": math.degrees(ra0),
        "CRVAL2": math.degrees(dec0),
        "CD1_1": float(CD[0, 0]),
        "CD1_2": float(CD[0, 1]),
        "CD2_1": float(CD[1, 0]),
        "CD2_2": float(CD[1, 1]),
        "LONPOLE": 180.0,
        "RADESYS": "ICRS",
    }


#: Instrument and telescope names of skynav's frames (FITS ``INSTRUME`` / ``TELESCOP``).
FITS_INSTRUME = "skynav simulated camera"
FITS_TELESCOP = "skynav simulated spacecraft"


def fits_frame_header(truth: Mapping) -> dict:
    """The standard FITS keywords of a frame, from its ground truth: ``{key: (value, comment)}``.

    Time (FITS 4.0 standard, section 9; Rots et al. 2015, A&A 574, A36): the truth's epoch is
    mid-exposure, TDB; the header gives UTC (``TIMESYS = 'UTC'``), ``DATE-OBS`` and ``MJD-OBS``
    at the *start* of the exposure (the standard's meaning), ``DATE-AVG``/``MJD-AVG`` at
    mid-exposure (the epoch of the WCS and of the truth) and ``DATE-END``/``MJD-END``; ISO 8601 with
    microseconds. TDB to UTC by astropy/ERFA with its installed leap-second table; an epoch
    after the table (the future) assumes no further leap second.
    ``EXPTIME`` (s); ``BUNIT = 'adu'`` (the DN); ``INSTRUME``, ``TELESCOP``, ``ORIGIN``;
    ``GAIN`` (e-/DN, the inverse of the sensor's ``gain_dn_per_e``), ``RDNOISE`` (e-),
    ``SATURATE`` (DN: the full-well charge read out, ``floor(K full_well + offset + 1/2)``,
    at most ``2**bit_depth - 1``).

    The observer (a spacecraft: ``OBSGEO-*`` are for Earth-fixed observatories) in short keys
    of this project: ``OBSFRAME = 'ICRS'`` (axes ICRS, origin the solar-system barycentre, as
    the truth's ``observer``), ``OBSPOS-X/Y/Z`` (km) and ``OBSVEL-X/Y/Z`` (km/s).

    Parameters
    ----------
    truth : mapping
        A ``skynav.frame/2`` dict (``epoch``, ``observer``, ``camera`` with its ``sensor``).
    """
    # astropy (~0.2-0.7 s to import) only for FITS files: the reader imports this module for PNGs
    from astropy.time import TimeDelta

    cam = Camera.from_dict(dict(truth["camera"]))
    sp = cam.sensor
    mid = time_from_tdb_seconds(epoch_tdb_seconds(truth["epoch"]))
    half = TimeDelta(cam.exposure_s / 2.0, format="sec")
    with warnings.catch_warnings():
        # UTC after the installed leap-second table (ERFA: "dubious year") assumes no further
        # leap second: TAI - UTC stays at its last value (37 s since 2017)
        warnings.filterwarnings("ignore", message=".*dubious year.*")
        utc = [t.utc for t in (mid - half, mid, mid + half)]
        for t in utc:
            t.precision = 6
        (start_iso, mid_iso, end_iso), (start_mjd, mid_mjd, end_mjd) = [t.isot for t in utc], [float(t.mjd) for t in utc]

    pos = [float(v) for v in np.asarray(truth["observer"]["position_km"], dtype=float)]
    vel = [float(v) for v in np.asarray(truth["observer"]["velocity_km_s"], dtype=float)]
    saturate = min(sp.max_dn, math.floor(sp.gain_dn_per_e * sp.full_well_e + sp.offset_dn + 0.5))
    h = {
        "TIMESYS": ("UTC", "time scale of DATE-*, MJD-*"),
        "DATE-OBS": (start_iso, "start of exposure"),
        "MJD-OBS": (start_mjd, "[d] start of exposure, UTC"),
        "DATE-AVG": (mid_iso, "mid-exposure: truth, WCS"),
        "MJD-AVG": (mid_mjd, "[d] mid-exposure, UTC"),
        "DATE-END": (end_iso, "end of exposure"),
        "MJD-END": (end_mjd, "[d] end of exposure, UTC"),
        "EXPTIME": (float(cam.exposure_s), "[s] exposure time"),
        "BUNIT": ("adu", "digital counts (DN) of the camera"),
        "INSTRUME": (FITS_INSTRUME, "rendered, not observed"),
        "TELESCOP": (FITS_TELESCOP, "rendered, not observed"),
        "ORIGIN": ("skynav", "software that wrote this file"),
        "GAIN": (1.0 / float(sp.gain_dn_per_e), "[e-/DN] system gain"),
        "RDNOISE": (float(sp.read_noise_e), "[e-] read noise"),
        "SATURATE": (int(saturate), "[DN] saturation level"),
        "BITDEPTH": (int(sp.bit_depth), "sensor bit depth"),
        "OBSFRAME": ("ICRS", "OBSPOS/OBSVEL: ICRS, barycentric"),
    }
    for axis, p in zip("XYZ", pos):
        h[f"OBSPOS-{axis}"] = (p, f"[km] observer position {axis}")
    for axis, v in zip("XYZ", vel):
        h[f"OBSVEL-{axis}"] = (v, f"[km/s] observer velocity {axis}")
    return h


# Keywords astropy derives from the data array; a caller's header must not contradict them.
_FITS_STRUCTURAL = frozenset({"SIMPLE", "BITPIX", "NAXIS", "NAXIS1", "NAXIS2", "EXTEND", "BZERO", "BSCALE"})


def write_fits(path, image, *, wcs_header: Mapping | None = None, header: Mapping | None = None) -> None:
    """Write an image (DN or float) to a single-HDU FITS file with an optional WCS, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Destination ``.fits``.
    image : ndarray, shape (H, W)
        uint8, uint16 (stored as int16 with ``BZERO = 32768``, read back as uint16 by astropy),
        int16/int32, float32 or float64. Row 0 of the array is FITS row 1 (no flip), so pixel
        ``(x, y)`` of docs/conventions.md is FITS ``(x + 1, y + 1)``.
    wcs_header : mapping, optional
        Output of :func:`tan_wcs_header`; ``NAXIS1/2`` in it must match the image.
    header : mapping, optional
        Extra keywords (<= 8 characters), e.g. ``{"EXPTIME": 0.4}`` or ``{"EXPTIME": (0.4,
        "[s] exposure time")}`` (value, comment); :func:`fits_frame_header` gives a frame's.

    Raises
    ------
    OutputFormatError
        Wrong shape or dtype, or a WCS made for another image size.
    """
    atomic_write_bytes(path, fits_bytes(image, wcs_header, header))


def fits_bytes(image, wcs_header, header) -> bytes:
    """The checked bytes of :func:`write_fits`."""
    # astropy (~0.2-0.7 s to import) only for FITS files: the reader imports this module for PNGs
    from astropy.io import fits

    a = np.asarray(image)
    if a.ndim != 2:
        raise OutputFormatError(f"FITS image has shape {a.shape}; expected a 2-D (H, W) array")
    if a.dtype.kind not in "uif" or a.dtype.itemsize > 8 or a.dtype == np.uint64:
        raise OutputFormatError(f"FITS image has dtype {a.dtype}; expected uint8/uint16/int16/int32/float32/float64")
    hdu = fits.PrimaryHDU(np.ascontiguousarray(a))
    for source in (wcs_header or {}), (header or {}):
        for key, value in source.items():
            key = str(key).upper()
            if key in ("NAXIS1", "NAXIS2"):
                n = a.shape[1] if key == "NAXIS1" else a.shape[0]
                if int(value) != n:
                    raise OutputFormatError(f"FITS {key} = {value} in the header but the image has {n}; was the WCS made for another camera?")
                continue
            if key in _FITS_STRUCTURAL:
                raise OutputFormatError(f"FITS keyword {key} is set from the data; remove it from the header")
            if isinstance(value, np.generic):
                value = value.item()
            hdu.header[key] = value
    buf = io.BytesIO()
    fits.HDUList([hdu]).writeto(buf)
    return buf.getvalue()


def read_fits(source):
    """(image ndarray (H, W), header as ``astropy.io.fits.Header``) of the primary HDU."""
    # astropy (~0.2-0.7 s to import) only for FITS files: the reader imports this module for PNGs
    from astropy.io import fits

    with open_binary(source) as f, fits.open(f, memmap=False) as hdul:
        return np.array(hdul[0].data), hdul[0].header.copy()
