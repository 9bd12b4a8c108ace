"""Evaluate a trained run on the validation (and test) data.

    hypa evaluate run=outputs/train/v2-lstm/2026-11-22_10-00-00-000000    # its recorded best checkpoint
    hypa evaluate run='path/to/checkpoints/best-epoch=12.ckpt'   # another checkpoint of it

Writes ``metrics.json``, ``metrics.csv``, PNG figures and ``summary.md`` into
``<run>/evaluation/`` (or ``out=``: held while it runs; refused when it, or anything in it, is a
symbolic link, or when it is a training run's own folder: :mod:`hypa.commands.output_folder`) and the
figures into the run's TensorBoard log
(``hypa.evaluation.api`` holds what it computes).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from omegaconf import DictConfig

from hypa.commands.config import EvaluateConfig, hydra_command, typed
from hypa.commands.output_folder import claim_output, holding_output
from hypa.evaluation.api import Evaluation, evaluate_run, run_datamodule
from hypa.evaluation.runs import load_run
from hypa.reporting.numbers import r_squared

__all__ = ["Evaluation", "evaluate_run", "main", "run_datamodule"]


@hydra_command("hypa evaluate", "evaluate")
@holding_output("hypa evaluate")  # Hydra's folder (its .hydra/, the log)
def main(cfg: DictConfig) -> None:
    from hypa.commands.entry import from_cwd
    from hypa.core.folders import FolderRefused

    config = typed(cfg, EvaluateConfig)
    run = load_run(from_cwd(config.run), config.trust)
    out = Path(config.out) if config.out else run.folder / "evaluation"
    board = run.folder / "tensorboard"
    if config.tensorboard and board.is_symlink():  # written into too: never through a link
        raise FolderRefused(f"{board} is a symbolic link (to {os.readlink(board)}): hypa evaluate adds its "
                            "figures to the run's TensorBoard log and writes nothing through a link; remove "
                            "the link, or give tensorboard=false")
    with claim_output("hypa evaluate", out, setting="out"):  # held; never a training run's own folder
        evaluation = evaluate_run(run, out, tensorboard=config.tensorboard)
    units, scale = evaluation.display_units, evaluation.display_factors
    for split, metrics in evaluation.metrics.splits.items():
        for mode in ("windowed", "free_run"):
            parts = [f"{k} R² {r_squared(v.r2)}, RMSE {v.rmse * scale.get(k, 1.0):.3g} {units.get(k, '')}"
                     for k, v in metrics.mode(mode)["all"].items() if k != "overall"]
            print(f"{run.label} {split} {mode}: {'; '.join(parts)}")
    for line in evaluation.warnings:
        print(f"warning: {line}")  # a level no data reach: one line naming the output and the likely state
    print(f"report: {out / 'summary.md'}")


if __name__ == "__main__":
    sys.exit(main())
