"""Scoring navigation states written by any program: ``skynav bench score nav DATASET RESULTS``.

Scoring module. A results file is JSON Lines, one object per frame of a ``sequence`` dataset and
per Monte Carlo run, in the published schema ``skynav/datasets/schemas/nav_results.schema.json``
(``skynav.nav_results/1``): ``frame`` (the dataset's 0-based index), ``position_km``,
``velocity_km_s`` (barycentric ICRS, the state after that frame's measurement), and optionally
``run`` (default 0), ``t_tdb_s`` (checked against the frame's epoch), ``covariance_km_km_s``
(6 x 6), ``status`` and ``time_ms``. Each line is validated on read; a line that is not JSON or
not in the schema, a frame the dataset does not have, a second line for the same run and frame,
an epoch that is not the frame's, or a covariance that is not a finite symmetric positive definite
matrix is one line naming the file and line (:class:`NavResultsFileError`). Keys the schema does
not name are kept and ignored, with one warning.

The states are scored as ``skynav bench nav`` scores its runs
(:func:`skynav.pipeline.scoring_nav_report.summarise`): estimate minus the dataset's true state,
on the frames every run of the file gives.
"""

from __future__ import annotations

import functools
import json
import warnings
from dataclasses import replace
from importlib.resources import files
from pathlib import Path

import numpy as np

from skynav.infra.errors import SkynavWarning

from .planet_centroid import CentroidNoise
from .scoring_nav_campaign import CampaignResult
from .scoring_nav_plan import NavInputError
from .scoring_results_file import json_lines

__all__ = ["NAV_RESULTS_SCHEMA", "NavResultsFileError", "read_nav_results", "score_nav_results", "write_nav_results"]

NAV_RESULTS_SCHEMA = "skynav.nav_results/1"
#: a line's ``t_tdb_s`` may differ from its frame's epoch by this much, s (the truth's epochs are
#: written with 17 significant digits: ~1e-7 s at 8e8 s past J2000)
EPOCH_TOLERANCE_S = 1e-3


class NavResultsFileError(NavInputError):
    """A navigation results file that cannot be scored: one line naming the file, the line and what is wrong.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "r.jsonl"
    >>> _ = p.write_text('{"frame": 0, "position_km": [1, 2, 3]}\\n')
    >>> read_nav_results(p, epochs_tdb_s=[0.0])
    Traceback (most recent call last):
    ...
    skynav.pipeline.scoring_nav_results.NavResultsFileError: ...r.jsonl line 1: 'velocity_km_s' is a required property
    """


@functools.lru_cache(maxsize=1)
def _validator():
    import jsonschema  # only reading a results file validates: not loaded by bench nav itself

    schema = json.loads((files("skynav.datasets") / "schemas" / "nav_results.schema.json").read_text(encoding="utf-8"))
    return jsonschema.Draft202012Validator(schema), frozenset(schema["properties"])


def _covariance(rec, where):
    if "covariance_km_km_s" not in rec:
        return None
    P = np.asarray(rec["covariance_km_km_s"], dtype=float)
    if not np.all(np.isfinite(P)):
        raise NavResultsFileError(f"{where}: covariance_km_km_s has a non-finite entry")
    if float(np.abs(P - P.T).max()) > 1e-9 * max(float(np.abs(P).max()), 1e-300):
        raise NavResultsFileError(f"{where}: covariance_km_km_s is not symmetric")
    try:
        np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        raise NavResultsFileError(f"{where}: covariance_km_km_s is not positive definite") from None
    return P


def read_nav_results(path, *, epochs_tdb_s) -> dict:
    """``{(run, frame): (state (6,), covariance (6, 6) or None, status, line number)}`` of a results file.

    ``epochs_tdb_s``: the dataset's frame epochs (F,), TDB s; a line for frame >= F is refused.
    Raises :class:`NavResultsFileError` on the first bad line, named.
    """
    epochs = np.asarray(epochs_tdb_s, dtype=float)
    validator, known = _validator()
    out, unknown = {}, set()
    for n, where, rec in json_lines(path, validator, NavResultsFileError):
        unknown |= {k for k in rec if k not in known}
        k, run = rec["frame"], rec.get("run", 0)
        if k >= len(epochs):
            raise NavResultsFileError(f"{where}: frame {k} does not exist (the dataset has {len(epochs)} frames, "
                                      f"0-{len(epochs) - 1})")
        if (run, k) in out:
            raise NavResultsFileError(f"{where}: run {run} frame {k} again (first at line {out[(run, k)][3]}); one line "
                                      "per run and frame")
        if "t_tdb_s" in rec and not abs(rec["t_tdb_s"] - epochs[k]) <= EPOCH_TOLERANCE_S:
            raise NavResultsFileError(f"{where}: t_tdb_s {rec['t_tdb_s']!r} is not frame {k}'s epoch "
                                      f"{epochs[k]!r} (within {EPOCH_TOLERANCE_S:g} s)")
        x = np.asarray(rec["position_km"] + rec["velocity_km_s"], dtype=float)
        if not np.all(np.isfinite(x)):
            raise NavResultsFileError(f"{where}: position_km or velocity_km_s has a non-finite entry")
        out[(run, k)] = (x, _covariance(rec, where), rec.get("status", ""), n)
    if not out:
        raise NavResultsFileError(f"{path}: no results (one JSON object per line, {NAV_RESULTS_SCHEMA})")
    if unknown:
        warnings.warn(f"{path}: results have keys skynav does not know ({', '.join(sorted(unknown)[:8])}); kept and "
                      "ignored", SkynavWarning, stacklevel=2)
    return out


def score_nav_results(plan, results, *, case: int = 1):
    """A results file as ``bench nav``'s :class:`~skynav.pipeline.scoring_nav.CampaignResult`:
    ``(result, plan of the scored frames, info)``. ``plan``: the dataset's
    :class:`~skynav.pipeline.scoring_nav.NavPlan` (its truth)."""
    got = read_nav_results(results, epochs_tdb_s=plan.t_tdb_s)
    runs = sorted({r for r, _ in got})
    frames = sorted(set.intersection(*({k for r2, k in got if r2 == r} for r in runs)))
    if not frames:
        raise NavResultsFileError(f"{results}: no frame is given by every run ({len(runs)} runs); give each run's "
                                  "states at the same frames")
    idx = np.asarray(frames)
    truth = np.concatenate([plan.position_km[idx], plan.velocity_km_s[idx]], 1)
    R, F = len(runs), len(frames)
    error = np.empty((R, F, 6))
    cov = np.full((R, F, 6, 6), np.nan)
    for a, r in enumerate(runs):
        for b, k in enumerate(frames):
            x, P, _, _ = got[(r, k)]
            error[a, b] = x - truth[b]
            if P is not None:
                cov[a, b] = P
    status = tuple(got[(runs[0], k)][2] or "ok" for k in frames)
    sub = replace(plan, frames=F, t_tdb_s=plan.t_tdb_s[idx], leg=plan.leg[idx], phase=tuple(plan.phase[k] for k in frames),
                  target=tuple(plan.target[k] for k in frames), position_km=plan.position_km[idx],
                  velocity_km_s=plan.velocity_km_s[idx], target_xy_px=plan.target_xy_px[idx])
    res = CampaignResult(case=case, noise=CentroidNoise(sigma0_px=float("nan")), t_tdb_s=sub.t_tdb_s, error=error,
                         cov=cov, residual_px=np.full((R, F, 2), np.nan), accepted=np.zeros((R, F), bool),
                         ip_status=status, measured_error_px=np.full((F, 2), np.nan), ip_time_s=0.0, filter_time_s=0.0,
                         pairs=(), filter_name=str(results), measured=np.zeros((R, F), bool))
    info = {"results_file": str(results), "runs": R, "frames_scored": F, "frames": int(plan.frames), "lines": len(got),
            "with_covariance": bool(all(v[1] is not None for v in got.values()))}
    return res, sub, info


def write_nav_results(path, res, plan) -> Path:
    """Write a campaign's states (``res``: a :class:`~skynav.pipeline.scoring_nav.CampaignResult`
    on ``plan``'s frames) as a results file in the published schema, one line per run and frame:
    the estimate is the error plus the truth (to float rounding, ~1e-8 km at 1 au)."""
    path = Path(path)
    truth = np.concatenate([plan.position_km, plan.velocity_km_s], 1)
    with open(path, "w", encoding="utf-8") as f:
        for r in range(res.error.shape[0]):
            for k in range(res.error.shape[1]):
                x = res.error[r, k] + truth[k]
                if not np.all(np.isfinite(x)):
                    continue
                rec = {"frame": k, "run": r, "t_tdb_s": float(plan.t_tdb_s[k]), "position_km": x[:3].tolist(),
                       "velocity_km_s": x[3:].tolist(), "status": res.ip_status[k]}
                if np.all(np.isfinite(res.cov[r, k])):
                    rec["covariance_km_km_s"] = res.cov[r, k].tolist()
                f.write(json.dumps(rec) + "\n")
    return path
