"""Benchmark hypa on a real data set: physics only, an end-to-end LSTM and a hybrid.

    hypa benchmark dataset=silverbox            # quick budget: minutes
    hypa benchmark dataset=emps budget=full     # the benchmark (longer)
    hypa benchmark dataset=emps budget=full seeds=[0,1,2]   # mean ± std over seeds
    hypa benchmark dataset=racecar data.dir=OTHER_LOG       # the suite on another log
    hypa benchmark --config-dir DIR dataset=mine models=[mine_physical,blackbox]   # your own
    hypa benchmark --config-dir DIR dataset=mine models=[mine,diagnosed] diagnose=mine   # + its diagnosis
    hypa benchmark dataset=silverbox diagnose=outputs/diagnose/silverbox_physical/<time>   # reuse one
    make benchmark ARGS="dataset=racecar budget=full"

Each model of the data set's suite (``conf/benchmark.yaml``; for a data set without one, the
models named by ``models=[...]``) is trained by ``hypa train`` in its own run folder
below this run's, with the data overrides of this command line (``data.dir=``, ``data.splits=``;
a run that trained on other data than asked is an error), then simulated free-running over every
test set, once per seed of ``seeds``. Prints and writes ``benchmark.md`` and ``benchmark.json``
(RMS in SI units, R², training time; means and standard deviations over the seeds, and each
seed) beside the published figures.

Both files are written again after every row: a row that fails (its training, its identification,
its scoring) is recorded as ``failed: <why>`` and the next rows go on (the command then ends with
exit status 1, naming the rows that failed); Ctrl-C writes the rows done so far and ends with exit
status 130. Each row prints its training time, and says where its identification or training
stopped at a cap (``identification.max_evaluations``, ``max_seconds``, ``trainer.max_epochs``):
"(capped)" in the table's time row, the cap under it.

``diagnose=M`` runs ``hypa diagnose model=M`` into ``<benchmark>/diagnosis/`` for the rows
``diagnosed`` and ``diagnosed_hybrid``; ``diagnose=PATH`` reuses a diagnosis folder instead (one that
``hypa diagnose`` wrote, maybe received: read as data, its ``diagnosis.json`` through its schema,
its ``conf/model/diagnosed*.yaml`` through the model schema and trained by ``model_file=``; no
symbolic link in it followed; a diagnosis of other inputs or outputs than the data's is refused).
"""

from __future__ import annotations

import logging
import re
import shlex
import signal
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from hypa.commands.config import BenchmarkConfig, hydra_command, typed
from hypa.commands.launch import hypa_argv, run_hypa
from hypa.commands.output_folder import holding_output
from hypa.core.errors import INTERRUPTED, UserError, is_user_error, one_line
from hypa.physics.discretization import HOLDS
from hypa.reporting.numbers import elapsed

if TYPE_CHECKING:
    from hypa.evaluation.runs import TrainedRun

log = logging.getLogger(__name__)
WRITTEN = ("diagnosed", "diagnosed_hybrid")  # the models hypa diagnose writes (model=...)
CHILD_ERROR = "hypa train: error: "  # how hypa train says what stopped it (hypa.core.errors.user_errors), one line


class RowFailed(UserError):
    """A row's training failed: its reason (the child's own one-line error), and how to run it alone."""

    def __init__(self, reason: str, command: str) -> None:
        super().__init__(f"{reason}; run it alone: {command}")
        self.reason = reason


def train_model(label: str, overrides: list[str], folder: Path, config_dirs: list[Path]) -> None:
    """Train one model through the command line a user types (its progress on the console, its
    stderr passed through as it comes). Ctrl-C: KeyboardInterrupt; a failure: :class:`RowFailed`
    with the child's own one-line error (``hypa train: error: ...``) as its reason."""
    argv = hypa_argv("train", [*overrides, f"hydra.run.dir={folder}"], config_dirs)
    log.info("training %s: %s", label, " ".join(argv[1:]))
    said = ""
    with subprocess.Popen(argv, stderr=subprocess.PIPE, text=True, errors="replace") as child:
        for line in child.stderr:
            sys.stderr.write(line)
            sys.stderr.flush()
            if line.startswith(CHILD_ERROR):
                said = line[len(CHILD_ERROR):].strip()
        status = child.wait()
    if status in (INTERRUPTED, -signal.SIGINT):  # Ctrl-C reached the child too: this command ends the same way
        raise KeyboardInterrupt
    if status != 0:
        raise RowFailed(said or f"hypa train ended with exit status {status} (its error above)",
                        "python " + " ".join(shlex.quote(a) for a in argv[1:]))


def diagnose_suite(dataset: str, nominal: str, overrides: list[str], folder: Path, config_dirs: list[Path]) -> Path:
    """Run ``hypa diagnose`` on the data set's nominal model; returns the folder of the models it
    writes (``conf``, for ``hydra.searchpath``)."""
    run_hypa("diagnose", [f"dataset={dataset}", f"model={nominal}", *overrides, "plot=false",
                          f"hydra.run.dir={folder}"], f"diagnosing {nominal}", config_dirs)
    return folder / "conf"


@hydra_command("hypa benchmark", "benchmark")
@holding_output("hypa benchmark")  # its folder held first (each training run below holds its own)
def main(cfg: DictConfig) -> None:
    from hypa.commands.entry import data_dir_from_config, data_overrides, user_config_dirs
    from hypa.data import datamodule_from_config
    from hypa.evaluation.benchmark import identified_only, reseeded
    from hypa.training.checkpoints import START_CHECKPOINT

    config = typed(cfg, BenchmarkConfig)  # every value checked (hypa.commands.config)
    dataset = HydraConfig.get().runtime.choices["dataset"]
    suite = config.suites.get(dataset)  # None: a user's own data set, its models named by models=[...]
    suite_models = suite.models if suite is not None else {}
    labels = list(config.models) if config.models else list(suite_models)
    configs = set(GlobalHydra.instance().config_loader().get_group_options("model"))  # --config-dir's too
    folder = diagnosis_folder(config.diagnose, configs)  # diagnose=PATH: a diagnosis to reuse
    nominal = config.diagnose or (suite.diagnose if suite is not None else None)
    check_models(config, dataset, labels, configs, folder, nominal)
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
    # the models hypa diagnose writes (model=diagnosed, diagnosed_hybrid) come from diagnosing the suite's
    # nominal model on the same data, once for all seeds, or from a diagnosis folder given (diagnose=PATH)
    written = [o for label in labels for o in suite_models.get(label, [f"model={label}"])
               if o.removeprefix("model=") in WRITTEN]
    searchpath, model_files = [], {}
    if folder is not None:  # checked whether or not a row needs it: a wrong folder is said at once
        model_files = reused_diagnosis(folder, sorted({o.removeprefix("model=") for o in written}), data,
                                       trust_of(config.train_overrides))
    elif written:
        if nominal is None:
            raise UserError(f"models {sorted(set(written))} are written by hypa diagnose, but no nominal model to "
                            f"diagnose is named: give diagnose=M (the model the diagnosis extends)"
                            + (f", or diagnose: M in the {dataset} suite of conf/benchmark.yaml" if suite else ""))
        conf = diagnose_suite(dataset, str(nominal), asked, out / "diagnosis", config_dirs)
        searchpath = [f"hydra.searchpath=[file://{conf}]"]
    units = {n: (data.channels[n].display_unit, data.channels[n].display_factor) for n in data.output_names}
    # the diagnosed row against the row of the nominal it extends, identified (where the suite has one)
    base = [label for label in labels if label == nominal or f"model={nominal}" in suite_models.get(label, ())]
    extends = {"diagnosed": base[0]} if base and "diagnosed" in labels and folder is None else {}
    rows = Rows(dataset, labels, seeds, suite.published if suite is not None else {}, units, out, extends)
    jobs = [(label, seed) for label in labels for seed in seeds]
    identified: dict[str, tuple[int, list, float, list[str]]] = {}  # physics-only row -> its seed's scores
    started: dict[str, list[str]] = {}  # a hybrid row -> its later seeds' start: its first seed's identified physics
    for i, (label, seed) in enumerate(jobs, 1):
        print(f"[{i}/{len(jobs)}] {dataset}: {label}" + (f", seed {seed}" if len(seeds) > 1 else ""), flush=True)
        if label in identified:  # identified without randomness: another seed would give the same model
            first, scores, seconds, caps = identified[label]
            rows.add(label, seed, reseeded(scores, seed), seconds, kept=False, caps=caps)
            print(f"[{i}/{len(jobs)}] {label}: physics only, identified (no seed enters): seed {first}'s model "
                  f"({out / f'{label}-seed{first}'}) is seed {seed}'s", flush=True)
            rows.write()
            continue
        run_folder = out / label if len(seeds) == 1 else out / f"{label}-seed{seed}"
        model = list(suite_models[label]) if label in suite_models else [f"model={label}"]
        model = [model_file_override(model_files[o.removeprefix("model=")]) if o.removeprefix("model=") in model_files
                 else o for o in model]
        if label in started:
            print(f"[{i}/{len(jobs)}] {label}: its physics starts from seed {seeds[0]}'s identification (no seed "
                  f"enters it): {' '.join(started[label])}", flush=True)
        overrides = [*searchpath, f"dataset={dataset}", *model, *asked, *config.budgets[config.budget],
                     *started.get(label, []), *config.train_overrides,
                     f"seed={seed}", f"data.seed={seed}"]  # the networks' start and the windows' order
        try:
            run, scores, caps = trained_row(label, seed, overrides, run_folder, config_dirs, expected)
        except KeyboardInterrupt:  # Ctrl-C: the rows done so far are written, then the command ends (130)
            rows.fail(label, seed, "interrupted")
            table, data_file = rows.write()
            print(f"\ninterrupted in row {i} of {len(jobs)} ({label}); the rows done so far: {table}, {data_file}",
                  flush=True)
            raise
        except OtherData:
            raise  # the data asked for are not what the runs read: every row would be wrong
        except Exception as error:  # one row's failure is its row's, the others go on
            if not is_user_error(error):
                log.exception("%s failed", label)  # a bug: its traceback in the log, the row says so
            rows.fail(label, seed, error.reason if isinstance(error, RowFailed) else one_line(error))
            print(f"[{i}/{len(jobs)}] {label} failed: {one_line(error)}; going on with the next row", flush=True)
        else:
            seconds = float(run.info.get("training_time_s", float("nan")))
            rows.add(label, seed, scores, seconds, kept=run.checkpoint.name == START_CHECKPOINT, caps=caps)
            if identified_only(run):
                identified[label] = (seed, scores, seconds, caps)
            elif label not in started and seed == seeds[0]:
                started[label] = identified_start(run_folder, run.info)
            print(f"[{i}/{len(jobs)}] {label}: trained in {elapsed(seconds)}"
                  + (f"; stopped at a cap: {'; '.join(caps)}" if caps else ""), flush=True)
        rows.write()
    table, data_file = rows.write()
    print(f"\n{rows.result().markdown()}\n\nwritten: {table}, {data_file}")
    if rows.failed:
        raise UserError(f"{len(rows.failed)} of {len(labels)} models failed ({'; '.join(rows.failed)}); the table "
                        f"holds the others: {table}")


def identified_start(run_folder: Path, info: dict) -> list[str]:
    """The overrides that start a hybrid's later seeds from the physics its first seed's run (in
    ``run_folder``, ``info`` its run.json) identified: ``identification.start`` and the hold the data
    chose there, so the fit settles in a few iterations and no second hold is fitted; none for a run
    that identified nothing."""
    identification = info.get("identification") if isinstance(info, dict) else None
    parameters = identification.get("parameters") if isinstance(identification, dict) else None
    if not isinstance(parameters, dict) or not parameters:
        return []
    hold = info.get("hold")
    chosen = [f"physics.hold={hold['chosen']}"] if isinstance(hold, dict) and hold.get("by") == "identification" \
        and hold.get("chosen") in HOLDS else []
    return [path_override("identification.start", run_folder), *chosen]


def check_models(config: BenchmarkConfig, dataset: str, labels: list[str], configs: set[str],
                 folder: Path | None, nominal: str | None) -> None:
    """Every model asked for is a row of the data set's suite or a model config, and the models
    ``hypa diagnose`` writes have a nominal model to diagnose (or a diagnosis folder): refused in one
    line before any data are read."""
    suite = config.suites.get(dataset)
    suite_models = suite.models if suite is not None else {}
    if suite is None and not config.models:
        raise UserError(f"dataset={dataset} has no benchmark suite ({', '.join(config.suites)} have): name the models "
                        "to benchmark, models=[M1,M2] (conf/model/M1.yaml, or in your --config-dir)")
    if config.diagnose and folder is None and config.diagnose not in configs:
        raise UserError(f"diagnose={config.diagnose} is not a model config (conf/model/*.yaml or your --config-dir)")
    if nominal is None and any(m in WRITTEN and m not in suite_models for m in labels):
        raise UserError(f"models {[m for m in labels if m in WRITTEN]} are written by hypa diagnose: give diagnose=M, "
                        "the model it extends (models=[M,diagnosed] diagnose=M)")
    unknown = [m for m in labels if m not in suite_models and m not in configs and not (nominal and m in WRITTEN)]
    if unknown:
        where = f"in the {dataset} suite ({', '.join(suite_models)}) nor " if suite is not None else ""
        raise UserError(f"models {unknown} are {'not ' + where if where else 'not '}model configs "
                        "(conf/model/*.yaml or your --config-dir)")


def trained_row(label: str, seed: int, overrides: list[str], run_folder: Path, config_dirs: list[Path],
                expected: Path) -> tuple[TrainedRun, list, list[str]]:
    """One row: ``hypa train`` with ``overrides`` into ``run_folder``, its run loaded and scored on the
    test sets (its caps said); :class:`OtherData` where it trained on other data than ``expected``."""
    from hypa.evaluation.api import run_datamodule
    from hypa.evaluation.benchmark import score_run, stopped_at_caps
    from hypa.evaluation.runs import load_run

    train_model(label, overrides, run_folder, config_dirs)
    run = load_run(run_folder, trust=("*",))  # the run it trained just now, from its own configuration
    trained_on = Path(str(run.info.get("data_dir", ""))).resolve()
    if trained_on != expected:
        raise OtherData(f"{label} trained on {trained_on}, not on the data asked for ({expected}); "
                        f"its run: {run_folder}")
    return run, score_run(run, run_datamodule(run), label, seed), stopped_at_caps(run)


class OtherData(UserError):
    """A row's run trained on other data than the benchmark's: every row would be wrong, so it stops."""


class Rows:
    """The benchmark's rows as they finish: their scores, training times, caps and failures, written
    as ``benchmark.md`` and ``benchmark.json`` (:func:`~hypa.evaluation.benchmark_result.write_report`)
    after every row, so that a row that fails or Ctrl-C keeps the others."""

    def __init__(self, dataset: str, labels: list[str], seeds: list[int], published: dict,
                 units: dict[str, tuple[str, float]], out: Path, extends: dict[str, str] | None = None) -> None:
        self.dataset, self.labels, self.seeds, self.published, self.units, self.out = (
            dataset, labels, seeds, published, units, out)
        self.extends = dict(extends or {})
        self.scores: list = []
        self.times: dict[str, list[float]] = {}
        self.kept: dict[str, list[int]] = {}
        self.caps: dict[str, list[str]] = {}
        self.failures: dict[str, dict[int, str]] = {}

    def add(self, label: str, seed: int, scores: list, seconds: float, kept: bool, caps: list[str]) -> None:
        self.scores += scores
        self.times.setdefault(label, []).append(seconds)
        if kept:  # hypa train kept the identified physics: said under the table
            self.kept.setdefault(label, []).append(seed)
        self.caps.setdefault(label, []).extend(caps if len(self.seeds) == 1 else [f"seed {seed}: {c}" for c in caps])

    def fail(self, label: str, seed: int, reason: str) -> None:
        self.failures.setdefault(label, {})[seed] = reason

    @property
    def failed(self) -> dict[str, str]:
        """Model -> why it (or each seed of it that failed) failed, one line."""
        return {label: (next(iter(f.values())) if len(self.seeds) == 1
                        else "; ".join(f"seed {s} failed: {r}" for s, r in f.items()))
                for label, f in self.failures.items()}

    def result(self):  # -> Benchmark
        from hypa.evaluation.benchmark import benchmark

        times = {label: sum(t) / len(t) for label, t in self.times.items()}  # mean per seed that finished
        order = {label: times.get(label) for label in self.labels if label in times or label in self.failures}
        return benchmark(self.dataset, self.scores, order, self.published, self.units, self.kept, self.caps,
                         self.failed, self.extends)

    def write(self) -> tuple[Path, Path]:
        from hypa.evaluation.benchmark_result import write_report

        return write_report(self.result(), self.out)


def trust_of(overrides: list[str]) -> tuple[str, ...]:
    """The import paths a ``trust=[...]`` among ``train_overrides`` names: the code a diagnosis folder's
    model files may name (hypa train reads them with the same)."""
    for override in overrides:
        key, _, value = override.partition("=")
        if key.lstrip("+") == "trust":
            return tuple(v.strip().strip("'\"") for v in value.strip().strip("[]").split(",") if v.strip())
    return ()


def model_file_override(path: Path) -> str:
    """``model_file=PATH`` as one Hydra override (:func:`path_override`)."""
    return path_override("model_file", path)


def path_override(key: str, path: Path) -> str:
    """``KEY=PATH`` as one Hydra override (quoted where the path holds characters Hydra parses)."""
    text = str(path)
    if re.fullmatch(r"[A-Za-z0-9_/.@:+-]+", text):
        return f"{key}={text}"
    if "'" in text or "\\" in text or "${" in text:
        raise UserError(f"{path}: a path with a quote, a backslash or ${{ cannot be passed to hypa train as {key}; "
                        "move or link the folder elsewhere")
    return f"{key}='{text}'"


def diagnosis_folder(value: str | None, configs: set[str]) -> Path | None:
    """``diagnose=PATH``: the diagnosis folder it names (``None`` where ``value`` is a model name, the
    nominal model to diagnose). A value that is no model config and looks like a path must be a folder."""
    from hypa.commands.entry import from_cwd

    if value is None or value in configs:
        return None
    path = from_cwd(value)
    if path.is_dir():
        return path
    if "/" in value or value.startswith((".", "~")):
        raise UserError(f"diagnose={value}: no such folder (a diagnosis folder of hypa diagnose, holding "
                        "diagnosis.json and conf/model/diagnosed.yaml, or a model name)")
    return None


def reused_diagnosis(folder: Path, models: list[str], data, trust: tuple[str, ...]) -> dict[str, Path]:
    """The model files of a diagnosis folder (``diagnose=PATH``) for ``models`` (``diagnosed``,
    ``diagnosed_hybrid``), checked before any row trains. The folder is data, maybe received: its
    ``diagnosis.json`` is read through its schema and its model files through the model schema
    (bounded, no symbolic link followed out of the folder, no import path that ``trust`` does not
    name), and the diagnosis must be of this data's inputs and outputs."""
    from hypa.core.trust import inside
    from hypa.diagnosis.result import Diagnosis
    from hypa.models.spec import read_model_file

    record = inside(folder, "diagnosis.json", f"diagnose={folder}")
    if not record.is_file():
        raise UserError(f"diagnose={folder}: no diagnosis.json in it (a folder written by hypa diagnose)")
    diagnosis = Diagnosis.from_json(record)
    system = diagnosis.system
    for role, theirs, ours in (("inputs", system.inputs, data.input_names), ("outputs", system.outputs,
                                                                               data.output_names)):
        if sorted(theirs) != sorted(ours):
            raise UserError(f"diagnose={folder}: its diagnosis is of {role} {', '.join(theirs) or 'none'}, this "
                            f"benchmark's data have {', '.join(ours) or 'none'}: diagnose this data set "
                            f"(diagnose=M, the nominal model)")
    files = {}
    for name in models:
        path = inside(folder, f"conf/model/{name}.yaml", f"diagnose={folder}")
        if not path.is_file():
            raise UserError(f"diagnose={folder}: no conf/model/{name}.yaml in it (hypa diagnose writes "
                            f"{', '.join(WRITTEN)})")
        read_model_file(path, trust)  # refused in one line now, not in the middle of the rows
        files[name] = path
    print(f"diagnosis of {system.model} reused from {folder} (causes: {', '.join(diagnosis.causes) or 'none'})",
          flush=True)
    return files


if __name__ == "__main__":
    sys.exit(main())
