"""Contact sheet of a dataset with ground-truth overlays: :func:`preview`.

Driver module (``skynav dataset preview``). Each tile is a frame's quick look
(:func:`skynav.datasets.quicklook.quicklook_u8`: zscale limits and an asinh stretch, so the sky is
a dark grey and faint stars show next to saturated planets), resized to ``tile_px``; stars in the field get a circle (scikit-image ``circle_perimeter``), bodies in the
field a square and a label (Pillow), and each tile its frame number and epoch. Written as an 8-bit
RGB PNG, atomically.
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw
from skimage.draw import circle_perimeter

from skynav.infra.atomic_files import atomic_write_bytes

from . import layout
from .errors import DatasetError
from .plots import plot_leg_magnitudes
from .quicklook import quicklook_u8
from .reader import open_dataset
from .samplers import make_plan

__all__ = ["preview", "contact_sheet"]

_STAR_RGB = (80, 200, 255)
_BODY_RGB = (255, 170, 40)
_TEXT_RGB = (255, 255, 255)


def _tile(record, tile_px: int, label: str, star_v_max: float = 7.0):
    truth = record.truth
    cam = truth["camera"]
    h, w = int(cam["height"]), int(cam["width"])
    img = quicklook_u8(np.asarray(record.dn))
    small = np.asarray(Image.fromarray(img).resize((tile_px, tile_px), Image.BILINEAR))
    rgb = np.repeat(small[:, :, None], 3, axis=2)
    sx, sy = tile_px / w, tile_px / h
    for s in truth.get("stars", []):
        if s.get("v_mag", 0.0) > star_v_max:  # fainter stars would hide the image
            continue
        x, y = s["xy"]
        # pixel centres at integers: scaled centre is (x + 0.5) * s - 0.5
        cx, cy = (x + 0.5) * sx - 0.5, (y + 0.5) * sy - 0.5
        r = max(2, int(round(4 - 0.4 * (s.get("v_mag", 6) - 2))))
        rr, cc = circle_perimeter(int(round(cy)), int(round(cx)), r, shape=rgb.shape[:2])
        rgb[rr, cc] = _STAR_RGB
    labels = []
    for b in truth.get("bodies", []):
        if not b.get("in_fov"):
            continue
        x, y = b["xy"]
        cx, cy = (x + 0.5) * sx - 0.5, (y + 0.5) * sy - 0.5
        vm = b.get("v_mag")
        labels.append((cx, cy, f"{b['name']} V={vm:.1f}" if isinstance(vm, (int, float)) and math.isfinite(vm) else b["name"]))
    im = Image.fromarray(rgb)
    draw = ImageDraw.Draw(im)
    for x, y, text in labels:  # Pillow squares: skimage's rectangle_perimeter needs matplotlib
        draw.rectangle((x - 6, y - 6, x + 6, y + 6), outline=_BODY_RGB)
        draw.text((x + 8, y - 6), text, fill=_BODY_RGB)
    draw.text((3, 2), label, fill=_TEXT_RGB)
    return im


def contact_sheet(records, *, columns: int = 4, tile_px: int = 256, star_v_max: float = 7.0):
    """A Pillow RGB image of frames (records with ``dn``, ``truth``, ``index``) in a grid."""
    records = list(records)
    if not records:
        raise ValueError("no frames to show")
    cols = max(1, min(columns, len(records)))
    rows = int(math.ceil(len(records) / cols))
    gap = 4
    sheet = Image.new("RGB", (cols * tile_px + (cols + 1) * gap, rows * tile_px + (rows + 1) * gap), (40, 40, 40))
    for i, rec in enumerate(records):
        label = f"#{rec.index} {rec.truth['epoch']['tdb_iso'][:16]}"
        tile = _tile(rec, tile_px, label, star_v_max)
        r, c = divmod(i, cols)
        sheet.paste(tile, (gap + c * (tile_px + gap), gap + r * (tile_px + gap)))
    return sheet


def preview(path, out_png, *, frames=None, count: int = 16, columns: int = 4, tile_px: int = 256,
            star_v_max: float = 7.0) -> Path:
    """Write a contact sheet PNG of a dataset with star circles and body labels.

    Parameters
    ----------
    path : str or os.PathLike
        A complete dataset.
    out_png : str or os.PathLike
        Output PNG.
    frames : sequence of int, optional
        Frames to show (default: ``count`` frames evenly spread over the dataset).
    count : int
        Number of frames shown when ``frames`` is not given.
    columns : int
        Tiles per row.
    tile_px : int
        Size of a tile, px (each frame scaled to fit).
    star_v_max : float
        Circle the stars brighter than this V magnitude.

    Returns
    -------
    pathlib.Path
        The PNG written (atomically).

    Examples
    --------
    >>> import tempfile
    >>> from skynav.datasets import generate, preset_recipe
    >>> from skynav.renderer import RenderOptions
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=2, camera={"preset": "paper", "width": 64, "height": 64, "fov_deg": 20})
    >>> tmp = tempfile.TemporaryDirectory()
    >>> summary = generate(recipe, tmp.name + "/ds", workers=1, progress=False,
    ...                    render_options=RenderOptions(backend="numpy"))
    >>> from PIL import Image
    >>> from skynav.datasets import preview
    >>> out = preview(tmp.name + "/ds", tmp.name + "/sheet.png", columns=2, tile_px=64)
    >>> Image.open(out).mode in ("RGB", "RGBA")
    True
    >>> tmp.cleanup()
    """
    ds = open_dataset(path)
    n = len(ds)
    if frames is None:
        frames = sorted(set(np.linspace(0, n - 1, min(count, n)).round().astype(int).tolist()))
    sheet = contact_sheet([ds[int(k)] for k in frames], columns=columns, tile_px=tile_px, star_v_max=star_v_max)
    buf = io.BytesIO()
    sheet.save(buf, format="PNG")
    out = Path(out_png)
    atomic_write_bytes(out, buf.getvalue())
    return out


def leg_plot(path, out_png, *, step_s: float = 6 * 3600.0) -> Path:
    """Write the planets' apparent V along the cruise of a ``sequence`` dataset (legs shaded).

    The plan is rebuilt from the manifest's recipe (the trajectory is recomputed).

    Parameters
    ----------
    path : str or os.PathLike
        A ``sequence`` dataset (complete or not: only the manifest is read).
    out_png : str or os.PathLike
        Output PNG.
    step_s : float
        Sampling step of the magnitudes along the cruise, s.

    Returns
    -------
    pathlib.Path
        The PNG written.

    Raises
    ------
    DatasetError
        The dataset is not a ``sequence``.

    Examples
    --------
    A ``montecarlo`` dataset has no legs:

    >>> import tempfile
    >>> from skynav.datasets import generate, preset_recipe
    >>> from skynav.renderer import RenderOptions
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=2, camera={"preset": "paper", "width": 64, "height": 64, "fov_deg": 20})
    >>> tmp = tempfile.TemporaryDirectory()
    >>> summary = generate(recipe, tmp.name + "/ds", workers=1, progress=False,
    ...                    render_options=RenderOptions(backend="numpy"))
    >>> from skynav.datasets import DatasetError, leg_plot
    >>> try:
    ...     leg_plot(tmp.name + "/ds", tmp.name + "/legs.png")
    ... except DatasetError as exc:
    ...     print(str(exc).split(": ", 1)[1])
    a 'montecarlo' dataset has no navigation legs to plot; only 'sequence' has
    >>> tmp.cleanup()
    """
    recipe = layout.read_manifest(path)["recipe"]
    if recipe.get("kind") != "sequence":
        raise DatasetError(f"{path}: a {recipe.get('kind')!r} dataset has no navigation legs to plot; only 'sequence' has")
    out = Path(out_png)
    plot_leg_magnitudes(make_plan(recipe), out, step_s=step_s)
    return out
