"""Plots for reports and benchmarks, drawn with matplotlib (Agg, no display needed).

Driver-side helper. :func:`leg_magnitudes` computes the apparent V magnitude of every planet
seen from the cruise; :func:`plot_leg_magnitudes` plots them along the navigation legs;
:func:`plot_lines_png` draws any set of series on labelled axes. Figures are made with
:class:`matplotlib.figure.Figure` on an Agg canvas (:func:`new_figure`), never through ``pyplot``:
no global state, no display, safe in worker processes and on headless machines;
:func:`figure_png` gives their PNG bytes (``skynav calibrate`` writes its figures with it too).

Labels are for people: every axis label ends with its unit in parentheses (``time (days)``,
``share of frames (%)``, ``NEES (no unit)``), legends and titles use words and symbols, never code
names (``sigma0_px``); tests/cli/test_figures_labelled.py checks it on every figure the commands
write.
"""

from __future__ import annotations

import io
import math

import numpy as np

from skynav.infra.atomic_files import atomic_write_bytes
from skynav.scenes.constants import SECONDS_PER_DAY
from skynav.scenes.sky import sky_bodies

__all__ = ["plot_lines_png", "lines_figure", "leg_magnitudes", "leg_magnitudes_figure", "plot_leg_magnitudes",
           "figure_png", "new_figure"]

_COLOURS = {"mercury": "#969696", "venus": "#d4a017", "earth": "#3c82ff", "moon": "#a0a0a0",
            "mars": "#e6502f", "jupiter": "#c8874b", "saturn": "#a08c3c", "uranus": "#2ab0b0",
            "neptune": "#5059e6"}


def new_figure(size_px=(900, 520), dpi: int = 100):
    """A matplotlib Figure of ``size_px`` pixels on an Agg canvas (no pyplot)."""
    # matplotlib only when a figure is drawn
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(size_px[0] / dpi, size_px[1] / dpi), dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def figure_png(fig, *, dpi=None) -> bytes:
    """PNG bytes of a matplotlib Figure (Agg; no timestamp or version in the file)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None}, **({} if dpi is None else {"dpi": dpi}))
    return buf.getvalue()


def plot_lines_png(x, series: dict, **kw) -> bytes:
    """PNG bytes of :func:`lines_figure` (same arguments)."""
    return figure_png(lines_figure(x, series, **kw))


def lines_figure(x, series: dict, *, title: str, xlabel: str, ylabel: str, invert_y: bool = False,
                 spans=(), size=(900, 520), colours=None, hlines=()):
    """A Figure of line plots ``series = {label: y (N,)}`` against ``x (N,)``, with a legend.

    Parameters
    ----------
    x : array_like, shape (N,)
    series : dict
        ``{label: y}``, each ``y`` of shape (N,); NaN breaks a line (e.g. a planet hidden by the
        Sun).
    title, xlabel, ylabel : str
        Axis labels carry their units, e.g. ``"V (mag)"``.
    invert_y : bool
        Smaller values up (magnitudes).
    spans : sequence of (x0, x1, label)
        Shaded vertical bands (e.g. tracking windows); one legend entry per distinct label.
    size : (int, int)
        Width and height, px (at 100 dpi).
    colours : dict, optional
        ``{label: matplotlib colour}``.
    hlines : sequence of (y, label)
        Dashed horizontal reference lines (e.g. a magnitude limit).
    """
    colours = colours or {}
    fig = new_figure(size)
    ax = fig.add_subplot()
    labelled = set()
    for a, b, label in spans:
        ax.axvspan(a, b, color="#dfe3f0", lw=0, zorder=0, label=None if label in labelled else label)
        labelled.add(label)
    x = np.asarray(x, dtype=float)
    for label, y in series.items():
        ax.plot(x, np.asarray(y, dtype=float), lw=1.6, label=label, color=colours.get(label))
    for y, label in hlines:
        ax.axhline(y, color="0.3", ls="--", lw=1.0, label=label)
    if invert_y:
        ax.invert_yaxis()
    ax.set_title(title, fontsize=10)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, color="0.88", lw=0.6)
    ax.set_axisbelow(True)
    ax.margins(x=0.01)
    ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), frameon=False, fontsize=9)
    return fig


def leg_magnitudes(plan, *, step_s: float = 6 * 3600.0, planets=("mercury", "venus", "earth", "mars", "jupiter", "saturn")):
    """(days since the cruise start (N,), {planet: V (N,)}, {planet: sun angle deg (N,)}) along a sequence plan."""
    t = np.arange(plan.start_tdb_s, plan.end_tdb_s, step_s)
    mags = {p: np.empty(t.size) for p in planets}
    sun = {p: np.empty(t.size) for p in planets}
    for i, ti in enumerate(t):
        r, v = plan.trajectory.state(ti)
        for b in sky_bodies(float(ti), r, v, ephemeris=plan.ephemeris, names=planets)[0]:
            mags[b.name][i] = b.v_mag
            sun[b.name][i] = math.degrees(b.elongation_rad)
    return (t - plan.start_tdb_s) / SECONDS_PER_DAY, mags, sun


def plot_leg_magnitudes(plan, out_png, *, step_s: float = 6 * 3600.0) -> None:
    """PNG of :func:`leg_magnitudes_figure` (atomic write)."""
    atomic_write_bytes(out_png, figure_png(leg_magnitudes_figure(plan, step_s=step_s)))


def leg_magnitudes_figure(plan, *, step_s: float = 6 * 3600.0):
    """The planets' V magnitudes along the cruise, tracking windows shaded (a Figure).

    A planet's line is broken while it is inside the pair Sun-angle limit (not trackable); the
    pair magnitude limit ``pair_limiting_v_mag`` is a dashed line.
    """
    days, mags, sun = leg_magnitudes(plan, step_s=step_s)
    limit = plan.s["pair_elongation_min_deg"]
    shown, colours = {}, {}
    for p, m in mags.items():
        y = np.where(sun[p] > limit, m, np.nan)
        label = p.capitalize() if np.isfinite(y).any() else f"{p.capitalize()} (always within {limit:g} deg)"
        shown[label], colours[label] = y, _COLOURS.get(p)
    spans = [((w.start_tdb_s - plan.start_tdb_s) / SECONDS_PER_DAY, (w.end_tdb_s - plan.start_tdb_s) / SECONDS_PER_DAY + 0.6,
              "tracking windows (widened)") for w in plan.windows if w.phase.startswith("track")]
    return lines_figure(
        days, shown,
        title=f"Planets' apparent V magnitude along the cruise ({plan.s['legs']} legs)\n"
              f"tracking windows shaded; a line stops within {limit:g} deg of the Sun",
        xlabel="time since cruise start (days)", ylabel="apparent V magnitude (mag)", invert_y=True, spans=spans,
        colours=colours,
        hlines=[(plan.s["pair_limiting_v_mag"], f"pair limit V < {plan.s['pair_limiting_v_mag']:g}")])
