"""Facility files (YAML, ``schema: skynav.facility/1``): read a file or a preset, write atomically."""

from __future__ import annotations

import difflib
import os
import tempfile
from pathlib import Path

import yaml

from skynav.infra.errors import ConfigValueError
from skynav.scenes import facility as fac
from skynav.scenes.psf_measured import resolve_psf_files

from .errors import FacilityFileError

#: the largest facility file read (a calibrated one is ~30 kB)
MAX_FILE_BYTES = 16 << 20


def load_facility(arg) -> fac.Facility:
    """A facility from a preset name (``screen``, ``screen_small``) or a YAML file path."""
    if str(arg) in fac.PRESETS:
        return fac.PRESETS[str(arg)]()
    path = Path(arg)
    renamed = fac.renamed_preset_line(str(arg))
    if renamed and not path.is_file():  # a former preset name (a file of that name is still read)
        raise FacilityFileError(renamed)
    if not path.is_file():
        close = difflib.get_close_matches(str(arg), list(fac.PRESETS), n=1)
        hint = f"did you mean the preset {close[0]}? " if close else ""
        raise FacilityFileError(f"{arg}: no such facility file{' (a folder)' if path.is_dir() else ''}; {hint}give a .yaml "
                                f"file or a preset: {', '.join(fac.PRESETS)}")
    if path.stat().st_size > MAX_FILE_BYTES:
        raise FacilityFileError(f"{path}: {path.stat().st_size} bytes; a facility file is at most {MAX_FILE_BYTES} bytes")
    try:
        with open(path, "rb") as fobj:
            data = yaml.safe_load(fobj)
    except yaml.YAMLError as exc:
        raise FacilityFileError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    try:
        return fac.facility_from_mapping(resolve_psf_files(data, path.resolve().parent))  # PSF files beside the file
    except ConfigValueError as exc:  # name the file too
        raise FacilityFileError(f"{path}: {exc}") from None


def write_text_atomic(path, text: str) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, path)
    return path


def write_facility(facility: fac.Facility, path) -> Path:
    text = (f"# skynav facility file ({fac.SCHEMA}); angles in degrees/arcsec, lengths mm, irradiance W/m^2\n"
            + yaml.safe_dump(facility.to_mapping(), sort_keys=False, default_flow_style=None, width=120))
    return write_text_atomic(path, text)
