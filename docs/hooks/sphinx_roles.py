"""Griffe extension: the Sphinx roles of the docstrings shown as code in the API pages.

The docstrings name other objects the Sphinx way (``:func:`render```, ``:class:`~a.b.Camera```,
as ``help()`` and IDEs read them), which Markdown would print literally. This extension rewrites
each role to a code span of the name Sphinx would show (the last component after ``~``), e.g.
``:func:`~skynav.scenes.timescales.to_time``` -> ```to_time```, before the numpy-style parser
reads the docstring. The docstrings themselves are unchanged.
"""

from __future__ import annotations

import re

import griffe

#: ``:role:`target``` or ``:role:`~target``` (Sphinx's Python-domain roles)
ROLE = re.compile(r":(?:py:)?(?:func|meth|class|mod|attr|data|exc|obj|const):`(~?)([^`<>]+?)`")


def as_code(match: re.Match) -> str:
    tilde, target = match.groups()
    shown = target.rsplit(".", 1)[-1] if tilde else target
    return f"`{shown}`"


def rewrite(text: str) -> str:
    """The docstring ``text`` with every role as a code span (``as_code``)."""
    return ROLE.sub(as_code, text)


class SphinxRoles(griffe.Extension):
    def on_package(self, *, pkg, **kwargs) -> None:  # griffe >= 1.14 name of the event
        self._walk(pkg, set())

    def on_package_loaded(self, *, pkg, **kwargs) -> None:  # older griffe
        self._walk(pkg, set())

    def _walk(self, obj, seen: set) -> None:
        if obj.is_alias:  # a public name bound to its defining object (lazy_exports.py)
            try:
                obj = obj.final_target
            except (griffe.AliasResolutionError, griffe.CyclicAliasError):
                return
        if id(obj) in seen:
            return
        seen.add(id(obj))
        if obj.docstring is not None:
            obj.docstring.value = rewrite(obj.docstring.value)
        for member in list(obj.members.values()):
            self._walk(member, seen)
