"""Every ``>>>`` example in the package's docstrings runs and prints what it says (doctests in CI).

The modules are found by walking the installed ``skynav`` packages, so a module added or moved is
covered without editing this file. Modules that need an optional accelerator are still imported
(imports are lazy everywhere); their examples avoid the accelerator. A module that imports an
optional extra at its top (``skynav.service.vizard``: pyzmq, the ``basilisk`` extra) is left out
where that extra is not installed, and run where it is.
"""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import numpy as np
import pytest

ROOMS = ("skynav.infra", "skynav.scenes", "skynav.renderer", "skynav.datasets", "skynav.pipeline",
         "skynav.calibration", "skynav.service")


def _importable(name: str) -> bool:
    """False for a module whose import needs an optional extra that is not installed (a missing
    third-party top-level package); any other import error is raised, as a failure."""
    try:
        importlib.import_module(name)
    except ModuleNotFoundError as exc:
        if exc.name and exc.name.split(".")[0] != "skynav":
            return False
        raise
    return True


def _modules():
    names = []
    for room in ROOMS:
        pkg = importlib.import_module(room)
        names.append(room)
        for info in pkgutil.walk_packages(pkg.__path__, prefix=room + "."):
            names.append(info.name)
    return sorted(n for n in names if _importable(n))


def _with_examples(name):
    mod = importlib.import_module(name)
    finder = doctest.DocTestFinder(exclude_empty=True)
    return [t for t in finder.find(mod) if t.examples]


MODULES = [m for m in _modules() if _with_examples(m)]


def test_doctests_are_collected():
    """A doctest run that finds nothing is a broken run, not a passing one."""
    assert sum(len(_with_examples(m)) for m in MODULES) >= 10


@pytest.mark.parametrize("name", MODULES)
def test_module_doctests(name):
    tests = _with_examples(name)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    with np.printoptions(legacy="1.25"):
        for t in tests:
            t.globs.setdefault("np", np)
            runner.run(t)
    res = runner.summarize(verbose=False)
    assert res.failed == 0, f"{res.failed} of {res.attempted} examples failed in {name}"


def test_a_wrong_example_fails():
    """The runner as configured above does report a wrong example (the check can fail)."""
    parser = doctest.DocTestParser()
    t = parser.get_doctest(">>> 1 + 1\n3\n", {}, "wrong", "wrong.py", 0)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    runner.run(t, out=lambda s: None)
    assert runner.summarize(verbose=False).failed == 1
