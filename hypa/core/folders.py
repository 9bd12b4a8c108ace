"""One command, one folder: the folder a command writes is held by that one process, and nothing in
it is written through a link.

Every hypa command that writes a folder (a training run, a diagnosis, an evaluation, an export, a
benchmark, an explanation) :func:`claim`\\ s it before it writes anything there:

- the folder is created, and refused when it is a file or a symbolic link;
- an exclusive, non-blocking lock (``flock`` on ``<folder>/.lock``, which then names the holder:
  ``pid 123 on host (hypa diagnose)``) keeps a second writer out: two commands into one folder would
  otherwise replace each other's reports without a word. The second is refused in one line; the
  lock goes with the process (closed file, ended process), so a killed command leaves no stale lock;
- a folder that holds a symbolic link anywhere (walked, at most :data:`MAX_ENTRIES` entries) is
  refused: a folder received from someone else could otherwise make the command overwrite or
  append to any file its user can write (``evaluation/summary.md -> ~/.bashrc``). The lock file
  itself is opened without following a link (``O_NOFOLLOW``, relative to the folder opened the same
  way), and refused when it is not a plain file of its own (a hard link would be truncated too).

:func:`write_atomic` replaces a file through a new temporary file (``O_EXCL | O_NOFOLLOW``: a link or
file placed at its name is never followed) renamed into place: readers see the old file or the whole
new one, and a link at the file's own name is replaced, not written through.

What this cannot keep out: a process that changes the folder while the command runs (the checks are
made once, when the folder is claimed), and a system without ``fcntl`` (there a warning says that
two commands into one folder are not kept apart).

This module is the core's: it imports nothing of hypa but its errors.
"""

from __future__ import annotations

import errno
import logging
import os
import re
import secrets
import socket
import stat
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

from hypa.core.errors import UserError

try:  # POSIX; elsewhere folders are not locked (said once in the log)
    import fcntl
except ImportError:  # pragma: no cover
    fcntl = None  # type: ignore[assignment]

log = logging.getLogger(__name__)

LOCK_FILE = ".lock"
MAX_ENTRIES = 100_000  # entries walked for links; far above any folder hypa writes
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
_DIRECTORY = getattr(os, "O_DIRECTORY", 0)
_LINK_ERRNOS = {errno.ELOOP, errno.EMLINK}  # O_NOFOLLOW on a link: ELOOP (Linux, macOS), EMLINK (FreeBSD)


class FolderRefused(UserError):
    """A folder a command may not write: held by another process, a link, one holding a link, a file."""


def _link_target(path: Path) -> str:
    try:
        return os.readlink(path)
    except OSError:  # pragma: no cover - removed meanwhile
        return "?"


def link_refused(link: Path, command: str, setting: str = "hydra.run.dir") -> FolderRefused:
    """The refusal of a folder, or a file in one, that is a symbolic link (one line naming it)."""
    return FolderRefused(f"{link} is a symbolic link (to {_link_target(link)}): {command} writes nothing through a "
                         f"link; remove the link, or give {command} a new folder ({setting}=...)")


def refuse_links(folder: Path, command: str, setting: str = "hydra.run.dir", limit: int = MAX_ENTRIES) -> None:
    """Refuse ``folder`` when any entry inside it, at any depth, is a symbolic link (links are not
    followed while walking); a folder of more than ``limit`` entries is refused too, rather than
    walked for ever."""
    folder, seen, pending = Path(folder), 0, [Path(folder)]
    while pending:
        with os.scandir(pending.pop()) as entries:
            for entry in entries:
                seen += 1
                if seen > limit:
                    raise FolderRefused(f"{folder} holds more than {limit} files and folders: too many to check "
                                        f"for links; give {command} a new folder ({setting}=...)")
                if entry.is_symlink():
                    raise link_refused(Path(entry.path), command, setting)
                if entry.is_dir(follow_symlinks=False):
                    pending.append(Path(entry.path))


def holder_of(text: str) -> str:
    """Who holds a folder, in words, from its lock file's content (``pid 7 on host (hypa train)``)."""
    text = text.strip()
    match = re.fullmatch(r"(pid \d+ on \S+) \((hypa[. ]\w+)\)", text)  # hypa.train: a lock of an older hypa
    if match:
        return f"another {match.group(2)} ({match.group(1)})"
    return f"another process ({text})" if text else "another process"


class HeldFolder:
    """A folder this process holds (see :func:`claim`); :meth:`release` gives it back."""

    def __init__(self, path: Path, lock: int | None) -> None:
        self.path = Path(path)
        self._lock = lock

    def release(self) -> None:
        if self._lock is not None:
            os.close(self._lock)  # closing the file releases the flock
            self._lock = None


def take(path: Path, command: str, setting: str = "hydra.run.dir", what: str | None = None) -> HeldFolder:
    """Hold ``path`` for ``command`` (created if need be): see the module docstring. ``setting``: the
    override that chooses the folder, named in the refusals (``hydra.run.dir``, ``out``); ``what``: the
    writer in the refusal's advice (``this run``; default the command). Release it with
    :meth:`HeldFolder.release`, or use :func:`claim`."""
    path, what = Path(path), what or command
    if path.is_symlink():
        raise link_refused(path, command, setting)
    if path.exists() and not path.is_dir():
        raise FolderRefused(f"{setting}={path} is a file, not a folder; give {command} a folder ({setting}=...)")
    path.mkdir(parents=True, exist_ok=True)
    if fcntl is None:  # pragma: no cover
        log.warning("no file locking on this system: do not start two commands into %s", path)
        refuse_links(path, command, setting)
        return HeldFolder(path, None)
    try:
        folder = os.open(path, os.O_RDONLY | _DIRECTORY | _NOFOLLOW)
    except OSError as error:
        if error.errno in _LINK_ERRNOS or path.is_symlink():  # replaced by a link since the check above
            raise link_refused(path, command, setting) from None
        raise
    try:
        try:
            lock = os.open(LOCK_FILE, os.O_RDWR | os.O_CREAT | _NOFOLLOW, 0o644, dir_fd=folder)
        except OSError as error:
            if error.errno in _LINK_ERRNOS:
                raise link_refused(path / LOCK_FILE, command, setting) from None
            raise
    finally:
        os.close(folder)
    try:
        status = os.fstat(lock)
        if not stat.S_ISREG(status.st_mode) or status.st_nlink != 1:
            raise FolderRefused(f"{path / LOCK_FILE} is not a plain file of its own (a hard link, a device); "
                                f"remove it, or give {command} a new folder ({setting}=...)")
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = holder_of(os.pread(lock, 200, 0).decode(errors="replace"))
            raise FolderRefused(f"{path} is being written by {holder}; give {what} its own folder ({setting}=...) "
                                "or wait for that one to end") from None
        refuse_links(path, command, setting)
        os.ftruncate(lock, 0)
        os.pwrite(lock, f"pid {os.getpid()} on {socket.gethostname()} ({command})\n".encode(), 0)
    except BaseException:
        os.close(lock)
        raise
    return HeldFolder(path, lock)


@contextmanager
def claim(path: Path, command: str, setting: str = "hydra.run.dir", what: str | None = None) -> Iterator[Path]:
    """``with claim(out, "hypa export"): ...``: :func:`take` ``path`` and release it at the end."""
    held = take(path, command, setting, what)
    try:
        yield held.path
    finally:
        held.release()


def _temporary(path: Path) -> Path:
    """A new name beside ``path``: the process and a random part, so no one can place a file there ahead."""
    return path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")


def write_atomic(path: Path, write: Callable[[IO[bytes]], None]) -> None:
    """Write ``path`` through ``write(file)`` into a new temporary sibling, flushed to disk, then rename
    it into place: readers see the old file or the whole new one. On an error (a full disk) the
    temporary file is removed and the old file kept. The temporary file is created, never opened:
    a link or file already at its name is refused, not followed."""
    path = Path(path)
    temporary = _temporary(path)
    try:
        descriptor = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW, 0o666)
    except FileExistsError:
        raise UserError(f"{temporary} already exists (a file or link placed there): {path.name} is written through "
                        "a new temporary file only; remove it") from None
    try:
        with os.fdopen(descriptor, "wb") as file:
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
