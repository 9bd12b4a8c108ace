"""One run, one folder: a ``hypa.train`` run folder is written by one process, for one run.

A run folder holds ``checkpoints/``, ``tensorboard/``, ``config.yaml`` (the run's resolved
configuration) and ``run.json`` (what the run was made from and its result, with the record of
its best checkpoint: path, validation loss, epoch and SHA-256). :class:`RunFolder` owns it:

- a lock (``.lock``, an exclusive ``flock`` held while the run trains) keeps a second writer out:
  two ``hypa.train`` with the same ``hydra.run.dir`` would otherwise mix their checkpoints,
  ``run.json`` and ``config.yaml``;
- a folder that already holds another run's checkpoints is refused, unless the run resumes one of
  that folder's own checkpoints (``ckpt_path=<folder>/checkpoints/last.ckpt``);
- ``run.json`` and ``config.yaml`` are replaced atomically (written to a temporary name, then
  renamed), so a full disk or a killed process leaves the previous version, never half a file.

Hydra writes ``.hydra/`` and the log before hypa's code runs, so a refused second writer may have
touched those; what hypa reads back (``config.yaml``, ``run.json``, the recorded checkpoint) it
has not.

In a run across processes (``trainer.strategy=ddp``) rank 0 holds the folder; the other ranks
:meth:`RunFolder.follow` it: they know where it is and never write it.
"""

from __future__ import annotations

import json
import logging
import os
import socket
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from hypa.errors import UserError
from hypa.metadata import file_name

try:  # POSIX; elsewhere runs are not locked (said once in the log)
    import fcntl
except ImportError:  # pragma: no cover
    fcntl = None  # type: ignore[assignment]

log = logging.getLogger(__name__)

RECORD_FILE = "run.json"
CONFIG_FILE = "config.yaml"
LOCK_FILE = ".lock"
CHECKPOINTS = "checkpoints"


def write_atomic(path: Path, write: Callable[[IO[bytes]], None]) -> None:
    """Write ``path`` through ``write(file)`` into a temporary sibling, flushed to disk, then rename
    it into place: readers see the old file or the whole new one. On an error (a full disk) the
    temporary file is removed and the old file kept."""
    path = Path(path)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with temporary.open("wb") as file:
            write(file)
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


def write_text_atomic(path: Path, text: str) -> None:
    """:func:`write_atomic` for a text file (UTF-8)."""
    write_atomic(path, lambda file: file.write(text.encode()))


def read_record(folder: Path) -> dict[str, Any]:
    """A run folder's ``run.json`` (empty when there is none); a damaged one is the user's error."""
    path = Path(folder) / RECORD_FILE
    if not path.is_file():
        return {}
    try:
        record = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as error:
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
        self._lock: IO[str] | None = None
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
            folder.path.mkdir(parents=True, exist_ok=True)
            folder._take_lock()
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

    def _take_lock(self) -> None:
        if fcntl is None:  # pragma: no cover
            log.warning("no file locking on this system: do not start two runs into %s", self.path)
            return
        lock = (self.path / LOCK_FILE).open("a+")
        try:
            fcntl.flock(lock.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            lock.seek(0)
            holder = lock.read().strip() or "another process"
            lock.close()
            raise UserError(f"{self.path} is being written by another hypa.train ({holder}); give this run its own "
                            "folder (hydra.run.dir=...) or wait for that one to end") from None
        lock.seek(0)
        lock.truncate()
        lock.write(f"pid {os.getpid()} on {socket.gethostname()}\n")
        lock.flush()
        self._lock = lock

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
        if self._lock is not None:
            self._lock.close()  # closing the file releases the flock
            self._lock = None

    def update_record(self, **fields: Any) -> None:
        """Add ``fields`` to ``run.json`` and write it (atomically); nothing on a following rank."""
        self.record.update(fields)
        if not self.writer:
            return
        write_text_atomic(self.path / RECORD_FILE, json.dumps(self.record, indent=2) + "\n")

    def relative(self, path: Path | str) -> str:
        """``path`` as recorded in ``run.json``: relative to the folder, so a moved folder still matches."""
        return file_name(Path(path), self.path)
