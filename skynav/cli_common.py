"""What every ``skynav`` sub-command shares: exit codes, the one-line error, argument types.

Each sub-command module (``cli_dataset``, ...) registers its parsers and may use these; the
translation of exceptions into one line and an exit code happens once, in :func:`run_command`
(called by :func:`skynav.cli.main` for every sub-command).

Exit codes: 0 success; 1 a check that ran and found a problem (``dataset verify``); 2 bad input
(any :class:`~skynav.scenes.errors.SkynavError`, an argparse usage error, an output path the
system refuses, a frame too large for memory); a traceback only for a bug.
"""

from __future__ import annotations

import argparse
import errno
import logging
import os
import sys
import warnings

__all__ = ["OneLineParser", "EXIT_OK", "EXIT_CHECK_FAILED", "EXIT_BAD_INPUT", "fail", "warn", "positive_int",
           "non_negative_int", "run_command", "add_quiet", "say", "ProgressBar"]

EXIT_OK = 0
EXIT_CHECK_FAILED = 1
EXIT_BAD_INPUT = 2


def fail(message: str) -> int:
    """Print ``skynav: error: <message>`` (one line) on stderr; returns :data:`EXIT_BAD_INPUT`."""
    print(f"skynav: error: {' '.join(str(message).split())}", file=sys.stderr)
    return EXIT_BAD_INPUT


def warn(message: str) -> None:
    """Print ``skynav: warning: <message>`` (one line) on stderr."""
    print(f"skynav: warning: {' '.join(str(message).split())}", file=sys.stderr)


def add_quiet(parser) -> None:
    """Give ``parser`` the ``-q/--quiet`` flag every long-running sub-command shares."""
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bar and no informational lines (warnings and errors still print)")


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


def _int_type(minimum: int, what: str):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}: expected {what}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{value}: expected {what}")
        return value

    parse.__name__ = what
    return parse


#: argparse ``type=`` for counts (>= 1); the usage error is one line and exit 2.
positive_int = _int_type(1, "a positive integer")
#: argparse ``type=`` for seeds (>= 0).
non_negative_int = _int_type(0, "a non-negative integer")


def _os_error_line(exc: OSError) -> str:
    where = exc.filename if exc.filename is not None else "output"
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
    from skynav.scenes.errors import SkynavError, SkynavWarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, SkynavWarning):
            warn(str(message))
        else:
            _default_show(message, category, filename, lineno, file, line)

    _default_show = warnings.showwarning
    warnings.showwarning = show
    undo_logging = _log_to_stderr(bool(getattr(args, "quiet", False)))
    try:
        return int(func(args) or 0)
    except SkynavError as exc:
        return fail(str(exc))
    except MemoryError:
        return fail("not enough memory for this frame; use a smaller camera (width x height)")
    except OSError as exc:
        if isinstance(exc, BrokenPipeError):  # output piped into `head` and closed early
            try:
                sys.stdout = open(os.devnull, "w")
            except OSError:
                pass
            return EXIT_OK
        return fail(_os_error_line(exc))
    except KeyboardInterrupt:
        return fail("interrupted")
    finally:
        warnings.showwarning = _default_show
        undo_logging()
