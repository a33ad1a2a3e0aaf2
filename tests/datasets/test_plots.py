"""Plots are drawn by matplotlib on an Agg canvas: headless, no pyplot, labelled, of the asked size."""

from __future__ import annotations

import io
import subprocess
import sys

import numpy as np
from PIL import Image

from skynav.datasets.plots import plot_leg_magnitudes, plot_lines_png


def _rgb(png: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(png)) as im:
        return np.asarray(im.convert("RGB"))


def _first_run(cols: np.ndarray) -> tuple:
    """(first, last) column of the first contiguous run (the line; the legend swatch comes after a gap)."""
    cols = np.unique(cols)
    breaks = np.flatnonzero(np.diff(cols) > 1)
    return int(cols[0]), int(cols[breaks[0]] if breaks.size else cols[-1])


def test_lines_png_size_colours_and_gaps():
    x = np.linspace(0.0, 10.0, 101)
    half = np.where(x <= 5.0, x, np.nan)  # a NaN gap ends the line at x = 5
    png = plot_lines_png(x, {"half": half, "full": 10.0 - x}, title="t", xlabel="x (s)", ylabel="y (m)",
                         colours={"half": "#ff0000", "full": "#0000ff"}, size=(600, 400),
                         spans=[(7.0, 8.0, "window")])
    img = _rgb(png).astype(int)
    assert img.shape == (400, 600, 3)
    red = np.argwhere((img[:, :, 0] > 230) & (img[:, :, 1] < 40) & (img[:, :, 2] < 40))[:, 1]
    blue = np.argwhere((img[:, :, 2] > 230) & (img[:, :, 0] < 40) & (img[:, :, 1] < 40))[:, 1]
    r0, r1 = _first_run(red)
    b0, b1 = _first_run(blue)
    # the full line spans x = 0..10, the half line 0..5: half the width, from the same left edge
    assert abs(r0 - b0) <= 2
    assert abs((r1 - r0) / (b1 - b0) - 0.5) < 0.03


def test_headless_without_pyplot(tmp_path):
    code = ("import sys, numpy as np\n"
            "from skynav.datasets.plots import plot_lines_png\n"
            "png = plot_lines_png(np.arange(3.0), {'a': np.arange(3.0)}, title='t', xlabel='x', ylabel='y')\n"
            "assert png[:8] == b'\\x89PNG\\r\\n\\x1a\\n'\n"
            "assert 'matplotlib.pyplot' not in sys.modules\n")
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "MPLCONFIGDIR": str(tmp_path / "mpl")}  # no DISPLAY
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]


def test_leg_plot_of_a_short_sequence(tmp_path):
    from skynav.datasets import preset_recipe, validate_recipe
    from skynav.datasets.samplers import make_plan

    r = preset_recipe("sequence")
    r["sequence"]["legs"] = 2
    plan = make_plan(validate_recipe(r))
    out = tmp_path / "legs.png"
    plot_leg_magnitudes(plan, out, step_s=86400.0)
    img = _rgb(out.read_bytes())
    assert img.shape == (520, 900, 3)
    # Venus's line (#d4a017) is drawn: it is a pair planet of these legs
    venus = (abs(img[:, :, 0].astype(int) - 0xd4) < 8) & (abs(img[:, :, 1].astype(int) - 0xa0) < 8) \
        & (abs(img[:, :, 2].astype(int) - 0x17) < 8)
    assert venus.sum() > 50
