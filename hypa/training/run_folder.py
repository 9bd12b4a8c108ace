"""One run, one folder: a ``hypa train`` run folder is written by one process, for one run.

A run folder holds ``checkpoints/``, ``tensorboard/``, ``config.yaml`` (the run's resolved
configuration) and ``run.json`` (what the run was made from and its result, with the record of
its best checkpoint: path, validation loss, epoch and SHA-256). :class:`RunFolder` owns it:

- it is held with :mod:`hypa.core.folders` (``.lock``, an exclusive ``flock`` held while the run trains,
  opened without following a link): a second writer is kept out, since two ``hypa train`` with the
  same ``hydra.run.dir`` would otherwise mix their checkpoints, ``run.json`` and ``config.yaml``; a
  folder that holds a symbolic link is refused, so that neither a new run nor a resumed one
  (``ckpt_path=``, which appends to the folder's ``train.log``) writes through one;
- a folder that already holds another run's checkpoints is refused, unless the run resumes one of
  that folder's own checkpoints (``ckpt_path=<folder>/checkpoints/last.ckpt``);
- ``run.json`` and ``config.yaml`` are replaced atomically (written to a temporary name, then
  renamed), so a full disk or a killed process leaves the previous version, never half a file.

Hydra's record of the run (``.hydra/``) is written by the command once the folder is held
(:func:`hypa.commands.output_folder.save_hydra_record`; ``conf/train.yaml`` sets ``hydra.output_subdir: null``),
so a refused second writer leaves the first run's intact; a resumed run's goes into the folder Hydra
made for the resume, held too. Hydra itself still creates the folder and opens ``train.log`` for
appending before hypa's code runs (a refused run writes nothing into it).

In a run across processes (``trainer.strategy=ddp``) rank 0 holds the folder; the other ranks
:meth:`RunFolder.follow` it: they know where it is and never write it.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from hypa.core.errors import UserError
from hypa.core.folders import LOCK_FILE, HeldFolder, take, write_atomic, write_text_atomic
from hypa.core.metadata import file_name
from hypa.core.trust import check_links, read_bounded

__all__ = ["CHECKPOINTS", "CONFIG_FILE", "LOCK_FILE", "RECORD_FILE", "RunFolder", "read_record",
           "training_run_marks", "write_atomic", "write_text_atomic"]

log = logging.getLogger(__name__)

RECORD_FILE = "run.json"
CONFIG_FILE = "config.yaml"
CHECKPOINTS = "checkpoints"
COMMAND = "hypa train"


def training_run_marks(folder: Path) -> list[str]:
    """What makes ``folder`` a ``hypa train`` run's (``run.json``, ``checkpoints/``); empty for another."""
    folder = Path(folder)
    return [name for name, there in ((RECORD_FILE, (folder / RECORD_FILE).exists()),
                                     (f"{CHECKPOINTS}/", (folder / CHECKPOINTS).exists())) if there]


def read_record(folder: Path) -> dict[str, Any]:
    """A run folder's ``run.json`` (empty when there is none); a damaged one is the user's error."""
    path = Path(folder) / RECORD_FILE
    check_links(path, Path(folder))  # never read through a link out of the folder
    if not path.is_file():
        if path.exists():
            raise UserError(f"{path}: not a file; the run folder is damaged")
        return {}
    try:
        record = json.loads(read_bounded(path, what="run record"))
    except (ValueError, UnicodeDecodeError, RecursionError) as error:
        raise UserError(f"{path}: not a readable run record ({error}); the run folder is damaged") from None
    if not isinstance(record, dict):
        raise UserError(f"{path}: not a run record (a JSON object); the run folder is damaged")
    return record


class RunFolder:
    """The folder of one training run, held by this process (see the module docstring).

    Use :meth:`claim` as a context manager: ``with RunFolder.claim(out, resume) as folder: ...``.
    """

    def __init__(self, path: Path, writer: bool = True) -> None:
        self.path = Path(path)
        self.writer = writer  # False: a rank > 0 of a run across processes (update_record writes nothing)
        self.record: dict[str, Any] = {}
        self._held: list[HeldFolder] = []
        self._log_handler: logging.Handler | None = None

    @property
    def checkpoints(self) -> Path:
        return self.path / CHECKPOINTS

    @classmethod
    @contextmanager
    def claim(cls, path: Path, resume: Path | None = None) -> Iterator[RunFolder]:
        """Hold ``path`` for one run: create it, lock it against other writers, refuse it when it
        holds another run's checkpoints (unless ``resume`` is one of them). A resumed run keeps
        the folder's ``run.json`` and logs into its ``train.log`` too."""
        folder = cls(path)
        try:
            folder._held.append(take(folder.path, COMMAND, what="this run"))
            folder._refuse_foreign_checkpoints(resume)
            if resume is not None and resume.parent.resolve() == folder.checkpoints.resolve():
                folder.record = read_record(folder.path)
                folder._log_here()
            yield folder
        finally:
            folder._release()

    @classmethod
    @contextmanager
    def follow(cls, path: Path) -> Iterator[RunFolder]:
        """The folder that rank 0 of a run across processes holds, seen from another rank: not
        locked, not checked, never written."""
        yield cls(path, writer=False)

    def hold_also(self, path: Path) -> None:
        """Hold ``path`` too while this run holds its folder (a resumed run's new Hydra folder)."""
        self._held.append(take(Path(path), COMMAND, what="this run"))

    def _refuse_foreign_checkpoints(self, resume: Path | None) -> None:
        existing = sorted(p.name for p in self.checkpoints.glob("*.ckpt")) if self.checkpoints.is_dir() else []
        if not existing:
            return
        if resume is not None and resume.parent.resolve() == self.checkpoints.resolve():
            return
        raise UserError(f"{self.path} already holds another run's checkpoints ({', '.join(existing)}); give this run "
                        f"its own folder (hydra.run.dir=...), or resume that run with "
                        f"ckpt_path={self.checkpoints / 'last.ckpt'}")

    def _log_here(self) -> None:
        """A resumed run's log also goes to its own run folder (Hydra logs into its new folder)."""
        target = (self.path / "train.log").resolve()
        root = logging.getLogger()
        if any(isinstance(h, logging.FileHandler) and Path(h.baseFilename) == target for h in root.handlers):
            return
        handler = logging.FileHandler(target, mode="a")
        formats = [h.formatter for h in root.handlers if h.formatter is not None]
        handler.setFormatter(formats[0] if formats
                             else logging.Formatter("[%(asctime)s][%(name)s][%(levelname)s] - %(message)s"))
        root.addHandler(handler)
        self._log_handler = handler

    def _release(self) -> None:
        if self._log_handler is not None:
            logging.getLogger().removeHandler(self._log_handler)
            self._log_handler.close()
            self._log_handler = None
        while self._held:
            self._held.pop().release()

    def update_record(self, **fields: Any) -> None:
        """Add ``fields`` to ``run.json`` and write it (atomically); nothing on a following rank."""
        self.record.update(fields)
        if not self.writer:
            return
        write_text_atomic(self.path / RECORD_FILE, json.dumps(self.record, indent=2) + "\n")

    def relative(self, path: Path | str) -> str:
        """``path`` as recorded in ``run.json``: relative to the folder, so a moved folder still matches."""
        return file_name(Path(path), self.path)
