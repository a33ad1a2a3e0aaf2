"""skynav.renderer: scene -> image.

Point sources rasterised with a pixel-integrated PSF along their streaks, resolved bodies
ray-traced by Mitsuba 3, then the camera's sensor (or the bench's display). Frames are returned
in memory; files are the datasets' business.

Public API at package level (listed in ``__all__``)::

    from skynav.renderer import RenderOptions, render
    from skynav.scenes import build_from_spec, default_scene_spec

    frame = render(build_from_spec(default_scene_spec()), seed=1,
                   options=RenderOptions(backend="numpy"))
    print(frame.dn.shape, frame.dn.dtype)

``render`` and the other names of :mod:`skynav.renderer.render` are imported with the package
(the function ``render`` must win over the submodule of the same name, whatever is imported
first; ``from skynav.renderer.render import ...`` works as before, but ``import
skynav.renderer.render as m`` binds the function); that module loads Mitsuba and Dr.Jit only
when a frame needs them. Every other name
loads its module on first use (module ``__getattr__``, PEP 562). ``import skynav.renderer``
loads neither Mitsuba nor Dr.Jit.
"""

import importlib as _importlib

from .render import Detection, ExpectedImage, Frame, RenderOptions, detect, expected_image, render  # noqa: F401

# name -> module that defines it; imported on first access. No module may share a name with an
# entry here: importing a submodule binds its name on the package, which would hide the entry.
_LAZY = {
    "GaussianKernel": "kernels", "Kernel": "kernels", "TableKernel": "table_kernels", "CutKernel": "table_kernels",
    "kernel_for": "optics", "rasterize": "raster",
    "Sensor": "detector", "ExposureDetails": "detector", "fixed_patterns": "detector",
    "CosmicRayHits": "cosmic_rays", "ChargeModel": "cosmic_rays", "draw_cosmic_rays": "cosmic_rays",
    "deposit": "cosmic_rays",
    "Radiometry": "radiometry", "BRDF": "brdf", "default_brdf": "brdf",
    "ScreenFrame": "display", "screen_frame": "display", "dn_of_electrons": "display",
    "frame_truth": "truth",
    "BackendUnavailableError": "errors", "SensorInputError": "errors", "ProjectionCropError": "errors",
}
_EAGER = ("Detection", "ExpectedImage", "Frame", "RenderOptions", "detect", "expected_image", "render")

__all__ = sorted(set(_EAGER) | set(_LAZY))


def __getattr__(name):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'skynav.renderer' has no attribute {name!r}")
    value = getattr(_importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
