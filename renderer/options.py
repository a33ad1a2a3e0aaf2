"""The options of a render: every speed/accuracy trade-off and the sensor backend, one value object
that :func:`~skynav.renderer.expected.expected_image`, :func:`~skynav.renderer.render.detect`
and :func:`~skynav.renderer.render.render` share."""

from __future__ import annotations

from dataclasses import dataclass

from skynav.infra.errors import ConfigValueError

__all__ = ["RenderOptions"]


@dataclass(frozen=True, kw_only=True)
class RenderOptions:
    """Every speed/accuracy trade-off of a render in one value object.

    Attributes
    ----------
    flux_fraction_lost : float
        Largest fraction of a source's flux the PSF stamp may cut off.
    path_step_px : float
        Spacing of the samples along a curved source path, px (straight paths use 2 samples).
    background_e_per_px_s : float
        Uniform sky background (zodiacal + galactic), e-/px/s.
    cosmic_rays_per_frame : float
        Mean number of cosmic-ray hits per frame (Andreis et al. (2024): 1).
    cosmic_ray_mode : str
        ``"poisson"``: Poisson count with mean ``cosmic_rays_per_frame``; ``"fixed"``.
    cosmic_ray_track_prob : float
        Probability that a cosmic-ray hit is a short track rather than a single pixel
        (:func:`~skynav.renderer.cosmic_rays.draw_cosmic_rays`; the draws do not depend on it,
        so 0 and 0.3 give the same hit positions and charges).
    mitsuba_spp, mitsuba_time_samples : int
        Samples per pixel and sub-frame instants for resolved bodies.
    resolved : bool
        Ray-trace bodies flagged ``resolved`` (False: draw every body as a point).
    noise : bool
        Apply the sensor noise chain and draw cosmic rays (False: DN of the expected signal, no
        cosmic rays: the frame is the same for every seed, apart from a resolved body's Monte
        Carlo sampling of its disc, which follows the seed).
    backend : str
        ``"auto"``, ``"llvm"``, ``"cuda"`` or ``"numpy"`` for the sensor (docs/conventions.md
        "Randomness": one seed gives the same DN on one backend, the same statistics across
        them).

    Raises
    ------
    ConfigValueError
        A value out of its range (the ``render.*`` key named).

    Examples
    --------
    >>> from skynav.renderer import RenderOptions
    >>> opts = RenderOptions(backend="numpy", cosmic_rays_per_frame=0.0)
    >>> opts.noise, opts.mitsuba_spp
    (True, 16)
    """

    flux_fraction_lost: float = 1e-6
    path_step_px: float = 0.5
    background_e_per_px_s: float = 0.0
    cosmic_rays_per_frame: float = 1.0
    cosmic_ray_mode: str = "poisson"
    cosmic_ray_track_prob: float = 0.0
    mitsuba_spp: int = 16
    mitsuba_time_samples: int = 1
    resolved: bool = True
    noise: bool = True
    backend: str = "auto"

    def __post_init__(self):
        if not 0 < self.flux_fraction_lost < 0.1:
            raise ConfigValueError("render.flux_fraction_lost", self.flux_fraction_lost, "in (0, 0.1)")
        if not self.path_step_px > 0:
            raise ConfigValueError("render.path_step_px", self.path_step_px, "> 0")
        if not self.background_e_per_px_s >= 0:
            raise ConfigValueError("render.background_e_per_px_s", self.background_e_per_px_s, ">= 0")
        if not self.cosmic_rays_per_frame >= 0:
            raise ConfigValueError("render.cosmic_rays_per_frame", self.cosmic_rays_per_frame, ">= 0")
        if self.cosmic_ray_mode not in ("poisson", "fixed"):
            raise ConfigValueError("render.cosmic_ray_mode", self.cosmic_ray_mode, "poisson or fixed")
        if not 0.0 <= self.cosmic_ray_track_prob <= 1.0:
            raise ConfigValueError("render.cosmic_ray_track_prob", self.cosmic_ray_track_prob, "in [0, 1]")
        if self.backend not in ("auto", "llvm", "cuda", "numpy"):
            raise ConfigValueError("render.backend", self.backend, "auto, llvm, cuda or numpy")
        if self.mitsuba_spp < 1 or self.mitsuba_time_samples < 1:
            raise ConfigValueError("render.mitsuba_spp", self.mitsuba_spp, ">= 1")
