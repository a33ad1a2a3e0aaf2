"""The ``skynav`` command line: parses, validates, calls the parts, prints.

Errors for people: any ``SkynavError`` (bad input), an output path the system refuses or a frame
too large for memory prints one line ``skynav: error: ...`` and exits with code 2; argparse usage
errors exit 2 as well (:mod:`skynav.cli_common`, shared by every sub-command). Anything else is a
bug and keeps its traceback.
"""

from __future__ import annotations

import importlib
import sys

from . import __version__
from .cli_common import COMMAND_HELP, OneLineParser, run_command

#: The module of each command (``skynav.cli_*``), in the order ``skynav --help`` lists them. Only
#: the module of the command being run is imported: each imports the rooms its command needs at its
#: top, so ``skynav --help`` loads none of them.
COMMAND_MODULES = {"scene": "cli_render", "render": "cli_render", "dataset": "cli_dataset", "bench": "cli_bench",
                   "calibrate": "cli_calibrate", "hil": "cli_hil", "serve": "cli_serve"}


def build_parser(command: str | None = None) -> OneLineParser:
    """The ``skynav`` parser, complete for ``command`` (for every command when it is None); the
    other commands are registered with their one-line help only."""
    p = OneLineParser(prog="skynav", description="Deep-space optical navigation imagery: "
                                "render star fields and planets as a spacecraft camera sees them.")
    p.add_argument("--version", action="version", version=f"skynav {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    for module in dict.fromkeys(COMMAND_MODULES.values()):
        names = [n for n, m in COMMAND_MODULES.items() if m == module]
        if command is None or command in names:
            # the command's module and the rooms it imports load only when that command runs
            importlib.import_module(f"skynav.{module}").add_parser(sub)
        else:
            for name in names:
                sub.add_parser(name, help=COMMAND_HELP[name], add_help=False)
    return p


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    command = next((a for a in argv if not a.startswith("-")), "")  # "": only the one-line helps
    parser = build_parser(command)
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    return run_command(args.func, args)
