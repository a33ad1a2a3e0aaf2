"""Errors of the bench calibration (each also subclasses the builtin a caller would expect)."""

from __future__ import annotations

from skynav.infra.errors import SkynavError


class CalibrationInputError(SkynavError, ValueError):
    """A calibration input (patterns, captures, measurements) is missing, malformed or inconsistent."""


class CaptureMismatchError(CalibrationInputError):
    """Captures that do not match the patterns (missing files, wrong size or bit depth)."""


class IdentificationError(SkynavError, RuntimeError):
    """Dots of a capture cannot be identified with certainty (ambiguous or too few matches)."""


class MeasurementError(CalibrationInputError):
    """A power-meter measurement file that is too short, non-monotone or malformed."""


class FacilityFileError(SkynavError, ValueError):
    """A facility file that cannot be read."""
