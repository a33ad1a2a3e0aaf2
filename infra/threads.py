"""The process's thread budget: ``SKYNAV_THREADS``, read in one place.

Both the renderer (the size of Dr.Jit's CPU pool) and the datasets side (OpenEXR's pool) size
their pools from it; it lives in ``scenes`` because both rooms may import ``scenes`` and neither
may make the other load (docs/architecture.md "Never": reading a dataset loads no renderer code). The
dataset runner sets it to ``cores // workers`` in its worker processes.
"""

from __future__ import annotations

from .environment import positive_int_from_env

ENV_VAR = "SKYNAV_THREADS"


def thread_budget() -> int | None:
    """``SKYNAV_THREADS`` as an int (threads this process may use), or None when unset.

    Raises
    ------
    ConfigValueError
        The variable is not a whole number >= 1.
    """
    return positive_int_from_env(ENV_VAR, "a whole number of threads >= 1")
