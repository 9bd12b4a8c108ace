"""``python -m hypa.testbench``: the command is :mod:`hypa.commands.testbench`.

The simulated test bench itself is the paper's instance, :mod:`hypa.paper.testbench`; importing its
names from here still works, with a deprecation warning.
"""

from __future__ import annotations

import importlib
import warnings
from typing import Any


def __getattr__(name: str) -> Any:
    """``from hypa.testbench import X``, the spelling before the move: X from :mod:`hypa.paper.testbench`."""
    if name.startswith("__"):
        raise AttributeError(name)
    warnings.warn("hypa.testbench is hypa.paper.testbench now; import from there", DeprecationWarning, stacklevel=2)
    return getattr(importlib.import_module("hypa.paper.testbench"), name)


if __name__ == "__main__":
    from hypa.commands.testbench import main

    main()
