"""Reproduce the paper's experiment on the default data: ``hypa reproduce``.

Trains every Table 1 row (``conf/row/``) over several seeds as one Hydra multirun (parallel
runs on this machine), evaluates each run (``hypa evaluate``) and writes, into ``results/``:
``table1.md`` / ``table1.csv`` (mean ± std over seeds, windowed and free-run, whole record,
stochastic part and unseen maneuvers), ``yaw_transfer.png`` (every model against the
measurement), ``rear_steer.png`` (the implicitly learned rear-wheel angles) and ``REPORT.md``,
which sets the paper's Table 1 beside ours (``hypa.paper.table1``): both rankings, the
paper's claims checked on our numbers, and every difference with its reason.
"""

from __future__ import annotations

import csv
import logging
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from hypa.commands.config import ReproduceConfig, hydra_command, typed
from hypa.commands.evaluate import Evaluation, evaluate_run
from hypa.commands.launch import run_hypa
from hypa.conf import CONF
from hypa.core.errors import UserError
from hypa.core.metrics import mean_std
from hypa.evaluation.figures import bode, rear_steer
from hypa.evaluation.runs import load_run
from hypa.paper.table1 import comparison_markdown
from hypa.reporting import markdown as md

log = logging.getLogger(__name__)
ROOT = Path(__file__).resolve().parents[2]  # the repository
COLUMNS = [("windowed", "all"), ("free_run", "all"), ("free_run", "stochastic"), ("free_run", "maneuvers")]
METRICS = ("mae", "mse", "mape", "r2")


def train_rows(rows: list[str], seeds: list[int], sweep_dir: Path, n_jobs: int, overrides: list[str]) -> None:
    """One Hydra multirun over rows x seeds (each run in ``sweep_dir/<model>-<ann>-seed<k>``)."""
    run_hypa("train", ["-m", "+experiment=table1", f"+row={','.join(rows)}", f"seed={','.join(map(str, seeds))}",
                       f"hydra.sweep.dir={sweep_dir}", f"hydra.launcher.n_jobs={n_jobs}", *overrides],
             "training", cwd=ROOT, after=f"the runs that finished are in {sweep_dir}")


def aggregate(evaluations: dict[str, list[Evaluation]]) -> list[dict[str, Any]]:
    """Mean and std over seeds of each Table 1 metric, per row (validation split): ``(mean, std)``,
    the sample std (``hypa.core.metrics.mean_std``; 0 for one seed), over the seeds that have the metric."""
    table = []
    for label, evals in evaluations.items():
        row: dict[str, Any] = {"model": label, "seeds": len(evals)}
        for mode, segment in COLUMNS:
            for metric in METRICS:
                overall = [e.metrics.splits["val"].mode(mode).get(segment, {}).get("overall") for e in evals]
                values = [getattr(m, metric) for m in overall if m is not None]
                if values:
                    s = mean_std(values)
                    row[f"{mode}/{segment}/{metric}"] = (s.mean, s.std)
        rear = [e.metrics.splits["val"].signals["rear_wheel_angle"].corr for e in evals
                if "rear_wheel_angle" in e.metrics.splits["val"].signals]
        if rear:
            s = mean_std(rear)
            row["rear_wheel_angle/corr"] = (s.mean, s.std)
        table.append(row)
    return table


def _cell(value: tuple[float, float] | None, metric: str) -> str:
    if value is None:
        return "–"
    mean, std = value
    return f"{mean:.4f} ± {std:.4f}" if metric in ("r2", "corr") else f"{mean:.3g} ± {std:.2g}"


def table_markdown(table: list[dict[str, Any]]) -> str:
    parts = []
    for mode, segment in COLUMNS:
        parts += [f"### {mode.replace('_', '-')}, {segment}", "",
                  *md.table(["model", "MAE [rad, rad/s]", "MSE", "MAPE [%]", "R²"],
                            [[row["model"], *(_cell(row.get(f"{mode}/{segment}/{m}"), m) for m in METRICS)]
                             for row in table]), ""]
    rear = [row for row in table if "rear_wheel_angle/corr" in row]
    if rear:
        parts += ["### rear-wheel angle of the model vs the measured one (free run, correlation)", "",
                  "Learned implicitly by V1 and V2; a fixed ratio of the steering angle for physical and V3.", "",
                  *md.table(["model", "correlation"], [[r["model"], _cell(r["rear_wheel_angle/corr"], "corr")]
                                                       for r in rear]), ""]
    return "\n".join(parts)


def write_csv(table: list[dict[str, Any]], path: Path) -> None:
    keys = list(dict.fromkeys(k for row in table for k in row if k not in ("model", "seeds")))
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["model", "seeds", *[f"{k}/{s}" for k in keys for s in ("mean", "std")]])
        for row in table:
            writer.writerow([row["model"], row["seeds"], *[x for k in keys for x in (row.get(k) or ("", ""))]])


def report(table: list[dict[str, Any]], config: ReproduceConfig, wall_s: float, runs: int) -> str:
    seeds = sorted({row["seeds"] for row in table})
    experiment = OmegaConf.load(CONF / "experiment" / "table1.yaml")
    return "\n".join([
        "# HyPA-Net: the paper's experiment on the hypa test bench", "",
        (f"{runs} runs ({len(table)} models x {'/'.join(map(str, seeds))} seeds), "
        f"{'evaluated (trained before)' if config.skip_training else 'trained and evaluated'} in "
        f"{wall_s / 60:.1f} min on this machine (this invocation). "
        "Metrics on the validation run, mean ± std over seeds; "
        "states in SI units (yaw rate rad/s, side slip rad), overall = mean over both states. "
        "MAPE is floored (|error| / max(|y|, 10 % of the channel's RMS)) so zero crossings cannot explode it."), "",
        ("*Windowed*: 100 steps from each measured state, as in training. *Free run*: the whole validation "
        "record simulated from its first sample. *Maneuvers*: lane change, step steer and sine sweep, "
        "which training never saw."), "",
        table_markdown(table), "",
        comparison_markdown(table), "",
        "## Yaw transfer function (steering-wheel angle to yaw rate, H1 estimate)", "",
        "![yaw transfer](yaw_transfer.png)", "",
        "## Implicitly learned rear-wheel angle", "", "![rear steer](rear_steer.png)", "",
        "## Configuration", "", "Training budget (`conf/experiment/table1.yaml`):", "", "```yaml",
        OmegaConf.to_yaml(experiment).strip(), "```", "",
        (f"Extra overrides: `{list(config.train_overrides)}`. Everything else as in `conf/train.yaml` "
        "(NAdam 5e-4, batch 32, windows of 100, early stopping on val/loss), the default test bench "
        "(`conf/testbench/default.yaml`) and the nominal vehicle (`conf/vehicle/sedan.yaml`). "
        "Per-run evaluations: `runs/*/evaluation/summary.md`."), ""])


@hydra_command("hypa reproduce", "reproduce")
def main(cfg: DictConfig) -> None:
    from hypa.commands.entry import from_cwd

    start = time.time()
    config = typed(cfg, ReproduceConfig)  # every value checked (hypa.commands.config)
    out = from_cwd(config.out)
    sweep = out / "runs"
    rows = config.rows  # rows=v2: one
    unknown = [r for r in rows if not (CONF / "row" / f"{r}.yaml").is_file()]
    if unknown:
        known = sorted(p.stem for p in (CONF / "row").glob("*.yaml"))
        raise UserError(f"rows {unknown} are not in conf/row/; known: {', '.join(known)}")
    if not config.skip_training:
        if sweep.is_dir() and any(sweep.iterdir()):  # one run, one folder: an earlier reproduction's runs move aside
            kept = sweep.with_name(f"runs-{time.strftime('%Y-%m-%d_%H-%M-%S', time.localtime(sweep.stat().st_mtime))}")
            kept = kept if not kept.exists() else kept.with_name(f"{kept.name}-{time.time_ns()}")
            sweep.rename(kept)
            print(f"the runs of the previous reproduction are kept in {kept}", flush=True)
        train_rows(rows, config.seeds, sweep, config.n_jobs, list(config.train_overrides))
    folders = sorted(d for d in sweep.iterdir() if (d / ".hydra").is_dir()) if sweep.is_dir() else []
    if not folders:
        raise FileNotFoundError(f"no runs in {sweep}")
    # Table 1's order: the default rows, then any others asked for
    rows = list(dict.fromkeys([*OmegaConf.load(CONF / "reproduce.yaml").rows, *rows]))
    order = {str(OmegaConf.load(CONF / "row" / f"{r}.yaml").table1_row): i for i, r in enumerate(rows)}
    evaluations: dict[str, list[Evaluation]] = defaultdict(list)
    for i, folder in enumerate(folders, 1):
        run = load_run(folder, trust=() if config.skip_training else ("*",))  # "*": a run it trained just now
        label = run.settings.table1_row or run.label
        log.info("evaluating %d/%d: %s (%s)", i, len(folders), label, folder.name)
        print(f"[{i}/{len(folders)}] evaluating {label} ({folder.name})", flush=True)
        evaluations[label].append(evaluate_run(run, folder / "evaluation", tensorboard=False))
    evaluations = dict(sorted(evaluations.items(), key=lambda kv: order.get(kv[0], len(order))))
    table = aggregate(evaluations)
    (out / "table1.md").write_text(table_markdown(table))
    write_csv(table, out / "table1.csv")
    first = {label: evals[0] for label, evals in evaluations.items()}
    with_transfer = {label: e.transfer for label, e in first.items() if e.transfer}
    if with_transfer:
        measured = next(iter(with_transfer.values()))["measured"]
        fig = bode({"measured": measured, **{label: t["model"] for label, t in with_transfer.items()}},
                   reference="measured", gain_unit="1/s")
        fig.savefig(out / "yaw_transfer.png", dpi=120)
    learned = {label: e.signals["rear_wheel_angle"] for label, e in first.items()
               if "rear_wheel_angle" in e.signals and any(b.kind == "ann" and "rear_wheel_angle" in b.outputs
                                             for b in e.model_blocks)}
    if learned:
        t, truth, _ = next(iter(learned.values()))
        window = (t >= 20.0) & (t < 50.0)  # 30 s of the stochastic part, readable
        fig = rear_steer(t[window], None if truth is None else truth[window],
                         {label: r[2][window] for label, r in learned.items()},
                         title="rear-wheel angle: measured vs implicitly learned")
        fig.savefig(out / "rear_steer.png", dpi=120)
    wall = time.time() - start
    (out / "REPORT.md").write_text(report(table, config, wall, len(folders)))
    print(table_markdown(table))
    print(f"wall time {wall / 60:.1f} min; report: {out / 'REPORT.md'}")


if __name__ == "__main__":
    sys.exit(main())
