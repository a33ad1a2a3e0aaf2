"""Shared fixtures of the datasets tests: a small, fast recipe and its 1-worker reference."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from skynav.datasets import preset_recipe


def small_recipe(frames: int = 50, keep=()) -> dict:
    """The Monte Carlo preset on a 256 x 256, 20 deg camera, stars to V = 7 (fast frames)."""
    r = preset_recipe("montecarlo")
    r["frames"] = frames
    r["seed"] = 424242
    r["camera"] = {"preset": "paper", "width": 256, "height": 256, "fov_deg": 20.0}
    r["catalog_limiting_v_mag"] = 7.0
    r["montecarlo"]["keep"] = list(keep)
    return r


def tree_sha256(root) -> dict:
    """{relative path: SHA-256} of every file under a folder."""
    root = Path(root)
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="session")
def reference_dataset(tmp_path_factory):
    """The 50-frame small recipe made in this process (1 worker): the byte-level reference."""
    from skynav.datasets import generate

    out = tmp_path_factory.mktemp("ref") / "ds"
    summary = generate(small_recipe(), out, workers=1, progress=False)
    return out, summary, tree_sha256(out)
