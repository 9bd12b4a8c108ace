"""``hypa fleet run 'logs/*/' | summary DIR``: a fleet of logs diagnosed, then summarized.

The library part (reading each log's diagnosis, the summary table, the Hydra callback that writes it
after a sweep) is :mod:`hypa.diagnosis.fleet`; this is the command line around it.
"""

from __future__ import annotations

import argparse
import glob
import os
import re
import shlex
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

from hypa.commands.launch import hypa_argv
from hypa.core.errors import UserError, user_errors
from hypa.diagnosis.fleet import __doc__ as FLEET_DOC
from hypa.diagnosis.fleet import report, write_summary


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


if __name__ == "__main__":
    sys.exit(main())
