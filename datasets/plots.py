"""Small PNG line plots with Pillow (no matplotlib): planets' magnitudes along a sequence.

Driver-side helper for reports and benchmarks. :func:`leg_magnitudes` computes the apparent V
magnitude of every planet seen from the cruise; :func:`plot_lines_png` draws series on axes.
"""

from __future__ import annotations

import io
import math

import numpy as np

from skynav.scenes.constants import SECONDS_PER_DAY

__all__ = ["plot_lines_png", "leg_magnitudes", "plot_leg_magnitudes"]

_COLOURS = {"mercury": (150, 150, 150), "venus": (230, 200, 80), "earth": (60, 130, 255), "moon": (200, 200, 200),
            "mars": (230, 80, 50), "jupiter": (220, 150, 90), "saturn": (190, 170, 100), "uranus": (100, 220, 220),
            "neptune": (80, 90, 230)}


def _nice_ticks(lo: float, hi: float, n: int = 6):
    span = hi - lo if hi > lo else 1.0
    step = 10 ** math.floor(math.log10(span / n))
    for m in (1, 2, 5, 10):
        if span / (m * step) <= n:
            step *= m
            break
    start = math.ceil(lo / step) * step
    return [start + i * step for i in range(int((hi - start) / step + 1e-9) + 1)]


def plot_lines_png(x, series: dict, *, title: str, xlabel: str, ylabel: str, invert_y: bool = False,
                   spans=(), size=(900, 520), colours=None) -> bytes:
    """PNG bytes of line plots ``series = {label: y (N,)}`` against ``x (N,)``.

    ``spans``: ``(x0, x1, label)`` shaded vertical bands (e.g. tracking windows).
    """
    from PIL import Image, ImageDraw

    colours = colours or {}
    w, h = size
    left, right, top, bottom = 70, 150, 40, 50
    im = Image.new("RGB", size, (255, 255, 255))
    d = ImageDraw.Draw(im)
    x = np.asarray(x, dtype=float)
    ys = [np.asarray(v, dtype=float) for v in series.values()]
    finite = np.concatenate([y[np.isfinite(y)] for y in ys]) if ys else np.zeros(1)
    y0, y1 = float(finite.min()), float(finite.max())
    pad = 0.05 * (y1 - y0 or 1.0)
    y0, y1 = y0 - pad, y1 + pad
    x0, x1 = float(x.min()), float(x.max() if x.max() > x.min() else x.min() + 1)

    def px(xv, yv):
        u = left + (xv - x0) / (x1 - x0) * (w - left - right)
        f = (yv - y0) / (y1 - y0)
        v = top + (f if invert_y else 1 - f) * (h - top - bottom)
        return u, v

    for a, b, _label in spans:
        u0, _ = px(a, y0)
        u1, _ = px(b, y0)
        d.rectangle((u0, top, max(u1, u0 + 1), h - bottom), fill=(235, 235, 245))
    d.rectangle((left, top, w - right, h - bottom), outline=(0, 0, 0))
    for t in _nice_ticks(x0, x1):
        u, _ = px(t, y0)
        d.line((u, h - bottom, u, h - bottom + 4), fill=(0, 0, 0))
        d.text((u - 10, h - bottom + 6), f"{t:g}", fill=(0, 0, 0))
    for t in _nice_ticks(y0, y1):
        _, v = px(x0, t)
        d.line((left - 4, v, left, v), fill=(0, 0, 0))
        d.line((left, v, w - right, v), fill=(225, 225, 225))
        d.text((left - 40, v - 6), f"{t:g}", fill=(0, 0, 0))
    for i, (label, y) in enumerate(series.items()):
        col = colours.get(label, (0, 0, 0))
        seg = []  # break the line where y is NaN (e.g. a planet too close to the Sun)
        for a, b in zip(x, np.asarray(y, dtype=float)):
            if np.isfinite(b):
                seg.append(px(a, b))
                continue
            if len(seg) > 1:
                d.line(seg, fill=col, width=2)
            seg = []
        if len(seg) > 1:
            d.line(seg, fill=col, width=2)
        d.line((w - right + 10, top + 10 + 16 * i, w - right + 30, top + 10 + 16 * i), fill=col, width=3)
        d.text((w - right + 35, top + 4 + 16 * i), label, fill=(0, 0, 0))
    d.text((left, 12), title, fill=(0, 0, 0))
    d.text(((w - right + left) // 2 - 40, h - 22), xlabel, fill=(0, 0, 0))
    d.text((5, top - 18), ylabel, fill=(0, 0, 0))
    buf = io.BytesIO()
    im.save(buf, format="PNG")
    return buf.getvalue()


def leg_magnitudes(plan, *, step_s: float = 6 * 3600.0, planets=("mercury", "venus", "earth", "mars", "jupiter", "saturn")):
    """(days since the cruise start (N,), {planet: V (N,)}, {planet: sun angle deg (N,)}) along a sequence plan."""
    from skynav.scenes.scene import sky_bodies

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
    """PNG of the planets' V magnitudes along the cruise, tracking legs shaded (atomic write)."""
    from .frame_files import atomic_write_bytes

    days, mags, sun = leg_magnitudes(plan, step_s=step_s)
    # hide a planet while it is inside the pair Sun-angle limit (not trackable)
    limit = plan.s["pair_elongation_min_deg"]
    shown = {p: np.where(sun[p] > limit, m, np.nan) for p, m in mags.items()}
    spans = [((w.start_tdb_s - plan.start_tdb_s) / SECONDS_PER_DAY, (w.end_tdb_s - plan.start_tdb_s) / SECONDS_PER_DAY + 0.6, w.phase)
             for w in plan.windows if w.phase.startswith("track")]
    pairs = "; ".join("/".join(p) for p in plan.describe()["pairs"][:3])
    png = plot_lines_png(days, shown, title=f"Apparent V magnitude of the planets along the cruise (legs shaded; pairs {pairs} ...)",
                         xlabel="days since cruise start", ylabel="V (mag)", invert_y=True, spans=spans, colours=_COLOURS)
    atomic_write_bytes(out_png, png)
