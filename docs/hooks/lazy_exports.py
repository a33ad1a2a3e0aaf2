"""Griffe extension: the public names of a package that loads its modules on first use.

``skynav.scenes``, ``.renderer``, ``.datasets`` and ``.service`` bind most public names lazily
(module ``__getattr__`` over a ``_LAZY`` table, PEP 562), which a static reader cannot follow:
``__all__ = sorted(_LAZY)`` is not a literal, and the names are not imported in the source. This
extension asks the imported package instead (importing it is cheap: that is the point of the
lazy table) and makes each public name an alias of the object that defines it, so the API pages
list every public name with its own docstring. A package without ``__all__`` exports its
non-underscore names (``dir()``, which includes the lazy table), modules excluded.
"""

from __future__ import annotations

import importlib
import inspect

import griffe

#: packages whose public names come from the running package rather than the source
PACKAGES = ("skynav.scenes", "skynav.renderer", "skynav.datasets", "skynav.pipeline", "skynav.service")


def public_names(module) -> list[str]:
    names = getattr(module, "__all__", None)
    if names is None:
        names = [n for n in dir(module) if not n.startswith("_") and not inspect.ismodule(getattr(module, n))]
    return list(names)


def defining_path(module, name: str) -> str | None:
    """Dotted path of the object ``module.name`` stands for, or None to keep what griffe read."""
    obj = getattr(module, name)
    obj = getattr(obj, "__wrapped__", obj)        # functools caches
    if inspect.isclass(obj) or inspect.isfunction(obj):
        return f"{obj.__module__}.{obj.__qualname__}"
    lazy = getattr(module, "_LAZY", {})
    if name in lazy:                              # a constant: the module the table names
        return f"{module.__name__}.{lazy[name]}.{name}"
    return None


class LazyExports(griffe.Extension):
    def on_package(self, *, pkg, **kwargs) -> None:  # griffe >= 1.14 name of the event
        self._fill(pkg)

    def on_package_loaded(self, *, pkg, **kwargs) -> None:  # older griffe
        self._fill(pkg)

    def _fill(self, pkg) -> None:
        for path in PACKAGES:
            try:
                target = pkg.get_member(path.split(".", 1)[1]) if "." in path else pkg
            except (KeyError, ValueError):
                continue
            module = importlib.import_module(path)
            names = public_names(module)
            # resolve every target before binding any: a function may share its module's name
            # (``skynav.renderer.render``), and binding it first would hide the module's other names
            targets = {}
            for name in names:
                where = defining_path(module, name)
                if where is not None and where != f"{path}.{name}":
                    targets[name] = pkg.get_member(where.split(".", 1)[1])
            for name, obj in targets.items():
                target.set_member(name, griffe.Alias(name, obj, parent=target))
            target.exports = names
