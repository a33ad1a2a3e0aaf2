"""The measured PSF model, and the reading of every PSF model from its mapping.

A measured PSF (``{model: tabulated, file: psf.npy, oversampling: 4}``, or ``field: [{x_px, y_px,
file}, ...]`` for a grid across the field) is read from ``.npy`` or ``.fits`` images, normalised to
a sum of 1 and fingerprinted (``sha256``); the formula models (Gaussian, Airy, optical) are in
:mod:`skynav.scenes.psf`, whose docstring describes all four. :func:`psf_from_dict` makes any of
them from the mapping a scene file, recipe, facility file, truth or manifest holds, and
:func:`resolve_psf_files` makes a file's relative PSF paths relative to that file's folder.

Pixel convention (docs/conventions.md): ``(x, y)`` with x along columns, the centre of the top-left
pixel at ``(0, 0)``. Tables are indexed ``[row, column]`` = ``[y, x]``.
"""

from __future__ import annotations

import contextvars
import dataclasses
import hashlib
import math
import os
from dataclasses import dataclass

import numpy as np

from skynav.infra.errors import ConfigValueError

from .psf import (FWHM_PER_SIGMA, MAX_HALF_SIZE_PX, PSF_MODELS, AiryPSFModel, GaussianPSFModel, OpticalPSFModel,
                  _check_cap, _half_max_fwhm, _num)

__all__ = ["PSFModel", "TabulatedPSFModel", "FieldPSF", "psf_from_dict", "resolve_psf_files", "PSF_FILE_OPENER"]


@dataclass(frozen=True, kw_only=True)
class FieldPSF:
    """One point of a tabulated PSF grid: the image ``file`` measured at pixel ``(x_px, y_px)``."""

    x_px: float
    y_px: float
    file: str


#: How a tabulated PSF reads its files. None (the default): ``file`` names are paths, read from
#: the file system (a relative one from the current directory) and stored absolute. Else a
#: function ``(name, key) -> binary file object`` that resolves and opens the name (raising a
#: :class:`ConfigValueError` where it may not), and the names are stored as given: the render
#: service reads a request's files so, only inside its ``--data-dir`` folders
#: (:mod:`skynav.service.files`).
PSF_FILE_OPENER: contextvars.ContextVar = contextvars.ContextVar("PSF_FILE_OPENER", default=None)


def _read_image(path: str, key: str, opener=None) -> np.ndarray:
    """A PSF image from a ``.npy`` or ``.fits`` file: 2-D, finite, >= 0, sum > 0; float64.
    ``opener(path, key)`` opens it where given (:data:`PSF_FILE_OPENER`), else ``open``."""
    low = path.lower()
    try:
        if not low.endswith((".npy", ".fits", ".fit", ".fits.gz")):
            raise ConfigValueError(key, path, "a .npy or .fits file")
        with (open(path, "rb") if opener is None else opener(path, key)) as f:
            if low.endswith(".npy"):
                a = np.load(f, allow_pickle=False)
            else:
                # astropy.io.fits: ~0.2 s to import, only a FITS PSF image needs it
                from astropy.io import fits

                with fits.open(f, memmap=False) as hdul:
                    a = next((h.data for h in hdul if h.data is not None), None)
    except OSError as e:
        raise ConfigValueError(key, path, f"a readable .npy or .fits file ({e.strerror or e})") from None
    except ValueError as e:
        if isinstance(e, ConfigValueError):
            raise
        raise ConfigValueError(key, path, f"a readable .npy or .fits file ({e})") from None
    if a is None or np.ndim(a) != 2 or min(np.shape(a)) < 3:
        raise ConfigValueError(key, path, "a 2-D image of at least 3 x 3 samples")
    a = np.asarray(a, dtype=float)
    if not np.all(np.isfinite(a)) or np.any(a < 0) or not a.sum() > 0:
        raise ConfigValueError(key, path, "an image of finite values >= 0 with a positive sum")
    return a / a.sum()


@dataclass(frozen=True, kw_only=True)
class TabulatedPSFModel:
    """A measured PSF: one image (``file``) or a rectangular grid of them across the field.

    Files are read once, when the model is made, and normalised to a sum of 1; ``sha256`` (of the
    normalised float64 tables) makes two models with the same paths but other contents differ.
    Relative paths are read from the current directory and stored absolute; a scene file, recipe
    or facility file first makes its own relative paths relative to its folder
    (:func:`resolve_psf_files`).

    Parameters
    ----------
    oversampling : int
        Samples of the image per pixel, 1..64 (the image is centred on its middle sample).
    file : str or None
        A ``.npy`` or ``.fits`` image (2-D, >= 0); or give ``field``.
    field : tuple of FieldPSF or of dict
        A rectangular grid of images across the field: ``{x_px, y_px, file}`` each (px).
    max_half_px : int
        Largest stamp half size, px.
    sha256 : str
        Filled on reading: the hash of the normalised tables.

    Raises
    ------
    ConfigValueError
        A missing or unreadable file, both or neither of ``file`` and ``field``, a grid that
        is not rectangular.

    Examples
    --------
    >>> import os, tempfile
    >>> from skynav.scenes import TabulatedPSFModel
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     y, x = np.mgrid[-8:9, -8:9]
    ...     np.save(os.path.join(tmp, "psf.npy"), np.exp(-(x**2 + y**2) / 8.0))   # 4 samples/px
    ...     psf = TabulatedPSFModel(file=os.path.join(tmp, "psf.npy"), oversampling=4)
    >>> psf.to_dict()["model"], psf.oversampling, len(psf.sha256)
    ('tabulated', 4, 64)
    """

    oversampling: int = 1
    file: str | None = None
    field: tuple = ()
    max_half_px: int = MAX_HALF_SIZE_PX
    sha256: str = dataclasses.field(default="", compare=True, repr=False)
    model = "tabulated"
    polychromatic = False

    def __post_init__(self):
        _check_cap(self)
        o = self.oversampling
        if isinstance(o, bool) or not isinstance(o, (int, np.integer)) or not 1 <= o <= 64:
            raise ConfigValueError("camera.psf.oversampling", o, "an integer in 1..64 (samples per pixel)")
        object.__setattr__(self, "oversampling", int(o))
        opener = PSF_FILE_OPENER.get()
        if (self.file is None) == (not self.field):
            raise ConfigValueError("camera.psf.file", self.file, "either file or field (a grid of {x_px, y_px, file}), not both")
        if self.file is not None:
            if not isinstance(self.file, str):
                raise ConfigValueError("camera.psf.file", self.file, "a path to a .npy or .fits file")
            if opener is None:
                object.__setattr__(self, "file", os.path.abspath(self.file))
            tables = (_read_image(self.file, "camera.psf.file", opener),)
            grid = None
        else:
            pts = []
            for i, p in enumerate(self.field):
                key = f"camera.psf.field[{i}]"
                if isinstance(p, dict):
                    extra = set(p) - {"x_px", "y_px", "file"}
                    if extra or not {"x_px", "y_px", "file"} <= set(p):
                        raise ConfigValueError(key, p, "a mapping with x_px, y_px and file")
                    p = FieldPSF(x_px=p["x_px"], y_px=p["y_px"], file=p["file"])
                if not isinstance(p, FieldPSF) or not isinstance(p.file, str):
                    raise ConfigValueError(key, p, "a mapping with x_px, y_px and file")
                pts.append(FieldPSF(x_px=_num(p.x_px, f"{key}.x_px"), y_px=_num(p.y_px, f"{key}.y_px"),
                                    file=p.file if opener is not None else os.path.abspath(p.file)))
            xs = sorted({p.x_px for p in pts})
            ys = sorted({p.y_px for p in pts})
            where = {(p.x_px, p.y_px): k for k, p in enumerate(pts)}
            if len(where) != len(pts) or len(pts) != len(xs) * len(ys):
                raise ConfigValueError("camera.psf.field", f"{len(pts)} points",
                                       "a rectangular grid: one file at every (x_px, y_px) of its distinct x and y values")
            object.__setattr__(self, "field", tuple(pts))
            tables = tuple(_read_image(p.file, f"camera.psf.field[{k}].file", opener) for k, p in enumerate(pts))
            if len({t.shape for t in tables}) != 1:
                raise ConfigValueError("camera.psf.field", [t.shape for t in tables], "images of one shape")
            grid = (tuple(xs), tuple(ys), tuple(tuple(where[(x, y)] for x in xs) for y in ys))
        h = hashlib.sha256()
        for t in tables:
            h.update(np.ascontiguousarray(t).tobytes())
            h.update(str(t.shape).encode())
        digest = h.hexdigest()
        if self.sha256 and self.sha256 != digest:
            raise ConfigValueError("camera.psf.sha256", self.sha256, f"the files' sha256 {digest} (a PSF file has changed)")
        object.__setattr__(self, "sha256", digest)
        object.__setattr__(self, "_tables", tables)
        object.__setattr__(self, "_grid", grid)

    @property
    def tables(self) -> tuple:
        """The normalised images, one per grid point (one without a field), ``[row, col]``."""
        return self._tables

    @property
    def grid(self):
        """``(xs, ys, index[iy][ix])`` of a field grid (index into :attr:`tables`), or None."""
        return self._grid

    def __getstate__(self):
        return {k: getattr(self, k) for k in ("oversampling", "file", "field", "max_half_px", "sha256", "_tables", "_grid")}

    def __setstate__(self, state):
        for k, v in state.items():
            object.__setattr__(self, k, v)

    def half_size_px(self, flux_fraction_lost: float, camera=None) -> int:
        """Half size of the smallest centred square holding all but ``flux_fraction_lost`` of
        every table (capped at the table's own half size)."""
        h_best = 0
        o = self.oversampling
        for t in self._tables:
            ny, nx = t.shape
            cy, cx = (ny - 1) / 2.0, (nx - 1) / 2.0
            yy = np.abs(np.arange(ny) - cy)[:, None] / o
            xx = np.abs(np.arange(nx) - cx)[None, :] / o
            cheb = np.maximum(yy, xx).ravel()
            order = np.argsort(cheb)
            outside = 1.0 - np.cumsum(t.ravel()[order])
            k = int(np.searchsorted(-outside, -flux_fraction_lost))  # first index where outside <= f
            r = cheb[order][min(k, cheb.size - 1)]
            h_best = max(h_best, int(math.ceil(r + 0.5 - 1e-9)))
        return int(min(self.max_half_px, h_best))

    def reach_px(self, camera=None) -> float:
        """How far from a source its light reaches, px: the stamp half size at 1e-6."""
        return float(self.half_size_px(1e-6, camera))

    def fwhm_px(self, camera=None) -> float:
        """Equivalent full width at half maximum of the widest image of the grid, px: the
        diameter of the disc whose area is the image's area above half its peak (counted in
        samples of ``1 / oversampling`` px: coarse for an image of 1 sample per px)."""
        return max(_half_max_fwhm(t, 1.0 / self.oversampling) for t in self._tables)

    def equivalent_sigma_px(self, camera=None) -> float:
        """The sigma of the Gaussian of the same (equivalent) FWHM, px."""
        return self.fwhm_px(camera) / FWHM_PER_SIGMA

    def to_dict(self) -> dict:
        """The model's mapping (a scene file's ``camera.psf``; :func:`psf_from_dict` inverts it)."""
        d = {"model": "tabulated", "oversampling": self.oversampling}
        if self.file is not None:
            d["file"] = self.file
        else:
            d["field"] = [{"x_px": p.x_px, "y_px": p.y_px, "file": p.file} for p in self.field]
        if self.max_half_px != MAX_HALF_SIZE_PX:
            d["max_half_px"] = self.max_half_px
        d["sha256"] = self.sha256
        return d


PSFModel = GaussianPSFModel | AiryPSFModel | OpticalPSFModel | TabulatedPSFModel


def _resolve_psf(psf: dict, folder: str) -> dict:
    def join(f):
        return os.path.normpath(os.path.join(folder, f)) if isinstance(f, str) and f and not os.path.isabs(f) else f

    out = dict(psf)
    if "file" in out:
        out["file"] = join(out["file"])
    if isinstance(out.get("field"), list):
        out["field"] = [dict(p, file=join(p["file"])) if isinstance(p, dict) and "file" in p else p for p in out["field"]]
    return out


def resolve_psf_files(mapping, folder):
    """A copy of a file's parsed mapping with the relative PSF file paths of its cameras (every
    ``camera: {psf: {file}}`` and ``camera: {psf: {field: [{file}]}}``, at any depth: a scene
    file's camera, a recipe's and each of its scenes', a facility file's) joined to ``folder``,
    the folder of the file that names them, as a reader of that file expects; absolute paths
    and anything else are left as written (the model's validation judges them).

    Examples
    --------
    >>> resolve_psf_files({"camera": {"psf": {"model": "tabulated", "file": "psf.npy"}}}, "/lab/run1")
    {'camera': {'psf': {'model': 'tabulated', 'file': '/lab/run1/psf.npy'}}}
    """
    folder = os.path.abspath(os.fspath(folder))

    def walk(node, parent=None):
        if isinstance(node, dict):
            return {k: _resolve_psf(v, folder) if k == "psf" and parent == "camera" and isinstance(v, dict) else walk(v, k)
                    for k, v in node.items()}
        if isinstance(node, list):
            return [walk(v, parent) for v in node]
        return node

    return walk(mapping)

_KEYS = {
    "gaussian": {"sigma_px"},
    "airy": {"obscuration", "wavelength_nm", "max_half_px"},
    "optical": {"obscuration", "wavelength_nm", "zernike_waves", "max_half_px"},
    "tabulated": {"file", "oversampling", "field", "max_half_px", "sha256"},
}


def psf_from_dict(d, key: str = "camera.psf"):
    """A PSF model from its mapping (a scene file's ``camera.psf``, or :meth:`to_dict`).

    Parameters
    ----------
    d : dict or PSF model
        ``{model: gaussian|airy|optical|tabulated, ...}`` with the keys of that model (module
        docstring); a model is returned as it is.
    key : str
        The mapping's dotted name, for the error messages.

    Returns
    -------
    GaussianPSFModel, AiryPSFModel, OpticalPSFModel or TabulatedPSFModel
        The model.

    Raises
    ------
    ConfigValueError
        Naming the bad key and what is allowed.

    Examples
    --------
    >>> from skynav.scenes import ConfigValueError, psf_from_dict
    >>> psf_from_dict({"model": "airy", "wavelength_nm": 550})
    AiryPSFModel(obscuration=0.0, wavelength_nm=550.0, max_half_px=16)
    >>> try:
    ...     psf_from_dict({"model": "moffat"})
    ... except ConfigValueError as exc:
    ...     print(exc)
    camera.psf.model = 'moffat' is not allowed; expected one of: gaussian, airy, optical, tabulated
    """
    if isinstance(d, (GaussianPSFModel, AiryPSFModel, OpticalPSFModel, TabulatedPSFModel)):
        return d
    if not isinstance(d, dict):
        raise ConfigValueError(key, d, "a mapping with model: " + ", ".join(PSF_MODELS))
    m = d.get("model")
    if not isinstance(m, str) or m not in _KEYS:
        raise ConfigValueError(f"{key}.model", m, "one of: " + ", ".join(PSF_MODELS))
    for k in d:
        if k != "model" and k not in _KEYS[m]:
            raise ConfigValueError(f"{key}.{k}", d[k], f"no such key for model {m}; allowed keys: " + ", ".join(sorted(_KEYS[m])))
    kw = {k: v for k, v in d.items() if k != "model"}
    if m == "gaussian":
        if "sigma_px" not in kw:
            raise ConfigValueError(f"{key}.sigma_px", None, "a value (px)")
        return GaussianPSFModel(kw["sigma_px"])
    if m == "airy":
        return AiryPSFModel(**kw)
    if m == "optical":
        if "wavelength_nm" not in kw:
            raise ConfigValueError(f"{key}.wavelength_nm", None, "a wavelength, nm: the optical model is monochromatic (its Zernike "
                                   "waves are at one wavelength); for a polychromatic pattern use model airy without wavelength_nm")
        z = kw.get("zernike_waves", {})
        if not isinstance(z, dict):
            raise ConfigValueError(f"{key}.zernike_waves", z, "a mapping of Noll index (2..36) to waves RMS")
        kw["zernike_waves"] = z
        return OpticalPSFModel(**kw)
    if "field" in kw:
        if not isinstance(kw["field"], (list, tuple)) or not kw["field"]:
            raise ConfigValueError(f"{key}.field", kw["field"], "a list of {x_px, y_px, file}")
        kw["field"] = tuple(kw["field"])
    return TabulatedPSFModel(**kw)
