"""Atomic file writes and checksums: the lowest layer of skynav's file handling.

Every file skynav writes goes through :func:`atomic_path` / :func:`atomic_write_bytes` (temp file
in the same folder, fsync, rename, fsync of the folder), so a reader never sees a partly written
file. :func:`sha256_file` gives the checksums of a dataset's manifest and per-frame records;
:func:`open_binary` lets a reader take a path or a binary file object. The file formats
(:mod:`skynav.datasets.frame_files`, :mod:`skynav.datasets.truth_schema`), the dataset layout, the
bench's files and the command line build on this module.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import secrets

__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_many", "open_binary", "sha256_file"]


def _fsync_dir(directory: str) -> None:
    """Make a rename durable: fsync the directory (best effort; not possible on Windows)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _temp_name(path: str) -> str:
    directory, name = os.path.split(os.path.abspath(path))
    return os.path.join(directory, f".{name}.{os.getpid()}.{secrets.token_hex(6)}.tmp")


@contextlib.contextmanager
def atomic_path(path, *, durable: bool = True):
    """Context manager yielding a temporary path that replaces ``path`` on success.

    The temporary file lives in the directory of ``path`` (so ``os.replace`` is an atomic
    rename on the same file system) under a unique hidden name
    ``.<name>.<pid>.<random>.tmp``. The body must create it. On normal exit the temp file is
    fsync'ed and renamed onto ``path`` (and the directory fsync'ed); on any exception it is
    removed and ``path`` is left as it was (absent, or the previous complete file).

    Parameters
    ----------
    path : str or os.PathLike
        Final destination. Its directory must exist.
    durable : bool
        fsync the file and its directory (default). False keeps only the atomic rename: after a
        power loss the file may be absent or empty, never partly new (for files whose loss is
        detected and repaired, like the per-frame checksum records).

    Yields
    ------
    str
        Temporary path to write to.

    Examples
    --------
    >>> with atomic_path("frame.fits") as tmp:  # doctest: +SKIP
    ...     hdul.writeto(tmp)
    """
    final = os.path.abspath(os.fspath(path))
    tmp = _temp_name(final)
    try:
        yield tmp
        if durable:
            fd = os.open(tmp, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        os.replace(tmp, final)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    if durable:
        _fsync_dir(os.path.dirname(final))


def atomic_write_bytes(path, data: bytes, *, durable: bool = True) -> None:
    """Write ``data`` to ``path`` atomically (temp file + fsync + rename).

    Parameters
    ----------
    path : str or os.PathLike
        Destination; its directory must exist.
    data : bytes
        The complete file content.
    durable : bool
        See :func:`atomic_path`.
    """
    with atomic_path(path, durable=durable) as tmp:
        # O_EXCL: the random name must not exist; the mode follows the umask like open().
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()


def atomic_write_many(files) -> None:
    """Write ``(path, bytes)`` pairs, each atomically and durably, on this thread: every temp file
    written and fsync'ed, then each renamed onto its path, then each folder fsync'ed once (what
    :func:`atomic_write_bytes` does per file, with one folder fsync for files that share a folder).
    A failure removes the temp files not yet renamed; files already renamed stay complete."""
    files = [(os.path.abspath(os.fspath(path)), data) for path, data in files]
    temps = []
    try:
        for final, data in files:
            tmp = _temp_name(final)
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
            temps.append(tmp)
            with os.fdopen(fd, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
        while temps:
            os.replace(temps[0], files[len(files) - len(temps)][0])
            temps.pop(0)
    finally:
        for tmp in temps:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
    for directory in dict.fromkeys(os.path.dirname(final) for final, _ in files):
        _fsync_dir(directory)


def sha256_file(path, *, chunk_bytes: int = 1 << 20) -> str:
    """Hexadecimal SHA-256 of a file's bytes (for ``manifest.json``)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(chunk_bytes):
            h.update(chunk)
    return h.hexdigest()


@contextlib.contextmanager
def open_binary(source):
    """Yield a binary file object for a path or pass a file object through (not closed)."""
    if hasattr(source, "read"):
        yield source
    else:
        with open(source, "rb") as f:
            yield f
