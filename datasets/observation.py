"""What the navigation pipeline may see of a frame: :class:`Observation`, and no ground truth.

Core module. docs/architecture.md: the pipeline sees only what a spacecraft would: the image, the time
tag, the exposure and the camera *as calibrated*. An :class:`Observation` holds exactly these;
no attribute leads to the truth (no truth dict, no file path, no reader object), and scoring code
opens the truth separately (:meth:`skynav.datasets.reader.Dataset.truth`).

The calibrated camera is the true one (the truth's camera record, through
``Camera.from_dict``), optionally perturbed by a :class:`CalibrationErrorModel`: a fixed bias of
the focal length, the principal point and the first radial distortion term, drawn once from the
model's seed (the same for every frame, as a real calibration is), so a campaign can test how
the pipeline copes with an imperfect calibration. The model (its sigmas and seed) is recorded on
the observation; the drawn offsets are not, and :meth:`CalibrationErrorModel.draw` gives them to
scoring code.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from skynav.infra.errors import ConfigValueError
from skynav.scenes.camera import Camera
from skynav.scenes.timescales import time_from_tdb_seconds

from .frame_truth import epoch_tdb_seconds

__all__ = ["CalibrationErrorModel", "CalibrationOffsets", "Observation", "make_observation"]


@dataclass(frozen=True, kw_only=True)
class CalibrationOffsets:
    """One draw of a :class:`CalibrationErrorModel`: calibrated minus true.

    Attributes
    ----------
    focal_length_rel : float
        Relative focal-length error: ``f_cal = f_true * (1 + focal_length_rel)`` (scales fx and fy).
    cx_px, cy_px : float
        Principal-point error, px.
    k1 : float
        Error of the first radial Brown-Conrady coefficient (normalised coordinates).
    """

    focal_length_rel: float
    cx_px: float
    cy_px: float
    k1: float


@dataclass(frozen=True, kw_only=True)
class CalibrationErrorModel:
    """Independent Gaussian errors of a camera calibration, drawn once from ``seed``.

    Parameters
    ----------
    focal_length_rel_sigma : float
        Standard deviation of the relative focal-length error (1e-4 = 100 ppm), >= 0.
    principal_point_sigma_px : float
        Standard deviation of each principal-point coordinate's error, px, >= 0.
    distortion_k1_sigma : float
        Standard deviation of the error of ``k1``, >= 0.
    seed : int
        Seed of the draw (``numpy.random.default_rng(seed)``), >= 0: the same model gives the
        same calibrated camera in every frame and every process.

    Examples
    --------
    >>> from skynav.datasets import CalibrationErrorModel
    >>> from skynav.scenes import paper_camera
    >>> m = CalibrationErrorModel(focal_length_rel_sigma=1e-4, principal_point_sigma_px=0.5, seed=7)
    >>> m.draw() == m.draw()
    True
    >>> cam = paper_camera()
    >>> calibrated = m.apply(cam)
    >>> bool(abs(calibrated.focal_length_mm / cam.focal_length_mm - 1) < 5e-4)
    True
    """

    focal_length_rel_sigma: float = 0.0
    principal_point_sigma_px: float = 0.0
    distortion_k1_sigma: float = 0.0
    seed: int = 0

    def __post_init__(self):
        for key in ("focal_length_rel_sigma", "principal_point_sigma_px", "distortion_k1_sigma"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v >= 0.0):
                raise ConfigValueError(f"calibration_error.{key}", v, "a finite number >= 0")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ConfigValueError("calibration_error.seed", self.seed, "an integer >= 0")

    def draw(self) -> CalibrationOffsets:
        """The offsets of this model, drawn from ``default_rng(seed)`` (the same every call).

        Four standard normals in the order focal length, cx, cy, k1, each times its sigma.

        Returns
        -------
        CalibrationOffsets
            ``focal_length_rel`` (no unit), ``cx_px``, ``cy_px`` (px), ``k1`` (no unit).
        """
        z = np.random.default_rng(int(self.seed)).standard_normal(4)
        return CalibrationOffsets(focal_length_rel=float(z[0] * self.focal_length_rel_sigma),
                                  cx_px=float(z[1] * self.principal_point_sigma_px),
                                  cy_px=float(z[2] * self.principal_point_sigma_px),
                                  k1=float(z[3] * self.distortion_k1_sigma))

    def apply(self, camera):
        """The calibrated camera: ``camera`` with this model's offsets added.

        Parameters
        ----------
        camera : skynav.scenes.camera.Camera
            The true camera.

        Returns
        -------
        skynav.scenes.camera.Camera
            ``focal_length_mm`` times ``1 + focal_length_rel``; ``cx``, ``cy`` (a centred
            principal point first made explicit from ``K``) plus the offsets; ``distortion.k1``
            plus its offset. All other fields unchanged (``dataclasses.replace``).
        """
        d = self.draw()
        K = np.asarray(camera.K, dtype=float)
        return dataclasses.replace(
            camera,
            focal_length_mm=camera.focal_length_mm * (1.0 + d.focal_length_rel),
            cx=float(K[0, 2]) + d.cx_px,
            cy=float(K[1, 2]) + d.cy_px,
            distortion=dataclasses.replace(camera.distortion, k1=camera.distortion.k1 + d.k1),
        )


@dataclass(frozen=True, kw_only=True, eq=False)
class Observation:
    """One frame as the spacecraft has it: image, time tag, exposure, calibrated camera.

    Attributes
    ----------
    index : int
        Frame number in the dataset.
    dn : ndarray, shape (H, W), uint8 or uint16, read-only
        Digital counts (raw, not rescaled).
    epoch_tdb_s : float
        Mid-exposure epoch, TDB seconds past J2000 (a float, the code's internal time; see
        :attr:`epoch` for an ``astropy.time.Time``).
    exposure_s : float
        Exposure time, s.
    camera : skynav.scenes.camera.Camera
        The camera as calibrated: the true one when ``calibration_error`` is None, else
        ``calibration_error.apply(true camera)``.
    calibration_error : CalibrationErrorModel or None
        The error model the camera was perturbed with (None: exact calibration).

    Examples
    --------
    >>> import tempfile
    >>> from skynav.datasets import generate, preset_recipe
    >>> from skynav.renderer import RenderOptions
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=2, camera={"preset": "paper", "width": 64, "height": 64, "fov_deg": 20})
    >>> tmp = tempfile.TemporaryDirectory()
    >>> summary = generate(recipe, tmp.name + "/ds", workers=1, progress=False,
    ...                    render_options=RenderOptions(backend="numpy"))
    >>> from skynav.datasets import CalibrationErrorModel, open
    >>> ds = open(tmp.name + "/ds")
    >>> obs = ds.observation(0, calibration_error=CalibrationErrorModel(principal_point_sigma_px=0.5))
    >>> obs.dn.shape, obs.exposure_s, obs.epoch.scale
    ((64, 64), 0.4, 'tdb')
    >>> obs.camera.cx != ds.camera.cx
    True
    >>> tmp.cleanup()
    """

    index: int
    dn: np.ndarray
    epoch_tdb_s: float
    exposure_s: float
    camera: object
    calibration_error: CalibrationErrorModel | None = None

    @property
    def epoch(self):
        """Mid-exposure epoch as ``astropy.time.Time`` in the TDB scale (two-part JD, exact)."""
        return time_from_tdb_seconds(self.epoch_tdb_s)

    def __repr__(self) -> str:
        return (f"Observation(index={self.index}, dn={self.dn.dtype}{self.dn.shape}, epoch_tdb_s={self.epoch_tdb_s!r}, "
                f"exposure_s={self.exposure_s!r}, calibration_error={self.calibration_error!r})")


def make_observation(truth: dict, dn: np.ndarray, *, index: int,
                     calibration_error: CalibrationErrorModel | None = None, camera=None) -> Observation:
    """Build the observation of a frame from its file contents; keeps nothing of the truth.

    Parameters
    ----------
    truth : dict
        The frame's ``skynav.frame/2`` dict: only ``epoch`` and ``camera`` are read.
    dn : ndarray, shape (H, W)
        The frame's digital counts (made read-only).
    index : int
        Frame number.
    calibration_error : CalibrationErrorModel, optional
        Perturb the camera by this model.
    camera : skynav.scenes.camera.Camera, optional
        The true camera, when the caller has read it already (default:
        ``Camera.from_dict(truth["camera"])``).
    """
    if camera is None:
        camera = Camera.from_dict(truth["camera"])
    if calibration_error is not None:
        camera = calibration_error.apply(camera)
    dn = np.asarray(dn)
    if dn.flags.writeable:
        dn = dn.copy()
        dn.setflags(write=False)
    return Observation(index=int(index), dn=dn, epoch_tdb_s=epoch_tdb_seconds(truth["epoch"]),
                       exposure_s=float(truth["camera"]["exposure_s"]), camera=camera,
                       calibration_error=calibration_error)
