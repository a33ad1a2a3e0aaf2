"""Your own star tracker, benchmarked by skynav: scikit-image centroids, tetra3rs's solver.

    skynav bench ip DATASET --pipeline docs/examples/ip_plugin.py:make -o REPORT

skynav calls ``make(camera)`` once, with the calibrated camera, then ``process(observation,
prediction)`` on every frame, and scores the returned ``R_cam_icrs`` against the truth beside any
other processor (``--pipeline skynav --pipeline tetra3rs``).
"""

import time

import numpy as np
import tetra3rs
from skimage import filters, measure

from skynav.pipeline import ImageResult


class SkimageTetra3rs:
    """Threshold the smoothed image at 5 sigma, centroid the blobs, solve lost in space."""

    def __init__(self, camera):
        fov_deg = float(np.degrees(camera.fov_x_rad))
        self.db = tetra3rs.SolverDatabase.generate_from_gaia(max_fov_deg=1.05 * fov_deg, min_fov_deg=0.95 * fov_deg)
        fx, cx, cy = camera.K[0, 0], camera.K[0, 2], camera.K[1, 2]
        self.model = tetra3rs.CameraModel(focal_length_px=float(fx), image_width=camera.width,
                                          image_height=camera.height)
        self.centre_xy_px = np.array([cx, cy])

    def process(self, observation, prediction):
        t0 = time.perf_counter()
        smooth = filters.gaussian(observation.dn.astype(float), sigma=1.0, preserve_range=True)
        background = np.median(smooth)
        noise = 1.4826 * np.median(np.abs(smooth - background))       # the MAD as a robust sigma
        blobs = measure.regionprops(measure.label(smooth > background + 5.0 * noise), intensity_image=smooth - background)
        blobs = sorted((b for b in blobs if b.area >= 3), key=lambda b: -b.image_intensity.sum())[:40]
        # (row, column) -> (x, y) px, centre of the top-left pixel at (0, 0) (skynav's convention)
        xy = np.array([b.centroid_weighted[::-1] for b in blobs]).reshape(-1, 2)
        flux = np.array([b.image_intensity.sum() for b in blobs])
        if len(xy) < 4:
            return ImageResult(R_cam_icrs=None, status="no_stars", centroids_xy_px=xy)
        # tetra3rs wants offsets from the image centre, +x right, +y down, and a brightness
        stars = np.column_stack([xy - self.centre_xy_px, flux])
        velocity = None if prediction is None else [float(v) for v in prediction.velocity_km_s]
        solution = self.db.solve_from_centroids(stars, camera_model=self.model, observer_velocity_km_s=velocity)
        ms = (time.perf_counter() - t0) * 1e3
        if not solution:
            return ImageResult(R_cam_icrs=None, status="id_failed", centroids_xy_px=xy, timings_ms={"total": ms})
        return ImageResult(R_cam_icrs=np.asarray(solution.rotation_matrix_icrs_to_camera, dtype=float),
                           centroids_xy_px=xy, method="lost_in_space", timings_ms={"total": ms})


def make(camera):
    """The factory ``--pipeline docs/examples/ip_plugin.py:make`` names."""
    return SkimageTetra3rs(camera)
