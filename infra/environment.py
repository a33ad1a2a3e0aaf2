"""skynav's environment variables that hold a count, read one way (``SKYNAV_THREADS``,
``SKYNAV_MAX_COUNT``): unset or empty means "no value"; anything else must be a whole number >= 1,
or the one-line :class:`~skynav.infra.errors.ConfigValueError` names the variable and its value."""

from __future__ import annotations

import os

from .errors import ConfigValueError


def positive_int_from_env(name: str, allowed: str) -> int | None:
    """The whole number >= 1 in environment variable ``name``, or None when it is unset or empty.

    ``allowed`` completes the error message ("expected <allowed>").

    Raises
    ------
    ConfigValueError
        The variable is set to anything but a whole number >= 1.
    """
    raw = os.environ.get(name, "").strip()
    if not raw:
        return None
    try:
        n = int(raw)
    except ValueError:
        n = 0
    if n < 1:
        raise ConfigValueError(name, raw, allowed)
    return n
