"""Benchmark hypa on a real data set: physics only, an end-to-end LSTM and a hybrid.

    python -m hypa.benchmark dataset=silverbox            # quick budget: minutes
    python -m hypa.benchmark dataset=emps budget=full     # the benchmark (longer)
    python -m hypa.benchmark dataset=emps budget=full seeds=[0,1,2]   # mean ± std over seeds
    python -m hypa.benchmark dataset=racecar data.dir=OTHER_LOG       # the suite on another log
    python -m hypa.benchmark --config-dir DIR dataset=mine models=[mine_physical,blackbox]   # your own
    python -m hypa.benchmark --config-dir DIR dataset=mine models=[mine,diagnosed] diagnose=mine   # + its diagnosis
    make benchmark ARGS="dataset=racecar budget=full"

Each model of the data set's suite (``conf/benchmark.yaml``; for a data set without one, the
models named by ``models=[...]``) is trained by ``python -m hypa.train`` in its own run folder
below this run's, with the data overrides of this command line (``data.dir=``, ``data.splits=``;
a run that trained on other data than asked is an error), then simulated free-running over every
test set, once per seed of ``seeds``. Prints and writes ``benchmark.md`` and ``benchmark.json``
(RMS in SI units, R², training time; means and standard deviations over the seeds, and each
seed) beside the published figures.
"""

from __future__ import annotations

import logging
from pathlib import Path

from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from hypa.commands.config import BenchmarkConfig, typed
from hypa.commands.output_folder import holding_output
from hypa.errors import UserError, hydra_command
from hypa.launch import run_hypa

log = logging.getLogger(__name__)
WRITTEN = ("diagnosed", "diagnosed_hybrid")  # the models hypa.diagnose writes (model=...)


def train_model(label: str, overrides: list[str], folder: Path, config_dirs: list[Path]) -> None:
    """Train one model through the command line a user types (its progress on the console)."""
    run_hypa("train", [*overrides, f"hydra.run.dir={folder}"], f"training {label}", config_dirs)


def diagnose_suite(dataset: str, nominal: str, overrides: list[str], folder: Path, config_dirs: list[Path]) -> Path:
    """Run ``python -m hypa.diagnose`` on the data set's nominal model; returns the folder of the models it
    writes (``conf``, for ``hydra.searchpath``)."""
    run_hypa("diagnose", [f"dataset={dataset}", f"model={nominal}", *overrides, "plot=false",
                          f"hydra.run.dir={folder}"], f"diagnosing {nominal}", config_dirs)
    return folder / "conf"


@hydra_command("hypa.benchmark", "benchmark")
@holding_output("hypa.benchmark")  # its folder held first (each training run below holds its own)
def main(cfg: DictConfig) -> None:
    from hypa.commands.entry import data_dir_from_config, data_overrides, user_config_dirs
    from hypa.commands.evaluate import run_datamodule
    from hypa.data import datamodule_from_config
    from hypa.evaluation.benchmark import benchmark, score_run
    from hypa.evaluation.runs import load_run
    from hypa.training.checkpoints import START_CHECKPOINT

    config = typed(cfg, BenchmarkConfig)  # every value checked (hypa.commands.config)
    dataset = HydraConfig.get().runtime.choices["dataset"]
    suite = config.suites.get(dataset)  # None: a user's own data set, its models named by models=[...]
    if suite is None and not config.models:
        raise UserError(f"dataset={dataset} has no benchmark suite ({', '.join(config.suites)} have): name the models "
                        "to benchmark, models=[M1,M2] (conf/model/M1.yaml, or in your --config-dir)")
    suite_models = suite.models if suite is not None else {}
    labels = list(config.models) if config.models else list(suite_models)
    configs = set(GlobalHydra.instance().config_loader().get_group_options("model"))  # --config-dir's too
    nominal = config.diagnose or (suite.diagnose if suite is not None else None)
    if config.diagnose and config.diagnose not in configs:
        raise UserError(f"diagnose={config.diagnose} is not a model config (conf/model/*.yaml or your --config-dir)")
    if nominal is None and any(m in WRITTEN and m not in suite_models for m in labels):
        raise UserError(f"models {[m for m in labels if m in WRITTEN]} are written by hypa.diagnose: give diagnose=M, "
                        "the model it extends (models=[M,diagnosed] diagnose=M)")
    unknown = [m for m in labels if m not in suite_models and m not in configs and not (nominal and m in WRITTEN)]
    if unknown:
        where = f"in the {dataset} suite ({', '.join(suite_models)}) nor " if suite is not None else ""
        raise UserError(f"models {unknown} are {'not ' + where if where else 'not '}model configs "
                        "(conf/model/*.yaml or your --config-dir)")
    seeds = config.seeds
    # the data asked for on this command line reach every run (after the suite's own settings), and
    # every run must have trained on them: never a quiet fallback to the bundled files
    asked = [o for o in data_overrides(HydraConfig.get().overrides.task) if not o.startswith("dataset=")]
    expected = data_dir_from_config(cfg).resolve()
    data = datamodule_from_config(cfg.data, expected)
    data.setup()
    if not data.records("test"):  # the benchmark's figures are test-set figures: none would be an empty table
        raise UserError(f"dataset={dataset} has no test records in {expected}: the benchmark scores the test sets; "
                        "add test files (test*.csv, ...) or a test part in data.splits")
    config_dirs = user_config_dirs()
    out = Path(HydraConfig.get().runtime.output_dir)
    # the models hypa.diagnose writes (model=diagnosed, diagnosed_hybrid) come from diagnosing the suite's
    # nominal model on the same data, once for all seeds
    written = [o for label in labels for o in suite_models.get(label, [f"model={label}"])
               if o.removeprefix("model=") in WRITTEN]
    searchpath = []
    if written:
        if nominal is None:
            raise UserError(f"models {sorted(set(written))} are written by hypa.diagnose, but no nominal model to "
                            f"diagnose is named: give diagnose=M (the model the diagnosis extends)"
                            + (f", or diagnose: M in the {dataset} suite of conf/benchmark.yaml" if suite else ""))
        conf = diagnose_suite(dataset, str(nominal), asked, out / "diagnosis", config_dirs)
        searchpath = [f"hydra.searchpath=[file://{conf}]"]
    scores, times, kept = [], {}, {}
    jobs = [(label, seed) for label in labels for seed in seeds]
    for i, (label, seed) in enumerate(jobs, 1):
        print(f"[{i}/{len(jobs)}] {dataset}: {label}" + (f", seed {seed}" if len(seeds) > 1 else ""), flush=True)
        folder = out / label if len(seeds) == 1 else out / f"{label}-seed{seed}"
        model = list(suite_models[label]) if label in suite_models else [f"model={label}"]
        overrides = [*searchpath, f"dataset={dataset}", *model, *asked, *config.budgets[config.budget],
                     *config.train_overrides,
                     f"seed={seed}", f"data.seed={seed}"]  # the networks' start and the windows' order
        train_model(label, overrides, folder, config_dirs)
        run = load_run(folder, trust=("*",))  # the run it trained just now, from its own configuration
        trained_on = Path(str(run.info.get("data_dir", ""))).resolve()
        if trained_on != expected:
            raise UserError(f"{label} trained on {trained_on}, not on the data asked for ({expected}); "
                            f"its run: {folder}")
        if run.checkpoint.name == START_CHECKPOINT:  # hypa.train kept the identified physics: said under the table
            kept.setdefault(label, []).append(seed)
        dm = run_datamodule(run)
        scores += score_run(run, dm, label, seed)
        seconds = float(run.info.get("training_time_s", float("nan")))
        times[label] = times.get(label, 0.0) + seconds / len(seeds)
    units = {n: (dm.channels[n].display_unit, dm.channels[n].display_factor) for n in dm.output_names}
    published = suite.published if suite is not None else {}
    result = benchmark(dataset, scores, times, published, units, kept)
    table = result.markdown()
    (out / "benchmark.md").write_text(table + "\n")
    result.to_json(out / "benchmark.json")
    print(f"\n{table}\n\nwritten: {out / 'benchmark.md'}, {out / 'benchmark.json'}")


if __name__ == "__main__":
    main()
