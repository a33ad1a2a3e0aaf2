"""A scene file's keys that name a mission's data files, marked, resolved and recorded.

- ``observer: {oem: FILE}`` / ``attitude: {aem: FILE}``: CCSDS messages
  (:mod:`skynav.scenes.mission_ccsds`);
- ``observer: {spice: {kernels, body}}`` / ``attitude: {spice: {kernels, frame}}``: SPICE kernels
  (:mod:`skynav.scenes.mission_spice`);
- ``ephemeris: {spk: FILE}``: a planetary SPK in place of DE421 for the bodies
  (:class:`~skynav.scenes.mission_spice.SpiceEphemeris`);
- ``epoch: 2027-02-01T00:00:00 UTC``: a UTC epoch, converted by CSPICE where a leapseconds kernel
  (LSK) is among the scene's kernels (``str2et``; the scene's epoch stays TDB).

Paths are read beside the scene file (:func:`mark_mission_files`); a mapping from elsewhere (a
service request) names no file, but kernels through the service's ``--data-dir`` rule
(:data:`~skynav.scenes.mission_spice.KERNEL_RESOLVER`). Every file read is recorded by the name
as given and its SHA-256 (:class:`MissionFiles`), for the truth.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from skynav.infra.errors import ConfigValueError

from .mission_ccsds import aem_attitude, oem_state, rate_deg_s, read_aem, read_oem
from .mission_spice import KERNEL_RESOLVER, SpiceEphemeris, kernel_pool, kernel_records, spice_source
from .timescales import tdb_seconds, time_from_tdb_seconds

__all__ = ["SceneFilePath", "MissionFiles", "mark_mission_files", "kernel_paths", "resolve_mission_sources"]

#: scene-file keys naming data files: (section, key)
_SOURCES = (("observer", "oem"), ("attitude", "aem"), ("observer", "spice"), ("attitude", "spice"),
            ("ephemeris", "spk"))
_EPOCH_HELP = "an ISO date in TDB, e.g. 2027-03-15T00:00:00 (or '... UTC' with a leapseconds kernel loaded)"


class SceneFilePath(str):
    """A data-file path named in a scene file, made absolute beside that file (``given``: the
    name as written). Only these are opened: a mapping from elsewhere (a service request)
    cannot name a file on the server, but for kernels through the service's ``--data-dir`` rule
    (:data:`~skynav.scenes.mission_spice.KERNEL_RESOLVER`)."""

    def __new__(cls, path, given=None):
        self = super().__new__(cls, path)
        self.given = str(path) if given is None else str(given)
        return self


@dataclass(frozen=True)
class MissionFiles:
    """What a scene's data files gave besides numbers: ``records`` (``{"key", "name", "sha256"}``
    of every file read, names as given) and the ephemeris of ``ephemeris: {spk: FILE}`` (a
    :class:`~skynav.scenes.mission_spice.SpiceEphemeris`; None: DE421)."""

    records: tuple = ()
    ephemeris: SpiceEphemeris | None = None


def mark_mission_files(mapping, folder):
    """The scene mapping with its data-file names (``_SOURCES``) made absolute beside the scene
    file's ``folder`` and marked as named by a file (:class:`SceneFilePath`)."""
    if not isinstance(mapping, Mapping):
        return mapping
    out = dict(mapping)
    for section, key in _SOURCES:
        sec = out.get(section)
        if isinstance(sec, Mapping) and isinstance(sec.get(key), str):
            out[section] = {**sec, key: SceneFilePath((Path(folder) / sec[key]).resolve(), sec[key])}
        elif (isinstance(sec, Mapping) and isinstance(sec.get(key), Mapping)
              and isinstance(sec[key].get("kernels"), list)):
            kernels = [SceneFilePath((Path(folder) / k).resolve(), k) if isinstance(k, str) else k
                       for k in sec[key]["kernels"]]
            out[section] = {**sec, key: {**sec[key], "kernels": kernels}}
    return out


def kernel_paths(kernels, key: str) -> list:
    """The files of a ``kernels:`` list (``key`` names it in errors): named in a scene file
    (:class:`SceneFilePath`), or by a request through
    :data:`~skynav.scenes.mission_spice.KERNEL_RESOLVER` where one is set."""
    if not isinstance(kernels, list) or not kernels:
        raise ConfigValueError(key, kernels, "a list of kernel files named in a scene file (read beside it)")
    resolve = KERNEL_RESOLVER.get()
    out = []
    for k in kernels:
        if isinstance(k, SceneFilePath):
            out.append(k)
        elif resolve is not None:
            out.append(SceneFilePath(resolve(k, key), k))
        else:
            raise ConfigValueError(key, kernels, "a list of kernel files named in a scene file (read beside it); "
                                   "a mapping from elsewhere cannot name a file")
    return out


def _spice_lists(d) -> list:
    """The scene's kernel lists (observer's, attitude's), resolved, in that order."""
    out = []
    for section in ("observer", "attitude"):
        sec = d.get(section)
        if isinstance(sec, Mapping) and isinstance(sec.get("spice"), Mapping):
            out.append(kernel_paths(sec["spice"].get("kernels"), f"{section}.spice.kernels"))
    return out


def _epoch_tdb_s(epoch, kernel_lists) -> float:
    """The scene's epoch, TDB s past J2000: ISO TDB, or ``'... UTC'`` through CSPICE's
    ``str2et`` with the first kernel list that holds a leapseconds kernel."""
    text = str(epoch).strip()
    if not text.upper().endswith("UTC"):
        try:
            return float(tdb_seconds(text))
        except Exception:
            raise ConfigValueError("epoch", epoch, _EPOCH_HELP) from None
    for paths in kernel_lists:
        with kernel_pool(paths) as sp:
            if sp.expool("DELTET/DELTA_AT"):
                try:
                    return float(sp.str2et(text[:-3].strip()))  # str2et reads UTC by default
                except Exception:
                    raise ConfigValueError("epoch", epoch, "a UTC date CSPICE reads, e.g. 2027-03-15T00:00:00 UTC") from None
    raise ConfigValueError("epoch", epoch, "a TDB date, or a UTC date with a leapseconds kernel (LSK) among the "
                                           "scene's observer or attitude kernels")


def _tdb_iso(t_tdb_s: float) -> str:
    t = time_from_tdb_seconds(t_tdb_s).tdb
    t.precision = 9
    return t.isot


def _ephemeris(spec, records: list):
    if not isinstance(spec, Mapping) or set(spec) != {"spk"}:
        raise ConfigValueError("ephemeris", spec, "a mapping {spk: FILE}: a planetary SPK in place of DE421")
    path = spec["spk"]
    if not isinstance(path, SceneFilePath):
        path = kernel_paths([path], "ephemeris.spk")[0]
    records += [{"key": "ephemeris.spk", **r} for r in kernel_records([path])]
    return SpiceEphemeris(path)


def resolve_mission_sources(d):
    """``(mapping, MissionFiles)``: the scene mapping with its data-file sources replaced by what
    they give at the scene's epoch (``observer``: ``position_km``, ``velocity_km_s``;
    ``attitude``: ``q_cam_icrs``, ``angular_velocity_deg_s``; a UTC ``epoch``: its TDB date)
    and the files' records; a mapping without sources as it is."""
    if not isinstance(d, Mapping):
        return d, MissionFiles()
    has_source = any(isinstance(d.get(s), Mapping) and k in d[s] for s, k in _SOURCES)
    if not has_source and not str(d.get("epoch", "")).strip().upper().endswith("UTC"):
        return d, MissionFiles()
    out = {k: v for k, v in d.items() if k != "ephemeris"}
    records: list = []
    eph = _ephemeris(d["ephemeris"], records) if "ephemeris" in d else None
    t = _epoch_tdb_s(d.get("epoch"), _spice_lists(d))
    if str(d.get("epoch", "")).strip().upper().endswith("UTC"):
        out["epoch"] = _tdb_iso(t)
    for section, key in _SOURCES[:4]:
        sec = d.get(section)
        if not isinstance(sec, Mapping) or key not in sec:
            continue
        if sorted(set(sec) - {key}):
            raise ConfigValueError(f"{section}", sorted(sec), f"{key} alone (the file gives the whole {section})")
        path = sec[key]
        if key == "spice":
            paths = kernel_paths(path.get("kernels") if isinstance(path, Mapping) else None, f"{section}.spice.kernels")
            out[section] = spice_source(section, {**path, "kernels": paths}, t)
            records += [{"key": f"{section}.spice.kernels", **r} for r in kernel_records(paths)]
            continue
        if not isinstance(path, SceneFilePath):
            raise ConfigValueError(f"{section}.{key}", path, "a file named in a scene file (read beside it); "
                                   "a mapping from elsewhere cannot name a file")
        if key == "oem":
            r, v = oem_state(read_oem(path), t)
            out[section] = {"position_km": [float(x) for x in r], "velocity_km_s": [float(x) for x in v]}
        else:
            q, w = aem_attitude(read_aem(path), t)
            out[section] = {"q_cam_icrs": [float(x) for x in q], "angular_velocity_deg_s": rate_deg_s(w)}
        records += [{"key": f"{section}.{key}", **r} for r in kernel_records([path])]
    return out, MissionFiles(tuple(records), eph)
