"""Benchmark hypa on a real data set: physics only, an end-to-end LSTM and a hybrid.

    python -m hypa.benchmark dataset=silverbox            # quick budget: minutes
    python -m hypa.benchmark dataset=emps budget=full     # the benchmark (longer)
    make benchmark ARGS="dataset=racecar budget=full"

Each model of the data set's suite (``conf/benchmark.yaml``) is trained by ``python -m
hypa.train`` in its own run folder below this run's, then simulated free-running over every
test set. Prints and writes ``benchmark.md`` and ``benchmark.json`` (RMS in SI units, R²,
training time) beside the published figures.
"""

from __future__ import annotations

import json
import logging
import subprocess
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from hypa.errors import UserError, user_errors

log = logging.getLogger(__name__)


def train_model(label: str, overrides: list[str], folder: Path) -> None:
    """Train one model through the command line a user types (its progress on the console)."""
    command = [sys.executable, "-m", "hypa.train", *overrides, f"hydra.run.dir={folder}"]
    log.info("training %s: %s", label, " ".join(command[1:]))
    result = subprocess.run(command)
    if result.returncode != 0:
        raise UserError(f"training {label} failed (exit status {result.returncode}); "
                        f"run it alone: python {' '.join(command[1:])}")


@hydra.main(config_path="../conf", config_name="benchmark", version_base="1.3")
@user_errors("hypa.benchmark")
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
    out = Path(HydraConfig.get().runtime.output_dir)
    scores, times = [], {}
    for i, label in enumerate(labels, 1):
        print(f"[{i}/{len(labels)}] {dataset}: {label}", flush=True)
        folder = out / label
        overrides = [f"dataset={dataset}", *suite.models[label], *cfg.budgets[cfg.budget], *cfg.train_overrides]
        train_model(label, overrides, folder)
        run = load_run(folder)
        dm = run_datamodule(run)
        scores += score_run(run, dm, label)
        times[label] = float(json.loads((folder / "run.json").read_text()).get("training_time_s", float("nan")))
    units = {n: (dm.channels[n].display_unit, dm.channels[n].display_factor) for n in dm.output_names}
    published = OmegaConf.to_container(suite.published, resolve=True)
    table = benchmark_table(scores, times, published, units, dataset)
    (out / "benchmark.md").write_text(table + "\n")
    write_benchmark_json(out / "benchmark.json", dataset, scores, times, published, units)
    print(f"\n{table}\n\nwritten: {out / 'benchmark.md'}, {out / 'benchmark.json'}")


if __name__ == "__main__":
    main()
