"""Writing the ``skynav bench ip`` report: results.csv, summary.json, report.md, report.html.

Driver-side scoring module: the HTML is self-contained (matplotlib PNGs embedded as base64, no
script, no external resource), and puts our numbers next to Tables 3 and 4 of Andreis et al.
(2023a), cited in the report's references section.
"""

from __future__ import annotations

import csv
import html
import json
import math
from pathlib import Path

import numpy as np

from .references import IMAGE_PROCESSING, references_md
from .scoring import WRONG_ATTITUDE_ARCSEC
from .report_html import REPORT_CSS, figure_base64_png, markdown_to_html, new_figure

__all__ = ["write_report", "report_figures", "time_histogram_figure", "side_by_side_md", "side_by_side_figure",
           "PAPER_TABLE3"]

# Andreis et al. (2023a), Table 3 (1031 scenes with a planet; 962 with an attitude): sigma_r km ->
# (sigma_ErrRot arcsec, % wrong attitude, % no attitude, % wrong beacon (of 962),
#  % wrong beacon with right attitude (of 962))
PAPER_TABLE3 = {
    "10000": (14.77, 3.88, 6.69, 4.57, 0.42),
    "100000": (15.18, 3.88, 6.69, 4.68, 0.52),
    "1e+06": (15.21, 4.07, 6.69, 7.69, 3.33),
    "1e+07": (15.48, 4.07, 6.69, 29.83, 25.47),
}
# Andreis et al. (2023a), Table 4: mean error (px) and det(P) (px^4) of the planet projection errors
PAPER_TABLE4 = {
    "10000": ((0.0014, -0.0003), 5.9e-5),
    "100000": ((0.0001, -0.0034), 7.05e-5),
    "1e+06": ((-0.0005, -0.0045), 9.94e-5),
    "1e+07": ((-0.0005, -0.0041), 7.05e-5),
}
CSV_FIELDS = ("pipeline", "frame", "sigma_km", "status", "attitude", "error_arcsec", "error_estimate_arcsec", "n_stars", "n_spots",
              "method", "time_ms", "beacon_name", "beacon_outcome", "beacon_error_px", "fault")


def _clean(x):
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, np.generic):
        return _clean(x.item())
    return x


#: Frames at the start of a run whose times the histogram leaves out: the first frame pays the
#: first calls' costs (lazy imports, caches: several times a later frame's time), which would
#: squeeze every other frame into one bin.
WARMUP_FRAMES = 1


def time_histogram_figure(rows):
    """Histogram of the pipeline's time per run (one run: one frame at one sigma_r), the first
    :data:`WARMUP_FRAMES` frame(s) left out; times above 1.25 x the 99th percentile go to an
    overflow bin. Returns ``(figure, caption)``."""
    warm = [r for r in rows if r.frame < WARMUP_FRAMES]
    t = np.array([r.time_ms for r in rows if r.frame >= WARMUP_FRAMES], dtype=float)
    t = t[np.isfinite(t)]
    fig = new_figure((800, 350))
    ax = fig.add_subplot()
    warm_ms = ", ".join(f"{r.time_ms:.1f}" for r in warm) or "none"
    which = "Frame 0" if WARMUP_FRAMES == 1 else f"Frames 0-{WARMUP_FRAMES - 1}"
    caption = (f"{which} left out: warm-up (the first calls' lazy imports and caches), its runs took {warm_ms} ms. "
               "Each run is one frame at one σr.")
    if len(t):
        top = 1.25 * float(np.percentile(t, 99))
        over = int(np.sum(t > top))
        edges = np.linspace(0.0, top, 41)
        ax.hist(np.minimum(t, top), bins=np.append(edges, top * 1.05), color="#aa7744",
                label=f"{len(t)} runs (frame {WARMUP_FRAMES} onward)")
        if over:
            caption += f" {over} run(s) slower than {top:.1f} ms are counted in the last bin (overflow)."
            ax.axvline(top, color="0.3", ls=":", lw=1.0, label=f"overflow bin: {over} run(s) > {top:.1f} ms")
        ax.legend(loc="upper right", fontsize=8)
    ax.set_xlabel("pipeline time per run, one frame at one σr (ms)")
    ax.set_ylabel("runs per bin (count)")
    ax.set_title("time per frame, warm-up frame left out")
    return fig, caption


def report_figures(rows, summary, sigmas):
    """The report's figures: a list of ``(title, caption, matplotlib Figure)``."""
    out = []
    s0 = [r for r in rows if r.sigma_km == float(sigmas[0])]
    errs = np.array([r.error_arcsec for r in s0 if r.attitude != "none"])
    fig = new_figure((1000, 380))
    ax = fig.subplots(1, 2)
    if len(errs):
        ax[0].hist(np.clip(errs, 0, 200), bins=50, color="#4477aa", label=f"{len(errs)} frames with an attitude")
        e = np.sort(np.maximum(errs, 1e-3))  # an exact attitude (0") on the log axis
        ax[1].plot(e, 100.0 * np.arange(1, len(e) + 1) / len(e), color="#4477aa", label="attitude error")
        ax[1].set_xscale("log")
        ax[0].legend(loc="upper right", fontsize=8)
    ax[0].set_xlabel("attitude error, above 200 in the last bin (arcsec)")
    ax[0].set_ylabel("frames per bin (count)")
    ax[1].set_xlabel("attitude error (arcsec)")
    ax[1].set_ylabel("cumulative share of frames (%)")
    ax[1].axvline(500, color="r", lw=0.8, label="wrong beyond 500 arcsec")
    ax[1].legend(loc="lower right", fontsize=8)
    fig.suptitle(f"attitude error at σr = {float(sigmas[0]):g} km", fontsize=10)
    out.append(("attitude error histogram and CDF", "", fig))

    fig = new_figure((800, 380))
    ax = fig.add_subplot()
    labels = [f"{s:g}" for s in sigmas]
    bottoms = np.zeros(len(sigmas))
    for outcome, name, color in (("correct", "correct", "#228833"), ("wrong", "wrong", "#ee6677"),
                                 ("none", "not found", "#bbbbbb")):
        v = np.array([summary["beacon"][f"{float(s):g}"][f"{outcome}_rate"] or 0.0 for s in sigmas])
        v = 100.0 * np.nan_to_num(v)
        ax.bar(labels, v, bottom=bottoms, color=color, label=f"beacon {name}")
        bottoms += v
    ax.set_xlabel("predicted-position error per axis, σr (km)")
    ax.set_ylabel("share of beacons (%)")
    ax.legend(loc="lower left", fontsize=8)
    out.append(("beacon outcomes per σr", "", fig))

    fig = new_figure((int(320 * len(sigmas)) + 40, 340))
    axes = np.atleast_1d(fig.subplots(1, len(sigmas), squeeze=False)[0])
    t = np.linspace(0, 2 * np.pi, 100)
    for ax, s in zip(axes, sigmas):
        d = np.array([bb.offset_px for r in rows if r.sigma_km == float(s) for bb in r.beacons if bb.outcome == "correct"]).reshape(-1, 2)
        if len(d):
            ax.scatter(d[:, 0], d[:, 1], s=3, alpha=0.5, label="found minus true")
        if len(d) > 2:
            C = np.cov(d.T)
            w, V = np.linalg.eigh(C)
            ell = (V @ (np.sqrt(11.8292 * np.clip(w, 0, None))[:, None] * np.stack([np.cos(t), np.sin(t)]))).T + d.mean(0)
            ax.plot(ell[:, 0], ell[:, 1], "r-", lw=1, label="3-sigma ellipse")
        ax.set_title(f"σr = {s:g} km", fontsize=9)
        ax.set_xlabel("dx (px)")
        ax.set_ylabel("dy (px)")
        ax.set_aspect("equal", adjustable="datalim")
        if len(d):
            ax.legend(loc="upper right", fontsize=7)
    out.append(("beacon projection errors with 3-sigma ellipses", "", fig))

    fig, caption = time_histogram_figure(rows)
    out.append(("time per frame", caption, fig))
    return out


def _table_md(summary, sigmas):
    a = summary["attitude"]
    lines = ["| σr (km) | ours: 1-sigma err arcsec | paper | ours: % wrong att. | paper | ours: % no att. | paper | "
             "ours: % beacon fail (with att.) | paper | ours: % fail (right att.) | paper |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in sigmas:
        k = f"{float(s):g}"
        p = PAPER_TABLE3.get(k)
        b = summary["beacon"][k]
        pct = lambda v: "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{100 * v:.2f}"
        lines.append(f"| {k} | {a['error_arcsec_1sigma']:.2f} | {p[0] if p else '-'} | {pct(a['wrong_rate'])} | "
                     f"{p[1] if p else '-'} | {pct(a['none_rate'])} | {p[2] if p else '-'} | "
                     f"{pct(b['failure_rate_with_attitude'])} | {p[3] if p else '-'} | "
                     f"{pct(b['failure_rate_with_right_attitude'])} | {p[4] if p else '-'} |")
    return "\n".join(lines)


def _pct(v):
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{100 * v:.2f}"


def _num(v, fmt=".2f"):
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, fmt)


def side_by_side_md(runs, sigmas_km, *, notes=None) -> list:
    """Markdown lines: every processor of ``runs`` (``{name: (rows, summary)}``) on the same frames
    and predicted states, with the published figures of Andreis et al. (2023a), Table 3 beside
    them, then each processor's faults (the frames it failed on, and why)."""
    k0 = f"{float(sigmas_km[0]):g}"
    p = PAPER_TABLE3.get(k0)
    md = ["## Side by side", "",
          f"Every processor on the same frames with the same predicted states (σr = {k0} km per axis for the "
          "attitude and beacon columns; time: the wall time of one call, every σr). Correct: attitude error "
          "<= 500 arcsec; fault: the processor raised, returned no valid rotation or ran past the frame time limit.", "",
          "| processor | correct % | wrong % | none % | faults | median error arcsec | p90 | 68th percentile | "
          "time median ms | time p90 ms | beacons correct % | beacon failures with attitude % |",
          "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, (rows, s) in runs.items():
        a, b = s["attitude"], s["beacon"].get(k0, {})
        md.append(f"| {name} | {_pct(a['correct_rate'])} | {_pct(a['wrong_rate'])} | {_pct(a['none_rate'])} | "
                  f"{sum(s.get('faults', {}).values())} | {_num(a['error_arcsec_median'])} | {_num(a['error_arcsec_p90'])} | "
                  f"{_num(a['error_arcsec_1sigma'])} | {_num(s['time_ms']['median'])} | {_num(s['time_ms']['p90'])} | "
                  f"{_pct(b.get('correct_rate'))} | {_pct(b.get('failure_rate_with_attitude'))} |")
    if p:
        md.append(f"| {IMAGE_PROCESSING.cite}, Table 3 (published) | {100 - p[1] - p[2]:.2f} | {p[1]} | {p[2]} | - | - | - | "
                  f"{p[0]} (their σ_ErrRot) | - | - | - | {p[3]} |")
    md += ["", "### Faults", ""]
    for name, (rows, s) in runs.items():
        faults = s.get("faults", {})
        md.append(f"- {name}: " + ("none" if not faults else "; ".join(f"{n} x {why}" for why, n in faults.items())))
    md += [f"- {name}: not run ({why})" for name, why in (notes or {}).items()]
    return md + [""]


def side_by_side_figure(runs, sigma0):
    """``(title, caption, figure)``: the cumulative attitude error of every processor of ``runs``
    (``{name: rows}``) at ``sigma0``, each over all its frames (so a curve ends at its correct
    share)."""
    fig = new_figure((900, 420))
    ax = fig.add_subplot()
    for name, rows in runs.items():
        s0 = [r for r in rows if r.sigma_km == float(sigma0)]
        e = np.sort(np.maximum([r.error_arcsec for r in s0 if r.attitude != "none"], 1e-3))
        if len(e):
            ax.step(e, 100.0 * np.arange(1, len(e) + 1) / max(len(s0), 1), where="post", label=name)
    ax.set_xscale("log")
    ax.axvline(WRONG_ATTITUDE_ARCSEC, color="r", lw=0.8, label="wrong beyond 500 arcsec")
    ax.set_xlabel("attitude error (arcsec)")
    ax.set_ylabel("share of all frames with an error below (%)")
    ax.set_ylim(0.0, 100.0)
    ax.legend(loc="lower right", fontsize=8)
    return ("attitude error, every processor side by side",
            f"σr = {float(sigma0):g} km; frames a processor did not solve (or failed on) keep its curve below 100 %.", fig)


def write_report(out_dir, rows, summary, *, sigmas_km, mode, seed, source, info, others=None):
    """Write the four report files into ``out_dir`` (created).

    ``rows``/``summary``: the first processor's scores and :func:`~skynav.pipeline.scoring.summarise`;
    ``others``: ``{name: (rows, summary)}`` of the processors benchmarked beside it (the same frames
    and predicted states), shown side by side and written to ``results.csv`` after the first.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    others = others or {}
    with open(out / "results.csv", "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(CSV_FIELDS)
        for r in list(rows) + [r for rs, _ in others.values() for r in rs]:
            base = [r.pipeline, r.frame, f"{r.sigma_km:g}", r.status, r.attitude, f"{r.error_arcsec:.3f}",
                    f"{r.error_estimate_arcsec:.3f}", r.n_stars, r.n_spots, r.method, f"{r.time_ms:.3f}"]
            if not r.beacons:
                w.writerow(base + ["", "", "", r.fault])
            for b in r.beacons:
                w.writerow(base + [b.name, b.outcome, f"{b.error_px:.4f}", r.fault])
    full = dict(summary)
    full["run"] = {"source": str(source), "mode": mode, "seed": int(seed), "sigmas_km": [float(s) for s in sigmas_km],
                   **{k: v for k, v in info.items() if k not in ("pipelines", "peer_rows", "peer_notes")}}
    (out / "summary.json").write_text(json.dumps(_clean(full), indent=2, allow_nan=False) + "\n", encoding="utf-8")
    a = summary["attitude"]
    first = rows[0].pipeline if rows else mode
    md = [f"# skynav bench ip: {source}", "",
          f"Processors: {', '.join([f'`{first}`'] + [f'`{n}`' for n in others])} (up to \"Side by side\", the "
          f"figures are `{first}`'s). Mode `{mode}`, seed {seed}, {summary['frames']} frames, predicted-position errors σr "
          f"{', '.join(f'{s:g}' for s in sigmas_km)} km per axis.", "",
          "## Attitude", "",
          f"- correct {100 * a['correct_rate']:.2f} %, wrong (> 500 arcsec) {100 * a['wrong_rate']:.2f} %, "
          f"none {100 * a['none_rate']:.2f} %",
          f"- error median {a['error_arcsec_median']:.2f} arcsec, p90 {a['error_arcsec_p90']:.2f}, "
          f"68th percentile {a['error_arcsec_1sigma']:.2f}",
          f"- status counts: {summary['status_counts']}",
          f"- time per frame: median {summary['time_ms']['median']:.2f} ms, p90 {summary['time_ms']['p90']:.2f} ms", "",
          f"## Next to {IMAGE_PROCESSING.cite}, Table 3", "",
          "The paper's rates are over the 1031 scenes with a planet in the field (beacon columns: of the 962 with an "
          "attitude); ours over all frames (attitude) and all visible in-field planets (beacons).", "",
          _table_md(summary, sigmas_km), "", "## Beacons", "",
          "| σr (km) | beacons | correct % | wrong % | none % | mean error px | mean (dx, dy) px | paper, Table 4 mean |",
          "|---|---|---|---|---|---|---|---|"]
    for s in sigmas_km:
        k = f"{float(s):g}"
        b = summary["beacon"][k]
        p4 = PAPER_TABLE4.get(k)
        f = lambda v: "-" if v is None or not math.isfinite(v) else f"{100 * v:.2f}"
        md.append(f"| {k} | {b['beacons']} | {f(b['correct_rate'])} | {f(b['wrong_rate'])} | {f(b['none_rate'])} | "
                  f"{b['error_px_mean']:.3f} | ({b['error_mean_px'][0]:.4f}, {b['error_mean_px'][1]:.4f}) | "
                  f"{p4[0] if p4 else '-'} |")
    md += side_by_side_md({first: (rows, summary), **others}, sigmas_km, notes=info.get("notes", {}))
    refs = references_md([IMAGE_PROCESSING])
    (out / "report.md").write_text("\n".join(md + refs), encoding="utf-8")
    body = "".join(f"<h2>{html.escape(t)}</h2><img alt=\"{html.escape(t)}\" src=\"data:image/png;base64,{figure_base64_png(fig)}\">"
                   + (f"<p>{html.escape(c)}</p>" if c else "")
                   for t, c, fig in report_figures(rows, summary, sigmas_km)
                   + ([side_by_side_figure({first: rows, **{n: r for n, (r, _) in others.items()}}, sigmas_km[0])]
                      if others else []))

    md_html = markdown_to_html("\n".join(md).splitlines())
    page = ("<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>skynav bench ip</title>"
            f"<style>{REPORT_CSS}</style></head><body>{md_html}{body}{markdown_to_html(refs)}</body></html>\n")
    (out / "report.html").write_text(page, encoding="utf-8")
    return out
