"""hypa timing [physics|diagnosis|fmu] [options]: see :mod:`hypa.commands.timing`."""

from __future__ import annotations

import sys

PARTS = ("physics", "diagnosis", "fmu")


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in ("-h", "--help"):
        print(__doc__.strip() + "\n\n  physics    the physics blocks' speed (hypa timing physics --help)\n"
              "  diagnosis  the time to name causes (hypa timing diagnosis --help)\n"
              "  fmu        an FMU block's sample loops, C against Python (hypa timing fmu --help)")
        return 0
    if argv and not argv[0].startswith("-") and argv[0] not in PARTS:
        print(f"hypa timing: error: unknown part {argv[0]!r}; choose one of {', '.join(PARTS)} (or none: both)",
              file=sys.stderr)
        return 2
    parts = [argv.pop(0)] if argv and argv[0] in PARTS else list(PARTS)
    if len(parts) > 1 and argv:
        print("hypa timing: error: options go after a part: hypa timing physics|diagnosis|fmu [options]",
              file=sys.stderr)
        return 2
    status = 0
    for part in parts:
        if part == "physics":
            from hypa.commands.timing.physics import main as run
        elif part == "fmu":
            from hypa.commands.timing.fmu import main as run
        else:
            from hypa.commands.timing.diagnosis import main as run
        status = run(argv) or status
    return status


if __name__ == "__main__":
    sys.exit(main())
