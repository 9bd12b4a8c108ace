"""A package's names imported when first used (PEP 562): the package's ``__init__`` stays cheap,
so what needs none of its heavy modules (torch, Lightning) is read without them.

    __getattr__, __dir__ = lazy_exports(__name__, globals(), {"ComposedModel": "composed"})

maps each exported name to the module that defines it: relative to the package (``composed``) or,
with a dot, absolute (``hypa.core.units``). A name is imported once and then kept in the package.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def lazy_exports(package: str, namespace: dict[str, Any],
                 exports: Mapping[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The package's module-level ``__getattr__`` and ``__dir__`` for ``exports`` (name -> module)."""

    def __getattr__(name: str) -> Any:
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        module = exports[name] if "." in exports[name] else f"{package}.{exports[name]}"
        value = getattr(importlib.import_module(module), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted({*namespace, *exports})

    return __getattr__, __dir__
