"""Facility files (YAML, ``schema: skynav.facility/1``): read a file or a preset, write atomically."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from skynav.scenes import facility as fac

from .errors import FacilityFileError


def load_facility(arg) -> fac.Facility:
    """A facility from a preset name (``bench``, ``bench_small``) or a YAML file path."""
    import yaml

    if str(arg) in fac.PRESETS:
        return fac.PRESETS[str(arg)]()
    path = Path(arg)
    if not path.is_file():
        raise FacilityFileError(f"{arg}: no such facility file (give a .yaml file or a preset: {', '.join(fac.PRESETS)})")
    try:
        with open(path, "rb") as fobj:
            data = yaml.safe_load(fobj)
    except yaml.YAMLError as exc:
        raise FacilityFileError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    return fac.facility_from_mapping(data)


def write_text_atomic(path, text: str) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, path)
    return path


def write_facility(facility: fac.Facility, path) -> Path:
    import yaml

    text = (f"# skynav facility file ({fac.SCHEMA}); angles in degrees/arcsec, lengths mm, irradiance W/m^2\n"
            + yaml.safe_dump(facility.to_mapping(), sort_keys=False, default_flow_style=None, width=120))
    return write_text_atomic(path, text)
