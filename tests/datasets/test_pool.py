"""skynav's one process pool (datasets/pool.py): results in job order, every result accepted as it
arrives, a worker's error raised in the caller."""

from __future__ import annotations

import math

import pytest

from skynav.datasets.pool import process_pool_map


def test_results_in_job_order_and_each_accepted():
    jobs = [9.0, 1.0, 4.0, 16.0, 0.25]
    seen = []
    got = process_pool_map(math.sqrt, jobs, 2, accept=seen.append)
    assert got == [3.0, 1.0, 2.0, 4.0, 0.5]
    assert sorted(seen) == sorted(got)


def test_a_workers_error_is_raised_here():
    with pytest.raises(ValueError, match="math domain error"):
        process_pool_map(math.sqrt, [1.0, -1.0], 2)
