"""What every ``skynav`` sub-command shares: exit codes, the one-line error, argument types.

Each sub-command module (``cli_dataset``, ...) registers its parsers and may use these; the
translation of exceptions into one line and an exit code happens once, in :func:`run_command`
(called by :func:`skynav.cli.main` for every sub-command).

Exit codes: 0 success; 1 a check that ran and found a problem (``dataset verify``); 2 bad input
(any :class:`~skynav.infra.errors.SkynavError`, an argparse usage error, an output path the
system refuses, a frame too large for memory); 130 interrupted (Ctrl-C, SIGINT: the shell's 128 + 2),
with the one line :data:`INTERRUPTED`; a traceback only for a bug.
"""

from __future__ import annotations

import argparse
import errno
import logging
import os
import re
import sys
import warnings
from pathlib import Path

from skynav.infra.errors import SkynavError, SkynavWarning

from .cli_args import after_parse_checks

#: The one-line help of each ``skynav`` command (``skynav --help`` lists them without importing
#: the commands' modules; each module's ``add_parser`` uses its line).
COMMAND_HELP = {
    "scene": "print what is in view (bodies, stars, Sun angle)",
    "render": "render one frame (PNG, EXR, ground-truth JSON)",
    "dataset": "generate, verify, inspect and preview datasets",
    "bench": "benchmark navigation software on datasets",
    "calibrate": "calibrate a hardware-in-the-loop facility (patterns, fits, virtual bench)",
    "hil": "hardware in the loop: facility files, screen-frame export",
    "serve": "render service: frames by pose over HTTP for flight software and simulators",
}

__all__ = ["OneLineParser", "EXIT_OK", "EXIT_CHECK_FAILED", "EXIT_BAD_INPUT", "fail", "warn", "check_output",
           "PathConflictError", "run_command", "say", "ProgressBar"]

EXIT_OK = 0
EXIT_CHECK_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130
#: What Ctrl-C prints, wherever it lands (importing, parsing, working, cleaning up).
INTERRUPTED = ("interrupted; files finished before it are kept, and dataset generate and hil export go on "
               "from there when run again")


def interrupted() -> int:
    """Print the one line :data:`INTERRUPTED` on stderr; returns :data:`EXIT_INTERRUPTED`."""
    print(f"skynav: error: {INTERRUPTED}", file=sys.stderr)
    return EXIT_INTERRUPTED


def fail(message: str) -> int:
    """Print ``skynav: error: <message>`` (one line) on stderr; returns :data:`EXIT_BAD_INPUT`."""
    print(f"skynav: error: {' '.join(str(message).split())}", file=sys.stderr)
    return EXIT_BAD_INPUT


def warn(message: str) -> None:
    """Print ``skynav: warning: <message>`` (one line) on stderr."""
    print(f"skynav: warning: {' '.join(str(message).split())}", file=sys.stderr)


def say(args, *lines) -> None:
    """Print informational lines on stdout, unless the command runs with ``-q/--quiet``."""
    if not getattr(args, "quiet", False):
        for line in lines:
            print(line)


class ProgressBar:
    """One tqdm bar fed by the ``progress(done, total)`` callbacks skynav's long functions call.

    The bar counts what ``unit`` names (``frame``, ``capture``): ``total`` is the number of such
    things the function will do, as it reports it. Quiet: no bar at all. Use as a context manager so
    the bar is closed when the work stops early (an error, Ctrl-C).

    >>> with ProgressBar("exporting", "frame", quiet=True) as bar:
    ...     bar(1, 2); bar(2, 2)
    """

    def __init__(self, desc: str, unit: str, *, quiet: bool = False):
        self.desc, self.unit, self.quiet = desc, unit, quiet
        self._bar = None

    def __call__(self, done: int, total: int) -> None:
        if self.quiet:
            return
        if self._bar is None:
            # tqdm is imported when a bar is shown: every command loads this module, skynav --help too
            from tqdm.auto import tqdm

            self._bar = tqdm(total=total, unit=self.unit, desc=self.desc)
        self._bar.update(done - self._bar.n)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


class _LogFormatter(logging.Formatter):
    """``skynav: <message>`` for notes, ``skynav: warning: <message>`` for warnings (one line each)."""

    def format(self, record):
        text = " ".join(record.getMessage().split())
        return f"skynav: {text}" if record.levelno < logging.WARNING else f"skynav: {record.levelname.lower()}: {text}"


def _log_to_stderr(quiet: bool):
    """Route the ``skynav`` loggers (e.g. the renderer's one-line backend note) to stderr for one
    command: notes (INFO) unless quiet, warnings always. Returns a function that undoes it."""
    logger = logging.getLogger("skynav")
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_LogFormatter())
    handler.setLevel(logging.WARNING if quiet else logging.INFO)
    before = (logger.level, logger.propagate)
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    logger.propagate = False

    def undo():
        logger.removeHandler(handler)
        logger.setLevel(before[0])
        logger.propagate = before[1]

    return undo


class OneLineParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line (``skynav: error: ...``) and exit 2.

    argparse prints the usage block before the message; the usage is one ``--help`` away, and
    one line is what scripts and the error catalogue expect. Sub-parsers made with
    ``add_subparsers().add_parser`` are of the same class.
    """

    def error(self, message):  # noqa: D102 - argparse API
        self.exit(EXIT_BAD_INPUT, f"skynav: error: {' '.join(message.split())} (see {self.prog} --help)\n")


class PathConflictError(SkynavError, ValueError):
    """An output path that is, or sits inside, one of the command's inputs (one line, exit 2)."""


def check_output(output, inputs=(), *, flag: str = "-o", kind: str = "folder") -> None:
    """Refuse an output that would write into, or over, an input; or of the wrong kind.

    ``inputs``: ``(flag or name, path)`` pairs of what the command reads (folders and files;
    presets and missing paths are skipped). The output may not be an input, nor sit inside an input
    folder. ``kind``: ``"folder"`` (the output must
    not be an existing file) or ``"file"`` (not an existing folder). Paths are compared resolved
    (symbolic links followed); messages name them as the user typed them.

    Raises
    ------
    PathConflictError
    """
    out = Path(output)
    if kind == "file" and out.is_dir():
        raise PathConflictError(f"{flag} {output}: is a folder; give a file name (e.g. {Path(output) / 'facility.yaml'})")
    if kind == "file" and out.exists() and not out.is_file():
        raise PathConflictError(f"{flag} {output}: is not a regular file (a device, pipe or socket); give a file on disk")
    if kind == "folder" and out.exists() and not out.is_dir():
        raise PathConflictError(f"{flag} {output}: is a file, not a folder; give a folder")
    # a kernel file system (/proc, /sys, /dev), under a file, not writable: the datasets' rule
    # (lazy: every command loads this module, skynav --help too, and the datasets load with a command)
    from skynav.datasets.frame_files import check_output_dir

    check_output_dir(out if kind == "folder" else (out.parent if str(out.parent) else Path(".")),
                     what=f"the folder of {flag} {output}" if kind == "file" else f"the {flag} folder")
    ro = out.resolve()
    for name, path in inputs:
        if path is None:
            continue
        p = Path(path)
        if not p.exists():
            continue
        rp = p.resolve()
        if ro == rp:
            raise PathConflictError(f"{flag} {output}: is the input {name} {path}; write to another path "
                                    "(skynav never writes into its inputs)")
        if p.is_dir() and rp in ro.parents:
            raise PathConflictError(f"{flag} {output}: is inside the input {name} folder {path}; write outside it "
                                    "(skynav never writes into its inputs)")


def user_path(path) -> str:
    """The path a user gave for one of skynav's hidden temporary files (``DIR/.NAME.XXXXXXXX.tmp``,
    written then renamed onto ``DIR/NAME`` by the atomic writers): ``DIR/NAME``; others unchanged."""
    text = os.fsdecode(path)
    m = re.fullmatch(r"\.(.+)\.[A-Za-z0-9_]{6,12}\.tmp", Path(text).name)
    return str(Path(text).with_name(m.group(1))) if m else text


def _os_error_line(exc: OSError) -> str:
    if exc.filename is None:  # e.g. an image decoder's error: no path to name, so say what happened
        if exc.errno == errno.ENOSPC:
            return "no space left on the device; free space and run the same command again (it resumes)"
        text = " ".join(str(exc).split()) or exc.__class__.__name__
        return f"a file could not be read or written ({exc.__class__.__name__}: {user_path(text)[:200]})"
    where = user_path(exc.filename)
    if exc.filename2 is not None and where != os.fsdecode(exc.filename):  # os.replace(temp, target)
        where = os.fsdecode(exc.filename2)
    if exc.errno == errno.ENOSPC:
        return f"{where}: no space left on the device; free space and run the same command again (it resumes)"
    return f"{where}: {exc.strerror or exc.__class__.__name__}"


def run_command(func, args) -> int:
    """Run a sub-command's function and turn a user's mistake into one line and an exit code.

    ``SkynavError`` (bad input), ``OSError`` (a path the system refuses, a full disk) and
    ``MemoryError`` print one line and give :data:`EXIT_BAD_INPUT`; warnings raised by skynav
    (``SkynavWarning``) print as one ``skynav: warning:`` line each, as do the ``skynav`` loggers'
    warnings; their notes (INFO, e.g. the renderer's backend) print as ``skynav: ...`` unless the
    command runs with ``-q``. Worker processes have no handler: a note prints once per run, from
    this process. Anything else is a bug and keeps its traceback.
    """
    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, SkynavWarning):
            warn(str(message))
        else:
            _default_show(message, category, filename, lineno, file, line)

    _default_show = warnings.showwarning
    warnings.showwarning = show
    undo_logging = _log_to_stderr(bool(getattr(args, "quiet", False)))
    try:
        after_parse_checks(args)
        return int(func(args) or 0)
    except SkynavError as exc:
        return fail(str(exc))
    except MemoryError:
        return fail("not enough memory for this run; make it smaller (a smaller camera or screen, fewer frames, "
                    "runs or workers)")
    except OSError as exc:
        if isinstance(exc, BrokenPipeError):  # output piped into `head` and closed early
            try:
                sys.stdout = open(os.devnull, "w")
            except OSError:
                pass
            return EXIT_OK
        return fail(_os_error_line(exc))
    except KeyboardInterrupt:
        return interrupted()
    finally:
        warnings.showwarning = _default_show
        undo_logging()
