"""Nothing too long to read: no module of the package over 600 lines, no function over 100.

A module that grows past 600 lines holds more than one idea and splits by meaning (as
``scenes/psf.py`` and ``scenes/psf_measured.py`` did); a function past 100 lines does more than
one step and splits into its steps. Counted on the source as written: every line of the file, and
a function's lines from its ``def`` (decorators included) to its last line, nested functions
counted in their parent.
"""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 100


def _package_files():
    with open(REPO / "pyproject.toml", "rb") as f:
        dirs = tomllib.load(f)["tool"]["setuptools"]["package-dir"]
    return [p for folder in dirs.values() for p in sorted((REPO / folder).glob("*.py"))]


def test_no_module_over_600_lines():
    long = {p.relative_to(REPO).as_posix(): n for p in _package_files()
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_MODULE_LINES}
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"


def test_no_function_over_100_lines():
    long = {}
    for p in _package_files():
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                start = min([node.lineno] + [d.lineno for d in node.decorator_list])
                n = node.end_lineno - start + 1
                if n > MAX_FUNCTION_LINES:
                    long[f"{p.relative_to(REPO).as_posix()}:{node.name}"] = n
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines: {long}"


def test_the_counts_see_a_long_function(tmp_path):
    """The walk counts a function's lines from its decorator to its end."""
    src = "@staticmethod\ndef f():\n" + "    x = 1\n" * 120
    node = ast.parse(src).body[0]
    assert node.end_lineno - min(node.lineno, node.decorator_list[0].lineno) + 1 == 122
