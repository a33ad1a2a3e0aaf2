"""The package-level API of ``skynav.scenes`` and ``skynav.renderer`` (``from skynav.scenes import
Camera``): every name in ``__all__`` resolves to what its module defines, and importing the
packages, or resolving every name, loads neither Mitsuba nor Dr.Jit (checked in a fresh
interpreter, where ``sys.modules`` shows what an import really loaded)."""

from __future__ import annotations

import importlib
import json
import pkgutil
import subprocess
import sys
import textwrap

import pytest

PACKAGES = ("skynav.scenes", "skynav.renderer")


@pytest.mark.parametrize("package", PACKAGES)
def test_every_name_in_all_resolves_to_its_modules_object(package):
    pkg = importlib.import_module(package)
    assert pkg.__all__ == sorted(set(pkg.__all__)) and len(pkg.__all__) >= 10
    for name in pkg.__all__:
        value = getattr(pkg, name)
        assert not isinstance(value, type(pkg)), f"{package}.{name} is a module, not the API object"
        home = importlib.import_module(value.__module__)
        assert getattr(home, name) is value, (package, name, value.__module__)
    assert set(pkg.__all__) <= set(dir(pkg))
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        pkg.not_a_name  # noqa: B018


@pytest.mark.parametrize("package", PACKAGES)
def test_no_submodule_shadows_a_package_name(package):
    """Importing a submodule binds its name on the package; a submodule named like an API entry
    would replace the entry as soon as anything imported it (``render`` the function against
    ``skynav.renderer.render`` the module is imported eagerly for that reason)."""
    pkg = importlib.import_module(package)
    lazy = set(getattr(pkg, "_LAZY", {}))
    modules = {m.name for m in pkgutil.iter_modules(pkg.__path__)}
    assert not modules & lazy, modules & lazy


_FRESH = textwrap.dedent("""
    import json, sys
    {first}
    import skynav.scenes, skynav.renderer
    after_import = sorted(m for m in sys.modules if m.split(".")[0] in ("mitsuba", "drjit"))
    from skynav.renderer import render
    render_is_function = callable(render) and not isinstance(render, type(sys))
    for pkg in (skynav.scenes, skynav.renderer):
        for name in pkg.__all__:
            getattr(pkg, name)
    after_all = sorted(m for m in sys.modules if m.split(".")[0] in ("mitsuba", "drjit"))
    print(json.dumps({{"after_import": after_import, "after_all": after_all,
                      "render_is_function": render_is_function}}))
""")


@pytest.mark.parametrize("first", ["", "import skynav.renderer.render, skynav.scenes.scene"])
def test_package_import_loads_no_mitsuba_or_drjit(first):
    """Fresh interpreter: ``import skynav.scenes, skynav.renderer`` and resolving every name of
    both ``__all__`` load no ``mitsuba`` or ``drjit`` module; ``from skynav.renderer import
    render`` is the function even when the submodule was imported first."""
    run = subprocess.run([sys.executable, "-c", _FRESH.format(first=first)], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    got = json.loads(run.stdout.strip().splitlines()[-1])
    assert got == {"after_import": [], "after_all": [], "render_is_function": True}


def test_scenes_package_loads_no_renderer():
    """The scenes room imports no other room but the infrastructure, and its package API must not either."""
    code = ("import sys, skynav.scenes as S\n[getattr(S, n) for n in S.__all__]\n"
            "print(sorted(m for m in sys.modules if m.startswith('skynav.')"
            " and not m.startswith(('skynav.scenes', 'skynav.infra'))))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.strip().splitlines()[-1] == "[]"
