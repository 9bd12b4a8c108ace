"""Benchmark: an FMU as a physics block, its sample loops in C against the same loops in Python.

    hypa timing fmu --fmu PATH [--samples 2000] [--repeat 3] [--reference single_track]

Runs the FMU over ``--samples`` samples of a smooth random input on each of its interfaces (model exchange:
hypa's RK4, and the sensitivities a gradient through it needs; co-simulation: its own steps), with the C loops
(``hypa.physics.fmu_loop``) and with the Python loops, and prints the time per sample of each (the best of
``--repeat`` runs) and the ratios measured in this one run; then the time of one identification step (one free
run per trainable parameter and one more) on that record, taking all the FMU's Real parameters as trainable;
with ``--reference single_track``, hypa's own single-track class (the tests' FMU's physics) over the same
samples, one record and 32 at once. The goal: the C loop at least 20x faster than the Python loop in model
exchange. Where no FMU is given the part says so and ends (``make timing`` runs it without one: give ``--fmu``
with an FMU of yours; ``make timing-fmu`` builds the tests' single-track FMU and times it).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np

GOAL = 20.0  # model exchange: the C loop this many times faster than the Python loop, at least


def _best(fn: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        started = time.perf_counter()
        fn()
        times.append(time.perf_counter() - started)
    return min(times)


def measure(path: str, samples: int, repeat: int) -> list[tuple[str, float, float | None]]:
    """(what, seconds per sample with the C loop, with the Python loop or None) for each interface."""
    from hypa.physics import fmu_loop
    from hypa.physics.fmu import FMUSimulator, read_fmu

    description = read_fmu(path)
    fed = description.input_names
    rng = np.random.default_rng(0)
    u = np.cumsum(rng.normal(size=(samples, len(fed))), axis=0) * 0.01
    dt = description.step or 0.01
    rows: list[tuple[str, float, float | None]] = []
    offered = (("model_exchange", description.exchange), ("co_simulation", description.cosimulation))
    interfaces = [interface for interface, identifier in offered if identifier]
    for interface in interfaces:
        seconds: dict[bool, tuple[float, float | None]] = {}
        for native in ((True, False) if fmu_loop.available() else (False,)):
            simulator = FMUSimulator(description, interface, native=native)
            try:
                run = simulator.run({}, fed, u, 0.0, dt)
                free = _best(lambda: simulator.run({}, fed, u, 0.0, dt), repeat) / samples  # noqa: B023
                sensitivities = None
                if interface == "model_exchange" and simulator.n:
                    sensitivities = _best(lambda: simulator.sensitivities(fed, u, run, 0.0, dt), 1) / samples  # noqa: B023
            finally:
                simulator.close()
            seconds[native] = (free, sensitivities)
        c, python = seconds.get(True, (None, None)), seconds[False]
        name = interface.replace("_", " ")
        rows.append((f"{name}: free run", c[0] or python[0], python[0] if c[0] else None))
        if python[1] is not None:
            rows.append((f"{name}: sensitivities", c[1] or python[1], python[1] if c[1] else None))
        step = (len(description.parameters) + 1) * (c[0] or python[0]) * samples
        rows.append((f"{name}: an identification step ({len(description.parameters)} parameters), per record",
                     step, None))
    return rows


def single_track_class(samples: int, repeat: int) -> list[tuple[str, float, float | None]]:
    """hypa's own single-track class (``hypa.vehicle``, the physics of the tests' FMU) over the same samples: a
    free run of one record and of 32 at once, per sample and record."""
    import torch

    from hypa.commands.timing.physics import _vehicle_block

    block = _vehicle_block(samples, trainable=False)
    rows = []
    for batch in (1, 32):
        x0, u = torch.zeros(batch, 2), torch.randn(batch, samples, 2)
        with torch.no_grad():
            block(x0, u)
            seconds = _best(lambda: block(x0, u), repeat)  # noqa: B023
        rows.append((f"hypa's single-track class: free run, {batch} record(s) at once", seconds / samples / batch,
                     None))
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="hypa timing fmu", description=__doc__.split("\n\n")[0])
    parser.add_argument("--fmu", help="the FMU to time (FMI 2.0 or 3.0)")
    parser.add_argument("--samples", type=int, default=2000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--reference", choices=["single_track"],
                        help="also time hypa's own class of the same physics (single_track: hypa.vehicle's)")
    args = parser.parse_args(argv)
    if not args.fmu:
        print("fmu: skipped: give an FMU to time, hypa timing fmu --fmu PATH (make timing-fmu times the tests' "
              "single-track FMU)\n")
        return 0
    from hypa.physics import fmu_loop

    rows = measure(args.fmu, args.samples, args.repeat)
    if args.reference == "single_track":
        rows += single_track_class(args.samples, args.repeat)
    print(f"FMU {args.fmu}, {args.samples} samples, the best of {args.repeat} runs; C loop: "
          f"{'yes' if fmu_loop.available() else 'no (no C compiler here)'}")
    print(f"  {'':<62} {'C loop':>12} {'Python loop':>12} {'ratio':>7}")
    for what, c, python in rows:
        per = "per record" in what
        show = (lambda s: f"{s * 1e3:10.1f} ms") if per else (lambda s: f"{s * 1e6:10.2f} µs")
        ratio = f"{python / c:6.0f}x" if python else ""
        print(f"  {what:<62} {show(c):>12} {show(python) if python else '':>12} {ratio:>7}")
    exchange = next(((c, p) for what, c, p in rows if what == "model exchange: free run" and p), None)
    if exchange:
        ratio = exchange[1] / exchange[0]
        print(f"\ngoal: model exchange, Python loop / C loop {ratio:.0f}x (goal >= {GOAL:g}x) "
              f"{'met' if ratio >= GOAL else 'NOT met'}")
    print()
    return 0
