"""Deprecated: ``python -m hypa.bench`` is ``python -m hypa.speed physics`` (:mod:`hypa.commands.speed.physics`)."""

from __future__ import annotations

import sys

from hypa.commands.speed.physics import main

if __name__ == "__main__":
    print("hypa.bench is deprecated: use python -m hypa.speed physics", file=sys.stderr)
    sys.exit(main())
