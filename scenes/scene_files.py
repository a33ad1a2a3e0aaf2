"""Reading scene files: YAML with a strict loader, into a mapping or a :class:`~skynav.scenes.config.SceneSpec`.

The loader reads ``2e-1`` as a number (YAML 1.2, as people mean it) and refuses a duplicate key
naming its line; every error names the file. The mapping is checked by
:func:`skynav.scenes.config.scene_spec_from_mapping` (the configuration layer); dataset recipes
and ``--set`` values are parsed with the same :func:`load_yaml`.
"""

from __future__ import annotations

import re
from pathlib import Path

import yaml

from .errors import SceneFileError

from .config import SceneSpec, scene_spec_from_mapping
from .mission_files import mark_mission_files
from .psf_measured import resolve_psf_files

__all__ = ["load_yaml", "read_scene_mapping", "read_scene_file", "load_scene_mapping", "load_scene_file"]


def _strict_loader():
    """A ``yaml.SafeLoader`` subclass: ``1e30`` and ``2e-1`` are numbers, a duplicate key is an error.

    PyYAML follows YAML 1.1, whose float pattern needs a dot (``1.0e30``), so ``2e-1`` would be
    the string ``'2e-1'``; YAML 1.2 (and every reader of JSON) reads it as a number, as people
    mean it. A mapping with the same key twice keeps the last value silently in PyYAML; here it
    is refused, naming the key and its line.
    """
    class StrictLoader(yaml.SafeLoader):
        pass

    StrictLoader.yaml_implicit_resolvers = {k: list(v) for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()}
    float_re = re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
        |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
        |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""", re.X)
    StrictLoader.add_implicit_resolver("tag:yaml.org,2002:float", float_re, list("-+0123456789."))

    def construct_mapping(loader, node, deep=False):
        seen = {}
        for key_node, _ in node.value:
            k = loader.construct_object(key_node, deep=deep)
            try:
                hash(k)
            except TypeError:
                raise yaml.constructor.ConstructorError(None, None, "a mapping key that is not a scalar",
                                                        key_node.start_mark) from None
            if k in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {k!r} (first at line {seen[k] + 1})", key_node.start_mark)
            seen[k] = key_node.start_mark.line
        return yaml.SafeLoader.construct_mapping(loader, node, deep=deep)

    StrictLoader.add_constructor("tag:yaml.org,2002:map", construct_mapping)
    return StrictLoader


def load_yaml(fobj):
    """Parse YAML with :func:`_strict_loader` (scientific numbers, no duplicate keys).

    Raises
    ------
    yaml.YAMLError
    """
    return yaml.load(fobj, Loader=_strict_loader())  # noqa: S506 - a SafeLoader subclass


def read_scene_mapping(fobj, name: str = "<scene>"):
    """Parse a YAML scene file object into its mapping, not yet validated (errors name the file)."""
    try:
        return load_yaml(fobj)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or "invalid YAML"
        raise SceneFileError(f"{name}: malformed YAML{where}: {problem}") from None


def read_scene_file(fobj, name: str = "<scene>") -> SceneSpec:
    """Parse a YAML scene file object into a :class:`SceneSpec` (errors name the file).

    Parameters
    ----------
    fobj : file object
        The YAML text (text or binary).
    name : str
        The file's name, for the error messages.

    Returns
    -------
    SceneSpec
        The scene, checked (keys and units as docs/conventions.md: degrees, ISO epochs in TDB,
        km), angles in radians.

    Raises
    ------
    SceneFileError
        Malformed YAML, or not a mapping of the scene keys.
    ConfigValueError
        A value out of its range (the dotted key named).

    Examples
    --------
    >>> import io
    >>> from skynav.scenes import read_scene_file
    >>> spec = read_scene_file(io.StringIO(
    ...     "epoch: 2030-01-01T00:00:00\\n"
    ...     "observer: {position_km: [1.5e8, 0, 0], velocity_km_s: [0, 30, 0]}\\n"
    ...     "attitude: {ra_deg: 90, dec_deg: 0}\\n"), "scene.yaml")
    >>> spec.epoch_tdb_iso, round(spec.attitude.ra_rad, 6), spec.camera.width
    ('2030-01-01T00:00:00.000', 1.570796, 1024)
    """
    return scene_spec_from_mapping(read_scene_mapping(fobj, name))


def load_scene_mapping(path):
    """The mapping of a scene file at ``path`` (not yet validated); relative PSF file paths in
    it are made relative to the file's folder (:func:`~skynav.scenes.psf_measured.resolve_psf_files`)."""
    path = Path(path)
    if not path.is_file():
        raise SceneFileError(f"{path}: no such scene file")
    with open(path, "rb") as f:
        return mark_mission_files(resolve_psf_files(read_scene_mapping(f, str(path)), path.parent), path.parent)


def load_scene_file(path) -> SceneSpec:
    """Read a YAML scene file into a :class:`SceneSpec`.

    Relative PSF file paths in it are taken relative to the file's folder.

    Parameters
    ----------
    path : str or os.PathLike
        The scene file (``docs/examples/default_scene.yaml`` is one to copy).

    Returns
    -------
    SceneSpec
        The scene, checked, angles in radians (:func:`read_scene_file`).

    Raises
    ------
    SceneFileError
        No such file, malformed YAML, or not a mapping of the scene keys.
    ConfigValueError
        A value out of its range (the dotted key named).

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> from skynav.scenes import load_scene_file
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     path = Path(tmp) / "scene.yaml"
    ...     _ = path.write_text("epoch: 2030-01-01T00:00:00\\n"
    ...                         "observer: {position_km: [1.5e8, 0, 0], velocity_km_s: [0, 30, 0]}\\n"
    ...                         "attitude: {point_at: auto}\\n"
    ...                         "camera: {preset: paper, exposure_s: 0.2}\\n")
    ...     spec = load_scene_file(path)
    >>> spec.attitude.point_at, spec.camera.exposure_s
    ('auto', 0.2)
    """
    return scene_spec_from_mapping(load_scene_mapping(path))
