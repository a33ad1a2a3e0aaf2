"""The arguments ``skynav`` commands share, built once: one name, one help and one check each.

Every command that takes a dataset, a facility, a seed, worker processes, an output path,
overrides or ``-q`` adds it with the builder here, so the same thing has the same spelling
everywhere and is refused with the same one line:

- ``DATASET``, a positional (``dataset verify|info|preview``, ``bench ip|nav``, ``hil export``);
  ``SCENE`` (``scene``, ``render``) and ``RECIPE`` (``dataset generate``, ``bench loop``) likewise;
- ``--facility FACILITY`` (a facility file or preset: ``render``, ``hil facility|export``,
  ``calibrate *``, ``serve``); the former spellings ``render --hil FACILITY`` and the facility as a
  positional of ``calibrate`` and ``hil facility`` are still read (documented commands use them);
- ``--seed`` (0..2**63-1), ``--workers`` (1..256), ``-o/--output``, ``--set KEY.SUB=VALUE``
  (:mod:`skynav.scenes.overrides`), ``--limit``, ``--dask-scheduler``, ``-q/--quiet``.

Usage errors are one line and exit 2 (:class:`skynav.cli_common.OneLineParser`); a check that
needs the whole command line (a facility given twice, or not at all) runs before the command, from
:func:`skynav.cli_common.run_command`, through :func:`after_parse_checks`.

>>> p = argparse.ArgumentParser(prog="demo")
>>> add_dataset_arg(p, "a dataset folder"); add_seed_arg(p, default=0, help="seed (default 0)")
>>> p.parse_args(["mc", "--seed", "3"])
Namespace(dataset='mc', seed=3)
"""

from __future__ import annotations

import argparse
import math

from skynav.infra.errors import SkynavError

#: most local worker processes a command starts (bench nav's runs, hil export's frames)
MAX_WORKERS = 256

#: the largest seed a command takes: seeds are recorded in JSON and read back as int64
MAX_SEED = 2 ** 63 - 1


class UsageError(SkynavError, ValueError):
    """A command line whose arguments do not fit together (one line, exit 2)."""


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

def int_in(minimum: int, maximum: int, why: str = ""):
    """argparse ``type=`` for an integer in ``minimum..maximum`` (a count with an upper bound
    derived from memory or time: ``why`` says which, and the error line and ``--help`` say it).

    >>> int_in(1, 8)("3")
    3
    """
    allowed = f"an integer in {minimum}..{maximum}" + (f" ({why})" if why else "")

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}: expected {allowed}") from None
        if not minimum <= value <= maximum:
            raise argparse.ArgumentTypeError(f"{value}: expected {allowed}")
        return value

    parse.__name__ = "integer"
    return parse


#: argparse ``type=`` for ``--seed`` (0..2**63-1)
seed_int = int_in(0, MAX_SEED)


def float_in(low: float, high: float, *, low_open: bool = False, high_open: bool = False, unit: str = ""):
    """argparse ``type=`` for a finite number in ``[low, high]`` (``low_open``/``high_open``: the
    end itself excluded); NaN and infinities are refused like any value out of range.

    >>> float_in(0, 1, low_open=True)("0.2")
    0.2
    """
    rng = f"{'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
    allowed = f"a finite number in {rng}" + (f" {unit}" if unit else "")

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}: expected {allowed}") from None
        ok = math.isfinite(value) and (value > low if low_open else value >= low) and (value < high if high_open else value <= high)
        if not ok:
            raise argparse.ArgumentTypeError(f"{text}: expected {allowed}")
        return value

    parse.__name__ = "number"
    return parse


# ----------------------------------------------------------------------------- --set KEY.SUB=VALUE
def parse_set(text: str):
    """argparse ``type=`` of ``--set KEY.SUB=VALUE``: ``(text, path, value)`` of
    :func:`skynav.scenes.overrides.parse_override`, whose refusal becomes a one-line usage error.

    >>> parse_set("camera.exposure_s=0.2")[1:]
    (('camera', 'exposure_s'), 0.2)
    """
    # lazy: every command loads this module, skynav --help too; the config reader loads with --set
    from skynav.scenes.overrides import OverrideError, parse_override

    try:
        return parse_override(text)
    except OverrideError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_set_arg(parser, target: str) -> None:
    """Add the repeatable ``--set KEY.SUB=VALUE`` option; ``target`` says what KEY addresses."""
    parser.add_argument("--set", dest="overrides", action="append", default=[], type=parse_set,
                        metavar="KEY.SUB=VALUE",
                        help=f"override a key of {target} (repeatable, applied in order; VALUE is YAML: 0.2, "
                             f"[png, json], true); an unknown key is refused as in the file")


def add_quiet(parser) -> None:
    """Give ``parser`` the ``-q/--quiet`` flag every long-running sub-command shares."""
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bar and no informational lines (warnings and errors still print)")


# ----------------------------------------------------------------------------- the builders
def _after_parse(parser, check) -> None:
    """Run ``check(args)`` after parsing, before the command (it raises :class:`UsageError`)."""
    checks = parser.get_default("after_parse")
    if checks is None:
        checks = []
        parser.set_defaults(after_parse=checks)
    checks.append(check)


def after_parse_checks(args) -> None:
    """Run the checks the builders registered on the command's parser.

    Raises
    ------
    UsageError
    """
    for check in getattr(args, "after_parse", None) or ():
        check(args)


def add_scene_arg(parser) -> None:
    """The optional ``SCENE`` positional (``args.scene``): a scene YAML file or preset, default the built-in one."""
    parser.add_argument("scene", nargs="?", metavar="SCENE",
                        help="scene YAML file or preset name (default: the built-in 'default')")


def add_recipe_arg(parser, help: str = "recipe YAML file or preset name") -> None:
    """The ``RECIPE`` positional (``args.recipe``): a dataset recipe YAML file or preset."""
    parser.add_argument("recipe", metavar="RECIPE", help=help)


def add_dataset_arg(parser, help: str = "dataset folder") -> None:
    """The ``DATASET`` positional (``args.dataset``): a folder of frames skynav reads."""
    parser.add_argument("dataset", metavar="DATASET", help=help)


class _Facility(argparse.Action):
    """Stores a facility; the same facility given twice under two spellings must agree, and an
    empty one is refused (it would name the current folder)."""

    def __call__(self, parser, namespace, value, option_string=None):
        given = getattr(namespace, "_facility_given", None)
        spelling = option_string or "FACILITY"
        if value is not None and not str(value).strip():
            parser.error(f"{spelling} {value!r}: expected a facility YAML file or a preset (screen, screen_small)")
        if given is not None and given[1] != value:
            parser.error(f"{given[0]} {given[1]} and {spelling} {value}: give the facility once, as --facility")
        setattr(namespace, "_facility_given", (spelling, value))
        setattr(namespace, self.dest, value)


def add_facility_arg(parser, *, required: bool, default: str | None = None, help: str = "",
                     former_positional: bool = False, former_option: str | None = None) -> None:
    """``--facility FACILITY`` (``args.facility``): a facility YAML file or preset (screen, screen_small).

    ``former_positional``/``former_option`` (e.g. ``"--hil"``): the spellings documented before
    the option was one, still read (hidden from ``--help``); given with ``--facility`` they must
    name the same facility.
    """
    what = help or "facility YAML file or preset (screen, screen_small)"
    if default:
        what += f" (default: {default})"
    elif required and former_positional:
        what += " (required)"
    parser.add_argument("--facility", action=_Facility, default=default, metavar="FACILITY", help=what,
                        required=required and not former_positional)
    if former_option:
        parser.add_argument(former_option, action=_Facility, dest="facility", default=argparse.SUPPRESS,
                            metavar="FACILITY", help=argparse.SUPPRESS)
    if former_positional:
        parser.add_argument("former_facility", nargs="?", action=_Facility, default=argparse.SUPPRESS,
                            metavar="FACILITY", help=argparse.SUPPRESS)

        def merge(args):
            if getattr(args, "former_facility", None) is not None:
                args.facility = args.former_facility

        _after_parse(parser, merge)
    if required and former_positional:
        def check(args):
            if getattr(args, "facility", None) is None:
                raise UsageError("the following arguments are required: --facility FACILITY (a facility YAML file "
                                 "or preset: screen, screen_small)")

        _after_parse(parser, check)


def add_seed_arg(parser, *, default, help: str) -> None:
    """``--seed`` (``args.seed``): an integer in 0..2**63-1 (recorded in JSON, read back as int64)."""
    parser.add_argument("--seed", type=seed_int, default=default, help=help)


def add_workers_arg(parser, *, default, help: str, why: str = "") -> None:
    """``--workers`` (``args.workers``): local processes, 1..:data:`MAX_WORKERS` (``why``: what
    bounds them, said in the error line)."""
    parser.add_argument("--workers", type=int_in(1, MAX_WORKERS, why), default=default, help=help)


def add_output_arg(parser, *, help: str, required: bool = True, default: str | None = None) -> None:
    """``-o/--output`` (``args.output``): where the command writes (never into one of its inputs)."""
    parser.add_argument("-o", "--output", required=required, default=default, help=help)


def add_limit_arg(parser, *, minimum: int = 1, help: str = "only the first N frames") -> None:
    """``--limit N`` (``args.limit``): only the first N frames (at least ``minimum``)."""
    parser.add_argument("--limit", type=int_in(minimum, MAX_SEED) if minimum > 1 else positive_int, default=None,
                        metavar="N", help=help)


def add_dask_arg(parser) -> None:
    """``--dask-scheduler ADDRESS`` (``args.dask_scheduler``): run on a Dask distributed cluster."""
    parser.add_argument("--dask-scheduler", default=None, metavar="ADDRESS", help="run on a Dask distributed cluster")
