"""Speed of the point-source rasteriser and of the star radiometry lookup.

Run: ``python benchmarks/raster_bench.py`` (prints the median of several repeats).

* ~4000 static stars into 1024 x 1024 (paper camera, Gaussian PSF sigma 0.5 px, 1e-6 lost flux)
* the same stars streaked 20 px (straight, random directions)
* the same stars on a curved path (rotation about the boresight, S = 9 samples, ~20 px arcs)
* ``Radiometry.star_electrons_per_s`` for 1e4 stars (table lookup)
"""

from __future__ import annotations

import time
import warnings

import numpy as np


def _median_time(fn, repeats):
    fn()  # warm-up
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def main() -> None:
    warnings.simplefilter("ignore")
    from skynav.renderer.kernels import GaussianKernel
    from skynav.renderer.radiometry import Radiometry
    from skynav.renderer.raster import rasterize
    from skynav.scenes.camera import paper_camera

    cam = paper_camera()
    psf = GaussianKernel(cam.defocus_sigma_px)
    shape = (cam.height, cam.width)
    rng = np.random.default_rng(2024)
    n = 4000
    xy = rng.uniform(0, 1023, (n, 2))
    e = 10 ** rng.uniform(2, 6, n)

    static = np.stack([xy, xy], 1)
    t_static = _median_time(lambda: rasterize(shape, static, e, psf), 20)

    a = rng.uniform(0, 2 * np.pi, n)
    d = 10.0 * np.stack([np.cos(a), np.sin(a)], -1)
    straight = np.stack([xy - d, xy + d], 1)
    t_straight = _median_time(lambda: rasterize(shape, straight, e, psf), 5)

    centre = np.array([cam.cx, cam.cy])
    rel = xy - centre
    ang = np.linspace(-0.5, 0.5, 9) * (20.0 / 512.0)  # ~20 px at the image corner radius
    ca, sa = np.cos(ang), np.sin(ang)
    curved = np.stack([centre[0] + rel[:, :1] * ca - rel[:, 1:] * sa, centre[1] + rel[:, :1] * sa + rel[:, 1:] * ca], -1)
    t_curved = _median_time(lambda: rasterize(shape, curved, e, psf), 5)

    rad = Radiometry.for_camera(cam)
    v = rng.uniform(-1, 8, 10_000)
    teff = rng.uniform(3000, 20000, 10_000)
    t_lookup = _median_time(lambda: rad.star_electrons_per_s(v, teff), 50)
    t0 = time.perf_counter()
    Radiometry(cam)
    t_build = time.perf_counter() - t0

    print(f"rasterize {n} static stars, 1024^2, sigma 0.5 px : {t_static * 1e3:8.2f} ms")
    print(f"rasterize {n} stars streaked 20 px (straight)    : {t_straight * 1e3:8.2f} ms")
    print(f"rasterize {n} stars on ~20 px arcs (S = 9)       : {t_curved * 1e3:8.2f} ms")
    print(f"star_electrons_per_s for 1e4 stars (lookup)       : {t_lookup * 1e6:8.1f} us")
    print(f"Radiometry(camera) build (tables, uncached)       : {t_build * 1e3:8.1f} ms")
    print(f"zero point (Vega at V=0, paper camera)            : {rad.zero_point_e_per_s:.4e} e-/s")


if __name__ == "__main__":
    main()
