"""Image processors by import path, called so that their faults are results, and skynav's own.

``MODULE:FACTORY`` names a factory (:class:`~skynav.pipeline.protocols.ImageProcessorFactory`):
:func:`load_factory` imports it (a bad path is one line, :class:`PluginError`),
:func:`load_image_processor` calls it with the calibrated camera. :func:`call_processor` runs one
frame through a processor and never raises for what the processor does: an exception, a result
of another type, an attitude that is not a finite (3, 3) proper rotation, or a frame over the time
limit comes back as a :class:`Fault` naming the reason.

The processors skynav ships are plug-ins through the same door (the benchmark has no special
case for any of them): ``skynav.pipeline.plugins:skynav_improved`` and ``:skynav_paper`` (the
pipeline, :func:`~skynav.pipeline.process_frame`, in its two modes), ``:skynav_tracking`` (the
improved mode passing each attitude to the next frame: the default of ``bench nav`` and ``bench
loop``), ``:tetra3rs`` (the ``peers`` extra) and ``:cedar_solve``.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .catalog import OnboardCatalog
from .errors import BenchInputError
from .process import process_frame
from .protocols import BeaconSighting, ImageProcessor, ImageResult
from .scoring_peers import Tetra3rsPeer

__all__ = ["BUILTIN", "Fault", "PluginError", "ROTATION_TOLERANCE", "SkynavProcessor", "Tetra3rsProcessor",
           "call_processor", "check_result", "image_result", "load_factory", "load_image_processor",
           "skynav_improved", "skynav_paper", "skynav_tracking", "tetra3rs", "cedar_solve"]

#: ``max |R R^T - I|`` a returned attitude may have: 1e-6 (a shear of 0.2 arcsec); a matrix
#: rounded to float32 (1e-7) passes, a matrix that is not a rotation does not.
ROTATION_TOLERANCE = 1e-6

#: Short names of skynav's plug-ins (``--pipeline skynav-paper`` = ``skynav.pipeline.plugins:skynav_paper``).
BUILTIN = {"skynav-improved": "skynav.pipeline.plugins:skynav_improved",
           "skynav-paper": "skynav.pipeline.plugins:skynav_paper",
           "skynav-tracking": "skynav.pipeline.plugins:skynav_tracking",
           "tetra3rs": "skynav.pipeline.plugins:tetra3rs",
           "cedar-solve": "skynav.pipeline.plugins:cedar_solve"}


class PluginError(BenchInputError):
    """A ``--pipeline`` that names no importable factory, or whose factory fails.

    Examples
    --------
    >>> load_factory("no_such_module:make")
    Traceback (most recent call last):
    ...
    skynav.pipeline.plugins.PluginError: --pipeline no_such_module:make: no module named 'no_such_module'
    """


@dataclass(frozen=True)
class Fault:
    """Why a frame failed inside a plug-in: ``kind`` (``"exception"``, ``"timeout"``,
    ``"wrong_type"``, ``"wrong_shape"``, ``"not_finite"``, ``"not_rotation"``) and a one-line
    ``message``."""

    kind: str
    message: str

    def __str__(self) -> str:
        return f"{self.kind}: {self.message}"


def load_factory(spec: str, *, option: str = "--pipeline", error: type = PluginError, shortcuts: dict | None = None,
                 example: str = "mypkg.tracker:make, or my_tracker.py:make", makes: str = "camera -> processor"):
    """The factory ``spec`` names: ``MODULE:FACTORY`` (a module importable from the current folder
    or the installed packages), ``path/to/file.py:FACTORY``, or a short name of ``shortcuts``
    (default :data:`BUILTIN`).

    The one loader of skynav's plug-ins: image processors (``--pipeline``) and navigation filters
    (``--filter``, :func:`skynav.pipeline.flight.load_filter_factory`); ``option`` names the flag
    in the message, ``error`` its error class.

    Raises
    ------
    PluginError
        (or ``error``) Not ``MODULE:FACTORY``, a module that does not import, or no callable of that name.
    """
    shortcuts = BUILTIN if shortcuts is None else shortcuts
    path = shortcuts.get(spec, spec)
    mod_name, sep, attr = str(path).rpartition(":")
    if not sep or not mod_name or not attr:
        raise error(f"{option} {spec}: give MODULE:FACTORY (e.g. {example})"
                    + (f" or one of {', '.join(shortcuts)}" if shortcuts else ""))
    mod = _import(spec, mod_name, option, error)
    obj = mod
    for part in attr.split("."):
        obj = getattr(obj, part, None)
        if obj is None:
            raise error(f"{option} {spec}: {mod_name} has no {attr!r}")
    if not callable(obj):
        raise error(f"{option} {spec}: {mod_name}:{attr} is not callable (give a factory: {makes})")
    return obj


def _import(spec, mod_name, option, error):
    """The module of a spec: a ``.py`` file by its path (executed once per process), else by name
    (the current folder last on ``sys.path``, as ``python -m`` would find it)."""
    try:
        if mod_name.endswith(".py"):
            file = Path(mod_name)
            if not file.is_file():
                raise error(f"{option} {spec}: no such file {mod_name}")
            key = f"skynav_plugin_{abs(hash(str(file.resolve())))}"
            if key not in sys.modules:
                loader_spec = importlib.util.spec_from_file_location(key, file)
                mod = importlib.util.module_from_spec(loader_spec)
                sys.modules[key] = mod
                try:
                    loader_spec.loader.exec_module(mod)
                except BaseException:
                    del sys.modules[key]
                    raise
            return sys.modules[key]
        if os.getcwd() not in sys.path and "" not in sys.path:
            sys.path.append(os.getcwd())
        return importlib.import_module(mod_name)
    except error:
        raise
    except KeyboardInterrupt:
        raise
    except ModuleNotFoundError as exc:
        raise error(f"{option} {spec}: no module named {exc.name!r}") from None
    except BaseException as exc:  # noqa: BLE001 - the user's module failing on import (even sys.exit) is one line too
        raise error(f"{option} {spec}: importing {mod_name} failed ({type(exc).__name__}: {_one_line(exc)})") from None


def load_image_processor(spec: str, camera) -> ImageProcessor:
    """The processor ``spec``'s factory makes for ``camera`` (the calibrated camera).

    Raises
    ------
    PluginError
        A bad ``spec`` (:func:`load_factory`), a factory that raises, or one whose product has no
        ``process`` method.
    """
    factory = load_factory(spec)
    try:
        proc = factory(camera)
    except PluginError:
        raise
    except Exception as exc:  # noqa: BLE001 - a failing factory is the user's input, one line
        raise PluginError(f"--pipeline {spec}: the factory raised {type(exc).__name__}: {exc}") from None
    if not isinstance(proc, ImageProcessor):
        raise PluginError(f"--pipeline {spec}: the factory returned a {type(proc).__name__}, which has no "
                          "process(observation, prediction) method")
    return proc


def check_result(value) -> tuple[ImageResult | None, Fault | None]:
    """``(result, None)`` for a usable :class:`ImageResult`, else ``(None, fault)``.

    Usable: an ``ImageResult`` whose ``R_cam_icrs`` is None or a finite (3, 3) proper rotation
    (``max |R R^T - I| <= ROTATION_TOLERANCE``, ``det R > 0``); it comes back with ``R_cam_icrs`` as
    a float ndarray.
    """
    if not isinstance(value, ImageResult):
        return None, Fault("wrong_type", f"returned {type(value).__name__}; expected skynav.pipeline.ImageResult")
    if value.R_cam_icrs is None:
        return value, None
    try:
        R = np.asarray(value.R_cam_icrs, dtype=float)
    except (TypeError, ValueError):
        return None, Fault("wrong_shape", "R_cam_icrs is not a numeric array")
    if R.shape != (3, 3):
        return None, Fault("wrong_shape", f"R_cam_icrs has shape {R.shape}; expected (3, 3)")
    if not np.all(np.isfinite(R)):
        return None, Fault("not_finite", "R_cam_icrs has a nan or inf entry")
    dev = float(np.max(np.abs(R @ R.T - np.eye(3))))
    if dev > ROTATION_TOLERANCE:
        return None, Fault("not_rotation", f"R_cam_icrs is not orthonormal (max |R R^T - I| = {dev:.2g} > "
                                           f"{ROTATION_TOLERANCE:g})")
    if np.linalg.det(R) < 0:
        return None, Fault("not_rotation", "R_cam_icrs is a reflection (det = -1), not a rotation")
    if R is not value.R_cam_icrs:
        value = replace(value, R_cam_icrs=R)
    return value, None


class _Timeout(BaseException):
    """Raised in the processor's call by the alarm (a BaseException, so its own ``except Exception`` lets it through)."""


def call_processor(processor, observation, prediction, *, timeout_s: float | None = None):
    """``(result or None, fault or None, wall_ms)``: one frame through ``processor``, its faults caught.

    ``timeout_s``: the frame's time limit. In the main thread of a POSIX process an alarm
    interrupts a call past it (Python code is interrupted at once, a long call into compiled code
    when it returns); anywhere, a call that returns past it is a ``"timeout"`` fault as well.
    """
    use_alarm = (timeout_s is not None and hasattr(signal, "setitimer")
                 and threading.current_thread() is threading.main_thread())
    old = outer = None
    if use_alarm:
        def _alarm(signum, frame):
            raise _Timeout

        outer = signal.getitimer(signal.ITIMER_REAL)  # a caller's own timer, given back after
        old = signal.signal(signal.SIGALRM, _alarm)
        signal.setitimer(signal.ITIMER_REAL, float(timeout_s))
    t0 = time.perf_counter()
    try:
        value = processor.process(observation, prediction)
    except _Timeout:
        value = _Timeout
    except Exception as exc:  # noqa: BLE001 - a plug-in's exception is a result of the benchmark
        wall_ms = (time.perf_counter() - t0) * 1e3
        return None, Fault("exception", f"{type(exc).__name__}: {_one_line(exc)}"), wall_ms
    finally:
        if use_alarm:
            signal.setitimer(signal.ITIMER_REAL, 0.0)
            signal.signal(signal.SIGALRM, old)
            if outer[0] > 0.0:
                signal.setitimer(signal.ITIMER_REAL, max(outer[0] - (time.perf_counter() - t0), 1e-3), outer[1])
    wall_ms = (time.perf_counter() - t0) * 1e3
    if value is _Timeout or (timeout_s is not None and wall_ms > timeout_s * 1e3):
        return None, Fault("timeout", f"over the {timeout_s:g} s frame time limit"), wall_ms
    result, fault = check_result(value)
    return result, fault, wall_ms


def _one_line(exc) -> str:
    text = str(exc).strip().splitlines()
    return (text[0] if text else "")[:200]


def image_result(fr) -> ImageResult:
    """The :class:`ImageResult` of a :class:`~skynav.pipeline.results.FrameResult` (nothing lost that
    the benchmark reads)."""
    beacons = tuple(BeaconSighting(name=b.name, xy_px=b.xy_px, predicted_xy_px=b.predicted_xy_px,
                                   predicted_cov_px2=b.predicted_cov_px2, status=b.status) for b in fr.beacons)
    return ImageResult(R_cam_icrs=fr.attitude.R_cam_icrs, status=fr.status, attitude_cov_rad2=fr.attitude.covariance_rad2,
                       centroids_xy_px=fr.centroids_xy_px, matched_star_ids=fr.matched_star_ids,
                       matched_spot_index=fr.matched_spot_index, beacons=beacons, method=fr.star_id_method,
                       error_estimate_arcsec=fr.attitude.error_estimate_arcsec, timings_ms=fr.timings_ms)


class SkynavProcessor:
    """skynav's pipeline (:func:`~skynav.pipeline.process_frame`) as an image processor.

    ``tracking``: pass each solved attitude to the next frame (a sequence); False (the Monte Carlo
    benchmark) processes every frame on its own.
    """

    def __init__(self, camera, *, mode: str = "improved", options=None, catalog=None, tracking: bool = False):
        self.catalog = catalog if catalog is not None else OnboardCatalog.load(camera=camera)
        self.mode = mode
        self.options = options
        self.tracking = tracking
        self.previous_attitude = None

    def process(self, observation, prediction) -> ImageResult:
        fr = process_frame(observation, catalog=self.catalog, predicted_state=prediction, mode=self.mode,
                           options=self.options, previous_attitude=self.previous_attitude if self.tracking else None)
        if self.tracking:
            self.previous_attitude = fr.attitude.R_cam_icrs if fr.ok else None
        return image_result(fr)


def skynav_improved(camera) -> SkynavProcessor:
    """skynav's pipeline in its improved mode, each frame on its own."""
    return SkynavProcessor(camera, mode="improved")


def skynav_tracking(camera) -> SkynavProcessor:
    """skynav's pipeline in its improved mode, each solved attitude passed to the next frame: the
    image processing of ``bench nav`` and ``bench loop`` by default (a sequence, frame after frame)."""
    return SkynavProcessor(camera, mode="improved", tracking=True)


def skynav_paper(camera) -> SkynavProcessor:
    """skynav's pipeline in the mode of Andreis et al. (2023a), each frame on its own."""
    return SkynavProcessor(camera, mode="paper")


class Tetra3rsProcessor:
    """tetra3rs lost in space (its own centroids on the DN image; the predicted velocity, when
    there is one, for aberration): :class:`~skynav.pipeline.scoring_peers.Tetra3rsPeer`."""

    def __init__(self, camera):
        self.peer = Tetra3rsPeer(camera)

    def process(self, observation, prediction) -> ImageResult:
        R, ms = self.peer.solve(observation.dn, None if prediction is None else prediction.velocity_km_s)
        return ImageResult(R_cam_icrs=R, status="ok" if R is not None else "unsolved", method="lost_in_space",
                           timings_ms={"total": ms})


def tetra3rs(camera) -> Tetra3rsProcessor:
    """tetra3rs (the ``peers`` extra: ``pip install tetra3rs``)."""
    try:
        import tetra3rs as _t3  # noqa: F401 - optional peer, checked before its database is built
    except ImportError:
        raise PluginError("--pipeline tetra3rs: tetra3rs is not installed (pip install 'skynav[peers]')") from None
    return Tetra3rsProcessor(camera)


def cedar_solve(camera):
    """cedar-solve: its release pins numpy < 2 and cannot be installed beside skynav (numpy >= 2).

    Raises
    ------
    PluginError
        Always here: not importable beside numpy >= 2, or (installed in some other way) without
        an adapter to this interface.
    """
    try:
        import cedar_solve as _cedar  # noqa: F401 - optional, and not installable beside numpy >= 2
    except ImportError:
        raise PluginError("--pipeline cedar-solve: not installable here: its release pins numpy < 2, skynav needs "
                          "numpy >= 2") from None
    raise PluginError("--pipeline cedar-solve: installed, but skynav has no adapter for it yet; wrap it in a "
                      "plug-in of your own (docs/benchmark.md)")
