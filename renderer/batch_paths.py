"""The pixel paths of a batch of frames' sources in one pass.

What it computes: :func:`~skynav.renderer.expected.source_paths` of every frame of a batch (each
frame its attitude, body rate and sources; one camera, or a few), as that function makes them
frame by frame: a still frame's paths are each source's pixel, twice; a turning frame's are its
sources' pixels at :func:`~skynav.renderer.expected.path_samples` instants of the exposure, the
attitude propagated at the body rate. Here the frames that share a camera and a sample count are
done together: the attitudes of every (frame, instant) by one vectorised Rodrigues formula
(:func:`~skynav.scenes.frames.rotation_vectors_to_dcm`), each frame's directions rotated to all
its instants by one matrix product, and every (frame, source, instant) row projected by one
array operation (in slices of bounded memory).

The reference is the per-frame function; the two agree to roundings (different summation
orders of the same products: tests/renderer/test_batch_paths.py), not to the bit.
"""

from __future__ import annotations

import numpy as np

from skynav.scenes import frames

from .expected import path_samples, sample_times

__all__ = ["batch_source_paths"]

#: Largest (source, instant) rows projected at once (the projection's temporaries, a few
#: float64 arrays of the rows, stay some tens of MB however long the streaks).
_ROWS_PER_SLICE = 1 << 18


def batch_source_paths(scenes, u_icrs, options) -> list:
    """Pixel paths of the sources of many frames, through each frame's camera.

    Parameters
    ----------
    scenes : sequence of Scene
        The frames (their attitudes, body rates and cameras).
    u_icrs : sequence of ndarray, each shape (N_i, 3)
        Each frame's apparent unit vectors, ICRS.
    options : RenderOptions
        ``path_step_px`` sets the instants of a turning frame's paths.

    Returns
    -------
    list of ndarray, each shape (N_i, S_i, 2), px
        :func:`~skynav.renderer.expected.source_paths` of each frame (to roundings).

    Examples
    --------
    >>> import dataclasses
    >>> import numpy as np
    >>> from skynav.renderer import RenderOptions
    >>> from skynav.renderer.batch_paths import batch_source_paths
    >>> from skynav.renderer.expected import source_paths
    >>> from skynav.scenes import build_from_spec, default_scene_spec
    >>> scene = build_from_spec(default_scene_spec())
    >>> turning = dataclasses.replace(scene, angular_velocity_rad_s=np.array([0.002, 0.0, 0.01]))
    >>> u = scene.stars.u_icrs
    >>> paths = batch_source_paths([scene, turning], [u, u], RenderOptions())
    >>> [p.shape[1] for p in paths]
    [2, 12]
    >>> bool(np.allclose(paths[1], source_paths(turning, u, RenderOptions()), rtol=0, atol=1e-9))
    True
    """
    u_all = [np.atleast_2d(np.asarray(u, dtype=float)).reshape(-1, 3) for u in u_icrs]
    if len(u_all) != len(scenes):
        raise ValueError(f"batch_source_paths: {len(scenes)} scenes and {len(u_all)} arrays of directions")
    cams, groups = [], {}
    for i, scene in enumerate(scenes):
        cam = scene.camera
        c = next((j for j, other in enumerate(cams) if other is cam or other == cam), None)
        if c is None:
            cams.append(cam)
            c = len(cams) - 1
        groups.setdefault(c, []).append(i)
    out = [None] * len(scenes)
    for c, idx in groups.items():
        for i, p in zip(idx, _camera_paths(cams[c], [scenes[i] for i in idx], [u_all[i] for i in idx], options)):
            out[i] = p
    return out


def _camera_paths(cam, scenes, u_list, options) -> list:
    """The paths of frames of one camera: the attitude at every (frame, instant) (a still
    frame: one instant, mid-exposure, drawn twice), every (source, instant) row rotated and
    projected, the rows then cut back into each frame's (N_i, S_i, 2)."""
    n = [path_samples(s, cam, len(u), options) for s, u in zip(scenes, u_list)]
    inst = [max(k, 1) for k in n]  # instants of each frame's attitude table
    t = np.concatenate([sample_times(cam.exposure_s, k) if k else np.zeros(1) for k in n])
    w = np.repeat(np.stack([np.asarray(s.angular_velocity_rad_s, dtype=float) for s in scenes]), inst, axis=0)
    R0 = np.repeat(np.stack([np.asarray(s.R_cam_icrs, dtype=float) for s in scenes]), inst, axis=0)
    Rs = frames.rotation_vectors_to_dcm(-w * t[:, None]) @ R0  # (sum S_i, 3, 3)
    # each frame's sources at each of its instants: one matrix product a frame (N_i x 3 by
    # 3 x 3 S_i), the rows of all frames then projected together
    first = np.concatenate([[0], np.cumsum(inst)])
    v = np.concatenate([(u @ Rs[first[i]:first[i + 1]].reshape(-1, 3).T).reshape(-1, 3) for i, u in enumerate(u_list)])
    xy = np.empty((len(v), 2))
    for a in range(0, len(v), _ROWS_PER_SLICE):
        xy[a:a + _ROWS_PER_SLICE] = cam.project(v[a:a + _ROWS_PER_SLICE])
    out, r = [], 0
    for u, k in zip(u_list, inst):
        p = xy[r:r + len(u) * k].reshape(len(u), k, 2)
        r += len(u) * k
        out.append(np.concatenate([p, p], axis=1) if k == 1 else p)
    return out
