"""skynav's one process pool: results in job order, every result accepted as it arrives, a
worker's error raised in the caller; the thread-count variables its workers inherit."""

from __future__ import annotations

import math
import os

import pytest

from skynav.infra.pool import process_pool_map


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
