"""The trust boundary: what hypa reads from files as data, and the few things that are code.

**Data** is everything a run, a diagnosis or an export leaves behind, and everything someone can
send you: checkpoints, ``run.json``, ``config.yaml``, ``diagnosis.json``, written model YAML,
exported files, measured data. Data is read through a schema and bounded before it is read:

- a file's size is checked before it is read (:func:`read_bounded`);
- YAML is parsed by the safe loader (no ``!!python`` tags) with at most a few aliases, so an alias
  bomb is refused rather than expanded (:func:`read_yaml`);
- a nested value is walked with a bound on its nodes (:func:`count_nodes`), so a structure that
  shares itself many times is refused rather than walked for ever;
- a path that a folder records is resolved inside that folder, never through a symbolic link
  (:func:`inside`);
- an import path found in data is never imported unless the user trusts it
  (:func:`check_imports`): ``trust=[mypkg]`` on the command line, or the same import path named in
  the command's own configuration.

**Code** is what the user names themselves: a config directory (``--config-dir``,
``hydra.searchpath``), systems and networks by import path on the command line or in their own
config directory, and their own catalogue files.

This module is the core's: it imports nothing of hypa but its errors.
"""

from __future__ import annotations

import os
import re
from collections.abc import Collection, Iterable
from pathlib import Path
from typing import Any

import yaml

from hypa.core.errors import UserError

# Bounds on what a file may make hypa do. They are far above what any hypa file needs (a run's
# config.yaml is a few kB, a diagnosis.json a few hundred kB) and far below what hurts a machine;
# a checkpoint's bound is the model's own (hypa.training.checkpoints).
MAX_TEXT_BYTES = 64 * 2**20  # a YAML or JSON file hypa reads as data
MAX_YAML_ALIASES = 100  # hypa writes none; a hand-edited file may use a few
MAX_YAML_DEPTH = 100  # levels of nesting (a hypa file has fewer than ten)
MAX_NODES = 1_000_000  # values in one nested structure read from a file


def read_bounded(path: Path, limit: int = MAX_TEXT_BYTES, what: str = "file") -> bytes:
    """The bytes of ``path``, refused in one line when it is larger than ``limit`` (checked on the
    open file before it is read, and while reading: a file that grows is cut off, not followed)."""
    path = Path(path)
    with path.open("rb") as file:
        size = os.fstat(file.fileno()).st_size
        if size > limit:
            raise UserError(f"{path}: {size / 2**20:.1f} MiB, larger than any {what} hypa writes "
                            f"({limit / 2**20:.0f} MiB at most); not read")
        content = file.read(limit + 1)
    if len(content) > limit:
        raise UserError(f"{path}: larger than any {what} hypa writes ({limit / 2**20:.0f} MiB at most); not read")
    return content


class _BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader (plain data only) that counts aliases and refuses more than a few."""

    def __init__(self, stream: Any) -> None:
        super().__init__(stream)
        self._aliases = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            self._aliases += 1
            if self._aliases > MAX_YAML_ALIASES:
                raise yaml.YAMLError(f"more than {MAX_YAML_ALIASES} aliases (*name): refused, not expanded")
        self._depth = getattr(self, "_depth", 0) + 1
        try:
            if self._depth > MAX_YAML_DEPTH:  # the composer and constructor recurse: refused before Python's limit
                raise yaml.YAMLError(f"nested more than {MAX_YAML_DEPTH} levels deep: refused")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def read_yaml(path: Path, what: str = "YAML file") -> Any:
    """A YAML file read as data: bounded in size, plain values only (no ``!!python`` tags), at most
    :data:`MAX_YAML_ALIASES` aliases, at most :data:`MAX_NODES` values. Anything else is one line
    naming the file."""
    path = Path(path)
    text = read_bounded(path, what=what)
    try:
        value = yaml.load(text, Loader=_BoundedLoader)
    except (yaml.YAMLError, RecursionError) as error:
        lines = " ".join(str(error).split())
        raise UserError(f"{path}: not a readable {what} ({lines[:300]})") from None
    count_nodes(value, f"{path}")
    return value


def count_nodes(value: Any, what: str, limit: int = MAX_NODES) -> int:
    """The number of values in ``value`` (dicts, lists and scalars, every occurrence of a shared one
    counted), refused in one line above ``limit``: what a schema walks is bounded."""
    count, stack = 0, [value]
    while stack:
        node = stack.pop()
        count += 1
        if count > limit:
            raise UserError(f"{what}: more than {limit:,} values (a structure that repeats itself?); not read")
        if isinstance(node, dict):
            stack.extend(node.keys())
            stack.extend(node.values())
        elif isinstance(node, (list, tuple)):
            stack.extend(node)
    return count


MAX_NAME = 200  # characters of a channel, signal or block name
_NOT_IN_NAMES = re.compile(r"[/\\.\x00-\x1f\x7f]")


def check_name(name: Any, what: str) -> str:
    """``name`` (a channel, signal or block name), refused in one line unless it is 1 to
    :data:`MAX_NAME` characters with no path separator, dot or control character: names become
    file names (a figure per output) and module keys, and one that is a path (``/etc/x``,
    ``../x``) must never lead a write out of its folder."""
    if not isinstance(name, str) or not name or len(name) > MAX_NAME or _NOT_IN_NAMES.search(name):
        shown = repr(name)[:60] + ("..." if len(repr(name)) > 60 else "")
        raise UserError(f"{what}: {shown} is not a name (1 to {MAX_NAME} characters, no '/', '\\', '.' or "
                        "control characters)")
    return name


def has_interpolation(value: Any) -> bool:
    """Whether a value read from a file holds an OmegaConf interpolation (``${...}``) anywhere: a
    file hypa reads as data holds values, never references for a resolver to follow."""
    if isinstance(value, str):
        return "${" in value
    if isinstance(value, dict):
        return any(has_interpolation(k) or has_interpolation(v) for k, v in value.items())
    if isinstance(value, list):
        return any(has_interpolation(v) for v in value)
    return False


def inside(folder: Path, recorded: str, what: str) -> Path:
    """The file ``recorded`` (a path a folder's own record names) inside ``folder``: a relative path
    that stays inside it, with no symbolic link on the way. Anything else is refused in one line:
    a received folder must not make hypa read (or write) elsewhere."""
    folder = Path(folder)
    if not isinstance(recorded, str) or not recorded or "\x00" in recorded:
        raise UserError(f"{what}: {recorded!r} is not a file name")
    relative = Path(recorded)
    if relative.is_absolute() or ".." in relative.parts:
        raise UserError(f"{what}: {recorded} is not inside {folder} (a folder records its own files by "
                        "relative paths only); not followed")
    path, walked = folder, folder
    for part in relative.parts:
        walked = walked / part
        if walked.is_symlink():
            raise UserError(f"{what}: {walked} is a symbolic link; hypa follows none in a folder it reads")
        path = walked
    return path


def check_links(path: Path, folder: Path) -> None:
    """Refuse ``path`` when it, or a folder between ``folder`` and it, is a symbolic link."""
    walked = Path(folder)
    for part in Path(path).relative_to(walked).parts:
        walked = walked / part
        if walked.is_symlink():
            raise UserError(f"{walked} is a symbolic link; hypa reads and writes no file through one in a run "
                            "folder (replace it by the file itself)")


def _names(path: str) -> Iterable[str]:
    """``a.b.c:D`` -> ``a``, ``a.b``, ``a.b.c``, ``a.b.c:D`` (and ``a.b.c.D``): every prefix a trust entry may name."""
    module, _, attribute = path.partition(":") if ":" in path else path.rpartition(".")
    parts = module.split(".")
    yield from (".".join(parts[:i]) for i in range(1, len(parts) + 1))
    if attribute:
        yield f"{module}:{attribute}"
        yield f"{module}.{attribute}"


def is_file_path(path: str) -> bool:
    """Whether ``path`` names a file (an FMU: ``car.fmu``, ``sims/car.fmu``) rather than an import path."""
    return path.endswith(".fmu") or "/" in path or "\\" in path


def trusted(path: str, trust: Collection[str]) -> bool:
    """Whether ``path`` is trusted by ``trust``: an import path by itself or its packages, a file (an FMU)
    by itself or a folder above it (compared resolved)."""
    if "*" in trust:
        return True
    if is_file_path(path):
        target = Path(path).resolve()
        return any(is_file_path(t) or Path(t).is_dir() for t in trust) and \
            any(target == Path(t).resolve() or Path(t).resolve() in target.parents for t in trust)
    return any(name in trust for name in _names(path))


def check_imports(found: dict[str, str], trust: Collection[str], source: Path | str) -> None:
    """Refuse the import paths in ``found`` (what -> import path, read from the data file ``source``)
    that ``trust`` does not name: one line naming the first and how to allow it."""
    untrusted = {what: path for what, path in found.items() if not trusted(path, trust)}
    if not untrusted:
        return
    what, path = next(iter(untrusted.items()))
    more = f" (and {len(untrusted) - 1} more)" if len(untrusted) > 1 else ""
    all_paths = ",".join(dict.fromkeys(untrusted.values()))
    raise UserError(f"{source}: its {what} is {path}{more}, code that is not built into hypa; a file is data, so "
                    f"hypa imports or runs nothing it names: if you trust that code, give trust=[{all_paths}] "
                    "(or its package or folder)")


__all__ = [
    "MAX_NAME",
    "MAX_NODES",
    "MAX_TEXT_BYTES",
    "MAX_YAML_ALIASES",
    "check_imports",
    "check_links",
    "check_name",
    "count_nodes",
    "has_interpolation",
    "inside",
    "is_file_path",
    "read_bounded",
    "read_yaml",
    "trusted",
]
