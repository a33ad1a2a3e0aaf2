"""A sequence's cruise and attitudes from a mission's SPICE kernels.

``sequence.observer: {spice: {kernels: [FILE, ...], body: NAME_OR_ID}}`` replaces the ballistic
cruise (Lambert search and propagation) by the body's states in the SPKs; the legs start where
the kernels' coverage of the body starts, and the kernels must cover the legs' whole span.
``sequence.attitude: {spice: {kernels: [...], frame: CAMERA_FRAME}}`` replaces the pointing rule
by the frame's attitude (a CK through its SCLK and FK) at each frame's epoch; the pointing error
the truth records is then the CK's rotation from the nominal pointing at the leg's planet.
Kernels are read beside the recipe file (:class:`~skynav.scenes.mission_spice.KernelName`);
the plan reads them once, on the driver, and its workers get numbers (no kernel is loaded in
a worker). The manifest records each kernel's name as written and its SHA-256.
"""

from __future__ import annotations

import math

import numpy as np

from skynav.scenes.constants import SECONDS_PER_DAY
from skynav.scenes.mission_files import SceneFilePath
from skynav.scenes.mission_spice import kernel_records, spice_attitudes, spice_coverage, spice_states
from skynav.scenes.timescales import time_from_tdb_seconds

from .errors import RecipeError

__all__ = ["KernelCruise", "kernel_attitudes", "rotation_vector", "describe_kernels"]


def _paths(kernels) -> list:
    """The files of a validated recipe's kernel names (named as written in errors)."""
    return [SceneFilePath(getattr(k, "path", k), str(k)) for k in kernels]


def _iso(t: float) -> str:
    x = time_from_tdb_seconds(t).tdb
    x.precision = 3
    return x.isot


class KernelCruise:
    """The cruise of ``sequence.observer: {spice: ...}``: :meth:`state` from the kernels.

    Parameters
    ----------
    source : dict
        The validated ``{spice: {kernels, body}}``.
    span_s : float
        The legs' span from the start, s; the kernels must cover it.
    """

    def __init__(self, source: dict, span_s: float):
        spec = source["spice"]
        self.names, self.body = list(spec["kernels"]), spec["body"]
        self.paths = _paths(self.names)
        cover = spice_coverage(self.paths, self.body)
        if cover is None:
            raise RecipeError("sequence.observer.spice", {"kernels": [str(k) for k in self.names], "body": self.body},
                              f"kernels with an SPK segment of body {self.body}")
        self.start_tdb_s = cover[0]
        if cover[1] < cover[0] + span_s:
            raise RecipeError("sequence.observer.spice.kernels", [str(k) for k in self.names],
                              f"kernels covering body {self.body} over the legs, {span_s / SECONDS_PER_DAY:.4g} days from "
                              f"{_iso(cover[0])} TDB (to {_iso(cover[0] + span_s)}); they stop at {_iso(cover[1])}")

    def state(self, t_tdb_s):
        """(position km, velocity km/s), barycentric ICRS, at one epoch (3,) or many (N, 3)."""
        r, v = spice_states(self.paths, self.body, t_tdb_s)
        return (r[0], v[0]) if np.ndim(t_tdb_s) == 0 else (r, v)


def kernel_attitudes(source: dict, t_tdb_s):
    """(``R_cam_icrs`` (N, 3, 3), angular velocities (N, 3) rad/s, camera frame) of
    ``sequence.attitude: {spice: {kernels, frame}}`` at the frames' epochs."""
    spec = source["spice"]
    return spice_attitudes(_paths(spec["kernels"]), spec["frame"], t_tdb_s)


def rotation_vector(M) -> np.ndarray:
    """``phi`` with ``frames.rotation_vector_to_dcm(phi) == M`` (a rotation below 180 deg)."""
    M = np.asarray(M, dtype=float)
    a = 0.5 * np.array([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]])
    s = float(np.linalg.norm(a))
    theta = math.atan2(s, 0.5 * (np.trace(M) - 1.0))
    return a if s < 1e-15 else a * (theta / s)


def describe_kernels(s: dict) -> dict:
    """The manifest's record of a sequence's kernel sources: for each, what was read (body or
    frame) and every kernel's name as written with its SHA-256."""
    out = {}
    for key, want in (("observer", "body"), ("attitude", "frame")):
        if key in s:
            spec = s[key]["spice"]
            out[key] = {"spice": {want: spec[want], "kernels": kernel_records(_paths(spec["kernels"]))}}
    return out
