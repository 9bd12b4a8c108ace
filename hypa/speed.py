"""``python -m hypa.speed [physics|diagnosis]``: the command is :mod:`hypa.commands.speed`."""

import sys

from hypa.commands.speed.main import main

if __name__ == "__main__":
    sys.exit(main())
