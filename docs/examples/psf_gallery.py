"""Pictures of the PSF models as the renderer draws them (docs/optics.md).

Each panel is the stamp of one point at a pixel centre, 25 x 25 px, log scale, for a camera
at f/20 with 5 um pixels (lambda F = 2.2 px at 550 nm, so diffraction is resolved).

    python docs/examples/psf_gallery.py OUT.png
"""

import sys
import tempfile

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from skynav.renderer.optics import kernel_for  # noqa: E402
from skynav.scenes.camera import Camera  # noqa: E402


def main(out):
    with tempfile.TemporaryDirectory() as tmp:
        u = (np.arange(65) - 32) / 4.0
        yy, xx = np.meshgrid(u, u, indexing="ij")
        blob = np.exp(-0.5 * ((xx / 1.2) ** 2 + (yy / 0.7) ** 2)) + 0.2 * np.exp(-0.5 * ((xx - 2.0) ** 2 + yy**2) / 0.5**2)
        np.save(f"{tmp}/measured.npy", blob)
        models = [
            ("gaussian, sigma 1 px", {"model": "gaussian", "sigma_px": 1.0}, None),
            ("airy, 550 nm, obscuration 0.3", {"model": "airy", "obscuration": 0.3, "wavelength_nm": 550.0}, None),
            ("airy, polychromatic (5800 K)", {"model": "airy", "obscuration": 0.3}, ("star", 5800.0)),
            ("optical: defocus 0.3 + coma 0.3 waves", {"model": "optical", "obscuration": 0.2, "wavelength_nm": 550.0,
                                                       "zernike_waves": {4: 0.3, 8: 0.3}}, None),
            ("tabulated (a measured image)", {"model": "tabulated", "file": f"{tmp}/measured.npy", "oversampling": 4}, None),
        ]
        fig, axes = plt.subplots(1, len(models), figsize=(3.0 * len(models), 3.3))
        for ax, (title, psf, src) in zip(axes, models):
            cam = Camera(width=64, height=64, focal_length_mm=100.0, pixel_pitch_um=5.0, f_number=20.0, psf=psf)
            k = kernel_for(cam, src, 1e-6)
            s = k.stamp(np.array([32.0, 32.0]), 12)
            ax.imshow(np.log10(np.maximum(s / s.max(), 1e-5)), vmin=-5, vmax=0, cmap="magma",
                      extent=(-12.5, 12.5, 12.5, -12.5))
            ax.set_title(title, fontsize=8)
            ax.set_xlabel("x (px)", fontsize=7)
            ax.tick_params(labelsize=7)
        axes[0].set_ylabel("y (px), log10 of peak", fontsize=7)
        fig.tight_layout()
        fig.savefig(out, dpi=90)
    print(f"wrote {out}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "psf_models.png")
