"""Several navigation filters side by side (``skynav bench nav --filter A --filter B``), and their faults.

Scoring module. Every filter flies the same frames from the same initial states
(:func:`skynav.pipeline.flight.initial_states`); its image processing gets the filter's own
predicted state, so a filter that drifts also sees its planets less well, as on board. Per
filter: the final sample 3-sigma and the filter's own, the RMS error over the last leg, the NEES
against its 95 % chi-square band (definitions: :mod:`skynav.pipeline.scoring_nav_report`), the
faults (a step the filter failed: an exception, a non-finite state, a covariance that is not
symmetric positive definite, with the reason) and the time; beside them the published figures of
Andreis et al. (2024) (final 3-sigma 1953 km, 0.41 m/s, 50 runs, software images, case 1).
"""

from __future__ import annotations

import html as _html

import numpy as np

from skynav.scenes.constants import SECONDS_PER_DAY

from .flight import DEFAULT_FILTER, load_filter_factory
from .references import NAVIGATION
from .report_html import figure_base64_png, new_figure
from .scoring_nav_report import PAPER_002, nees_per_run, summarise

__all__ = ["filter_specs", "filters_summary", "filters_lines", "filters_markdown",
           "filters_figure_html", "PUBLISHED"]

#: Andreis et al. (2024) (software images, case 1, 50 runs, the Earth-Mars cruise): final 3-sigma.
PUBLISHED = PAPER_002


def filter_specs(given) -> list:
    """The ``--filter`` values in order, repeats dropped (default: skynav's EKF), each imported
    now so that a bad path is one line before any frame is read."""
    specs = list(dict.fromkeys(given or [DEFAULT_FILTER]))
    for spec in specs:
        load_filter_factory(spec)
    return specs


def filters_summary(by_filter: dict, *, plan, plans=None) -> list:
    """Per filter (``{spec: CampaignResult}``, one case): the side-by-side figures (module docstring).
    ``plans``: ``{spec: plan}`` where a filter's frames are not ``plan``'s (results files)."""
    out = []
    for spec, res in by_filter.items():
        s = summarise({res.case: res}, primary=res.case, time_s=res.ip_time_s + res.filter_time_s,
                      plan=(plans or {}).get(spec, plan))
        out.append({"filter": spec, "case": res.case, "runs": s["runs"], "final": s["final"],
                    "nees": {k: s["nees"][k] for k in ("mean", "band_low", "band_high", "fraction_inside", "final")},
                    "measurements_accepted_fraction": s["measurements"]["accepted_fraction"], "faults": s["faults"],
                    "filter_time_s": float(res.filter_time_s), "ip_time_s": float(res.ip_time_s)})
    return out


def _num(v, fmt):
    return "-" if v is None or not np.isfinite(v) else format(v, fmt)


def filters_lines(rows: list) -> list:
    """One line per filter for the terminal (none with a single filter and no fault)."""
    if len(rows) < 2 and not any(r["faults"]["steps_failed"] for r in rows):
        return []
    out = []
    for r in rows:
        f, n, fl = r["final"], r["nees"], r["faults"]
        out.append(f"{r['filter']}: final 3-sigma {_num(f['position_3sigma_km'], '.0f')} km (filter "
                   f"{_num(f['filter_position_3sigma_km'], '.0f')}), {_num(f['velocity_3sigma_m_s'], '.3f')} m/s; NEES mean "
                   f"{_num(n['mean'], '.2f')}; {fl['steps_failed']} failed steps"
                   + (f" ({'; '.join(f'{k}: {v}' for k, v in fl['reasons'].items())})" if fl["steps_failed"] else ""))
    return out


def filters_markdown(rows: list) -> list:
    """The report's "Filters side by side" section, with the published figures beside them."""
    md = ["## Filters side by side (the same frames and initial states)", "",
          "| filter | position 3-sigma [km] (sample / filter) | velocity 3-sigma [m/s] (sample / filter) | "
          "RMS error, last leg [km] | NEES mean (95 % band) | frames in band | failed steps | filter time [s] |",
          "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        f, n = r["final"], r["nees"]
        md.append(f"| `{r['filter']}` | {_num(f['position_3sigma_km'], '.0f')} / {_num(f['filter_position_3sigma_km'], '.0f')} | "
                  f"{_num(f['velocity_3sigma_m_s'], '.3f')} / {_num(f['filter_velocity_3sigma_m_s'], '.3f')} | "
                  f"{_num(f['position_error_rms_km'], '.0f')} | {_num(n['mean'], '.2f')} ({_num(n['band_low'], '.2f')} .. "
                  f"{_num(n['band_high'], '.2f')}) | {_num(100 * n['fraction_inside'] if n['fraction_inside'] is not None else None, '.0f')} % | "
                  f"{r['faults']['steps_failed']} | {r['filter_time_s']:.1f} |")
    md.append(f"| {NAVIGATION.cite} (published, 50 runs, 100-day cruise) | {PUBLISHED['position_3sigma_km']:.0f} | "
              f"{PUBLISHED['velocity_3sigma_m_s']:.2f} | - | - | - | - | - |")
    for r in rows:
        for k, v in r["faults"]["reasons"].items():
            md.append(f"- `{r['filter']}` failed {v} step(s): {k}")
    return md + [""]


def _runs_mean(a) -> np.ndarray:
    """Mean over the runs (axis 0) of the finite values; NaN at a frame without any."""
    a = np.asarray(a, dtype=float)
    ok = np.isfinite(a)
    n = ok.sum(0)
    return np.where(n > 0, np.where(ok, a, 0.0).sum(0) / np.maximum(n, 1), np.nan)


def filters_figure_html(by_filter: dict) -> str:
    """The error and 3-sigma along the cruise per filter: sample 3-sigma of the position error norm
    (``3 sqrt(mean_runs |e_r|^2)``, solid) and the filter's own (``3 sqrt(mean_runs tr P_rr)``,
    dashed), and the runs' mean NEES; an ``<h2>`` and an embedded PNG."""
    fig = new_figure((900, 620))
    ax, bx = fig.subplots(2, 1, sharex=True)
    for k, (spec, res) in enumerate(by_filter.items()):
        days = (res.t_tdb_s - res.t_tdb_s[0]) / SECONDS_PER_DAY
        colour = f"C{k % 10}"
        s3 = 3 * np.sqrt(_runs_mean(np.sum(res.error[..., :3] ** 2, -1)))
        f3 = 3 * np.sqrt(_runs_mean(np.trace(res.cov[..., :3, :3], axis1=-2, axis2=-1)))
        ax.semilogy(days, s3, color=colour, lw=1.4, label=f"{spec}: sample 3-sigma")
        ax.semilogy(days, f3, color=colour, lw=1.0, ls="--", label=f"{spec}: filter 3-sigma")
        bx.semilogy(days, _runs_mean(nees_per_run(res)), ".", ms=3, color=colour, label=spec)
    ax.axhline(PUBLISHED["position_3sigma_km"], color="gray", ls=":",
               label=f"{NAVIGATION.cite}: final 3-sigma {PUBLISHED['position_3sigma_km']:.0f} km")
    ax.set_ylabel("position 3-sigma (km)")
    ax.legend(fontsize=7)
    bx.axhline(6.0, color="gray", ls=":", label="6, the state's dimension (a consistent filter's mean)")
    bx.set_ylabel("mean NEES, 6 dof (no unit)")
    bx.set_xlabel("time since the first frame (days)")
    bx.legend(fontsize=7)
    t = _html.escape("Filters side by side: position error and 3-sigma along the cruise, NEES")
    return f"<h2>{t}</h2><img alt=\"{t}\" src=\"data:image/png;base64,{figure_base64_png(fig)}\">"
