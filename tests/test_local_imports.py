"""Imports at the top: a module's dependencies are read in its first lines.

Every ``import`` inside a function of the package (every room and the command line) is listed with
``ast``. None may import one of skynav's own modules or any other module except a heavy or optional
package (:data:`OPTIONAL`, :data:`HEAVY`), and that one only with a reason comment (on its line, or
above it or above its block of imports; a bare ``# noqa`` is not a reason). The one exception is the
command line (:data:`LAZY_ROOMS`): ``skynav --help`` must not load the rooms, so a command's module
and :mod:`skynav.cli_common` may import them in a function, again only with the reason on the line
or above it.
"""

from __future__ import annotations

import ast
import re
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: Optional packages (or ones only a few paths need) a function may import on first use, each with
#: a comment saying why.
OPTIONAL = ("mitsuba", "drjit", "matplotlib", "dask", "distributed", "PIL", "tetra3rs", "cedar_solve",
            "ccsds_ndm", "spiceypy", "torch", "jax", "webdataset", "datasets")

#: Packages slow to import (scipy's submodules 0.2-0.5 s, astropy.time 0.7 s, colour-science 1 s,
#: jsonschema 0.1 s, tqdm 35 ms, OpenEXR) that a module on a light path (the dataset reader, the
#: pipeline's start, ``skynav --help``) needs only in one function: imported there, with the reason.
HEAVY = ("scipy", "astropy", "colour", "jsonschema", "tqdm", "OpenEXR")

#: Folders whose functions may also import skynav's own modules and other packages, with a reason:
#: the command line, whose start-up (``skynav --help``) loads no room.
LAZY_ROOMS = ("skynav",)


def _modules():
    """(room folder, path relative to the repo, source) of every module of the package."""
    with open(REPO / "pyproject.toml", "rb") as f:
        dirs = tomllib.load(f)["tool"]["setuptools"]["package-dir"]
    return [(folder, p.relative_to(REPO).as_posix(), p.read_text(encoding="utf-8"))
            for folder in dirs.values() for p in sorted((REPO / folder).glob("*.py"))]


def _reason(lines, lineno) -> bool:
    """A comment other than a bare ``noqa`` on the import's line, or on a comment line or block
    opener (``try:  # why``) right above it or above the block of import lines it ends."""
    k = lineno - 1
    while k >= 0:
        text = lines[k].strip()
        code, _, comment = text.partition("#")
        comment = re.sub(r"noqa(:\s*[A-Z0-9, ]+)?", "", comment).strip(" -:")
        is_import = code.startswith(("import ", "from "))
        if k < lineno - 1 and not (is_import or code == "" or code.rstrip().endswith(":")):
            return False  # another statement: its comment is about it
        if comment:
            return True
        if k < lineno - 1 and not is_import:
            return False
        k -= 1
    return False


def local_imports(source: str):
    """``(line, top-level module name or '.' for a relative import, has a reason comment)`` of
    every import inside a function of ``source``."""
    lines = source.splitlines()
    out = []
    for fn in ast.walk(ast.parse(source)):
        if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for node in ast.walk(fn):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = ["." if node.level else node.module]
            else:
                continue
            out += [(node.lineno, n.split(".")[0] if n != "." else ".", _reason(lines, node.lineno)) for n in names]
    return sorted(set(out))


def violations(folder: str, source: str):
    """The function-local imports of one module that break the rule (module docstring)."""
    bad = []
    for line, name, reason in local_imports(source):
        if name in OPTIONAL + HEAVY or folder in LAZY_ROOMS:
            if not reason:
                bad.append((line, name, "optional package without a reason comment" if name in OPTIONAL + HEAVY
                            else "lazy import without a reason comment"))
        else:
            bad.append((line, name, "skynav's own module" if name in (".", "skynav") else "not an optional package"))
    return bad


def test_the_rule_catches_what_it_should():
    src = '''
def a():
    from .catalog import OnboardCatalog
def b():
    import skynav.scenes
def c():
    import yaml
def d():
    import matplotlib  # noqa: F401
def e():
    # matplotlib: heavy, only for the report's figures
    import matplotlib
def f():
    from PIL import Image  # PIL only for colour PNGs
def g():
    # the figure's libraries, loaded only when a report draws one
    from matplotlib.figure import Figure
    from matplotlib.backends.backend_agg import FigureCanvasAgg
def h():
    x = 1  # a comment on another statement
    import dask
'''
    got = [(n, why) for _, n, why in violations("pipeline", src)]
    assert got == [(".", "skynav's own module"), ("skynav", "skynav's own module"), ("yaml", "not an optional package"),
                   ("matplotlib", "optional package without a reason comment"),
                   ("dask", "optional package without a reason comment")]
    assert [n for _, n, _ in violations("renderer", src)] == [n for n, _ in got]  # every room
    lazy = [(n, why) for _, n, why in violations("skynav", src)]  # the command line: anything, with a reason
    assert lazy == [(".", "lazy import without a reason comment"), ("skynav", "lazy import without a reason comment"),
                    ("yaml", "lazy import without a reason comment"),
                    ("matplotlib", "optional package without a reason comment"),
                    ("dask", "optional package without a reason comment")]
    assert violations("skynav", "def f():\n    # lazy: skynav --help loads no room\n    from . import cli_dataset\n") == []


def test_no_function_local_imports_but_optional_packages_with_their_reason():
    bad = [f"{rel}:{line}: {name} ({why})" for folder, rel, src in _modules() for line, name, why in violations(folder, src)]
    assert bad == [], "imports go at the top of the module; a function may import only a heavy optional package, " \
                      "with a comment saying why:\n" + "\n".join(bad)


def private_uses(source: str):
    """``(line, name)`` of every ``_``-prefixed (not dunder) name a module imports with ``from``,
    and of every ``_``-prefixed attribute it reads on an object other than ``self``/``cls``."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.module != "__future__":
            out += [(node.lineno, a.name) for a in node.names if a.name.startswith("_") and not a.name.startswith("__")]
        elif isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
            if not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls")):
                out.append((node.lineno, node.attr))
    return out


def test_the_private_rule_catches_what_it_should():
    src = "from numpy.linalg import _umath_linalg\nfrom .x import __version__\ndef f(s, o):\n" \
          "    return s._col, o.__class__, self._ok\n"
    assert private_uses(src) == [(1, "_umath_linalg"), (4, "_col")]


def test_strict_rooms_use_no_private_name_of_another_module():
    bad = [f"{rel}:{line}: {name}" for folder, rel, src in _modules() if folder == "pipeline"
           for line, name in private_uses(src)]
    assert bad == [], "a private name is another module's business; ask it for a public one:\n" + "\n".join(bad)
