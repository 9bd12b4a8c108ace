"""What the domain packages add to the generic layers, found through Python entry points.

A package declares in its ``pyproject.toml`` what it adds, and the generic code finds it there
without naming the package (no link upward, not even as a string)::

    [project.entry-points."hypa.systems"]        # name -> {system name: factory(block) -> LTIModel}
    vehicle = "hypa.vehicle:SYSTEMS"
    [project.entry-points."hypa.catalogues"]     # name -> the path of a catalogue of causes (YAML)
    vehicle = "hypa.vehicle:CATALOGUE"
    [project.entry-points."hypa.data_sources"]   # data.source -> folder(settings) -> Path
    testbench = "hypa.paper.testbench.dataset:folder_from_settings"

hypa's own domains (:mod:`hypa.vehicle`, :mod:`hypa.paper`) register this way, and so can a
user's package (``pip install`` it beside hypa): its systems are built-ins by name, its catalogue
joins the diagnosis's, its data source is a ``data.source``. Only installed packages are read:
an entry point is code the user installed, never something a data file names.
"""

from __future__ import annotations

import functools
from importlib import metadata
from typing import Any

from hypa.core.errors import UserError

GROUPS = ("systems", "catalogues", "data_sources")


@functools.cache
def plugins(group: str) -> dict[str, Any]:
    """Every object registered in the entry-point group ``hypa.<group>``, by entry-point name
    (sorted). One that fails to load is an error naming it and its package; none at all, with hypa
    itself not installed, says how to install it (its own domains would be missing)."""
    if group not in GROUPS:
        raise ValueError(f"unknown plugin group {group!r}; one of {', '.join(GROUPS)}")
    found = sorted(metadata.entry_points(group=f"hypa.{group}"), key=lambda e: e.name)
    if not found:
        try:
            metadata.distribution("hypa")
        except metadata.PackageNotFoundError:
            raise UserError(f"hypa is not installed, so its built-in {group.replace('_', ' ')} are not registered: "
                            "pip install -e . (or make install) in the repository") from None
    return {entry.name: _load(entry, group) for entry in found}


def _load(entry: metadata.EntryPoint, group: str) -> Any:
    try:
        return entry.load()
    except Exception as error:  # an installed package's code: one line that names it
        package = entry.dist.name if entry.dist is not None else "?"
        raise UserError(f"hypa.{group} plugin {entry.name!r} ({entry.value}, package {package}) does not load: "
                        f"{type(error).__name__}: {error}") from error
