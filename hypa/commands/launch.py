"""hypa's commands run as a user types them, in a child process: one way for every caller.

The benchmark trains and diagnoses, the reproduction sweeps: each runs ``hypa <command> ...``
(its output on the console is the progress) and, when the
child fails, stops with one line that gives the command to run alone (the child's own error is
above it). Running a child rather than calling the command in this process keeps Hydra's global
state, the random seeds and the run folder of each command its own.
"""

from __future__ import annotations

import logging
import signal
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

from hypa.core.errors import UserError

log = logging.getLogger(__name__)


def hypa_argv(command: str, arguments: Sequence[str], config_dirs: Sequence[Path] = ()) -> list[str]:
    """``hypa <command> [--config-dir DIR ...] ARGUMENTS`` as an argv (this interpreter)."""
    return [sys.executable, "-m", "hypa", command, *(a for d in config_dirs for a in ("--config-dir", str(d))),
            *arguments]


def run_hypa(command: str, arguments: Sequence[str], what: str, config_dirs: Sequence[Path] = (),
             cwd: Path | None = None, error: type[UserError] = UserError, after: str = "") -> None:
    """Run ``hypa <command> ARGUMENTS``; ``error`` (one line) when it fails.

    what: the step in words, for the log line and the error (``training lstm``); after: a clause
    added to the error (``the runs that finished are in DIR``).
    """
    argv = hypa_argv(command, arguments, config_dirs)
    log.info("%s: %s", what, " ".join(argv[1:]))
    status = subprocess.run(argv, cwd=cwd, check=False).returncode
    if status in (130, -signal.SIGINT):  # Ctrl-C reached the child too: it said so, this command ends the same way
        raise KeyboardInterrupt
    if status != 0:
        raise error(f"{what} failed (exit status {status}, its error above){'; ' + after if after else ''}; "
                    f"run it alone: python {' '.join(argv[1:])}")
