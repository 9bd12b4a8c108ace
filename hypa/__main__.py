"""``python -m hypa <command> [arguments]``, the same as the ``hypa`` console script (:mod:`hypa.commands.cli`)."""

import sys

from hypa.commands.cli import main

if __name__ == "__main__":
    sys.exit(main())
