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
import os
import sys
import warnings

__all__ = ["OneLineParser", "EXIT_OK", "EXIT_CHECK_FAILED", "EXIT_BAD_INPUT", "fail", "warn", "positive_int",
           "non_negative_int", "run_command"]

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
    (``SkynavWarning``) print as one ``skynav: warning:`` line each. Anything else is a bug and
    keeps its traceback.
    """
    from skynav.scenes.errors import SkynavError, SkynavWarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, SkynavWarning):
            warn(str(message))
        else:
            _default_show(message, category, filename, lineno, file, line)

    _default_show = warnings.showwarning
    warnings.showwarning = show
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
