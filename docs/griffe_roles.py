"""griffe extension for the API reference: Sphinx roles in the docstrings read as code.

The docstrings name other objects as ``:mod:`x```, ``:class:`~a.b.C```, ...; rendered as
Markdown they would show the role. Each becomes a code span, ``x`` (``C`` for ``~a.b.C``).
"""

import re

import griffe

_ROLE = re.compile(r":(?:mod|meth|func|class|attr|data|obj|exc|const):`(~?)([^`]+)`")


def _code(match: re.Match) -> str:
    tilde, target = match.groups()
    return f"`{target.rsplit('.', 1)[-1] if tilde else target}`"


class SphinxRolesAsCode(griffe.Extension):
    def on_instance(self, *, obj: griffe.Object, **kwargs) -> None:
        if obj.docstring is not None:
            obj.docstring.value = _ROLE.sub(_code, obj.docstring.value)
