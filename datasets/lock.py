"""One generator per dataset folder: an advisory lock held for the whole run.

Adapter module. :func:`dataset_lock` takes ``<dataset>/.skynav.lock`` with ``fcntl.flock``
(exclusive, non-blocking) and writes ``pid host`` into it. A second generator on the same
folder fails to take it and is refused with one line naming the holder
(``already running (pid N on host H)``). The kernel drops a flock when its process dies, so a
lock left by a killed run is stale by construction and the next run simply takes it over. The
file is removed when the run ends, so a finished folder holds the same files as one made in a
single run.

``flock`` works between processes of one host and, on Linux NFS (v4, or v3 with lockd), between
hosts; on a file system without locks the run goes on unlocked rather than refusing.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import socket
from pathlib import Path

from .errors import DatasetError

__all__ = ["LOCK_NAME", "DatasetLockedError", "dataset_lock"]

LOCK_NAME = ".skynav.lock"


class DatasetLockedError(DatasetError):
    """Another generator holds the dataset folder's lock.

    Attributes
    ----------
    pid : int or None
    host : str or None
    """

    def __init__(self, message: str, *, pid=None, host=None):
        self.pid = pid
        self.host = host
        super().__init__(message)


def _holder(path: Path):
    try:
        pid, _, host = path.read_text(encoding="utf-8").strip().partition(" ")
        return int(pid), host or "?"
    except (OSError, ValueError):
        return None, None


@contextlib.contextmanager
def dataset_lock(root, *, what: str = "dataset"):
    """Hold ``<root>/.skynav.lock`` for the ``with`` block (``what`` the folder holds, for the
    message: ``dataset``, ``capture folder``, ...).

    Raises
    ------
    DatasetLockedError
        Another live process holds it.
    """
    path = Path(root) / LOCK_NAME
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                pid, host = _holder(path)
                who = f"pid {pid} on host {host}" if pid is not None else "another process"
                raise DatasetLockedError(f"{root}: already running ({who}): another skynav run is writing this {what}; "
                                         f"wait for it, or stop it first", pid=pid, host=host) from None
            if exc.errno in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS):  # no locks here: go on
                yield None
                return
            raise
        # the file we locked may have been removed by a run that just ended: lock the live one
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()} {socket.gethostname()}\n".encode())
        yield path
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)
        os.close(fd)
