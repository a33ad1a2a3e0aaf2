"""Errors of the datasets room.

Every class subclasses :class:`skynav.infra.errors.SkynavError` (so the command line prints one
line and exits with code 2) and the builtin exception a caller would expect.
"""

from __future__ import annotations

from skynav.infra.errors import ConfigValueError, SkynavError

__all__ = [
    "DatasetError",
    "RecipeError",
    "IncompleteDatasetError",
    "DatasetMismatchError",
    "FrameIndexError",
    "SceneSamplingError",
    "OutputFormatError",
    "OutputPathError",
    "TruthSchemaError",
]


class DatasetError(SkynavError, OSError):
    """A dataset folder cannot be read or written as asked.

    Examples
    --------
    >>> import tempfile
    >>> from skynav.datasets import DatasetError, open
    >>> with tempfile.TemporaryDirectory() as empty:
    ...     try:
    ...         open(empty)
    ...     except DatasetError as exc:
    ...         print(str(exc).split(": ", 1)[1])
    no manifest.json; not a skynav dataset (or its generation never started)
    """


class RecipeError(ConfigValueError):
    """A recipe key holds a value outside what is allowed (names the key and the range).

    Examples
    --------
    >>> from skynav.datasets import RecipeError, preset_recipe, validate_recipe
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe["frames"] = 0
    >>> try:
    ...     validate_recipe(recipe)
    ... except RecipeError as exc:
    ...     print(exc.key)
    frames
    """


class IncompleteDatasetError(DatasetError):
    """The folder holds a dataset whose manifest does not say ``"complete": true``.

    Attributes
    ----------
    path : str
        The dataset folder.
    done, total : int or None
        Frames present and frames planned, when the manifest says so.

    Examples
    --------
    >>> import tempfile
    >>> from skynav.datasets import generate, preset_recipe
    >>> from skynav.renderer import RenderOptions
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=2, camera={"preset": "paper", "width": 64, "height": 64, "fov_deg": 20})
    >>> tmp = tempfile.TemporaryDirectory()
    >>> summary = generate(recipe, tmp.name + "/ds", workers=1, progress=False, max_frames=1,
    ...                    render_options=RenderOptions(backend="numpy"))
    >>> from skynav.datasets import IncompleteDatasetError, open
    >>> try:
    ...     open(tmp.name + "/ds")
    ... except IncompleteDatasetError as exc:
    ...     print(exc.done, exc.total)
    1 2
    >>> tmp.cleanup()
    """

    def __init__(self, message: str, *, path=None, done=None, total=None):
        self.path = path
        self.done = done
        self.total = total
        super().__init__(message)


class DatasetMismatchError(DatasetError):
    """A resumed run asked for another dataset than the folder holds.

    Another recipe, seed, version, render options or backend than the folder's, or a worker ran
    another backend than the dataset records.

    Examples
    --------
    >>> import tempfile
    >>> from skynav.datasets import generate, preset_recipe
    >>> from skynav.renderer import RenderOptions
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=2, camera={"preset": "paper", "width": 64, "height": 64, "fov_deg": 20})
    >>> tmp = tempfile.TemporaryDirectory()
    >>> summary = generate(recipe, tmp.name + "/ds", workers=1, progress=False,
    ...                    render_options=RenderOptions(backend="numpy"))
    >>> from skynav.datasets import DatasetMismatchError
    >>> recipe["seed"] += 1
    >>> try:
    ...     generate(recipe, tmp.name + "/ds", workers=1, progress=False)
    ... except DatasetMismatchError as exc:
    ...     print(str(exc).split(": ", 1)[1])
    its recipe differs (differs at: seed); use a new folder or remove it
    >>> tmp.cleanup()
    """


class FrameIndexError(SkynavError, IndexError):
    """A frame index outside ``0 .. len(dataset) - 1``.

    Examples
    --------
    >>> import tempfile
    >>> from skynav.datasets import generate, preset_recipe
    >>> from skynav.renderer import RenderOptions
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=2, camera={"preset": "paper", "width": 64, "height": 64, "fov_deg": 20})
    >>> tmp = tempfile.TemporaryDirectory()
    >>> summary = generate(recipe, tmp.name + "/ds", workers=1, progress=False,
    ...                    render_options=RenderOptions(backend="numpy"))
    >>> from skynav.datasets import FrameIndexError, open
    >>> try:
    ...     open(tmp.name + "/ds")[2]
    ... except FrameIndexError as exc:
    ...     print(exc)
    frame 2 out of range; the dataset has 2 frames (0..1)
    >>> tmp.cleanup()
    """


class SceneSamplingError(SkynavError, RuntimeError):
    """A sampler could not draw a scene that passes the recipe's keep-filters.

    Examples
    --------
    >>> import tempfile
    >>> from skynav.datasets import SceneSamplingError, generate, preset_recipe
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe["montecarlo"]["max_draws_per_frame"] = 1
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     try:
    ...         generate(recipe, tmp + "/ds", workers=1, progress=False)
    ...     except SceneSamplingError as exc:
    ...         print(exc)
    frame 0: no scene passed the keep-filters ['visible_planet'] in 1 draws; raise montecarlo.max_draws_per_frame or relax montecarlo.keep
    """


class OutputFormatError(SkynavError, ValueError):
    """An image or header cannot be written in the requested file format (bad dtype, shape...).

    Examples
    --------
    >>> from skynav.datasets import OutputFormatError
    >>> from skynav.datasets.frame_files import png_bytes
    >>> try:
    ...     png_bytes(np.zeros((2, 2)))
    ... except OutputFormatError as exc:
    ...     print(exc)
    PNG image has dtype float64; expected uint8 (bit depth <= 8) or uint16 (9-16)
    """


class OutputPathError(DatasetError):
    """An output path that cannot be written (an existing file, under a file, not writable, a kernel
    file system, a file name with a path in it); checked before any work."""


class TruthSchemaError(SkynavError, ValueError):
    """Ground truth (or a manifest) that does not follow its published JSON Schema.

    Attributes
    ----------
    problems : list of str
        One line per problem, e.g. ``"$.attitude.q_cam_icrs: missing"``.

    Examples
    --------
    >>> from skynav.datasets import FrameTruth, TruthSchemaError
    >>> try:
    ...     FrameTruth.from_dict({"schema": "skynav.frame/2"}, source="frame.json")
    ... except TruthSchemaError as exc:
    ...     print(exc)
    frame.json: does not follow skynav.frame/2: $.attitude: missing (+7 more)
    """

    def __init__(self, message: str, problems=()):
        self.problems = list(problems)
        super().__init__(message)
