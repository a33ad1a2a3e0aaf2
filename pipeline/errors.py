"""Errors of the pipeline room (each also a :class:`skynav.infra.errors.SkynavError`, so the
command line prints one line and exits with code 2)."""

from __future__ import annotations

from skynav.infra.errors import SkynavError

__all__ = ["BenchInputError", "SkynavError"]


class BenchInputError(SkynavError, ValueError):
    """The benchmark's input folder is not a dataset or a folder of frames in the frame schema,
    or a frame lacks a key the benchmark needs."""
