"""The navigation campaign's plan: what ``skynav bench nav`` needs of a ``sequence`` dataset.

Scoring module (it reads the truth: the trajectory and the target's pixel, for the initial
states and the scores). The frames the image processing sees are read through the datasets
reader (:func:`observation`; ``--images`` replaces their DN).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

import skynav.datasets as sdat
from skynav.datasets.errors import DatasetError
from skynav.datasets.reader import read_image_dn
from skynav.scenes.constants import OBLIQUITY_J2000_RAD

from .errors import BenchInputError

__all__ = ["NavInputError", "NavPlan", "load_plan", "observation", "image_path", "icrs_to_ecliptic"]


class NavInputError(BenchInputError):
    """The dataset cannot feed a navigation campaign (not a sequence, no visible planet, missing frame)."""


def icrs_to_ecliptic() -> np.ndarray:
    """Rotation ICRS -> ecliptic J2000 (mean obliquity of J2000), shape (3, 3)."""
    e = OBLIQUITY_J2000_RAD
    c, s = math.cos(e), math.sin(e)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


@dataclass(frozen=True, kw_only=True, eq=False)
class NavPlan:
    """What the campaign needs of the dataset (truth columns for scoring only)."""

    root: str
    frames: int
    t_tdb_s: np.ndarray            # (F,)
    leg: np.ndarray                # (F,) int
    phase: tuple                   # (F,) str
    target: tuple                  # (F,) str: commanded pointing
    position_km: np.ndarray        # (F, 3) truth
    velocity_km_s: np.ndarray      # (F, 3) truth
    target_xy_px: np.ndarray       # (F, 2) truth xy of the target (NaN: not visible)
    plan_pairs: tuple              # per leg (A, B) of the dataset's planner
    images: str | None = None


def load_plan(path, *, images=None, limit=None) -> NavPlan:
    """Read and check a ``sequence`` dataset. Raises :class:`NavInputError` with one line."""
    root = Path(path)
    try:
        ds = sdat.open(root)
    except (DatasetError, OSError, ValueError) as exc:
        raise NavInputError(f"{root}: not a readable dataset ({exc})") from None
    kind = ds.recipe.get("kind")
    if kind != "sequence":
        raise NavInputError(f"{root}: a {kind!r} dataset has no navigation sequence; give a 'sequence' dataset "
                            "(skynav dataset generate sequence -o DIR)")
    n = len(ds) if limit is None else min(len(ds), int(limit))
    if n < 2:
        raise NavInputError(f"{root}: {n} frame(s); a navigation campaign needs at least 2")
    try:
        rows = ds.index
    except (DatasetError, OSError, ValueError) as exc:
        raise NavInputError(f"{root}: unreadable index.csv ({exc})") from None
    if len(rows) < n:
        raise NavInputError(f"{root}: index.csv lists {len(rows)} frames, the manifest {len(ds)}")
    for i in range(n):
        for rel in rows[i].get("files", "").split(";"):
            if rel.endswith((".png", ".json")) and not (root / rel).is_file():
                raise NavInputError(f"{root}: frame {i} is missing ({rel})")
        if images is not None and not image_path(images, i).is_file():
            raise NavInputError(f"--images {images}: frame {i} is missing ({image_path(images, i).name})")
    t = np.empty(n)
    leg = np.empty(n, dtype=int)
    phase, target = [], []
    pos = np.empty((n, 3))
    vel = np.empty((n, 3))
    xy = np.full((n, 2), np.nan)
    any_visible = False
    for i in range(n):
        tr = ds.truth(i, validate=False)
        meta = tr.raw.get("dataset", {})
        t[i] = tr.epoch_tdb_s
        leg[i] = int(meta.get("leg", 0))
        phase.append(str(meta.get("phase", "")))
        tgt = str(meta.get("target") or "")
        target.append(tgt)
        pos[i], vel[i] = tr.position_km, tr.velocity_km_s
        for b in tr.bodies:
            if b.name == tgt and b.visible and b.in_fov:
                xy[i] = b.xy
                any_visible = True
    if not any_visible:
        raise NavInputError(f"{root}: no frame shows its target planet (no visible planet to navigate on)")
    pairs = ds.manifest.get("plan", {}).get("pairs") if isinstance(ds.manifest.get("plan"), dict) else None
    if not pairs:
        pairs = []
        for lg in sorted(set(leg.tolist())):
            a = [target[i] for i in range(n) if leg[i] == lg and phase[i] == "track_A"]
            b = [target[i] for i in range(n) if leg[i] == lg and phase[i] == "track_B"]
            pairs.append((a[0] if a else "", b[0] if b else ""))
    return NavPlan(root=str(root), frames=n, t_tdb_s=t, leg=leg, phase=tuple(phase), target=tuple(target),
                   position_km=pos, velocity_km_s=vel, target_xy_px=xy, plan_pairs=tuple(tuple(p) for p in pairs),
                   images=None if images is None else str(images))


def image_path(images, i) -> Path:
    """Frame ``i``'s PNG in an ``--images`` folder (``NNNNNN.png`` at the top or in ``frames/``)."""
    d = Path(images)
    p = d / f"{i:06d}.png"
    return p if p.is_file() or not (d / "frames").is_dir() else d / "frames" / f"{i:06d}.png"


def observation(ds, plan: NavPlan, i):
    """Frame ``i``'s observation, its DN from ``plan.images`` when given."""
    obs = ds.observation(i)
    if plan.images is None:
        return obs
    dn = read_image_dn(image_path(plan.images, i))  # the DN of scaled (sBIT) and raw PNGs alike
    if dn.shape != np.shape(obs.dn):
        raise NavInputError(f"--images {plan.images}: frame {i} is {dn.shape}, the dataset's {np.shape(obs.dn)}")
    return replace(obs, dn=dn)
