"""skynav's one process pool: results in job order, every result accepted as it arrives, a
worker's error raised in the caller; jobs shared between this process and helpers that join when
ready; the thread-count variables the workers inherit."""

from __future__ import annotations

import math
import multiprocessing
import os
import time

import pytest

from skynav.infra.pool import process_pool_map, share_jobs


def test_results_in_job_order_and_each_accepted():
    jobs = [9.0, 1.0, 4.0, 16.0, 0.25]
    seen = []
    got = process_pool_map(math.sqrt, jobs, 2, accept=seen.append)
    assert got == [3.0, 1.0, 2.0, 4.0, 0.5]
    assert sorted(seen) == sorted(got)


def test_a_workers_error_is_raised_here():
    with pytest.raises(ValueError, match="math domain error"):
        process_pool_map(math.sqrt, [1.0, -1.0], 2)


def test_worker_thread_variables_are_set_for_the_pool_and_restored(monkeypatch):
    from skynav.infra.pool import THREAD_VARS, WorkerThreads

    for name in THREAD_VARS:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "7")  # the user's choice is kept
    with WorkerThreads(2) as ctx:
        assert ctx.threads == max(1, (os.cpu_count() or 1) // 2)
        assert os.environ["SKYNAV_THREADS"] == str(ctx.threads)
        assert os.environ["OPENBLAS_NUM_THREADS"] == str(ctx.threads)
        assert os.environ["OMP_NUM_THREADS"] == "7"
    assert "SKYNAV_THREADS" not in os.environ and "OPENBLAS_NUM_THREADS" not in os.environ
    assert os.environ["OMP_NUM_THREADS"] == "7"


def _loop(claims, emit):
    """A share_jobs loop: the calling process (named in each job) is slow, a helper is quick."""
    for parent_pid, k, fail_at in claims:
        if k == fail_at:
            raise ValueError(f"job {k} failed")
        if os.getpid() == parent_pid:
            time.sleep(0.1)
        emit((k, k * k, os.getpid()))


def test_shared_jobs_each_give_one_result_and_a_helper_takes_part():
    got = []
    share_jobs(_loop, [(os.getpid(), k, None) for k in range(60)], 2, got.append)
    assert sorted(r[:2] for r in got) == [(k, k * k) for k in range(60)]
    assert {r[2] for r in got} - {os.getpid()}, "the helper made none of the jobs"
    assert multiprocessing.active_children() == []


def test_a_helpers_error_is_raised_here_and_no_helper_is_left():
    with pytest.raises(ValueError, match="job 30 failed"):
        share_jobs(_loop, [(os.getpid(), k, 30) for k in range(60)], 2, lambda r: None)
    assert multiprocessing.active_children() == []


def test_a_helper_still_starting_when_the_jobs_are_done_is_stopped():
    got = []
    share_jobs(_loop, [(-1, k, None) for k in range(3)], 3, got.append)  # quick jobs: done before any helper starts
    assert sorted(r[0] for r in got) == [0, 1, 2]
    assert multiprocessing.active_children() == []


def test_helpers_start_only_once_they_pay():
    asked = []

    def pays(mine, left, seconds):
        asked.append((mine, left))
        return False

    got = []
    share_jobs(_loop, [(-1, k, None) for k in range(5)], 2, got.append, pays=pays)
    assert sorted(r[0] for r in got) == list(range(5)) and {r[2] for r in got} == {os.getpid()}
    assert asked[:2] == [(0, 5), (1, 4)]  # asked before each job, with the jobs nobody has taken
    assert multiprocessing.active_children() == []
