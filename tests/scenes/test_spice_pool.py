"""CSPICE's kernel pool is global to the process: scenes with different kernels, one after the
other, from threads at once and from a pool of worker processes, each get their own kernels'
answer (the same NAIF id in two SPKs 1000 km apart)."""

import concurrent.futures
import multiprocessing

import numpy as np
import pytest

sp = pytest.importorskip("spiceypy")

from skynav.scenes.mission_spice import release_kernels  # noqa: E402
from skynav.scenes.scene_files import load_scene_file  # noqa: E402

from .test_spice import _scene, _spk  # noqa: E402

OFFSET_KM = 1000.0


@pytest.fixture
def two_scenes(tmp_path):
    for name, shift in (("a", 0.0), ("b", OFFSET_KM)):
        (tmp_path / name).mkdir()
        _spk(tmp_path / name / "craft.bsp", r0=np.array([1.2e8, -4.0e7, 2.5e7]) + shift)
    return [str(_scene(tmp_path / name, ["craft.bsp"])) for name in ("a", "b")]


def _x(path) -> float:
    return load_scene_file(path).position_km[0]


def _check(paths, xs):
    a = _x(paths[0])
    for p, x in zip(paths, xs):
        assert x == a + (OFFSET_KM if p.endswith("b/scene.yaml") else 0.0)


def test_one_process_one_after_the_other(two_scenes):
    paths = two_scenes * 5
    _check(paths, [_x(p) for p in paths])


def test_threads_at_once(two_scenes):
    paths = two_scenes * 20
    with concurrent.futures.ThreadPoolExecutor(4) as ex:
        xs = list(ex.map(_x, paths))
    _check(paths, xs)


@pytest.mark.parametrize("method", ["fork", "spawn"])
def test_a_pool_of_worker_processes(two_scenes, method):
    """Workers forked after the parent loaded a set inherit it and the record of it; spawned ones
    start empty: either way each scene gets its own kernels."""
    _x(two_scenes[1])  # the parent's pool holds b's kernel when the workers fork
    paths = two_scenes * 4
    with concurrent.futures.ProcessPoolExecutor(2, mp_context=multiprocessing.get_context(method)) as ex:
        xs = list(ex.map(_x, paths))
    _check(paths, xs)


def test_code_of_yours_that_changes_the_pool_is_seen(two_scenes, tmp_path):
    """A kclear or furnsh outside skynav between two scenes of the same set: reloaded."""
    a = _x(two_scenes[0])
    sp.kclear()
    assert _x(two_scenes[0]) == a
    sp.furnsh(str(tmp_path / "b" / "craft.bsp"))  # b's craft loaded last would win in CSPICE
    assert _x(two_scenes[0]) == a
    release_kernels()
    assert sp.ktotal("ALL") == 0
