"""The machine's C compiler: found on PATH, run with its first error line kept (``hypa.export``'s native FMU
and the FMU block's sample loop, ``hypa.physics.fmu_loop``, compile with it)."""

from __future__ import annotations

import shutil
import subprocess
from collections.abc import Sequence
from pathlib import Path


def c_compiler() -> str | None:
    """The path of cc, gcc or clang on PATH (the first found), or None."""
    return shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")


def compile_c(command: Sequence[str], cwd: Path, timeout: float = 600.0) -> str:
    """Run the compiler ``command`` in ``cwd``; an empty string where it succeeded, else its first error line
    (the first line where none says "error")."""
    try:
        result = subprocess.run(list(command), cwd=cwd, capture_output=True, text=True, timeout=timeout, check=False)
    except (OSError, subprocess.TimeoutExpired) as error:
        return str(error).splitlines()[0] if str(error) else type(error).__name__
    return "" if result.returncode == 0 else first_error(result)


def first_error(result: subprocess.CompletedProcess) -> str:
    """A failed program's first error line (its first output line where none says "error")."""
    lines = [line.strip() for line in (result.stderr + result.stdout).splitlines() if line.strip()]
    errors = [line for line in lines if "error" in line.lower()]
    return (errors or lines or [f"exit status {result.returncode}"])[0]
