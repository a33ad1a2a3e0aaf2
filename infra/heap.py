"""The heap of a process that makes many frames: the garbage collector and glibc's allocator.

Two contexts for a loop of frames (a dataset worker's, a render service worker's), each leaving
the process as it found it on exit: :class:`WarmHeap` keeps the cyclic garbage collector off the
objects a warm process holds, :class:`LargeArraysOnHeap` has glibc serve large arrays from its
heap where the environment has switched that off. Neither changes a result: only where memory
comes from and how often the collector walks it.
"""

from __future__ import annotations

import ctypes
import gc
import os

__all__ = ["LargeArraysOnHeap", "WarmHeap"]


class WarmHeap:
    """Context for a loop of frames: after :meth:`warm` (call it once the first frame is made) the
    cyclic garbage collector no longer walks the objects that exist then; on exit it does again.

    A warm worker holds ~220,000 objects (astropy, Mitsuba, Dr.Jit, the catalogue, the tables). A
    frame's ground truth is a few thousand small containers, and those alive when a young
    generation is collected are promoted, so a full collection ran every ~15 frames and walked
    them all, at random frames. :func:`gc.freeze` moves the warm objects to the
    permanent generation, which no collection walks; the frames' own cycles are still collected.
    Reference counting frees everything as before, so nothing else changes. The objects go back
    with :func:`gc.unfreeze` when the loop ends (a caller's process is left as it was); a process
    whose heap someone else froze is left alone.

    The youngest generation is also collected less often: every :attr:`YOUNG` net new containers
    instead of Python's 700. A frame's truth holds a few thousand containers, freed by reference
    counting when the frame is written, so a collection every 700 found almost nothing and ran
    ~5 times a frame (467 objects freed in 1059 collections over 200 frames, measured with
    ``gc.callbacks``). The frames' own cycles (a sequence frame leaves
    ~80 objects to the collector) are still collected, after at most :attr:`YOUNG` of them. The
    thresholds go back on exit, as the freeze does.
    """

    #: The youngest generation's threshold inside the loop (Python's default is 700).
    YOUNG = 20_000

    def __init__(self):
        self.frozen = False
        self.thresholds = None

    def __enter__(self):
        self.owner = gc.get_freeze_count() == 0
        return self

    def warm(self) -> None:
        if self.owner and not self.frozen:
            gc.freeze()
            self.frozen = True
            self.thresholds = gc.get_threshold()
            gc.set_threshold(max(self.YOUNG, self.thresholds[0]), *self.thresholds[1:])

    def __exit__(self, *exc):
        if self.frozen:
            gc.unfreeze()
            self.frozen = False
            gc.set_threshold(*self.thresholds)
        return False


class LargeArraysOnHeap:
    """Context for a loop of frames: glibc serves the frames' large arrays from its heap, not from
    a fresh memory mapping each, where the environment has fixed glibc's thresholds.

    glibc maps every block above its mmap threshold afresh and unmaps it when freed; it raises
    that threshold as such blocks are freed (up to 32 MiB), so a process soon serves a frame's
    1-8 MB images from its heap. A ``MALLOC_TRIM_THRESHOLD_`` or ``MALLOC_MMAP_THRESHOLD_`` in the
    environment switches that off: Dask's nanny starts every worker with
    ``MALLOC_TRIM_THRESHOLD_=65536`` (``distributed.nanny.pre-spawn-environ``), and there each
    image's pages were faulted in and zeroed by the kernel, frame after frame, and a Dask worker
    made less than half the frames of a process of its own. Inside this context the mmap
    threshold is 32 MiB (glibc's largest) and the trim threshold 256 MiB; on exit both go back to
    the environment's values (glibc's defaults for the one not given) and the heap's free memory
    is handed back to the system (``malloc_trim``), as the environment asked. Elsewhere, and
    without glibc, it does nothing.
    """

    _M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
    _DEFAULT = 128 * 1024  # glibc's initial trim and mmap thresholds

    def __enter__(self):
        self.libc = None
        if not any(v in os.environ for v in ("MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_")):
            return self
        try:
            libc = ctypes.CDLL(None)
            libc.mallopt, libc.malloc_trim  # noqa: B018 - glibc has both
        except (OSError, AttributeError):
            return self
        if libc.mallopt(self._M_MMAP_THRESHOLD, 32 << 20) and libc.mallopt(self._M_TRIM_THRESHOLD, 256 << 20):
            self.libc = libc
        return self

    def __exit__(self, *exc):
        if self.libc is not None:
            for name, param in (("MALLOC_MMAP_THRESHOLD_", self._M_MMAP_THRESHOLD), ("MALLOC_TRIM_THRESHOLD_", self._M_TRIM_THRESHOLD)):
                try:
                    value = int(os.environ.get(name, self._DEFAULT))
                except ValueError:
                    value = self._DEFAULT
                self.libc.mallopt(param, value)
            self.libc.malloc_trim(0)
        return False
