"""Per-frame checksum records: a frame is kept on resume only when its record says so.

Adapter module (one file format). After a worker has written frame k's files (each atomically),
it writes ``frames/NNNNNN.sha256``, atomically too, in ``sha256sum`` format (``<hex>  <name>``,
one line per file, sorted). The record is the frame's commit point: a frame whose record is
missing was interrupted and is redone; a frame whose files do not match their record, or do not
decode (PNG, EXR, JSON), was damaged after it was written and is redone.

Why a record per frame rather than one append-only journal: frames are written by several local
processes or by Dask workers on other hosts that share the folder; one file per frame needs no
lock and no append across hosts (``O_APPEND`` is not atomic on NFS), and it is written with the
same temp + fsync + rename as the frame's files, so it is either whole or absent.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from skynav.infra.atomic_files import atomic_write_bytes, sha256_file

from . import layout
from .fits_files import read_fits
from .frame_files import read_exr, read_png

__all__ = ["RECORD_EXT", "record_relpath", "record_bytes", "write_record", "read_record", "decode_problem", "frame_problem",
           "check_frame"]

RECORD_EXT = "sha256"


def record_relpath(k: int) -> str:
    """``frames/NNNNNN.sha256`` (POSIX separators, relative to the dataset root)."""
    return f"{layout.FRAMES_DIR}/{layout.frame_stem(k)}.{RECORD_EXT}"


def record_bytes(files: dict) -> bytes:
    """The record of ``{relpath: sha256}``: ``<hex>  <file name>\\n`` per file, sorted by name."""
    return "".join(f"{sha}  {rel.rsplit('/', 1)[-1]}\n" for rel, sha in sorted(files.items())).encode("ascii")


def write_record(root, k: int, files: dict) -> dict:
    """Write frame ``k``'s record atomically (after its files); returns ``{record relpath: sha256}``."""
    data = record_bytes(files)
    rel = record_relpath(k)
    # Atomic rename, no fsync: the frame's files are already durable (each fsynced with its
    # folder), and a record lost or emptied by a power cut reads as "no record", so the frame is
    # made again; an fsync here would only add a disk flush per frame.
    atomic_write_bytes(Path(root) / rel, data, durable=False)
    return {rel: hashlib.sha256(data).hexdigest()}


def read_record(root, k: int):
    """``{relpath: sha256}`` of frame ``k``'s record, or None when it is missing or malformed."""
    p = Path(root) / record_relpath(k)
    try:
        text = p.read_bytes().decode("ascii")
    except (OSError, UnicodeDecodeError):
        return None
    out = {}
    for line in text.splitlines():
        sha, sep, name = line.partition("  ")
        if not sep or len(sha) != 64 or not name or "/" in name:
            return None
        out[f"{layout.FRAMES_DIR}/{name}"] = sha
    return out or None


def decode_problem(path) -> str | None:
    """None if the file decodes as its format (PNG, EXR, JSON, FITS), else a short reason."""
    path = Path(path)
    ext = path.suffix.lower()
    try:
        if path.stat().st_size == 0:
            return "empty file (0 bytes)"
        if ext == ".png":
            read_png(path)
        elif ext == ".exr":
            read_exr(path)
        elif ext == ".json":
            data = json.loads(path.read_bytes().decode("utf-8"))
            if not isinstance(data, dict):
                return "JSON is not an object"
        elif ext == ".fits":
            read_fits(path)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        return f"truncated or invalid JSON ({exc.__class__.__name__})"
    except Exception as exc:  # noqa: BLE001 - any decoder failure means a damaged file
        return f"does not decode as {ext[1:].upper()} ({exc.__class__.__name__})"
    return None


def frame_problem(root, k: int, formats, *, recorded=None, decode: bool = True):
    """Why frame ``k`` cannot be kept, or None with its checksums.

    Returns
    -------
    (problem, files, record) : tuple
        ``problem`` is None when the frame is complete: its record exists, names exactly the
        frame's files, every file's SHA-256 equals the record (and ``recorded``, the manifest's
        table, where it has the file) and every file decodes; ``files`` is then
        ``{relpath: sha256}`` and ``record`` ``{record relpath: sha256}``.
    """
    root = Path(root)
    recorded = recorded or {}
    rels = list(layout.frame_relpaths(k, formats).values())
    record = read_record(root, k)
    if record is None:
        return "no checksum record (interrupted)", None, None
    if set(record) != set(rels):
        return "checksum record names other files", None, None
    rec_rel = record_relpath(k)
    rec_sha = hashlib.sha256((root / rec_rel).read_bytes()).hexdigest()
    if rec_rel in recorded and recorded[rec_rel] != rec_sha:
        return "checksum record altered", None, None
    files = {}
    for rel in rels:
        p = root / rel
        if not p.is_file():
            return f"{rel} missing", None, None
        sha = sha256_file(p)
        if sha != record[rel] or (rel in recorded and recorded[rel] != sha):
            return f"{rel} SHA-256 mismatch", None, None
        if decode:
            why = decode_problem(p)
            if why is not None:
                return f"{rel} {why}", None, None
        files[rel] = sha
    return None, files, {rec_rel: rec_sha}


def check_frame(root, k: int, formats, **kw) -> bool:
    """True if frame ``k`` can be kept (see :func:`frame_problem`)."""
    return frame_problem(root, k, formats, **kw)[0] is None
