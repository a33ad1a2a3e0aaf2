"""``SKYNAV_MAX_COUNT``: one cap on the counts a run decides, read in one place.

Set to a whole number N, it caps the counts that make a command or a function long (the frames
of a generated dataset, ``bench nav``'s Monte Carlo runs, the exposures ``calibrate simulate``
averages) at N, and each capped count says so in one :class:`~skynav.infra.errors.SkynavWarning`
line. Nothing else changes: image sizes, seeds, options and files are what the command makes
without it. It is for smoke tests and for the documentation test (``tests/test_docs.py``), which
runs every documented command as typed, at small sizes. It lives in ``scenes`` because every room
and the command line may import ``scenes``.
"""

from __future__ import annotations

import warnings

from .environment import positive_int_from_env
from .errors import SkynavWarning

ENV_VAR = "SKYNAV_MAX_COUNT"


def count_cap() -> int | None:
    """``SKYNAV_MAX_COUNT`` as an int, or None when unset or empty.

    Raises
    ------
    ConfigValueError
        The variable is not a whole number >= 1.
    """
    return positive_int_from_env(ENV_VAR, "a whole number >= 1 (the largest count a run may take)")


def cap_count(n: int, what: str, *, minimum: int = 1) -> int:
    """``n``, or the cap of ``SKYNAV_MAX_COUNT`` (at least ``minimum``) when that is smaller.

    A capped count warns (``SkynavWarning``), naming ``what`` and both numbers.
    """
    cap = count_cap()
    if cap is None or n <= max(cap, minimum):
        return n
    capped = max(cap, minimum)
    warnings.warn(f"{ENV_VAR}={cap}: {what} capped at {capped} (asked for {n})", SkynavWarning, stacklevel=2)
    return capped
