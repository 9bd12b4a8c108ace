"""Benchmark: the lifted physics block against the step-by-step recursion and a bare matmul.

    hypa timing physics [--batch 32] [--horizons 25 50 100 200 400 800] [--min-time 0.3]
                         [--scheduled-only]

Prints forward+backward wall times and the ratios measured in this one run (absolute times
depend on the machine; the ratios are what the lifted form is for). Goals at N = 100, B = 32:
frozen physics >= 30x faster than the recursion and <= 2x a bare matmul of the same shape;
trainable physics (lifted matrices rebuilt every step) >= 5x faster than the recursion.

Then the velocity-scheduled single track at N = 100 (matrices per sample: one batched call of
the system's batch-safe code, verified once against vmap; one batched hold exponential of the
n x n A dt; a parallel-prefix scan with a hand-written adjoint), forward and forward+backward,
against the python recursion over the same per-sample matrices and against the constant-matrix
lifted block (trainable cf, cr in all three). Goals: scheduled <= 10x the lifted block's forward
(which, without gradients, is its cached window matrices times the inputs) and <= 3x its
forward+backward. A quick run of this part alone: ``hypa timing physics --scheduled-only --min-time 0.1``.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable

import torch
from torch.utils.benchmark import Timer

from hypa.physics import LTIBlock, Scaling, simulate_recursive
from hypa.physics.scheduled import simulate_scheduled_recursive
from hypa.vehicle import SingleTrack, VehicleParameters, vehicle_parameters

GOALS = {"frozen_vs_recursion": 30.0, "frozen_vs_matmul": 2.0, "trainable_vs_recursion": 5.0,
         "scheduled_vs_lifted": 10.0, "scheduled_vs_lifted_backward": 3.0}


def _time(fn: Callable[[], None], min_time: float) -> float:
    """Median seconds per call."""
    fn()  # warm-up (and builds any cache)
    return Timer(stmt="fn()", globals={"fn": fn}).blocked_autorange(min_run_time=min_time).median


def _vehicle_block(horizon: int, trainable: bool, scheduled: tuple[str, ...] = (), table: bool = False) -> LTIBlock:
    t = lambda *v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    scaling = Scaling(t(0.0, 0.0), t(0.09, 0.012), t(0.0, 0.0), t(0.02, 0.003), t(0.0, 0.0), t(0.09, 0.012))
    params = vehicle_parameters(VehicleParameters(), trainable=["cf", "cr"] if trainable else [])
    return LTIBlock(SingleTrack(), params, dt=1 / 32, horizon=horizon, scaling=scaling, scheduled=scheduled,
                    table=table)


def measure_scheduled(horizon: int, batch: int, min_time: float) -> dict[str, float]:
    """Seconds of the scheduled block, the per-sample recursion and the lifted block; forward and +backward."""
    x0 = torch.randn(batch, 2, requires_grad=True)
    u = torch.randn(batch, horizon, 2, requires_grad=True)
    velocity = torch.linspace(5.0, 30.0, horizon).expand(batch, horizon)[..., None] + torch.rand(batch, horizon, 1)
    scheduled = _vehicle_block(horizon, trainable=True, scheduled=("velocity",))
    lifted = _vehicle_block(horizon, trainable=True)
    table = _vehicle_block(horizon, trainable=True, scheduled=("velocity",), table=True)

    def recursion() -> torch.Tensor:  # the same per-sample matrices, then one python step per sample
        return simulate_scheduled_recursive(scheduled.normalized_rows(velocity), 1, x0, u)

    def naive() -> torch.Tensor:  # each step builds its own matrices (for the batch), then steps
        x, states = x0, []
        for j in range(horizon):
            rows = scheduled.normalized_rows(velocity[:, j : j + 1])  # (B, 1, n, n + m + 1)
            x = simulate_scheduled_recursive(rows, 1, x, u[:, j : j + 1])[:, 0]
            states.append(x)
        return torch.stack(states, 1)

    variants = {"scheduled": lambda: scheduled(x0, u, velocity), "table": lambda: table(x0, u, velocity),
                "recursion": recursion, "naive": naive, "lifted": lambda: lifted(x0, u)}
    times: dict = {}
    for name, fn in variants.items():
        with torch.no_grad():
            times[name] = _time(fn, min_time)
        times[name + "_backward"] = _time(lambda fn=fn: fn().sum().backward(), min_time)
    with torch.no_grad():  # what the table costs: its build, its memory, its accuracy beside the exact forward's
        fresh = _vehicle_block(horizon, trainable=True, scheduled=("velocity",), table=True)
        start = time.perf_counter()
        got = fresh(x0, u, velocity)
        times["table_build"] = time.perf_counter() - start - times["table"]
        table = fresh.tables.last[1] if fresh.tables.last else None
        times["table_line"] = fresh.tables.lines[-1] if fresh.tables.lines else "none"
        times["table_bytes"] = table.coefficients.numel() * table.coefficients.element_size() if table else 0
        reference = scheduled(x0.double(), u.double(), velocity.double())
        scale = float(reference.abs().max())
        times["table_error"] = float((got.double() - reference).abs().max()) / scale
        times["exact_error"] = float((scheduled(x0, u, velocity).double() - reference).abs().max()) / scale
    return times


def measure(horizon: int, batch: int, min_time: float) -> dict[str, float]:
    """Forward+backward seconds of each variant for one horizon."""
    n, m = 2, 2
    x0 = torch.randn(batch, n, requires_grad=True)
    u = torch.randn(batch, horizon, m, requires_grad=True)
    frozen = _vehicle_block(horizon, trainable=False)
    trainable = _vehicle_block(horizon, trainable=True)
    weight = torch.randn(horizon * n, horizon * m)

    def lifted_frozen() -> None:
        frozen(x0, u).sum().backward()

    def recursion_frozen() -> None:
        with torch.no_grad():
            norm = frozen.lifted(torch.float32)[1]
        simulate_recursive(norm.a, norm.b_taps, norm.h, x0, u).sum().backward()

    def bare_matmul() -> None:
        (u.reshape(batch, -1) @ weight.T).sum().backward()

    def lifted_trainable() -> None:
        trainable(x0, u).sum().backward()

    def recursion_trainable() -> None:
        norm = trainable.normalized(torch.float32)
        simulate_recursive(norm.a, norm.b_taps, norm.h, x0, u).sum().backward()

    variants = {"lifted_frozen": lifted_frozen, "recursion_frozen": recursion_frozen, "bare_matmul": bare_matmul,
                "lifted_trainable": lifted_trainable, "recursion_trainable": recursion_trainable}
    return {name: _time(fn, min_time) for name, fn in variants.items()}


def ratios(t: dict[str, float]) -> dict[str, float]:
    return {
        "frozen_vs_recursion": t["recursion_frozen"] / t["lifted_frozen"],
        "frozen_vs_matmul": t["lifted_frozen"] / t["bare_matmul"],
        "trainable_vs_recursion": t["recursion_trainable"] / t["lifted_trainable"],
    }


def _print_goals(checks: list[tuple[str, float, str, float]]) -> None:
    """One line per (label, measured ratio, ">=" or "<=", goal): the ratio and whether it meets the goal."""
    for label, value, op, goal in checks:
        ok = value >= goal if op == ">=" else value <= goal
        print(f"  {label:<32} {value:8.2f}x  (goal {op} {goal:g}x)  {'met' if ok else 'NOT met'}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--horizons", type=int, nargs="+", default=[25, 50, 100, 200, 400, 800])
    parser.add_argument("--min-time", type=float, default=0.3, help="seconds of timing per variant")
    parser.add_argument("--threads", type=int, default=1,
                        help="intra-op threads (default 1: these matrices are too small to split)")
    parser.add_argument("--scheduled-only", action="store_true", help="only the scheduled block's table")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, batch {args.batch}, "
          "single-track block (n=2, m=2), median of repeated runs\n")
    if not args.scheduled_only:
        _constant_table(args)
    t = measure_scheduled(100, args.batch, args.min_time)
    print(f"scheduled single track (velocity per sample, trainable cf, cr), N = 100, batch {args.batch}:")
    print(f"  {'':<17} {'scheduled':>10} {'table':>10} {'recursion':>10} {'naive':>10} {'lifted':>10}"
          f" {'sched/lifted':>13} {'table/lifted':>13} {'rec/sched':>10}")
    for label, key in (("forward", ""), ("forward+backward", "_backward")):
        s, b, r, a, c = (t[name + key] for name in ("scheduled", "table", "recursion", "naive", "lifted"))
        print(f"  {label:<17} {s * 1e3:9.3f}m {b * 1e3:9.3f}m {r * 1e3:9.3f}m {a * 1e3:9.3f}m {c * 1e3:9.3f}m"
              f" {s / c:12.1f}x {b / c:12.1f}x {r / s:9.1f}x")
    print("  times in ms; scheduled: the matrices of every sample computed exactly; table: the same block with\n"
          "  table: true (read off a verified interpolation table where no gradient needs them: its forward;\n"
          "  its forward+backward computes them exactly, as scheduled); recursion: all per-sample matrices at\n"
          "  once, then a python loop over the samples; naive: the loop builds each sample's matrices too;\n"
          "  lifted: the constant-matrix block (eq. 11) at one velocity (its forward without gradients\n"
          "  multiplies cached window matrices, as the table's reads a cached table)")
    print(f"  the table: {t['table_line']}; built in {t['table_build'] * 1e3:.1f} ms, "
          f"{t['table_bytes'] / 1024:.0f} KiB;"
          f" the table's forward deviates {t['table_error']:.1e} from float64, the exact float32 forward"
          f" {t['exact_error']:.1e} (of the largest output)")
    print("\ngoals, scheduled at N = 100:")
    _print_goals([
        ("forward: scheduled / lifted", t["scheduled"] / t["lifted"], "<=", GOALS["scheduled_vs_lifted"]),
        ("forward: table / lifted", t["table"] / t["lifted"], "<=", GOALS["scheduled_vs_lifted"]),
        ("fwd+bwd: scheduled / lifted", t["scheduled_backward"] / t["lifted_backward"], "<=",
         GOALS["scheduled_vs_lifted_backward"]),
    ])
    return 0


def _constant_table(args: argparse.Namespace) -> None:
    """The constant-matrix block's table (forward+backward) and its goals at N = 100."""
    header = (f"{'N':>5} {'lifted':>10} {'recursion':>10} {'matmul':>10} {'lifted*':>10} {'recursion*':>11}"
              f" {'rec/lifted':>11} {'lifted/mm':>10} {'rec*/lifted*':>13}")
    print("constant-matrix block, forward+backward:\n" + header + "\n" + "-" * len(header))
    results = {}
    for horizon in args.horizons:
        t = measure(horizon, args.batch, args.min_time)
        r = ratios(t)
        results[horizon] = r
        ms = lambda k: f"{t[k] * 1e3:9.3f}m"  # noqa: E731, B023 -- called in this iteration
        print(f"{horizon:>5} {ms('lifted_frozen'):>10} {ms('recursion_frozen'):>10} {ms('bare_matmul'):>10}"
              f" {ms('lifted_trainable'):>10} {ms('recursion_trainable'):>11}"
              f" {r['frozen_vs_recursion']:>10.1f}x {r['frozen_vs_matmul']:>9.2f}x"
              f" {r['trainable_vs_recursion']:>12.1f}x",
              flush=True)
    print("\ntimes in ms; * = trainable physical parameters (cf, cr): lifted matrices rebuilt every step")
    if 100 in results:
        r = results[100]
        print("\ngoals at N = 100:")
        _print_goals([
            ("frozen: recursion / lifted", r["frozen_vs_recursion"], ">=", GOALS["frozen_vs_recursion"]),
            ("frozen: lifted / bare matmul", r["frozen_vs_matmul"], "<=", GOALS["frozen_vs_matmul"]),
            ("trainable: recursion / lifted", r["trainable_vs_recursion"], ">=", GOALS["trainable_vs_recursion"]),
        ])
    print()


if __name__ == "__main__":
    sys.exit(main())
