"""The documentation site builds with warnings as errors, and its API reference is complete.

Runs ``mkdocs build --strict`` (the README's command; mkdocs.yml) into a temporary folder when the
docs extra is installed (``pip install -e ".[docs]"``), and skips with that reason otherwise. The
API pages (docs/api/) are generated from the docstrings by mkdocstrings; every public name of
``skynav.scenes``, ``.renderer``, ``.datasets``, ``.pipeline`` and ``.service`` (each package's
``__all__``, or its non-underscore names where it has none) must have its own entry there.
"""

from __future__ import annotations

import importlib
import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("scenes", "renderer", "datasets", "pipeline", "service")
NEEDED = ("mkdocs", "mkdocstrings", "mkdocstrings_handlers.python")


def _missing() -> list[str]:
    missing = []
    for name in NEEDED:
        try:
            if importlib.util.find_spec(name) is None:
                missing.append(name)
        except ModuleNotFoundError:
            missing.append(name)
    return missing


def _public_names(package: str) -> list[str]:
    sys.path.insert(0, str(ROOT / "docs" / "hooks"))
    try:
        from lazy_exports import public_names
    finally:
        sys.path.remove(str(ROOT / "docs" / "hooks"))
    return public_names(importlib.import_module(f"skynav.{package}"))


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    missing = _missing()
    if missing:
        pytest.skip(f"the docs extra is not installed ({', '.join(missing)}): pip install -e \".[docs]\"")
    out = tmp_path_factory.mktemp("site")
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"mkdocs build --strict failed:\n{proc.stdout}\n{proc.stderr}"
    return out


def test_site_builds_with_warnings_as_errors(site):
    assert (site / "index.html").is_file()


@pytest.mark.parametrize("package", PACKAGES)
def test_api_reference_has_every_public_name(site, package):
    html = (site / "api" / package / "index.html").read_text(encoding="utf-8")
    anchors = set(re.findall(r'id="(skynav\.[A-Za-z0-9_.]+)"', html))
    names = _public_names(package)
    assert names, package
    missing = [n for n in names if f"skynav.{package}.{n}" not in anchors]
    assert not missing, f"not in docs/api/{package}.md's page: {missing}"


def test_every_page_is_in_the_navigation():
    nav = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    pages = [p.relative_to(ROOT / "docs").as_posix() for p in (ROOT / "docs").rglob("*.md")]
    missing = [p for p in pages if not p.startswith("hooks/") and f" {p}" not in nav]
    assert not missing, f"pages missing from mkdocs.yml's nav: {missing}"


@pytest.mark.parametrize("package", PACKAGES)
def test_api_pages_show_no_sphinx_role(site, package):
    """The docstrings' ``:func:`x``` roles reach the page as code (docs/hooks/sphinx_roles.py)."""
    html = (site / "api" / package / "index.html").read_text(encoding="utf-8")
    left = re.findall(r":(?:func|meth|class|mod|attr|data|exc|obj):", html)
    assert not left, f"{len(left)} Sphinx roles printed literally in docs/api/{package}.md's page"


def test_sphinx_roles_become_code_spans():
    pytest.importorskip("griffe", reason="the docs extra (pip install -e \".[docs]\") is not installed")
    sys.path.insert(0, str(ROOT / "docs" / "hooks"))
    try:
        from sphinx_roles import rewrite
    finally:
        sys.path.remove(str(ROOT / "docs" / "hooks"))
    assert rewrite("see :func:`~skynav.scenes.timescales.to_time` and :class:`Camera`.") == (
        "see `to_time` and `Camera`.")
    assert rewrite(":meth:`Camera.replace`, ``:func:`` alone") == "`Camera.replace`, ``:func:`` alone"
