"""Deprecated: ``python -m hypa.bench_diagnosis`` is ``python -m hypa.speed diagnosis``
(:mod:`hypa.commands.speed.diagnosis`)."""

from __future__ import annotations

import sys

from hypa.commands.speed.diagnosis import main

if __name__ == "__main__":
    print("hypa.bench_diagnosis is deprecated: use python -m hypa.speed diagnosis", file=sys.stderr)
    sys.exit(main())
