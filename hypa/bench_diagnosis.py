"""Benchmark: how long ``python -m hypa.diagnose`` takes to name the cause on the default test bench.

    python -m hypa.bench_diagnosis [--seconds S] [--cache-dir PATH]

Default data: the default test bench (``TestbenchConfig()``: 2 training records of 5 min and a
3 min validation record at 1024 Hz), decimated to 32 Hz by ``HypaDataModule`` as the entry
point does. Prints the data size and the wall time of step 1 (``analyze_residuals``) and
step 2 (``name_causes``) separately; goal: both together < 60 s on 2 cores. Then the one
engine's naming with ``conf/model/vehicle_nominal.yaml`` (``hypa.diagnosis.engine``; goal ≤ 10 s). ``--seconds S``
shortens every record to S s of stochastic excitation without manoeuvres (for a quick check;
the goal is only judged on the default data). Data generation is not timed.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

GOAL_S = 60.0  # [s] steps 1 + 2 on the default data, 2 cores
ENGINE_GOAL_S = 10.0  # [s] the one engine's naming (hypa.diagnose model=vehicle_nominal), 2 cores
NOMINAL = Path(__file__).resolve().parents[1] / "conf" / "model" / "vehicle_nominal.yaml"


def testbench_config(seconds: float | None):
    """The default test bench, or every record shortened to ``seconds`` of stochastic excitation."""
    from hypa.testbench import TestbenchConfig

    if seconds is None:
        return TestbenchConfig()
    return TestbenchConfig.from_dict({"records": {name: {"stochastic_duration_s": float(seconds), "maneuvers": []}
                                                  for name in ("train_1", "train_2", "val")}})


def run(seconds: float | None = None, cache_dir: Path | None = None, hold: str = "foh",
        rear_steering: str = "none") -> dict[str, float]:
    """Generate (or find) the data, then time steps 1 and 2; returns the sizes and seconds."""
    from hypa.data import HypaDataModule
    from hypa.diagnosis import analyze_residuals, name_causes
    from hypa.vehicle import VehicleParameters
    from hypa.testbench import ensure_dataset

    folder = ensure_dataset(testbench_config(seconds), cache_dir)
    dm = HypaDataModule(folder)
    dm.setup()
    train, val = dm.records("train"), dm.records("val")
    vehicle = VehicleParameters()  # the nominal sedan of conf/vehicle/sedan.yaml
    started = time.perf_counter()
    analyze_residuals(val, vehicle, dm.dt, hold=hold, rear_steering=rear_steering)
    residuals_s = time.perf_counter() - started
    started = time.perf_counter()
    diagnosis = name_causes(train, val, vehicle, dm.dt, hold=hold, rear_steering=rear_steering)
    naming_s = time.perf_counter() - started
    import yaml

    from hypa.diagnosis.engine import Problem
    from hypa.diagnosis.engine import name_causes as name_with_engine
    from hypa.models.spec import parse_model_spec

    spec = parse_model_spec(yaml.safe_load(NOMINAL.read_text()))
    started = time.perf_counter()
    # a quick check (--seconds) times the first round only: which cause comes first
    search = name_with_engine(spec, Problem(dm, vehicle.as_dict(), hold=hold, horizon=100),
                              max_causes=5 if seconds is None else 1)
    engine_s = time.perf_counter() - started
    return {"train_records": len(train), "val_records": len(val),
            "train_samples": sum(len(r) for r in train), "val_samples": sum(len(r) for r in val),
            "dt": dm.dt, "analyze_residuals_s": residuals_s, "name_causes_s": naming_s,
            "causes": diagnosis.causes, "engine_s": engine_s, "engine_causes": [f.cause for f in search.named]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=None,
                        help="shorten every record to this many seconds (default: the full default test bench)")
    parser.add_argument("--cache-dir", type=Path, default=None,
                        help="test-bench cache (default: $HYPA_CACHE_DIR/testbench or ~/.cache/hypa/testbench)")
    args = parser.parse_args(argv)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(f"diagnosis benchmark: {cores} cores available; generating or finding the test-bench data "
          "(not timed)", flush=True)
    r = run(args.seconds, args.cache_dir)
    rate = 1.0 / r["dt"]
    print(f"data: {r['train_records']} training records, {r['train_samples']} samples "
          f"({r['train_samples'] * r['dt'] / 60:.1f} min); {r['val_records']} validation records, "
          f"{r['val_samples']} samples ({r['val_samples'] * r['dt'] / 60:.1f} min); at {rate:g} Hz after decimation")
    total = r["analyze_residuals_s"] + r["name_causes_s"]
    print(f"step 1 analyze_residuals: {r['analyze_residuals_s']:8.2f} s")
    print(f"step 2 name_causes:       {r['name_causes_s']:8.2f} s   (named: {', '.join(r['causes']) or 'none'})")
    print(f"total:                    {total:8.2f} s")
    print(f"the one engine (hypa.diagnose model=vehicle_nominal), naming: {r['engine_s']:8.2f} s   "
          f"(named: {', '.join(r['engine_causes']) or 'none'})")
    if args.seconds is None:
        print(f"goal: steps 1 + 2 < {GOAL_S:g} s on 2 cores ({cores} here): {'met' if total < GOAL_S else 'NOT met'}")
        print(f"goal: the engine's naming <= {ENGINE_GOAL_S:g} s on 2 cores: "
              f"{'met' if r['engine_s'] <= ENGINE_GOAL_S else 'NOT met'}")
    else:
        print(f"goal (< {GOAL_S:g} s on 2 cores) judged only on the default data (run without --seconds)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
