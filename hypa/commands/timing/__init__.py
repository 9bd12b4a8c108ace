"""How fast hypa is, measured: ``hypa timing [physics|diagnosis|fmu] [options]``.

- ``physics`` (:mod:`hypa.commands.timing.physics`): the lifted physics block against the step-by-step
  recursion and a bare matmul, and the speed-scheduled block against both; ratios measured in
  one run, against their goals.
- ``diagnosis`` (:mod:`hypa.commands.timing.diagnosis`): how long ``hypa diagnose`` takes to name the
  causes, on the default test bench and each bundled real data set, against its goals.

- ``fmu`` (:mod:`hypa.commands.timing.fmu`): an FMU block's sample loops in C against the same loops
  in Python, per sample, and an identification step (``--fmu PATH``; without one it is skipped).

Without a part, all run (``make timing``). Speed is measured here, never asserted in a test:
CI machines are shared and noisy. (The accuracy benchmark on real data is ``hypa benchmark``.)
"""
