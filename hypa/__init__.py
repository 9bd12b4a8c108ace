"""hypa: hybrid physics-augmented neural networks for dynamic systems with partially known physics.

The package holds its layers (``docs/layout.md``): :mod:`hypa.core` and :mod:`hypa.reporting` at
the bottom; :mod:`hypa.physics`, :mod:`hypa.ann`, :mod:`hypa.data` and :mod:`hypa.models` above
them; the library (:mod:`hypa.identification`, :mod:`hypa.training`, :mod:`hypa.evaluation`,
:mod:`hypa.diagnosis`, :mod:`hypa.explain`, :mod:`hypa.export`); the domains
(:mod:`hypa.vehicle`, :mod:`hypa.paper`); and :mod:`hypa.commands`, run as ``hypa <command>``.

The spellings from before this layout keep working for one release, each with one deprecation
line: ``python -m hypa.train`` and the other command modules (now ``hypa train``), and the
modules that moved into a layer (``hypa.errors`` is :mod:`hypa.core.errors`).
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings
from types import CodeType, ModuleType

# module -> where it lives now
_MOVED_MODULES = {
    **{f"hypa.{name}": f"hypa.core.{name}"
       for name in ("errors", "trust", "folders", "machine", "metadata", "metrics")},
    "hypa.markdown": "hypa.reporting.markdown",
    "hypa.plots": "hypa.reporting.figures",
    "hypa.reporting.plots": "hypa.reporting.figures",
    "hypa.evaluation.evaluation": "hypa.evaluation.api",
    "hypa.explain.run": "hypa.explain.api",
    "hypa.export.run": "hypa.export.api",
    "hypa.diagnosis.system": "hypa.diagnosis.api",
    "hypa.explain.report": "hypa.explain.result",
    "hypa.identification.report": "hypa.identification.result",
    "hypa.evaluation.plots": "hypa.evaluation.figures",
    "hypa.launch": "hypa.commands.launch",
    "hypa.testbench": "hypa.paper.testbench",
    "hypa.data.units": "hypa.core.units",
}
# python -m <module> -> the command's words after `hypa`
_MOVED_COMMANDS = {
    **{f"hypa.{name}": (name,) for name in ("train", "evaluate", "simulate", "diagnose", "benchmark", "reproduce",
                                            "testbench")},
    "hypa.explain.__main__": ("explain",),
    "hypa.export.__main__": ("export",),
    "hypa.speed": ("timing",),
    "hypa.bench": ("timing", "physics"),
    "hypa.bench_diagnosis": ("timing", "diagnosis"),
}


class _OldSpellings(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds the old names only (asked after every real finder): an import of a moved module gets
    the module itself, with a DeprecationWarning; ``python -m`` of an old command module runs the
    command, after one line on stderr."""

    def find_spec(self, name: str, path: object = None, target: object = None) -> importlib.machinery.ModuleSpec | None:
        if name in _MOVED_MODULES or name in _MOVED_COMMANDS:
            return importlib.util.spec_from_loader(name, self)
        return None

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType | None:
        return None

    def exec_module(self, module: ModuleType) -> None:
        new = _MOVED_MODULES.get(module.__name__)
        if new is None:
            words = " ".join(_MOVED_COMMANDS[module.__name__])
            raise ImportError(f"{module.__name__} is no module any more: the command is `hypa {words}`")
        warnings.warn(f"{module.__name__} is {new} now; import it from there (the old name goes in the next release)",
                      DeprecationWarning, stacklevel=3)
        sys.modules[module.__name__] = importlib.import_module(new)  # the import returns the module itself

    def get_code(self, name: str) -> CodeType:
        """What ``python -m <old command module>`` runs (:func:`runpy.run_module` asks for it)."""
        if name not in _MOVED_COMMANDS:
            raise ImportError(f"{name} is {_MOVED_MODULES[name]} now, a module, not a command")
        spelling, words = name.removesuffix(".__main__"), list(_MOVED_COMMANDS[name])
        source = f"from hypa.commands.cli import deprecated\ndeprecated({spelling!r}, {words!r})\n"
        return compile(source, f"<{name}>", "exec")


sys.meta_path.append(_OldSpellings())
