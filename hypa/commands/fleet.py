"""``hypa fleet run 'logs/*/' | summary DIR``: a fleet of logs diagnosed, then summarized.

The library part (reading each log's diagnosis, the summary table) is :mod:`hypa.diagnosis.fleet`;
this is the command line around it, with the Hydra glue of a fleet sweep: :class:`FleetSummary`
(the callback that writes the summary after the sweep) and :func:`record_failures` (a failed log
recorded, the others go on).
"""

from __future__ import annotations

import argparse
import functools
import glob
import json
import os
import re
import shlex
import subprocess
import sys
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from hypa.commands.launch import hypa_argv
from hypa.core.errors import UserError, full_error_requested, is_user_error, one_line, user_errors
from hypa.diagnosis.fleet import ERROR_FILE, JOB_NAME, report, write_summary
from hypa.diagnosis.fleet import __doc__ as FLEET_DOC


def expand_logs(patterns: Sequence[str]) -> list[Path]:
    """The log folders that the glob ``patterns`` match (``**`` recurses), sorted, each once."""
    folders: dict[Path, None] = {}
    for pattern in patterns:
        for match in sorted(glob.glob(os.path.expanduser(pattern), recursive=True)):
            if Path(match).is_dir():
                folders[Path(match)] = None
    if not folders:
        raise UserError(f"no log folder matches {' '.join(patterns)}; give folders or a glob such as 'logs/*/'")
    return list(folders)


def hydra_quoted(text: str) -> str:
    """``text`` as a quoted Hydra override value (spaces, commas and quotes in a path survive the sweep)."""
    quoted = re.sub(r"(\\*)'", lambda m: 2 * m.group(1) + "\\'", text)
    quoted = re.sub(r"(\\+)$", lambda m: 2 * m.group(1), quoted).replace("${", "\\${")
    return f"'{quoted}'"


def diagnose_command(folders: Sequence[Path], overrides: Sequence[str]) -> list[str]:
    """``hypa diagnose -m`` over ``folders`` (``dataset=files`` unless a dataset is chosen)."""
    dataset = [] if any(o.lstrip("+~").startswith("dataset=") for o in overrides) else ["dataset=files"]
    return hypa_argv("diagnose", ["-m", *dataset, "data.dir=" + ",".join(hydra_quoted(str(f)) for f in folders),
                                  *overrides])


def _shell_word(word: str) -> str:
    """``word`` as a shell reads it back, in double quotes where it holds Hydra's single quotes."""
    if "'" in word and not re.search(r'["$`\\!]', word):
        return f'"{word}"'
    return shlex.quote(word)


F = TypeVar("F", bound=Callable[..., Any])


@user_errors("hypa fleet")
def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="hypa fleet", description=FLEET_DOC.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("run", help="diagnose every log folder that the globs match, then summarize")
    run.add_argument("logs", nargs="+", metavar="LOG_OR_GLOB|KEY=VALUE",
                     help="log folders or globs (quoted: 'logs/*/'); arguments with = go to hypa diagnose")
    summary = commands.add_parser("summary", help="(re)build fleet.md and fleet.json of an existing sweep folder")
    summary.add_argument("sweep_dir", type=Path)
    args = parser.parse_args(argv)
    if args.command == "summary":
        print(report(write_summary(args.sweep_dir)), flush=True)
        return 0
    overrides = [a for a in args.logs if "=" in a]
    patterns = [a for a in args.logs if "=" not in a]
    if not patterns:
        raise UserError("no log folder given; e.g. hypa fleet run 'logs/*/'")
    command = diagnose_command(expand_logs(patterns), overrides)
    print("python " + " ".join(_shell_word(word) for word in command[1:]), flush=True)
    return subprocess.run(command, check=False).returncode


class FleetSummary(Callback):
    """Hydra callback (``hydra.callbacks`` in conf/diagnose.yaml): after the last job of a
    multirun, on the machine that launched it, write the fleet summary into the sweep folder.
    Like ``make -k``, the sweep goes on past a failed log but its exit status is 1 if any failed,
    or if the summary cannot be written (Hydra would only warn of an error raised here)."""

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        try:
            fleet = write_summary(Path(str(config.hydra.sweep.dir)))
        except Exception as error:  # noqa: BLE001 (Hydra would turn it into a warning and exit 0)
            if not is_user_error(error) or full_error_requested():
                traceback.print_exc()
            print(f"hypa {JOB_NAME}: error: fleet summary: {one_line(error)}", file=sys.stderr, flush=True)
            sys.exit(1)
        print(report(fleet), flush=True)
        if len(fleet.diagnosed) < len(fleet.logs):
            sys.exit(1)


def record_failures(command: str) -> Callable[[F], F]:
    """In a multirun, a job that fails writes its one-line error to ``error.json`` in its folder
    and returns, so one bad log does not end the sweep (Hydra's sweepers stop at a failed job and
    skip the callbacks) and the summary shows it as failed. A user error prints
    ``<command>: error: <message>``, a bug its traceback. In a single run the error passes on
    (to :func:`hypa.core.errors.user_errors` above)."""
    def decorate(main: F) -> F:
        @functools.wraps(main)
        def wrapped(*args: Any, **kwargs: Any) -> Any:
            from hydra.core.hydra_config import HydraConfig
            from hydra.types import RunMode

            try:
                return main(*args, **kwargs)
            except Exception as error:
                if HydraConfig.get().mode != RunMode.MULTIRUN:
                    raise
                user = is_user_error(error)
                message = str(error) if user else f"{type(error).__name__}: {error}"
                one_line = " ".join(message.split())
                folder = Path(HydraConfig.get().runtime.output_dir)
                (folder / ERROR_FILE).write_text(json.dumps({"error": one_line, "user_error": user}, indent=2))
                if user and not full_error_requested():
                    print(f"{command}: error: {one_line}", file=sys.stderr, flush=True)
                else:
                    traceback.print_exc()
                return None

        return wrapped  # type: ignore[return-value]

    return decorate


if __name__ == "__main__":
    sys.exit(main())
