"""A griffe extension for the API reference: the docstrings' Sphinx roles
(``:class:`~a.b.C```, ``:func:`f```, ``:mod:`.x```) shown as code, as
``help()`` readers see them, instead of raw role markup."""

from __future__ import annotations

import re

import griffe

_ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|data|attr|obj|exc|const|ref):`~?([^`]+)`")


def _code(match: re.Match) -> str:
    target = match.group(1)
    return f"`{target.rsplit('.', 1)[-1] if '`~' in match.group(0) else target}`"


class SphinxRoles(griffe.Extension):
    def on_instance(self, *, obj: griffe.Object, **kwargs) -> None:
        if obj.docstring is not None and ":" in obj.docstring.value:
            obj.docstring.value = _ROLE.sub(_code, obj.docstring.value)
