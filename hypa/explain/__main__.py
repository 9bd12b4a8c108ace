"""Explain what the learned blocks of a trained run learned.

    python -m hypa.explain run=outputs/train/v1-lstm/2026-11-22_10-00-00                    # every ANN block
    python -m hypa.explain run=outputs/train/v1-lstm/2026-11-22_10-00-00 block=rear_steering
    python -m hypa.explain run=RUN baseline=outputs/train/physical/...   # the replacement beside a baseline

Writes ``explanation.md``, ``explanation.json`` and the figures into the Hydra run folder
(``outputs/explain/<time>/``; :mod:`hypa.explain.run` holds what it computes).
"""

from __future__ import annotations

import time
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from hypa.errors import hydra_command


@hydra_command("hypa.explain", "explain", config_path="../../conf")
def main(cfg: DictConfig) -> None:
    from hydra.utils import get_original_cwd

    from hypa.errors import setting
    from hypa.evaluation.evaluation import run_datamodule
    from hypa.evaluation.runs import load_run
    from hypa.explain.report import replacement_line
    from hypa.explain.run import Settings, explain_run, select_blocks

    path = Path(setting(cfg, "run", str)).expanduser()
    block = setting(cfg, "block", str, optional=True)
    extra = cfg.get("extra")
    settings = Settings(extra=None if extra is None else tuple(str(n) for n in ([extra] if isinstance(extra, str) else extra)),
                        penalty=setting(cfg, "penalty", float), margin=setting(cfg, "margin", float),
                        max_lag=setting(cfg, "max_lag", float), max_delay=setting(cfg, "max_delay", float),
                        plot=bool(cfg.plot))
    def here(p: Path) -> Path:
        return p if p.is_absolute() else Path(get_original_cwd()) / p

    run = load_run(here(path))
    baseline = setting(cfg, "baseline", str, optional=True)
    baseline = load_run(here(Path(baseline).expanduser())) if baseline else None
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
    main()
