"""One process pool for every parallel job of skynav: dataset frames, bench exports, benchmarks.

:func:`share_jobs` runs a loop over jobs in this process and in ``n_workers - 1`` spawned helpers
that take the jobs one at a time as each is ready for one: this process starts at once, a helper
is started only where the jobs left are worth its start-up and adds its work once it has loaded
what it needs, so more workers never make a run slower than one (a helper that finds no job
left is stopped). :func:`process_pool_map` runs ``fn(job)`` for each job in ``n_workers``
**spawned** processes. Children are spawned, never forked: Dr.Jit/LLVM start threads and JIT
state in a process, and a fork of a parent that already used them inherits locked mutexes and a
half-copied JIT, so children start fresh and load the package themselves. Each worker gets
``cores // n_workers`` threads for the libraries that start thread pools (:class:`WorkerThreads`:
Dr.Jit and OpenEXR via ``SKYNAV_THREADS``, OpenBLAS/OpenMP/MKL via their ``*_NUM_THREADS``; a
variable the user set is left alone): N processes each with a pool as wide as the machine spin
against each other (``benchmarks/dataset_bench.py`` measures the scaling). A worker ends itself
when its parent is gone (:func:`exit_with_parent`).
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import pickle
import queue
import signal
import threading
import time
from concurrent.futures import ProcessPoolExecutor, as_completed

__all__ = ["THREAD_VARS", "WorkerThreads", "end_workers", "exit_with_parent", "interrupts_to_this_process", "process_pool_map",
           "share_jobs"]

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


@contextlib.contextmanager
def interrupts_to_this_process():
    """Context: the processes started inside it never see SIGINT (Ctrl-C); this one still does.

    A terminal's Ctrl-C goes to every process of its foreground group, so without this each
    spawned worker would raise ``KeyboardInterrupt`` wherever it was (importing numpy, drawing a
    frame) and print its own traceback, and a pool whose workers die that way can leave its
    manager thread waiting forever. SIGINT is blocked while the processes start: a blocked signal
    stays blocked across ``fork`` and ``exec`` and Python does not unblock it, so the workers never
    receive it; here it is unblocked on exit, and a Ctrl-C pressed meanwhile is delivered then
    (it is held, not lost). This process alone decides what an interrupt does (see
    :func:`process_pool_map`). Outside the main thread, or where signals cannot be masked, it
    does nothing.
    """
    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "pthread_sigmask"):
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def end_workers(executor) -> None:
    """Stop a ``ProcessPoolExecutor``'s workers now (SIGTERM, then wait for each), so that its
    shutdown does not wait for the frames in flight. Their futures end as ``BrokenProcessPool``;
    files they were writing stay temporary files (:mod:`skynav.infra.atomic_files`), which the
    next run removes. The executor keeps its workers in ``_processes`` (CPython 3.9 to 3.13; 3.14
    has ``terminate_workers()``)."""
    stop = getattr(executor, "terminate_workers", None)
    if stop is not None:
        stop()
        return
    procs = list((getattr(executor, "_processes", None) or {}).values())
    for p in procs:
        with contextlib.suppress(Exception):
            p.terminate()
    for p in procs:
        with contextlib.suppress(Exception):
            p.join(timeout=10)


def process_pool_map(fn, jobs, n_workers: int, *, accept=None) -> list:
    """``[fn(j) for j in jobs]`` in ``n_workers`` spawned processes, in the order of ``jobs``.

    ``fn`` must be a module-level function (it travels pickled, as do the jobs and results).
    ``accept(result)``, if given, is called in this process as each result arrives (in completion
    order). A worker's exception is raised here and the jobs not started are cancelled.

    Ctrl-C reaches this process only (:func:`interrupts_to_this_process`): it stops the workers
    at once (:func:`end_workers`) and raises ``KeyboardInterrupt`` here, which the command line
    prints as one line; the finished jobs' results have been passed to ``accept``.
    """
    jobs = list(jobs)
    out = [None] * len(jobs)
    with WorkerThreads(n_workers), \
            ProcessPoolExecutor(max_workers=n_workers, mp_context=multiprocessing.get_context("spawn"),
                                initializer=exit_with_parent, initargs=(os.getpid(),)) as ex:
        with interrupts_to_this_process():  # the workers start at the submits
            futs = {ex.submit(fn, j): k for k, j in enumerate(jobs)}
        try:
            for fut in as_completed(futs):
                out[futs[fut]] = fut.result()
                if accept is not None:
                    accept(out[futs[fut]])
        except KeyboardInterrupt:
            end_workers(ex)  # its futures end broken; cancelling them as well trips CPython 3.11's pool
            raise
        except BaseException:
            for f in futs:
                f.cancel()
            raise
    return out


class _Claims:
    """The jobs this process takes, one at a time, from a list shared through ``counter`` (the
    index of the next job nobody has taken); ``between()`` runs before each take."""

    def __init__(self, jobs, counter, between=None, first=None):
        self.jobs, self.counter, self.between, self.first = jobs, counter, between, first

    def __iter__(self):
        while True:
            if self.between is not None:
                self.between()
            with self.counter.get_lock():
                k = self.counter.value
                if k >= len(self.jobs):
                    return
                self.counter.value = k + 1
            if self.first is not None:
                self.first()
                self.first = None
            yield self.jobs[k]


class _Counter:
    """The index of the next job nobody has taken: a plain int in this process until helpers
    share it (:meth:`share`), then a ``multiprocessing.Value`` (so that a run without helpers
    starts no process at all, not even multiprocessing's resource tracker)."""

    def __init__(self):
        self.local, self.shared = 0, None

    def share(self, ctx):
        self.shared = ctx.Value("q", self.local)
        return self.shared

    def get_lock(self):
        return self.shared.get_lock() if self.shared is not None else contextlib.nullcontext()

    @property
    def value(self) -> int:
        return self.shared.value if self.shared is not None else self.local

    @value.setter
    def value(self, v: int) -> None:
        if self.shared is not None:
            self.shared.value = v
        else:
            self.local = v


def _portable(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else a RuntimeError with its type and message."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # noqa: BLE001 - any exception that does not travel becomes its message
        return RuntimeError(f"{type(exc).__name__}: {exc}")


def _helper(loop, jobs, counter, results, parent_pid: int, me: int) -> None:
    """A spawned helper of :func:`share_jobs`: ``loop`` over the jobs it takes, each result sent
    back as it comes. Ctrl-C is the parent's to handle (it stops the helpers)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    exit_with_parent(parent_pid)
    try:
        loop(_Claims(jobs, counter, first=lambda: results.put(("took", me))), lambda r: results.put(("result", r)))
    except BaseException as exc:
        with counter.get_lock():
            counter.value = len(jobs)  # nobody takes another job
        results.put(("error", _portable(exc)))
    else:
        results.put(("done", me))


class _Sharing:
    """This process's side of :func:`share_jobs`: the helpers, the results queue, what came back."""

    def __init__(self, loop, jobs: list, n_workers: int, accept, pays):
        self.loop, self.jobs, self.n_helpers, self.accept, self.pays = loop, jobs, n_workers - 1, accept, pays
        self.ctx = multiprocessing.get_context("spawn")
        self.counter, self.results = _Counter(), None
        self.helpers: list = []
        self.threads = WorkerThreads(n_workers)
        self.received, self.mine, self.took, self.ended = 0, 0, set(), set()
        self.t0 = time.perf_counter()

    def start_helpers(self) -> None:
        """Spawn the helpers (they inherit the thread budget of one of the workers)."""
        shared, self.results = self.counter.share(self.ctx), self.ctx.Queue()
        self.helpers = [self.ctx.Process(target=_helper, daemon=True, name=f"skynav-helper-{i}",
                                         args=(self.loop, self.jobs, shared, self.results, os.getpid(), i))
                        for i in range(self.n_helpers)]
        with interrupts_to_this_process():  # Ctrl-C while a helper imports would be its traceback
            for p in self.helpers:
                p.start()

    def take(self, block: bool) -> None:
        """One message of a helper, if one comes (within 0.2 s when ``block``)."""
        try:
            kind, value = self.results.get(block=block, timeout=0.2 if block else None)
        except queue.Empty:
            return
        if kind == "result":
            self.received += 1
            self.accept(value)
        elif kind == "took":
            self.took.add(value)
        elif kind == "done":
            self.ended.add(value)
        else:
            raise value

    def between(self) -> None:
        """Before each of this process's jobs: start the helpers once they pay; take what came back."""
        if not self.helpers and (self.pays is None or self.pays(self.mine, len(self.jobs) - self.counter.value,
                                                                time.perf_counter() - self.t0)):
            self.start_helpers()
        self.mine += 1
        while self.results is not None and not self.results.empty():
            self.take(block=False)

    def emit(self, result) -> None:
        self.received += 1
        self.accept(result)

    def wait_for_the_helpers(self) -> None:
        """Take the helpers' results until every job's has come; a helper that ended without a
        word is an error."""
        while self.received < len(self.jobs):
            self.take(block=True)
            lost = [p for i, p in enumerate(self.helpers) if p.exitcode is not None and i not in self.ended]
            if lost and self.results.empty():
                raise RuntimeError(f"a worker process ended unexpectedly (exit code {lost[0].exitcode})")

    def stop(self, failed: bool) -> None:
        """End the helpers: all of them after a failure (no job is taken any more), else those
        still starting (they would find no job left); wait for the others to end."""
        if failed:
            with self.counter.get_lock():
                self.counter.value = len(self.jobs)
        for i, p in enumerate(self.helpers):
            if failed or i not in self.took:
                p.terminate()
            p.join()


def share_jobs(loop, jobs, n_workers: int, accept, *, pays=None) -> None:
    """Run ``loop(claims, emit)`` in this process and in ``n_workers - 1`` spawned helpers, which
    share ``jobs``: each process takes the next job nobody has taken whenever it is ready for one.

    ``loop`` is a module-level function (it travels pickled, with the jobs, once per helper);
    ``claims`` iterates over the jobs its process takes and ``emit(result)`` reports a result.
    Every result reaches ``accept`` in this process (this process's own at once, the helpers'
    between two of its jobs and at the end). This process starts on the jobs at once. The helpers
    are started before its first job, or, with ``pays``, before the first of its jobs for which
    ``pays(jobs this process has taken, jobs nobody has taken, seconds since the start)`` is
    true: a helper's start-up (imports, caches) is then paid only where the jobs left are worth
    it. Every process has the thread budget of one of ``n_workers`` workers
    (:class:`WorkerThreads`), this one from its first job. A helper adds its work once it has
    started, and one that has taken no job when the last result arrives is stopped, so a run
    with helpers is not slower than one without. A helper's exception is raised here (the others
    take no further job); so is this process's, after the helpers are stopped.
    """
    jobs = list(jobs)
    if n_workers <= 1 or len(jobs) <= 1:
        loop(iter(jobs), accept)
        return
    sharing = _Sharing(loop, jobs, n_workers, accept, pays)
    with sharing.threads:
        try:
            loop(_Claims(jobs, sharing.counter, between=sharing.between), sharing.emit)
            sharing.wait_for_the_helpers()
        except BaseException:
            sharing.stop(failed=True)
            raise
        sharing.stop(failed=False)
