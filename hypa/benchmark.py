"""Benchmark hypa on a real data set: physics only, an end-to-end LSTM and a hybrid.

    python -m hypa.benchmark dataset=silverbox            # quick budget: minutes
    python -m hypa.benchmark dataset=emps budget=full     # the benchmark (longer)
    python -m hypa.benchmark dataset=emps budget=full seeds=[0,1,2]   # mean ± std over seeds
    make benchmark ARGS="dataset=racecar budget=full"

Each model of the data set's suite (``conf/benchmark.yaml``) is trained by ``python -m
hypa.train`` in its own run folder below this run's, then simulated free-running over every
test set, once per seed of ``seeds``. Prints and writes ``benchmark.md`` and ``benchmark.json``
(RMS in SI units, R², training time; means and standard deviations over the seeds, and each
seed) beside the published figures.
"""

from __future__ import annotations

import json
import logging
import subprocess
import sys
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from hypa.errors import UserError, hydra_command

log = logging.getLogger(__name__)


def train_model(label: str, overrides: list[str], folder: Path) -> None:
    """Train one model through the command line a user types (its progress on the console)."""
    command = [sys.executable, "-m", "hypa.train", *overrides, f"hydra.run.dir={folder}"]
    log.info("training %s: %s", label, " ".join(command[1:]))
    result = subprocess.run(command)
    if result.returncode != 0:
        raise UserError(f"training {label} failed (exit status {result.returncode}); "
                        f"run it alone: python {' '.join(command[1:])}")


@hydra_command("hypa.benchmark", "benchmark")
def main(cfg: DictConfig) -> None:
    from hypa.evaluate import run_datamodule
    from hypa.evaluation.benchmark import benchmark_table, score_run, write_benchmark_json
    from hypa.evaluation.runs import load_run

    dataset = HydraConfig.get().runtime.choices["dataset"]
    if dataset not in cfg.suites:
        raise UserError(f"no benchmark suite for dataset={dataset}; suites: {', '.join(cfg.suites)}")
    if cfg.budget not in cfg.budgets:
        raise UserError(f"unknown budget={cfg.budget}; use {' or '.join(cfg.budgets)}")
    suite = cfg.suites[dataset]
    labels = list(cfg.models) if cfg.models else list(suite.models)
    unknown = [m for m in labels if m not in suite.models]
    if unknown:
        raise UserError(f"models {unknown} are not in the {dataset} suite: {', '.join(suite.models)}")
    seeds = [int(s) for s in cfg.seeds]
    if not seeds or len(set(seeds)) != len(seeds):
        raise UserError(f"seeds must name at least one seed, each once; got {seeds}")
    out = Path(HydraConfig.get().runtime.output_dir)
    scores, times = [], {}
    jobs = [(label, seed) for label in labels for seed in seeds]
    for i, (label, seed) in enumerate(jobs, 1):
        print(f"[{i}/{len(jobs)}] {dataset}: {label}" + (f", seed {seed}" if len(seeds) > 1 else ""), flush=True)
        folder = out / label if len(seeds) == 1 else out / f"{label}-seed{seed}"
        overrides = [f"dataset={dataset}", *suite.models[label], *cfg.budgets[cfg.budget], *cfg.train_overrides,
                     f"seed={seed}", f"data.seed={seed}"]  # the networks' start and the windows' order
        train_model(label, overrides, folder)
        run = load_run(folder)
        dm = run_datamodule(run)
        scores += score_run(run, dm, label, seed)
        seconds = float(json.loads((folder / "run.json").read_text()).get("training_time_s", float("nan")))
        times[label] = times.get(label, 0.0) + seconds / len(seeds)
    units = {n: (dm.channels[n].display_unit, dm.channels[n].display_factor) for n in dm.output_names}
    published = OmegaConf.to_container(suite.published, resolve=True)
    table = benchmark_table(scores, times, published, units, dataset)
    (out / "benchmark.md").write_text(table + "\n")
    write_benchmark_json(out / "benchmark.json", dataset, scores, times, published, units)
    print(f"\n{table}\n\nwritten: {out / 'benchmark.md'}, {out / 'benchmark.json'}")


if __name__ == "__main__":
    main()
