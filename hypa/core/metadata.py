"""What a run was made from, so a result can be trusted later: code, packages, data.

``hypa train`` writes :func:`run_metadata` into the run's ``run.json``: the hypa version, the
git commit of the hypa checkout (with a dirty flag; absent when hypa is not a git checkout or
git is missing), the versions of the packages that shape a result and the SHA-256 of every
data file the run read. ``hypa evaluate`` compares the data it reads with the recorded
checksums (:func:`data_differences`): evaluating on other data than the run was trained on is
allowed (new measurements), but it should never happen unnoticed.
"""

from __future__ import annotations

import hashlib
import subprocess
from collections.abc import Iterable, Mapping
from importlib import metadata
from pathlib import Path
from typing import Any

PACKAGES: tuple[str, ...] = ("torch", "lightning", "hydra-core")
_CHUNK = 1 << 20


def package_version(name: str) -> str | None:
    """The installed version of a distribution, ``None`` when it is not installed."""
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def git_state(folder: Path | None = None) -> dict[str, Any] | None:
    """``{"commit": sha, "dirty": bool}`` of the git checkout holding hypa's own files.

    ``None`` when hypa is not a tracked file of a git checkout (an installed package, even one
    inside someone else's repository) or git is missing. ``dirty``: tracked files differ
    from the commit (untracked files do not count).
    """
    folder = Path(folder) if folder is not None else Path(__file__).resolve().parent

    def git(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(["git", "-C", str(folder), *args], capture_output=True, text=True, timeout=10,
                              check=False)

    try:
        if git("ls-files", "--error-unmatch", "__init__.py").returncode != 0:
            return None
        commit = git("rev-parse", "HEAD")
        status = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.SubprocessError):  # no git, or it hangs
        return None
    if commit.returncode != 0 or status.returncode != 0:
        return None
    return {"commit": commit.stdout.strip(), "dirty": bool(status.stdout.strip())}


def sha256(path: Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    with Path(path).open("rb") as file:
        for chunk in iter(lambda: file.read(_CHUNK), b""):
            digest.update(chunk)
    return digest.hexdigest()


def file_name(path: Path, data_dir: Path) -> str:
    """A data file's name as recorded: relative to the data folder (so a moved folder matches)."""
    path, data_dir = Path(path).resolve(), Path(data_dir).resolve()
    return path.relative_to(data_dir).as_posix() if path.is_relative_to(data_dir) else str(path)


def checksums(files: Iterable[Path], data_dir: Path) -> dict[str, str]:
    """``{name relative to data_dir: sha256}`` of the files, sorted by name."""
    return dict(sorted((file_name(f, data_dir), sha256(f)) for f in files))


def run_metadata(files: Iterable[Path], data_dir: Path) -> dict[str, Any]:
    """The run.json fields that say what a run was made from (see the module docstring)."""
    info: dict[str, Any] = {"hypa_version": package_version("hypa")}
    git = git_state()
    if git is not None:
        info["git"] = git
    info["packages"] = {name: package_version(name) for name in PACKAGES}
    info["data_files"] = checksums(files, data_dir)
    return info


def data_differences(recorded: Mapping[str, str], files: Iterable[Path], data_dir: Path) -> list[str]:
    """How the data files now read differ from the ones a run recorded: one phrase per
    difference (``changed: val_00.csv``), empty when they are the same files."""
    now = checksums(files, data_dir)
    changed = sorted(name for name in recorded.keys() & now.keys() if recorded[name] != now[name])
    missing = sorted(recorded.keys() - now.keys())
    new = sorted(now.keys() - recorded.keys())
    return [f"{label}: {', '.join(names)}" for label, names in
            (("changed", changed), ("not read now", missing), ("not read in training", new)) if names]
