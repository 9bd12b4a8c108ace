"""The folder a command writes, under Hydra: held before anything is written there
(:mod:`hypa.core.folders`), never a training run's folder, and with Hydra's record of the command
(``.hydra/``) written by hypa once the folder is held.

Hydra creates the run folder (``hydra.run.dir``) before the command's code runs, and would write
``.hydra/`` (``config.yaml``, ``hydra.yaml``, ``overrides.yaml``) there too: a second command
started into the same folder would replace the first one's record before hypa could refuse it. The
configurations of the commands that hold their folder (``conf/{train,diagnose,evaluate,export,
explain,benchmark}.yaml``) therefore set ``hydra.output_subdir: null``, and :func:`save_hydra_record`
writes the same three files, as Hydra would, once the folder is held. What Hydra still does before
hypa's code runs: it creates the folder and opens its log ``<folder>/<command>.log`` for appending
(a refused second command writes nothing into it; a link there is opened, not written, and then
refused), and a sweep (``-m``) writes ``multirun.yaml`` into the sweep folder.

A command's folder is refused when it is a ``hypa train`` run's (it holds ``run.json`` or
``checkpoints/``): ``hypa.export hydra.run.dir=<run>`` would otherwise replace that run's files.
``hypa evaluate``'s default, ``<run>/evaluation/``, is a folder of its own inside the run's.
"""

from __future__ import annotations

import copy
import functools
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

from hypa.core.folders import FolderRefused, claim, write_text_atomic

F = TypeVar("F", bound=Callable[..., Any])

HYDRA_RECORD = ".hydra"  # Hydra's own name for it (its default hydra.output_subdir)
_HELD: set[Path] = set()  # the folders this process holds through claim_output (absolute)


def hydra_folder() -> Path | None:
    """The folder Hydra made for this command (``hydra.runtime.output_dir``); None outside Hydra."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return None
    output = HydraConfig.get().runtime.get("output_dir")
    return Path(str(output)) if output else None


def save_hydra_record(folder: Path, task: Any = None) -> None:
    """Write ``.hydra/config.yaml`` (the command's configuration, ``task``: by default the one Hydra
    composed), ``hydra.yaml`` and ``overrides.yaml`` into ``folder``, Hydra's folder for this command,
    as Hydra writes them; nothing when Hydra writes them itself (``hydra.output_subdir`` set) or
    ``folder`` is not Hydra's."""
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf, open_dict, read_write

    own = hydra_folder()
    if own is None or own.resolve() != Path(folder).resolve() or HydraConfig.get().output_subdir is not None:
        return
    hydra = HydraConfig.get()
    if task is None:  # the configuration Hydra composed, untouched by the command (it got a copy)
        task = copy.deepcopy(hydra._get_parent())
        with read_write(task), open_dict(task):
            del task["hydra"]
    record = Path(folder) / HYDRA_RECORD
    record.mkdir(exist_ok=True)
    write_text_atomic(record / "config.yaml", OmegaConf.to_yaml(task))
    write_text_atomic(record / "hydra.yaml", OmegaConf.to_yaml(HydraConfig.instance().cfg))
    write_text_atomic(record / "overrides.yaml", OmegaConf.to_yaml(hydra.overrides.task))


def refuse_training_run(folder: Path, command: str, setting: str = "hydra.run.dir") -> None:
    """Refuse ``folder`` when it is a ``hypa train`` run's (one line)."""
    from hypa.training.run_folder import training_run_marks

    marks = training_run_marks(folder)
    if marks:
        raise FolderRefused(f"{folder} is a hypa train run's folder (it holds {' and '.join(marks)}): {command} "
                            f"writes nothing into it; give {command} a folder of its own ({setting}=...)")


@contextmanager
def claim_output(command: str, path: Path | None = None, setting: str = "hydra.run.dir",
                 task: Any = None) -> Iterator[Path]:
    """Hold ``path`` (default: Hydra's folder for this command) for ``command`` while the block runs,
    refused when it is a training run's; in Hydra's folder, Hydra's record is written once held."""
    own = hydra_folder()
    path = Path(path) if path is not None else own
    if path is None:
        raise ValueError(f"{command}: no folder to claim outside Hydra")
    held = Path(os.path.abspath(path))  # as spelt (links are the claim's to refuse)
    if held in _HELD:  # held already (hypa evaluate out= Hydra's own folder): the same claim
        yield path
        return
    refuse_training_run(path, command, setting)
    with claim(path, command, setting):
        _HELD.add(held)
        try:
            save_hydra_record(path, task)
            yield path
        finally:
            _HELD.discard(held)


def record_training_run(folder: Any, resume: Path | None) -> None:
    """Hydra's record of a ``hypa train`` run (``.hydra/``), written once ``folder`` (its
    :class:`~hypa.training.run_folder.RunFolder`) is held; a resumed run's into the folder Hydra made
    for the resume, held too, as Hydra would have."""
    own = hydra_folder()
    if own is None:
        return
    if own.resolve() != folder.path.resolve():
        if resume is None:  # not this run's folder (Hydra runs another command): nothing of it
            return
        refuse_training_run(own, "hypa train")
        folder.hold_also(own)
    save_hydra_record(own)


def holding_output(command: str) -> Callable[[F], F]:
    """Decorate a command's ``main(cfg)``, below ``@hydra_command``: Hydra's folder for the command is
    held (:func:`claim_output`) before ``main`` runs and until it returns; a refusal is the command's
    one-line error."""
    def decorate(main: F) -> F:
        @functools.wraps(main)
        def wrapped(cfg: Any, *args: Any, **kwargs: Any) -> Any:
            with claim_output(command, task=cfg):
                return main(cfg, *args, **kwargs)

        return wrapped  # type: ignore[return-value]

    return decorate
