"""``hypa <command> [arguments]``: one entry for every command (also ``python -m hypa <command>``).

Each command is a module of :mod:`hypa.commands` with one shape, ``main(argv) -> exit status``:
the Hydra commands take overrides (``hypa train model=v2 ann=lstm``), ``fleet`` and ``timing``
take options (``hypa timing physics --help``). ``hypa`` alone, or ``hypa --help``, lists them.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class Command:
    """A command: the module in :mod:`hypa.commands` that runs it, and what it does in a line."""

    module: str
    summary: str


COMMANDS: dict[str, Command] = {
    "train": Command("train", "train a model, or identify a physics-only one"),
    "evaluate": Command("evaluate", "a trained run against its validation and test data"),
    "simulate": Command("simulate", "a physics model at its configured values against data"),
    "diagnose": Command("diagnose", "what the physics gets wrong, named, and the extended model"),
    "fleet": Command("fleet", "the diagnosis over a fleet of logs, and its summary"),
    "explain": Command("explain", "a trained network explained by physical forms"),
    "benchmark": Command("benchmark", "every model of a data set over seeds, beside published figures"),
    "reproduce": Command("reproduce", "the paper's Table 1 over seeds"),
    "export": Command("export", "a trained model as ONNX, an FMU or state space, checked against hypa"),
    "testbench": Command("testbench", "the paper's simulated test-bench data"),
    "timing": Command("timing.main", "how fast the physics blocks and the diagnosis are"),
}


def usage() -> str:
    """The list of commands, as ``hypa --help`` prints it."""
    width = max(map(len, COMMANDS))
    lines = [f"  {name:<{width}}  {command.summary}" for name, command in COMMANDS.items()]
    return ("usage: hypa <command> [arguments]   (or: python -m hypa <command> ...)\n\ncommands:\n"
            + "\n".join(lines) + "\n\nhypa <command> --help: the command's own settings")


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``hypa <command> ARGUMENTS``: the command's exit status (2 for an unknown command)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return 0 if argv else 2
    name, arguments = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"hypa: error: unknown command {name!r}; one of {', '.join(COMMANDS)} (hypa --help)", file=sys.stderr)
        return 2
    module = importlib.import_module(f"hypa.commands.{COMMANDS[name].module}")
    # Lightning's ddp launcher starts the other ranks as `python -m <__main__.__spec__.name>` with the
    # run's settings: that is the command's own module (each runs alone as `python -m hypa.commands.X`).
    main_module = sys.modules.get("__main__")
    if main_module is not None:
        main_module.__spec__ = module.__spec__
    sys.argv = [f"hypa {name}", *arguments]
    status = module.main(arguments)
    return status if isinstance(status, int) else 0


def deprecated(spelling: str, command: Sequence[str]) -> None:
    """Run a spelling from before ``hypa <command>`` (``hypa train ...``) as the command,
    after one line on stderr that names the new spelling; exits with the command's status."""
    new = " ".join(["hypa", *command])
    print(f"python -m {spelling} is deprecated and goes in the next release: use `{new}`", file=sys.stderr)
    sys.exit(main([*command, *sys.argv[1:]]))
