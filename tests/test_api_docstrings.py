"""Every public name of the library rooms has a numpydoc docstring that the API reference can show.

The public names are the ``__all__`` of ``skynav.scenes``, ``.renderer``, ``.datasets``,
``.pipeline`` and ``.service``. For each one (a simple parser on ``__doc__``, numpydoc's section
underlines):

- a one-line summary (the first line, ending with a full stop);
- functions: ``Parameters`` naming exactly the signature's parameters (a name the signature lacks
  is a warning in the rendered reference; a parameter left out is a gap), ``Returns`` (or
  ``Yields``) and ``Examples``;
- classes: their constructor's parameters named in ``Parameters`` or ``Attributes`` (dataclass
  fields are both), and ``Examples``;
- exceptions: a summary and ``Examples`` (where the error comes from).

Every ``Examples`` section has at least one ``>>>`` line; ``tests/test_doctests.py`` runs them.
Names that are not callables (a dict of presets) carry the docstring of an assignment (a string
right after it, which the API reference shows); they are listed in ``NOT_CALLABLE`` with their
module, whose source is read for it.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import re

import pytest

PACKAGES = ("skynav.scenes", "skynav.renderer", "skynav.datasets", "skynav.pipeline", "skynav.service")

# Constants in ``__all__`` -> the module that assigns them: a dict has no ``__doc__`` of its own.
NOT_CALLABLE = {"skynav.datasets.PRESETS": "skynav.datasets.recipes",
                "skynav.pipeline.CASES": "skynav.pipeline.measurement"}

_SECTION = re.compile(r"^(\w[\w ]*)\n-{3,}$", re.M)


def public_names():
    out = []
    for package in PACKAGES:
        pkg = importlib.import_module(package)
        for name in pkg.__all__:
            out.append((package, name))
    return out


def sections(doc: str) -> dict[str, str]:
    """Section title -> its body, from a numpydoc docstring (cleaned by ``inspect.getdoc``)."""
    heads = list(_SECTION.finditer(doc))
    out = {}
    for i, m in enumerate(heads):
        end = heads[i + 1].start() if i + 1 < len(heads) else len(doc)
        out[m.group(1)] = doc[m.end():end]
    return out


def documented_names(body: str) -> set[str]:
    """The item names of a Parameters/Attributes section: unindented lines ``name : type`` or
    ``name``; ``a, b : float`` documents both."""
    names = set()
    for line in body.splitlines():
        if not line or line[0].isspace():
            continue
        head = line.split(" : ")[0].strip()
        for part in head.split(","):
            names.add(part.strip())
    return names


def signature_names(obj) -> set[str] | None:
    try:
        sig = inspect.signature(obj)
    except (TypeError, ValueError):
        return None
    names = set()
    for p in sig.parameters.values():
        if p.name.startswith("_"):   # private fields (a dataclass's init=True internals)
            continue
        prefix = {p.VAR_POSITIONAL: "*", p.VAR_KEYWORD: "**"}.get(p.kind, "")
        names.add(prefix + p.name)
    return names


def problems(qualname: str, obj) -> list[str]:
    doc = inspect.getdoc(obj) or ""
    if isinstance(obj, type) and obj.__doc__ is None:
        doc = ""
    found = []
    first = doc.split("\n\n")[0].strip()
    if not first:
        return [f"{qualname}: no docstring"]
    if "\n" in first or not first.endswith("."):
        found.append(f"{qualname}: the summary is not one line ending with a full stop: {first[:80]!r}")
    secs = sections(doc)
    if "Examples" not in secs or ">>>" not in secs["Examples"]:
        found.append(f"{qualname}: no Examples section with a >>> line")
    if isinstance(obj, type) and issubclass(obj, BaseException):
        return found
    params = signature_names(obj)
    if isinstance(obj, type):
        if getattr(obj, "_is_protocol", False):   # a Protocol is not constructed
            return found
        documented = documented_names(secs.get("Parameters", "")) | documented_names(secs.get("Attributes", ""))
        if params and not params <= documented:
            found.append(f"{qualname}: constructor parameters not documented: {sorted(params - documented)}")
        return found
    documented = documented_names(secs.get("Parameters", ""))
    if params is not None and params != documented:
        missing, extra = sorted(params - documented), sorted(documented - params)
        found.append(f"{qualname}: Parameters differ from the signature: missing {missing}, not in it {extra}")
    if "Returns" not in secs and "Yields" not in secs:
        found.append(f"{qualname}: no Returns section")
    return found


@pytest.mark.parametrize("package", PACKAGES)
def test_every_public_name_has_numpydoc_sections(package):
    pkg = importlib.import_module(package)
    assert pkg.__all__, package
    found = []
    for name in pkg.__all__:
        qualname = f"{package}.{name}"
        obj = getattr(pkg, name)
        if qualname in NOT_CALLABLE:
            assert not callable(obj), f"{qualname} is callable now: check its docstring"
            continue
        found += problems(qualname, obj)
    assert not found, "\n".join(found)


def test_the_checker_finds_a_missing_section():
    """The parser above does report what it is meant to (the check can fail)."""
    def f(x, y=1):
        """Add.

        Parameters
        ----------
        x : float
            A number.
        z : int
            Not a parameter.

        Examples
        --------
        >>> 1
        1
        """
    got = "\n".join(problems("f", f))
    assert "missing ['y']" in got and "not in it ['z']" in got and "no Returns section" in got


def _run_alone(qualname: str, obj) -> str | None:
    """Run the Examples of ``obj``'s docstring with nothing but ``np`` defined (as a reader
    pastes them): None when they pass, else the doctest report."""
    import doctest
    import io

    import numpy as np

    doc = inspect.getdoc(obj) or ""
    test = doctest.DocTestParser().get_doctest(sections(doc).get("Examples", ""), {"np": np}, qualname, None, 0)
    out = io.StringIO()
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    with np.printoptions(legacy="1.25"):
        runner.run(test, out=out.write)
    return out.getvalue() if runner.failures else None


@pytest.mark.parametrize("package", PACKAGES)
def test_examples_run_on_their_own(package):
    """Each public name's Examples import what they use: they run in a namespace holding only
    ``np`` (``tests/test_doctests.py`` runs them in their module's namespace)."""
    pkg = importlib.import_module(package)
    failed = []
    for name in pkg.__all__:
        if f"{package}.{name}" in NOT_CALLABLE:
            continue
        report = _run_alone(f"{package}.{name}", getattr(pkg, name))
        if report:
            failed.append(report)
    assert not failed, "\n".join(failed)[-4000:]


def assignment_docstring(module_name: str, name: str) -> str:
    """The string literal right after ``name = ...`` at the top level of a module's source."""
    tree = ast.parse(inspect.getsource(importlib.import_module(module_name)))
    body = tree.body
    for node, after in zip(body, body[1:]):
        targets = node.targets if isinstance(node, ast.Assign) else [getattr(node, "target", None)]
        if any(isinstance(t, ast.Name) and t.id == name for t in targets):
            if isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant) and isinstance(after.value.value, str):
                return after.value.value
    return ""


@pytest.mark.parametrize("qualname", sorted(NOT_CALLABLE))
def test_constants_have_an_assignment_docstring(qualname):
    package, name = qualname.rsplit(".", 1)
    assert name in importlib.import_module(package).__all__, qualname
    doc = assignment_docstring(NOT_CALLABLE[qualname], name)
    assert doc.strip().endswith("."), f"{qualname}: no docstring after its assignment in {NOT_CALLABLE[qualname]}"
