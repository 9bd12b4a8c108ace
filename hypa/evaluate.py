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

from hypa.evaluation.evaluation import Evaluation, evaluate_run, run_datamodule
from hypa.evaluation.runs import load_run
from hypa.errors import hydra_command

__all__ = ["Evaluation", "evaluate_run", "run_datamodule", "main"]


@hydra_command("hypa.evaluate", "evaluate")
def main(cfg: DictConfig) -> None:
    from hydra.utils import get_original_cwd

    path = Path(str(cfg.run))
    run = load_run(path if path.is_absolute() else Path(get_original_cwd()) / path)
    out = Path(str(cfg.out)) if cfg.out else run.folder / "evaluation"
    evaluation = evaluate_run(run, out, tensorboard=bool(cfg.tensorboard))
    units, scale = evaluation.display_units, evaluation.display_factors
    for split, modes in evaluation.metrics["splits"].items():
        for mode in ("windowed", "free_run"):
            parts = [f"{k} R² {v['r2']:.4f}, RMSE {v['mse'] ** 0.5 * scale.get(k, 1.0):.3g} {units.get(k, '')}"
                     for k, v in modes[mode]["all"].items() if k != "overall"]
            print(f"{run.label} {split} {mode}: {'; '.join(parts)}")
    print(f"report: {out / 'summary.md'}")


if __name__ == "__main__":
    main()
