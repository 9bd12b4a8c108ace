"""Explain what the learned blocks of a trained run learned.

    hypa explain run=outputs/train/v1-lstm/2026-11-22_10-00-00-000000                    # every ANN block
    hypa explain run=outputs/train/v1-lstm/2026-11-22_10-00-00-000000 block=rear_steering
    hypa explain run=RUN baseline=outputs/train/physical/...   # the replacement beside a baseline

Writes ``explanation.md``, ``explanation.json`` and the figures into the Hydra run folder
(``outputs/explain/<time>/``, held while it runs: :mod:`hypa.commands.output_folder`; :mod:`hypa.explain.api`
holds what it computes).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from hypa.commands.config import ExplainConfig, hydra_command, typed
from hypa.commands.output_folder import holding_output


@hydra_command("hypa explain", "explain")
@holding_output("hypa explain")  # its folder held before anything is written
def main(cfg: DictConfig) -> None:
    from hypa.commands.entry import from_cwd
    from hypa.evaluation.api import run_datamodule
    from hypa.evaluation.runs import load_run
    from hypa.explain.api import Settings, explain_run, select_blocks
    from hypa.explain.result import replacement_line

    config = typed(cfg, ExplainConfig)  # every value checked (hypa.commands.config)
    block = config.block
    settings = Settings(extra=config.extra, penalty=config.penalty, margin=config.margin, max_lag=config.max_lag,
                        max_delay=config.max_delay, plot=config.plot)
    run = load_run(from_cwd(config.run), config.trust)
    baseline = load_run(from_cwd(config.baseline), config.trust) if config.baseline else None
    select_blocks(run.module.model.spec, block)  # a wrong block name fails before the data are read
    out = Path(HydraConfig.get().runtime.output_dir)
    dm = run_datamodule(run)
    started = time.perf_counter()
    results = explain_run(run, dm, out, block, settings, progress=lambda text: print(text, flush=True),
                          baseline=baseline)
    seconds = time.perf_counter() - started
    for result in results:
        print(result.summary(), flush=True)
        if result.replacement:
            print("  " + replacement_line(result.replacement), flush=True)
    fits = ", ".join(f"{r.problem.block} {r.problem.output} {r.seconds:.1f} s" for r in results)
    print(f"explained in {seconds:.1f} s after training (fitting the ladders: {fits}); "
          f"report: {out / 'explanation.md'}", flush=True)


if __name__ == "__main__":
    sys.exit(main())
