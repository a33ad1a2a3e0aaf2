"""The files a render request may name: only inside the folders the operator allows.

A request's file-valued keys (``camera.psf.file``, ``camera.psf.field[].file``) name files
relative to the server's ``--data-dir`` folders, never server paths. A name is resolved in each
folder in turn (symlinks followed, ``..`` included) and read only where the resolved path lies
inside that folder, is a regular file (not a FIFO, device or folder: opened without blocking,
then checked on the open descriptor) and holds at most ``max_bytes``. Everything else, a name
that does not exist included, gets one line that says nothing of the file system
(:func:`refused`), so that a client cannot probe which paths exist. The truth records the name as
given and the tables' digest (:class:`skynav.scenes.psf_measured.TabulatedPSFModel`), never a path.

SPICE kernels (``observer.spice.kernels``, ``attitude.spice.kernels``, ``ephemeris.spk``) follow
the same rule (:func:`kernel_path`), without the size bound: CSPICE reads a kernel by its path
and only the parts it needs, so the resolved path is handed to it, checked to be a regular file
inside a folder. The truth records each kernel's name as given and its SHA-256. A meta-kernel
in a ``--data-dir`` folder is the operator's file: the kernels it names are loaded beside it, or
from where its absolute paths say.
"""

from __future__ import annotations

import contextlib
import io
import os
import stat

from skynav.infra.errors import ConfigValueError
from skynav.scenes.mission_spice import KERNEL_RESOLVER
from skynav.scenes.psf_measured import PSF_FILE_OPENER

#: Default bound on one file a request names, bytes (``skynav serve --max-data-file-bytes``):
#: a 512 x 512 float64 PSF image is 2 MiB.
MAX_DATA_FILE_BYTES = 4 * 1024 * 1024


def refused(key: str, name, data_dirs, max_bytes: int) -> ConfigValueError:
    """The one error of every name that cannot be read (the same whatever the reason)."""
    if not data_dirs:
        return ConfigValueError(key, name, "no file: this server reads no files (its operator allows folders "
                                           "with skynav serve --data-dir DIR)")
    return ConfigValueError(key, name, f"the name of a regular .npy or .fits file of at most {max_bytes} bytes "
                                       "inside the server's --data-dir folders, relative to them")


def _inside(path: str, folder: str) -> bool:
    return os.path.commonpath([path, folder]) == folder


def _read_at_most(fd: int, n: int) -> bytes:
    chunks, got = [], 0
    while got < n:
        chunk = os.read(fd, n - got)
        if not chunk:
            break
        chunks.append(chunk)
        got += len(chunk)
    return b"".join(chunks)


def _relative_name(name) -> bool:
    """A name a request may give: a non-empty relative path without NUL."""
    return isinstance(name, str) and bool(name) and "\x00" not in name and not os.path.isabs(name)


def _opened_inside(name: str, data_dirs):
    """``(path, fd)`` for each of ``data_dirs`` where ``name``, symlinks resolved, stays inside the
    folder and opens (read-only, without blocking on a FIFO); the caller closes ``fd``."""
    for folder in data_dirs:
        path = os.path.realpath(os.path.join(folder, name))
        if not _inside(path, folder):
            continue
        try:
            fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
        except OSError:
            continue
        yield path, fd


def read_data_file(name, key: str, data_dirs, max_bytes: int) -> bytes:
    """The bytes of the file ``name`` in the first of ``data_dirs`` (resolved, absolute folders)
    that holds it as the module says; :func:`refused` where none does."""
    if not _relative_name(name):
        raise refused(key, name, data_dirs, max_bytes)
    for _, fd in _opened_inside(name, data_dirs):
        try:
            st = os.fstat(fd)
            if not stat.S_ISREG(st.st_mode) or st.st_size > max_bytes:
                continue
            data = _read_at_most(fd, max_bytes + 1)
        finally:
            os.close(fd)
        if len(data) <= max_bytes:
            return data
    raise refused(key, name, data_dirs, max_bytes)


def kernel_refused(key: str, name, data_dirs) -> ConfigValueError:
    """The one error of every kernel name that cannot be loaded (the same whatever the reason)."""
    if not data_dirs:
        return ConfigValueError(key, name, "no file: this server reads no files (its operator allows folders "
                                           "with skynav serve --data-dir DIR)")
    return ConfigValueError(key, name, "the name of a SPICE kernel (a regular file) inside the server's "
                                       "--data-dir folders, relative to them")


def kernel_path(name, key: str, data_dirs) -> str:
    """The resolved path of the kernel ``name`` in the first of ``data_dirs`` (resolved, absolute
    folders) where it is a regular file inside the folder; :func:`kernel_refused` where none."""
    if not _relative_name(name):
        raise kernel_refused(key, name, data_dirs)
    for path, fd in _opened_inside(name, data_dirs):
        try:
            regular = stat.S_ISREG(os.fstat(fd).st_mode)
        finally:
            os.close(fd)
        if regular:
            return path
    raise kernel_refused(key, name, data_dirs)


@contextlib.contextmanager
def request_files(data_dirs=(), max_bytes: int = MAX_DATA_FILE_BYTES, max_total_bytes: int | None = None):
    """Within: the PSF files of the scenes built are read only as :func:`read_data_file` allows
    and their kernels loaded only as :func:`kernel_path` allows (none where ``data_dirs`` is
    empty), their names kept as given, and the PSF files at most ``max_total_bytes`` in all (a
    field grid may name one file at every point: each is read and held again; the request's
    memory budget, :class:`skynav.service.budget.Budget`)."""
    folders = tuple(os.path.realpath(d) for d in data_dirs)
    read = [0]

    def opener(name, key):
        data = read_data_file(name, key, folders, max_bytes)
        read[0] += len(data)
        if max_total_bytes is not None and read[0] > max_total_bytes:
            raise ConfigValueError(key, name, f"files of at most {max_total_bytes} bytes in all in one request "
                                              "(their tables are held in memory; skynav serve --max-request-memory)")
        return io.BytesIO(data)

    token = PSF_FILE_OPENER.set(opener)
    # no folders: a request's kernel names get the scene layer's "cannot name a file"
    k_token = KERNEL_RESOLVER.set((lambda name, key: kernel_path(name, key, folders)) if folders else None)
    try:
        yield
    finally:
        KERNEL_RESOLVER.reset(k_token)
        PSF_FILE_OPENER.reset(token)
