"""One process pool for every parallel job of skynav: dataset frames, bench exports, benchmarks.

:func:`process_pool_map` runs ``fn(job)`` for each job in ``n_workers`` **spawned** processes
(Dr.Jit/LLVM start threads and JIT state in a process; a fork of a parent that already used them
inherits locked mutexes and a half-copied JIT, so children are spawned fresh and load the
package themselves). Each worker gets ``cores // n_workers`` threads for the libraries that start
thread pools (:class:`WorkerThreads`: Dr.Jit and OpenEXR via ``SKYNAV_THREADS``,
OpenBLAS/OpenMP/MKL via their ``*_NUM_THREADS``; a variable the user set is left alone): N
processes each with a pool as wide as the machine spin against each other
(``benchmarks/dataset_bench.py`` measures the scaling), and
ends itself when its parent is gone (:func:`exit_with_parent`).
"""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
from concurrent.futures import ProcessPoolExecutor, as_completed

__all__ = ["THREAD_VARS", "WorkerThreads", "exit_with_parent", "process_pool_map"]

THREAD_VARS = ("SKYNAV_THREADS", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


class WorkerThreads:
    """Context: thread-count variables the spawned workers inherit (``cores // workers`` each).

    Spawned children read their environment when they start (inside the ``with`` block, when the
    pool submits); the parent's environment is restored on exit. Variables already set by the
    user are kept. ``threads``: this many per worker instead (e.g. ``skynav serve --threads``).
    """

    def __init__(self, n_workers: int, threads: int | None = None):
        self.threads = int(threads) if threads else max(1, (os.cpu_count() or 1) // max(1, n_workers))
        self.set_here: list = []

    def __enter__(self):
        self.set_here = [name for name in THREAD_VARS if name not in os.environ]
        for name in self.set_here:
            os.environ[name] = str(self.threads)
        return self

    def __exit__(self, *exc):
        for name in self.set_here:
            os.environ.pop(name, None)
        return False


def exit_with_parent(parent_pid: int, poll_s: float = 0.5) -> None:
    """Pool initializer: end this worker when the process that started it is gone.

    A spawned worker holds both ends of its pool's call queue, so it never sees end-of-file when
    the parent is killed (SIGTERM or SIGKILL from a batch scheduler): without this it waits for
    work forever, holding its memory (two such workers were found 40 minutes after their parent).
    """

    def watch():
        while os.getppid() == parent_pid:
            time.sleep(poll_s)
        os._exit(1)

    threading.Thread(target=watch, name="skynav-exit-with-parent", daemon=True).start()


def process_pool_map(fn, jobs, n_workers: int, *, accept=None) -> list:
    """``[fn(j) for j in jobs]`` in ``n_workers`` spawned processes, in the order of ``jobs``.

    ``fn`` must be a module-level function (it travels pickled, as do the jobs and results).
    ``accept(result)``, if given, is called in this process as each result arrives (in completion
    order). A worker's exception is raised here and the jobs not started are cancelled.
    """
    jobs = list(jobs)
    out = [None] * len(jobs)
    with WorkerThreads(n_workers), \
            ProcessPoolExecutor(max_workers=n_workers, mp_context=multiprocessing.get_context("spawn"),
                                initializer=exit_with_parent, initargs=(os.getpid(),)) as ex:
        futs = {ex.submit(fn, j): k for k, j in enumerate(jobs)}
        try:
            for fut in as_completed(futs):
                out[futs[fut]] = fut.result()
                if accept is not None:
                    accept(out[futs[fut]])
        except BaseException:
            for f in futs:
                f.cancel()
            raise
    return out
