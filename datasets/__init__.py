"""skynav.datasets: Monte Carlo scenes and navigation sequences, reproducible, resumable, at any scale.

Public API (each ``skynav dataset`` sub-command calls one of these):

- :func:`generate` (``generate``): recipe -> dataset folder, local processes or Dask;
- :func:`open` (the reader): ``ds = skynav.datasets.open(path); dn, truth = ds[0]``;
- :func:`verify`, :func:`info`, :func:`preview` (and :func:`leg_plot` for sequences);
- recipes: :func:`preset_recipe`, :func:`validate_recipe`, :func:`load_recipe_file`.
"""

from .errors import (  # noqa: F401
    DatasetError,
    DatasetMismatchError,
    FrameIndexError,
    IncompleteDatasetError,
    RecipeError,
    SceneSamplingError,
)
from .preview import leg_plot, preview  # noqa: F401
from .reader import Dataset, FrameRecord, open_dataset  # noqa: F401
from .recipes import PRESETS, load_recipe_file, preset_recipe, validate_recipe  # noqa: F401
from .runner import GenerateSummary, generate, regenerate_frame  # noqa: F401
from .verify import VerifyReport, info, verify  # noqa: F401

open = open_dataset  # noqa: A001 - skynav.datasets.open(path), as asked by the room's issue
