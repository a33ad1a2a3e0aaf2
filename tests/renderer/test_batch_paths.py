"""The pixel paths of a batch in one pass (renderer/batch_paths.py) against the per-frame
reference (expected.source_paths), and the vectorised Rodrigues formula against the one-vector
one and a closed form."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from skynav.renderer.batch_paths import batch_source_paths
from skynav.renderer.expected import source_paths
from skynav.renderer.render import RenderOptions
from skynav.scenes import BrownConrady, build_from_spec, default_scene_spec, paper_camera
from skynav.scenes.frames import rotation_vector_to_dcm, rotation_vectors_to_dcm

#: Agreement of the batch's paths with the reference, px. The two multiply the same rotations
#: and directions in different orders (a product a frame against numpy's einsum), so they differ
#: by roundings of float64 (1e-16 rad x a 3000 px focal length, ~1e-12 px); 1e-9 px (~1e-8 ")
#: leaves room and is far below anything a pixel can show.
PATH_TOL_PX = 1e-9


def _scenes():
    """Still and turning frames (a twist, a tiny rate, a fast one), one with no star, and a
    second camera with distortion in the same batch."""
    scene = build_from_spec(default_scene_spec())
    distorted = build_from_spec(dataclasses.replace(default_scene_spec(), camera=paper_camera(
        distortion=BrownConrady(k1=-0.08, k2=0.01, p1=2e-4, p2=-1e-4))))
    rng = np.random.default_rng(5)
    rates = [np.zeros(3), np.array([0.0, 0.0, 0.05]), np.array([1e-12, 0.0, 0.0]), rng.normal(0, 0.004, 3),
             rng.normal(0, 0.02, 3), np.array([1e-300, 0.0, 0.0])]
    out = [dataclasses.replace(s, angular_velocity_rad_s=w) for w in rates for s in (scene, distorted)]
    no_stars = dataclasses.replace(scene.stars, **{f.name: getattr(scene.stars, f.name)[:0]
                                                   for f in dataclasses.fields(scene.stars)})
    return out + [dataclasses.replace(out[3], stars=no_stars)]


def test_batch_paths_are_the_per_frame_paths():
    scenes = _scenes()
    opts = RenderOptions()
    got = batch_source_paths(scenes, [s.stars.u_icrs for s in scenes], opts)
    for scene, paths in zip(scenes, got):
        ref = source_paths(scene, scene.stars.u_icrs, opts)
        assert paths.shape == ref.shape
        np.testing.assert_array_equal(np.isnan(paths), np.isnan(ref))
        assert np.nanmax(np.abs(paths - ref), initial=0.0) <= PATH_TOL_PX
    assert {p.shape[1] for p in got} > {2}  # streaks of several lengths in one batch
    assert got[-1].shape == (0, 2, 2)


def test_one_frame_and_no_frame():
    scene = _scenes()[4]
    opts = RenderOptions(path_step_px=0.25)
    (one,) = batch_source_paths([scene], [scene.stars.u_icrs[:3]], opts)
    assert np.max(np.abs(one - source_paths(scene, scene.stars.u_icrs[:3], opts))) <= PATH_TOL_PX
    assert batch_source_paths([], [], opts) == []
    with pytest.raises(ValueError, match="2 scenes and 1 arrays"):
        batch_source_paths([scene, scene], [scene.stars.u_icrs], opts)


def test_rotation_vectors_to_dcm():
    rng = np.random.default_rng(11)
    phi = np.concatenate([rng.normal(0, 1, (200, 3)), rng.normal(0, 1e-9, (20, 3)), np.zeros((1, 3))])
    many = rotation_vectors_to_dcm(phi)
    one = np.stack([rotation_vector_to_dcm(p) for p in phi])
    assert np.max(np.abs(many - one)) < 1e-15  # the same formula, roundings apart
    # independent of both: orthonormal, proper, and a turn about z is the closed form
    assert np.max(np.abs(many @ np.swapaxes(many, -1, -2) - np.eye(3))) < 1e-14
    assert np.allclose(np.linalg.det(many), 1.0, atol=1e-14)
    a = 0.7
    expected = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
    assert np.max(np.abs(rotation_vectors_to_dcm(np.array([[0.0, 0.0, a]]))[0] - expected)) < 1e-15
