"""Errors of the datasets room.

Every class subclasses :class:`skynav.scenes.errors.SkynavError` (so the command line prints one
line and exits with code 2) and the builtin exception a caller would expect.
"""

from __future__ import annotations

from skynav.scenes.errors import ConfigValueError, LambertError, SkynavError

__all__ = [
    "SkynavError",
    "ConfigValueError",
    "DatasetError",
    "RecipeError",
    "IncompleteDatasetError",
    "DatasetMismatchError",
    "FrameIndexError",
    "SceneSamplingError",
    "LambertError",
    "OutputFormatError",
    "OutputPathError",
    "TruthSchemaError",
]


class DatasetError(SkynavError, OSError):
    """A dataset folder cannot be read or written as asked."""


class RecipeError(ConfigValueError):
    """A recipe key holds a value outside what is allowed (names the key and the range)."""


class IncompleteDatasetError(DatasetError):
    """The folder holds a dataset whose manifest does not say ``"complete": true``.

    Attributes
    ----------
    path : str
    done, total : int or None
        Frames present and frames planned, when the manifest says so.
    """

    def __init__(self, message: str, *, path=None, done=None, total=None):
        self.path = path
        self.done = done
        self.total = total
        super().__init__(message)


class DatasetMismatchError(DatasetError):
    """A resumed run was asked for another recipe, seed, version, render options or backend than the
    folder holds, or a worker ran another backend than the dataset records."""


class FrameIndexError(SkynavError, IndexError):
    """A frame index outside ``0 .. len(dataset) - 1``."""


class SceneSamplingError(SkynavError, RuntimeError):
    """A sampler could not draw a scene that passes the recipe's keep-filters."""


class OutputFormatError(SkynavError, ValueError):
    """An image or header cannot be written in the requested file format (bad dtype, shape...)."""


class OutputPathError(DatasetError):
    """An output path that cannot be written (an existing file, under a file, not writable, a kernel
    file system, a file name with a path in it); checked before any work."""


class TruthSchemaError(SkynavError, ValueError):
    """Ground truth (or a manifest) that does not follow its published JSON Schema.

    Attributes
    ----------
    problems : list of str
        One line per problem, e.g. ``"$.attitude.q_cam_icrs: missing"``.
    """

    def __init__(self, message: str, problems=()):
        self.problems = list(problems)
        super().__init__(message)
