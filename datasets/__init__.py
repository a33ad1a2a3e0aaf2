"""skynav.datasets: Monte Carlo scenes and navigation sequences, reproducible, resumable, at any scale.

Public API (each ``skynav dataset`` sub-command calls one of these):

- :func:`generate` (``generate``): recipe -> dataset folder, local processes or Dask;
- :func:`open` (the reader): ``ds = skynav.datasets.open(path); dn, truth = ds[0]``;
  ``ds.observation(k)`` for the navigation pipeline (no truth), ``ds.truth(k)`` for scoring;
- :func:`verify`, :func:`info`, :func:`preview` (and :func:`leg_plot` for sequences);
- recipes: :func:`preset_recipe`, :func:`validate_recipe`, :func:`load_recipe_file`, :func:`recipe_yaml`
  (a preset as a commented YAML file to edit);
- training: :func:`stream` (a recipe's frames in batches, in memory, with their labels; adapters
  :func:`torch_dataset` and :func:`jax_batches`); :func:`export_webdataset` (``export
  --webdataset``) and :func:`hf_dataset` (a dataset folder for WebDataset and Hugging Face loaders);
- files: :func:`write_frame` (a rendered frame's PNG/EXR/JSON/FITS), the schemas
  (:func:`load_schema`, :func:`validate_truth`, :func:`validate_manifest`).

Only the reading path is imported with the package; the makers (runner, recipes, samplers,
previews) load on first use (module ``__getattr__``), so that reading a dataset loads no
renderer, Mitsuba or Dr.Jit code (docs/architecture.md "Never").
"""

import importlib as _importlib

from .errors import (  # noqa: F401
    DatasetError,
    DatasetMismatchError,
    FrameIndexError,
    IncompleteDatasetError,
    OutputFormatError,
    RecipeError,
    SceneSamplingError,
    TruthSchemaError,
)
from .frame_truth import BodyTruth, FrameTruth  # noqa: F401
from .observation import CalibrationErrorModel, Observation  # noqa: F401
from .reader import Dataset, FrameRecord, open_dataset  # noqa: F401

open = open_dataset  # noqa: A001 - skynav.datasets.open(path), as asked by the room's issue

# name -> module that defines it; imported on first access. No module may share a name with a
# function here: importing a submodule binds its name on the package, which would hide the function.
_LAZY = {
    "leg_plot": "contact_sheet", "preview": "contact_sheet",
    "PRESETS": "recipes", "load_recipe_file": "recipes", "preset_recipe": "recipes", "validate_recipe": "recipe_checks",
    "recipe_yaml": "recipes",
    "GenerateSummary": "runner", "generate": "runner", "regenerate_frame": "runner",
    "VerifyReport": "integrity", "info": "integrity", "verify": "integrity",
    "write_frame": "frame_files",
    "stream": "training", "torch_dataset": "training", "jax_batches": "training",
    "export_webdataset": "shards", "hf_dataset": "shards",
    "load_schema": "truth_schema", "validate_truth": "truth_schema", "validate_manifest": "truth_schema",
}


# The public API (what the README and docs/ use): the reading path above, the makers below.
__all__ = sorted({
    "open", "open_dataset", "Dataset", "FrameRecord", "Observation", "CalibrationErrorModel", "FrameTruth",
    "BodyTruth", "DatasetError", "DatasetMismatchError", "FrameIndexError", "IncompleteDatasetError",
    "OutputFormatError", "RecipeError", "SceneSamplingError", "TruthSchemaError", *_LAZY,
})


def __getattr__(name):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'skynav.datasets' has no attribute {name!r}")
    value = getattr(_importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
