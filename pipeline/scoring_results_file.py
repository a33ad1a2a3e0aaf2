"""Scoring a results file written by any program: ``skynav bench score ip DATASET RESULTS``.

Scoring module. A results file is JSON Lines, one object per frame in the published schema
``skynav/datasets/schemas/ip_results.schema.json`` (``skynav.ip_results/1``): ``frame`` (the
dataset's 0-based index), ``R_cam_icrs`` (3 rows of 3 numbers, or null: not solved), and
optionally ``sigma_km`` (the predicted-state sigma the result used; absent: none used, the line
answers every sigma), ``status``, ``time_ms``, ``method``, ``error_estimate_arcsec`` and
``beacons`` (``name``, ``xy_px``). Each line is validated on read; a line that is not JSON or not
in the schema, a frame the dataset does not have, a second line for the same frame (and sigma),
or an attitude that is not a finite proper rotation is one line naming the file and line
(:class:`ResultsFileError`). Keys the schema does not name are kept and ignored, with one
warning. A frame without a line counts as not solved (status ``"no_record"``).

The lines are scored as ``skynav bench ip`` scores a plug-in's results
(:func:`~skynav.pipeline.scoring.score_frame`): the same truth, the same outcome classes.
"""

from __future__ import annotations

import functools
import json
import warnings
from importlib.resources import files
from pathlib import Path

import numpy as np

from skynav.infra.errors import SkynavWarning

from .errors import BenchInputError
from .plugins import check_result
from .protocols import BeaconSighting, ImageResult
from .scoring import open_frames, predicted_state, score_frame

__all__ = ["RESULTS_SCHEMA", "ResultsFileError", "read_results_file", "score_results_file", "write_predictions"]

RESULTS_SCHEMA = "skynav.ip_results/1"
#: lines read at most (a results file of more lines than this is not one dataset's)
MAX_LINES = 10_000_000


class ResultsFileError(BenchInputError):
    """A results file that cannot be scored: one line naming the file, the line and what is wrong.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "r.jsonl"
    >>> _ = p.write_text('{"frame": 0}\\n')
    >>> read_results_file(p, frames=1)
    Traceback (most recent call last):
    ...
    skynav.pipeline.scoring_results_file.ResultsFileError: ...r.jsonl line 1: 'R_cam_icrs' is a required property
    """


@functools.lru_cache(maxsize=1)
def _validator():
    import jsonschema  # 0.1 s to import: only a results file being read needs it

    schema = json.loads((files("skynav.datasets") / "schemas" / "ip_results.schema.json").read_text(encoding="utf-8"))
    return jsonschema.Draft202012Validator(schema), frozenset(schema["properties"]), \
        frozenset(schema["properties"]["beacons"]["items"]["properties"])


def _no_constant(name):
    raise ValueError(f"{name} is not JSON (write null)")


def json_lines(path, validator, error):
    """``(n, where, record)`` of each non-blank line of the JSON Lines file ``path`` (at most
    :data:`MAX_LINES`), ``where`` naming the file and line, each record valid under the JSON
    Schema ``validator``; the first unreadable file, line that is not JSON (NaN and Infinity
    included) or record the schema refuses raises ``error`` with one line naming it."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{path}: not a readable results file ({type(exc).__name__})") from None
    for n, line in enumerate(text.splitlines()[:MAX_LINES], start=1):
        if not line.strip():
            continue
        where = f"{path} line {n}"
        try:
            rec = json.loads(line, parse_constant=_no_constant)
        except ValueError as exc:
            raise error(f"{where}: not a JSON object ({str(exc).splitlines()[0]})") from None
        err = next(iter(sorted(validator.iter_errors(rec), key=lambda e: len(e.absolute_path))), None)
        if err is not None:
            at = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in err.absolute_path)
            raise error(f"{where}: {'$' + at + ': ' if at else ''}{err.message[:200]}")
        yield n, where, rec


def read_results_file(path, *, frames: int) -> dict:
    """``{(frame, sigma_km or None): (ImageResult, time_ms, line number)}`` of a results file.

    Parameters
    ----------
    path : path-like
        The JSON Lines file.
    frames : int
        The dataset's frame count (a line for frame >= ``frames`` is refused).

    Raises
    ------
    ResultsFileError
        The first bad line, named.
    """
    validator, known, beacon_known = _validator()
    out, unknown = {}, set()
    every = {}   # frame -> line of its sigma-less record
    some = {}    # frame -> line of a record with a sigma
    for n, where, rec in json_lines(path, validator, ResultsFileError):
        unknown |= {k for k in rec if k not in known}
        unknown |= {f"beacons[].{k}" for b in rec.get("beacons", ()) for k in b if k not in beacon_known}
        k, sigma = rec["frame"], rec.get("sigma_km")
        if k >= frames:
            raise ResultsFileError(f"{where}: frame {k} does not exist (the dataset has {frames} frames, 0-{frames - 1})")
        key = (k, None if sigma is None else float(sigma))
        if key in out:
            also = f" at sigma_km {sigma:g}" if sigma is not None else ""
            raise ResultsFileError(f"{where}: frame {k}{also} again (first at line {out[key][2]}); one line per frame")
        if (sigma is None and k in some) or (sigma is not None and k in every):
            first = some[k] if sigma is None else every[k]
            raise ResultsFileError(f"{where}: frame {k} has a line for every sigma (no sigma_km) and one for a given "
                                   f"sigma_km (line {first}); give one or the other")
        (every if sigma is None else some).setdefault(k, n)
        out[key] = (_image_result(rec, where), rec.get("time_ms"), n)
    if unknown:
        warnings.warn(f"{path}: results have keys skynav does not know ({', '.join(sorted(unknown)[:8])}); kept and "
                      "ignored", SkynavWarning, stacklevel=2)
    return out


def _image_result(rec, where) -> ImageResult:
    beacons = tuple(BeaconSighting(name=b["name"], xy_px=b["xy_px"], xy_cov_px2=b.get("xy_cov_px2"),
                                   status="found" if b["xy_px"] is not None else "not_found")
                    for b in rec.get("beacons", ()))
    est = rec.get("error_estimate_arcsec")
    res = ImageResult(R_cam_icrs=None if rec["R_cam_icrs"] is None else np.asarray(rec["R_cam_icrs"], dtype=float),
                      status=rec.get("status", ""), method=rec.get("method", ""), beacons=beacons,
                      error_estimate_arcsec=float("nan") if est is None else float(est))
    checked, fault = check_result(res)
    if fault is not None:
        raise ResultsFileError(f"{where}: {fault.message}")
    return checked


def score_results_file(dataset, results, *, sigmas_km=None, limit=None, name=None):
    """Score a results file against a dataset's truth: ``(scores, info)``, as
    :func:`~skynav.pipeline.scoring.run_benchmark` returns them.

    ``sigmas_km``: the sigmas scored (default: those the file names, else 1e4 km); a line without
    ``sigma_km`` answers each. ``name``: the processor's name in the report (default the file's
    stem).
    """
    src = open_frames(dataset)
    n = len(src) if limit is None else min(limit, len(src))
    got = read_results_file(results, frames=len(src))
    if sigmas_km is None:
        sigmas_km = tuple(sorted({s for _, s in got if s is not None})) or (1e4,)
    sigmas_km = tuple(float(s) for s in sigmas_km)
    stray = next(((k, s, v[2]) for (k, s), v in got.items() if s is not None and s not in sigmas_km), None)
    if stray is not None:
        raise ResultsFileError(f"{results} line {stray[2]}: sigma_km {stray[1]:g} is not one of the sigmas scored "
                               f"({', '.join(f'{s:g}' for s in sigmas_km)} km); give it with --position-sigma-km")
    name = name or Path(results).stem
    rows = []
    for k in range(n):
        truth = src.truth(k)
        for s in sigmas_km:
            res, ms, _ = got.get((k, s)) or got.get((k, None)) or (ImageResult(R_cam_icrs=None, status="no_record"),
                                                                    None, 0)
            rows.append(score_frame(res, truth, frame=k, sigma_km=s, time_ms=float("nan") if ms is None else ms,
                                    pipeline=name))
    return rows, {"frames": n, "results_file": str(results), "sigmas_km": sigmas_km,
                  "lines": len(got)}


def write_predictions(dataset, out, *, sigmas_km, seed=0, limit=None) -> int:
    """Write the predicted states ``bench ip`` gives every processor, for a program that runs apart.

    One JSON line per frame and sigma: ``frame``, ``sigma_km``, ``position_km``, ``velocity_km_s``
    and ``position_cov_km2`` (ICRS, barycentric), drawn as :func:`~skynav.pipeline.scoring.run_benchmark`
    draws them (``SeedSequence([seed, frame, i_sigma])``). A program that answers with the line's
    ``sigma_km`` is scored at that sigma, on the prediction every plug-in had.

    Returns
    -------
    int
        The lines written.
    """
    src = open_frames(dataset)
    n = len(src) if limit is None else min(limit, len(src))
    lines = []
    for k in range(n):
        truth = src.truth(k)
        for i, s in enumerate(sigmas_km):
            ps = predicted_state(truth, float(s), np.random.default_rng(np.random.SeedSequence([int(seed), k, i])))
            lines.append(json.dumps({"frame": k, "sigma_km": float(s), "position_km": ps.position_km.tolist(),
                                     "velocity_km_s": ps.velocity_km_s.tolist(),
                                     "position_cov_km2": ps.position_cov_km2.tolist()}))
    Path(out).write_text("".join(line + "\n" for line in lines), encoding="utf-8")
    return len(lines)
