"""Benchmark: how long ``hypa diagnose`` takes to name the causes on the default test bench.

    hypa timing diagnosis [--seconds S] [--cache-dir PATH]

Times the one engine's naming (:func:`hypa.diagnosis.search.name_causes`) from the nominal
model ``conf/model/vehicle_nominal.yaml`` with the settings ``hypa diagnose`` uses
(first-order hold, windows of ``data.window`` = 100 samples, the built-in catalogues, at most
``MAX_CAUSES`` causes). Default data: the default test bench (``TestbenchConfig()``: 2 training records of
5 min and a 3 min validation record at 1024 Hz), decimated to 32 Hz by ``HypaDataModule`` as
the entry point does. Data generation (or finding it in the cache) and reading are not timed.

Prints the data size, the named causes with their fitted values, the time of each search round
(each fits every candidate of the catalogue against the model named so far) and the total;
goal: the total <= 10 s on 2 cores. ``--seconds S`` shortens every record to S s of stochastic
excitation without manoeuvres and stops after the first round (which cause comes first): a quick
check; the goal is only judged on the default data.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

from hypa.conf import CONF

ENGINE_GOAL_S = 10.0  # [s] the engine's naming (hypa diagnose model=vehicle_nominal) on the default data, 2 cores
NOMINAL = CONF / "model" / "vehicle_nominal.yaml"
MAX_CAUSES = 8  # as conf/diagnose.yaml's diagnosis.max_causes
QUICK_MAX_CAUSES = 1  # --seconds: the first round only


def testbench_config(seconds: float | None):
    """The default test bench, or every record shortened to ``seconds`` of stochastic excitation."""
    from hypa.paper.testbench import TestbenchConfig

    if seconds is None:
        return TestbenchConfig()
    return TestbenchConfig.from_dict({"records": {name: {"stochastic_duration_s": float(seconds), "maneuvers": []}
                                                  for name in ("train_1", "train_2", "val")}})


def run(seconds: float | None = None, cache_dir: Path | None = None, hold: str = "foh") -> dict[str, Any]:
    """Generate (or find) and read the data (not timed), then time the engine's naming.

    Returns the data sizes, the :class:`~hypa.diagnosis.search.Search`, ``engine_s`` (the wall
    time of ``name_causes``), ``setup_s`` (of it: the training windows, the validation stretches
    and the nominal model's score) and ``round_s`` (each search round's wall time)."""
    import yaml

    from hypa.data import HypaDataModule
    from hypa.diagnosis.problem import Problem
    from hypa.diagnosis.search import name_causes
    from hypa.models.spec import parse_model_spec
    from hypa.paper.testbench import ensure_dataset
    from hypa.paper.testbench.sensors import TESTBENCH_CHANNELS
    from hypa.vehicle import VehicleParameters

    folder = ensure_dataset(testbench_config(seconds), cache_dir)
    dm = HypaDataModule(folder, TESTBENCH_CHANNELS)  # window 100, 32 Hz: the defaults of conf/dataset/testbench.yaml
    dm.setup()
    train, val = dm.records("train"), dm.records("val")
    spec = parse_model_spec(yaml.safe_load(NOMINAL.read_text()))
    problem = Problem(dm, VehicleParameters().as_dict(), hold=hold, horizon=dm.window)
    marks: list[tuple[str, float]] = []  # the engine reports after the nominal score and after each named cause
    started = time.perf_counter()
    search = name_causes(spec, problem, max_causes=MAX_CAUSES if seconds is None else QUICK_MAX_CAUSES,
                         progress=lambda text: marks.append((text, time.perf_counter())))
    engine_s = time.perf_counter() - started
    ends = [t - started for text, t in marks if text.startswith("named ")][: len(search.named)]
    if len(search.rounds) > len(ends):  # the last round named nothing: it ends with the search
        ends.append(engine_s)
    setup_s = next((t - started for text, t in marks if text.startswith("nominal model")), engine_s)
    round_s = [b - a for a, b in zip([setup_s, *ends], ends)]
    return {"train_records": len(train), "val_records": len(val),
            "train_samples": sum(len(r) for r in train), "val_samples": sum(len(r) for r in val),
            "dt": dm.dt, "search": search, "engine_s": engine_s, "setup_s": setup_s, "round_s": round_s}


REAL = ("racecar", "silverbox", "emps")  # the bundled real data sets (../shared/data), each with its nominal model
REAL_GOAL_S = 30.0  # [s] the naming on each of them, 2 cores


def run_dataset(name: str) -> dict[str, Any]:
    """Time the naming on a bundled real data set with its own nominal model, as
    ``hypa diagnose dataset=NAME`` runs it (reading the data is not timed)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from hypa.commands.config import register_configs
    from hypa.commands.entry import datamodule, vehicle_from_config
    from hypa.diagnosis.problem import Problem, nominal_hold
    from hypa.diagnosis.search import name_causes
    from hypa.models.spec import parse_model_spec

    register_configs()  # the schemas and resolvers conf/diagnose.yaml composes with
    with initialize_config_dir(config_dir=str(NOMINAL.parents[1]), version_base=None):
        cfg = compose("diagnose", overrides=[f"dataset={name}"])
    if not Path(str(cfg.data.dir)).is_dir():
        return {"missing": str(cfg.data.dir)}
    dm = datamodule(cfg)
    dm.setup()
    spec = parse_model_spec(OmegaConf.to_container(cfg.model, resolve=True))
    values = vehicle_from_config(cfg.vehicle).as_dict() if cfg.get("vehicle") else {}
    problem = Problem(dm, values, hold=nominal_hold(spec, cfg.physics.hold), horizon=int(cfg.data.window))
    started = time.perf_counter()
    search = name_causes(spec, problem, max_causes=int(cfg.diagnosis.max_causes))
    return {"search": search, "engine_s": time.perf_counter() - started}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=None,
                        help="shorten every record to this many seconds and time the first round only "
                             "(default: the full default test bench, every round)")
    parser.add_argument("--real", action=argparse.BooleanOptionalAction, default=True,
                        help="also time the naming on each bundled real data set found in ../shared/data "
                             "(default: on; --no-real skips them)")
    parser.add_argument("--cache-dir", type=Path, default=None,
                        help="test-bench cache (default: $HYPA_CACHE_DIR/testbench or ~/.cache/hypa/testbench)")
    args = parser.parse_args(argv)
    import torch

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(f"diagnosis benchmark: {cores} cores available, torch uses {torch.get_num_threads()} threads; "
          "generating or finding the test-bench data (not timed)", flush=True)
    r = run(args.seconds, args.cache_dir)
    search = r["search"]
    print(f"data: {r['train_records']} training records, {r['train_samples']} samples "
          f"({r['train_samples'] * r['dt'] / 60:.1f} min); {r['val_records']} validation records, "
          f"{r['val_samples']} samples ({r['val_samples'] * r['dt'] / 60:.1f} min); at {1.0 / r['dt']:g} Hz "
          "after decimation")
    error = "cross-validated error" if search.folds > 1 else "validation error"
    print(f"the engine's naming (hypa diagnose model=vehicle_nominal): {error} "
          f"{100 * search.nominal_score:.3g} % of the output variance (nominal) -> {100 * search.final_score:.3g} % "
          "(named causes applied)")
    print(f"named causes ({len(search.named)}):")
    for k, finding in enumerate(search.named, 1):
        print(f"  {k}. {finding.describe()}   ({error} {100 * finding.gain:.0f} % lower)")
    if not search.named:
        print("  none")
    print("wall time of the naming (hypa.diagnosis.search.name_causes):")
    width = 64
    print(f"  {'setup (training windows, validation stretches, nominal score):':{width}}{r['setup_s']:8.2f} s")
    for k, (seconds, findings) in enumerate(zip(r["round_s"], search.rounds), 1):
        outcome = f"named {search.named[k - 1].cause}" if k <= len(search.named) else "nothing left to name"
        print(f"  {f'round {k} ({len(findings)} candidates):':{width}}{seconds:8.2f} s   ({outcome})")
    print(f"  {'total:':{width}}{r['engine_s']:8.2f} s")
    if args.seconds is None:
        met = r["engine_s"] <= ENGINE_GOAL_S
        print(f"goal: the engine's naming <= {ENGINE_GOAL_S:g} s on 2 cores ({cores} here): "
              f"{'met' if met else 'NOT met'}")
    else:
        print(f"quick check (first round only; goal <= {ENGINE_GOAL_S:g} s on 2 cores judged only on the default "
              "data: run without --seconds)")
    if args.real and args.seconds is None:
        for name in REAL:
            d = run_dataset(name)
            if "missing" in d:
                print(f"{name}: no data in {d['missing']}, skipped")
                continue
            named = ", ".join(f.cause for f in d["search"].named) or "none"
            met = d["engine_s"] <= REAL_GOAL_S
            print(f"{name} (hypa diagnose dataset={name}): named {named} in {d['engine_s']:.1f} s; "
                  f"goal <= {REAL_GOAL_S:g} s on 2 cores: {'met' if met else 'NOT met'}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
