"""Evaluate a trained run on the validation (and test) data.

    python -m hypa.evaluate run=outputs/train/v2-lstm/2026-11-22_10-00-00    # its recorded best checkpoint
    python -m hypa.evaluate run='path/to/checkpoints/best-epoch=12.ckpt'   # another checkpoint of it

Writes ``metrics.json``, ``metrics.csv``, PNG figures and ``summary.md`` into
``<run>/evaluation/`` and the figures into the run's TensorBoard log
(``hypa.evaluation.evaluation`` holds what it computes).
"""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from hypa.commands.config import EvaluateConfig, typed
from hypa.errors import hydra_command
from hypa.evaluation.evaluation import Evaluation, evaluate_run, run_datamodule
from hypa.evaluation.runs import load_run

__all__ = ["Evaluation", "evaluate_run", "main", "run_datamodule"]


@hydra_command("hypa.evaluate", "evaluate")
def main(cfg: DictConfig) -> None:
    from hypa.commands.entry import from_cwd

    config = typed(cfg, EvaluateConfig)
    run = load_run(from_cwd(config.run))
    out = Path(config.out) if config.out else run.folder / "evaluation"
    evaluation = evaluate_run(run, out, tensorboard=config.tensorboard)
    units, scale = evaluation.display_units, evaluation.display_factors
    for split, metrics in evaluation.metrics.splits.items():
        for mode in ("windowed", "free_run"):
            parts = [f"{k} R² {v.r2:.4f}, RMSE {v.rmse * scale.get(k, 1.0):.3g} {units.get(k, '')}"
                     for k, v in metrics.mode(mode)["all"].items() if k != "overall"]
            print(f"{run.label} {split} {mode}: {'; '.join(parts)}")
    print(f"report: {out / 'summary.md'}")


if __name__ == "__main__":
    main()
