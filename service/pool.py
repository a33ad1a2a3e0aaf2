"""The server's side of the render workers: ``n`` warm worker processes and the queue in front.

Each worker (:func:`skynav.service.worker.worker_main`) is a process of its own, at the other end
of a :class:`multiprocessing.connection.Connection`. The server speaks to it from the event loop
that serves HTTP, through asyncio streams over the same socket, in the connection's framing (a
4-byte big-endian signed length, -1 then an 8-byte length from 2 GiB, then a pickle): a request
``(JSON body, outputs, bounds)`` out, its answer in; the worker uses the connection's own
``recv`` and ``send``.
Concurrency is bounded: ``n`` frames render at once, ``max_queue`` more wait for an idle worker,
the next is refused (:class:`ServiceBusy`). A worker that dies (killed, out of memory) fails its
request (:class:`WorkerDied`) and is replaced by a fresh one; so does one that reaches its
address-space cap (``Limits.worker_memory``: it answers so and ends) or passes the request's wall
deadline (``Limits.request_deadline``: it is killed). Other requests are not held up meanwhile:
they go to the other workers, and the replacement warms up off the event loop.
"""

from __future__ import annotations

import asyncio
import multiprocessing
import os
import pickle
import socket
import struct
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

from skynav.infra.pool import WorkerThreads

from .budget import MAX_REQUEST_MEMORY, MAX_REQUEST_SECONDS, Budget
from .files import MAX_DATA_FILE_BYTES
from .protocol import MAX_CAMERA_PIXELS, MAX_QUEUE, MAX_REQUEST_BYTES
from .worker import worker_main


class ServiceStartError(Exception):
    """The server could not start (a worker failed to warm up, a bad facility); one line."""


class ServiceBusy(Exception):
    """Every worker renders and the queue is full; one line."""


class WorkerDied(Exception):
    """The worker rendering a request died before it answered; one line."""


class ClientGone(Exception):
    """The client of a queued request hung up before a worker was free: the frame is not rendered."""


#: Default address-space cap of each worker, bytes (``skynav serve --worker-memory``): a warm
#: worker reserves about 1 GB of address space, the request budget adds 1 GiB at most.
WORKER_MEMORY = 4 * 1024**3

#: Default wall seconds a worker may spend on one request (``skynav serve --request-deadline``):
#: beyond, it is killed and replaced. Six times the default time budget: a request within the
#: budget finishes well before it, even on a loaded machine.
REQUEST_DEADLINE_S = 60.0


@dataclass
class Limits:
    max_request_bytes: int = MAX_REQUEST_BYTES
    max_camera_pixels: int = MAX_CAMERA_PIXELS
    max_queue: int = MAX_QUEUE
    data_dirs: tuple = ()                       # folders whose files a request may name (--data-dir)
    max_data_file_bytes: int = MAX_DATA_FILE_BYTES
    max_request_memory: float = MAX_REQUEST_MEMORY    # the estimate's budget (skynav.service.budget)
    max_request_seconds: float = MAX_REQUEST_SECONDS
    worker_memory: int | None = WORKER_MEMORY        # each worker's address-space cap, bytes (None: none)
    request_deadline: float | None = REQUEST_DEADLINE_S  # wall seconds a worker may spend on one request

    def worker_bounds(self) -> dict:
        """The bounds a worker applies to each request (:func:`skynav.service.worker.answer`)."""
        return {"max_camera_pixels": self.max_camera_pixels, "data_dirs": tuple(self.data_dirs),
                "max_data_file_bytes": self.max_data_file_bytes,
                "budget": Budget(self.max_request_memory, self.max_request_seconds)}


class _Worker:
    """One render process and the server's end of its pipe."""

    def __init__(self, ctx, facility, threads, memory_cap=None):
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(target=worker_main, args=(child, facility, threads, memory_cap), daemon=True)
        # the spawned worker reads its thread budget from the environment it starts with: Dr.Jit
        # and OpenEXR (SKYNAV_THREADS) and OpenBLAS/OpenMP/MKL alike, so that N workers on N cores
        # do not each start a pool as wide as the machine
        with WorkerThreads(1, threads=threads):
            self.process.start()
        child.close()

    def wait_ready(self, timeout_s: float) -> dict:
        if not self.conn.poll(timeout_s):
            raise ServiceStartError(f"a render worker did not warm up within {timeout_s:.0f} s")
        try:
            kind, info = self.conn.recv()
        except (EOFError, OSError):
            raise ServiceStartError(f"a render worker died while warming up (exit code {self.process.exitcode})") from None
        if kind != "ready":
            raise ServiceStartError(info)
        return info

    async def attach(self) -> None:
        """Open this worker's streams in the running event loop (after :meth:`wait_ready`)."""
        sock = socket.socket(fileno=os.dup(self.conn.fileno()))
        self.reader, self.writer = await asyncio.open_unix_connection(sock=sock, limit=1 << 22)

    async def exchange(self, request: tuple) -> tuple:
        """Send one request and read its answer; EOFError or OSError when the worker is gone."""
        data = pickle.dumps(request, protocol=pickle.HIGHEST_PROTOCOL)
        self.writer.write(struct.pack("!i", len(data)) + data)   # a request is small (the JSON body is bounded)
        (n,) = struct.unpack("!i", await self.reader.readexactly(4))
        if n == -1:
            (n,) = struct.unpack("!Q", await self.reader.readexactly(8))
        return pickle.loads(await self.reader.readexactly(n))

    def detach(self) -> None:
        self.writer.close()

    def alive(self) -> bool:
        """The process runs and its end of the pipe is open: an idle worker's pipe has nothing to
        read, so anything readable is its end (asked of the pipe itself, as the event loop may
        not have read that end yet; and ``is_alive`` alone errs once the process is reaped)."""
        return not self.reader.at_eof() and not self.conn.poll(0) and self.process.is_alive()

    def stop(self, timeout_s: float = 30.0) -> None:
        try:
            self.conn.send(None)
        except (OSError, ValueError):
            pass
        self.process.join(timeout_s)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(5)
        self.conn.close()


class WorkerPool:
    """``n`` warm render processes; :meth:`render` waits for an idle one."""

    def __init__(self, n: int, *, facility=None, threads=None, limits: Limits = Limits()):
        self.n, self.facility_arg, self.limits = n, facility, limits
        self.threads = threads or max(1, (os.cpu_count() or 1) // max(1, n))   # per worker
        self._ctx = multiprocessing.get_context("spawn")
        self.workers: list[_Worker] = []
        self.info: dict = {}
        self.busy = 0
        self.waiting = 0
        self._idle: asyncio.Queue | None = None
        self._tasks: set = set()
        # where a dead worker's successor starts and warms up, off the event loop
        self._executor = ThreadPoolExecutor(max_workers=max(1, n), thread_name_prefix="skynav-worker")

    def start(self, timeout_s: float = 600.0) -> float:
        """Start the workers and wait until each has warmed up; seconds."""
        t0 = time.perf_counter()
        try:
            self.workers = [_Worker(self._ctx, self.facility_arg, self.threads, self.limits.worker_memory)
                            for _ in range(self.n)]
            infos = [w.wait_ready(timeout_s) for w in self.workers]
        except BaseException:
            self.stop()
            raise
        self.info = infos[0]
        return time.perf_counter() - t0

    async def attach(self) -> None:
        """Open the workers' streams and make the idle queue in the running event loop (the app's startup)."""
        self._idle = asyncio.Queue()
        for w in self.workers:
            await w.attach()
            self._idle.put_nowait(w)

    def detach(self) -> None:
        """Close the workers' streams (the app's shutdown, once the last request has its answer)."""
        for w in self.workers:
            w.detach()

    async def render(self, body: bytes, outputs: tuple, gone=None) -> tuple:
        """``(the worker's answer, seconds waited for an idle worker)`` for one request: ``body``
        the request's JSON, whose envelope :func:`skynav.service.app.parse_request` has checked.

        The answer is ``("ok", content type, warning lines, render seconds, HTTP body)`` or
        ``(kind, one line)`` (:func:`skynav.service.worker.answer`). Raises :class:`ServiceBusy`
        when the queue is full, :class:`WorkerDied` when the worker died on this request,
        :class:`ClientGone` when ``await gone()`` (asked once a worker is free) says that the
        client hung up while the request waited.
        """
        if self.busy >= self.n and self.waiting >= self.limits.max_queue:
            raise ServiceBusy(f"the server is busy ({self.busy} frames rendering, {self.waiting} waiting; "
                              f"the queue holds {self.limits.max_queue}); try again")
        t0 = time.perf_counter()
        self.waiting += 1
        try:
            worker = await self._idle_worker()
        finally:
            self.waiting -= 1
        queue_s = time.perf_counter() - t0
        if gone is not None and await gone():
            self._idle.put_nowait(worker)
            raise ClientGone("the client hung up while its request waited")
        self.busy += 1
        # the exchange is a task of its own, shielded from this request's cancellation: the worker
        # goes back to the idle queue only once its answer has been read, so that the next request
        # never reads this one's frame
        task = self._keep(self._exchange(worker, (bytes(body), outputs, self.limits.worker_bounds())))
        return await asyncio.shield(task), queue_s

    async def _idle_worker(self) -> _Worker:
        """The next idle worker that is alive; one that died while idle (killed, out of memory)
        is replaced and the request waits for the next (a fresh one when it was the only one)."""
        while True:
            worker = await self._idle.get()
            if worker.alive():
                return worker
            print(f"skynav serve: a render worker died while idle (exit code {worker.process.exitcode}); replacing it",
                  file=sys.stderr)
            self._keep(self._replace(worker))

    def _keep(self, coro) -> asyncio.Task:
        """``coro`` as a task held until it is done (the loop keeps only weak references), its
        outcome read then (a request that went away leaves its WorkerDied to no one)."""
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(lambda t: (self._tasks.discard(t), t.cancelled() or t.exception()))
        return task

    async def _exchange(self, worker: _Worker, request: tuple) -> tuple:
        """The worker's answer; the worker is replaced when it dies, when it passes the
        request's deadline (killed here) and when it reached its memory cap (it ends itself)."""
        died = False
        deadline = self.limits.request_deadline
        try:
            answer = await asyncio.wait_for(worker.exchange(request), deadline)
            if answer[0] == "cap":
                died = True
                raise WorkerDied(answer[1])
            return answer
        except asyncio.TimeoutError:
            died = True
            worker.process.kill()
            raise WorkerDied(f"the render went past the server's deadline of {deadline:g} s (skynav serve "
                             "--request-deadline); the worker was replaced; ask for a smaller frame, PSF or spp") from None
        except (EOFError, OSError):
            died = True
            raise WorkerDied("the render worker died while rendering this frame (out of memory?); "
                             "ask for a smaller camera or try again") from None
        finally:
            self.busy -= 1
            if died:   # a fresh worker takes its place when warm (the requests meanwhile wait for it)
                self._keep(self._replace(worker))
            else:
                self._idle.put_nowait(worker)

    async def _replace(self, dead: _Worker) -> None:
        dead.detach()
        dead.stop(1)
        try:
            worker = await asyncio.get_running_loop().run_in_executor(self._executor, self._respawn)
            await worker.attach()
        except Exception as exc:  # noqa: BLE001 - logged; the next request tries again
            print(f"skynav serve: a render worker could not be replaced: {' '.join(str(exc).split())}", file=sys.stderr)
            self._idle.put_nowait(dead)
            return
        self.workers[self.workers.index(dead)] = worker
        self._idle.put_nowait(worker)

    def _respawn(self) -> _Worker:
        w = _Worker(self._ctx, self.facility_arg, self.threads, self.limits.worker_memory)
        w.wait_ready(600)
        return w

    def stop(self) -> None:
        for w in self.workers:
            w.stop()
        self._executor.shutdown(wait=False)
