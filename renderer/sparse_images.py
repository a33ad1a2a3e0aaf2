"""A dark frame's images handled over the pixels it drew: the one fast path of :func:`render`.

A default frame draws its stars' and planets' stamps into ~3 % of its pixels. Two steps of a frame
would otherwise pass over every pixel of two 8 MB float64 images: making them (fresh zeros) and
converting them to float32 (the sensor's input, the EXR channels). Here both go over the drawn
pixels only (``ExpectedImage.support``): :func:`float32_image` converts just those, and the images a
frame drew into are set back to zero over them and kept for the next frame of that size
(:func:`keep_zero_images`, :func:`take_zero_images`). The reference is the plain path
(``image.astype(np.float32)``, fresh ``np.zeros``), which gives the same bits
(tests/renderer/test_render.py: the support holds every lit pixel; a frame after others is the
frame alone). Frames with a background light every pixel: they have no support and take the plain
path. Measured saving on the default frame in docs/performance.md.
"""

from __future__ import annotations

import numpy as np

__all__ = ["float32_image", "take_zero_images", "keep_zero_images"]

#: ``{(H, W): (electrons, irradiance)}``: the float64 images :func:`render` drew its last frame
#: into, zero again, for its next frame of that size (one size kept). A pair is taken out while a
#: frame uses it, so two threads never draw into the same images.
_ZERO_IMAGES: dict = {}


def float32_image(image: np.ndarray, support: np.ndarray | None = None) -> np.ndarray:
    """``image.astype(np.float32)``, reading only ``support`` (flat indices holding every nonzero
    pixel; None: every pixel): a float32 zero image with those pixels converted, the same bits."""
    if support is None:
        return image.astype(np.float32)
    out = np.zeros(image.shape, np.float32)
    out.reshape(-1)[support] = image.reshape(-1)[support]
    return out


def take_zero_images(shape: tuple) -> tuple | None:
    """The kept pair of float64 zero images ``(electrons, irradiance)`` of ``shape`` (taken out
    of the cache), or None (the caller makes fresh ones)."""
    return _ZERO_IMAGES.pop(tuple(shape), None)


def keep_zero_images(expected) -> None:
    """Set an :class:`~skynav.renderer.expected.ExpectedImage`'s electrons and irradiance back to
    zero over its support and keep them for the next frame of their size (nothing without a
    support: every pixel was lit)."""
    if expected.support is None or expected.irradiance_w_m2 is None:
        return
    for image in (expected.electrons, expected.irradiance_w_m2):
        image.reshape(-1)[expected.support] = 0.0
    _ZERO_IMAGES.clear()
    _ZERO_IMAGES[expected.electrons.shape] = (expected.electrons, expected.irradiance_w_m2)
