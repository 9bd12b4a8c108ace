"""Export a trained run as a one-step model that runs without hypa.

    hypa export run=outputs/train/v2-lstm/2026-11-22_10-00-00-000000
    hypa export run=RUN format=onnx record=1
    hypa export run=RUN format=fmu           # + model.fmu, FMI 2.0 co-simulation (Python and onnxruntime inside)
    hypa export run=RUN format=c             # + native.fmu, source-code FMI 2.0 FMU in C99 (CS and ME)
    hypa export run=RUN format=statespace    # + statespace.mat / .json, physics-only models
    hypa export run=RUN format=all           # every format the model allows

Writes ``model.onnx``, ``reference.csv`` and ``export.json`` (and the format's files) into the
Hydra run folder (``outputs/export/<time>/``; held while it runs, never a training run's:
:mod:`hypa.commands.output_folder`) and succeeds only when each format reproduces
hypa's free run of the reference record: onnxruntime, fmpy (both FMUs), the discrete state space
(:mod:`hypa.export` holds what it builds and checks).
"""

from __future__ import annotations

import sys
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from hypa.commands.config import ExportConfig, hydra_command, typed
from hypa.commands.output_folder import holding_output


@hydra_command("hypa export", "export")
@holding_output("hypa export")  # its folder held before anything is written
def main(cfg: DictConfig) -> None:
    from hypa.commands.entry import from_cwd
    from hypa.evaluation.api import run_datamodule
    from hypa.evaluation.runs import load_run
    from hypa.export import export_run, formats_to_build

    config = typed(cfg, ExportConfig)
    formats_to_build(config.format)  # an unknown format fails before the run is read
    run = load_run(from_cwd(config.run), config.trust)
    out = Path(HydraConfig.get().runtime.output_dir)
    export = export_run(run, run_datamodule(run), out, config.format, config.record, config.tolerance)
    sizes = ", ".join(f"{name} {size / 1024:.1f} KiB" for name, size in export.sizes().items())
    print(f"{run.label}: one step, {export.state_size} states; {sizes}", flush=True)
    for check in export.checks.values():
        print(check.summary(), flush=True)
    if export.native:
        print(native_summary(export.native), flush=True)
    for name, why in export.skipped.items():
        print(f"skipped {name}: {why}", flush=True)
    print(f"export: {out}", flush=True)


def native_summary(figures: dict) -> str:
    """One line on the C step: its time, model exchange, and its distance from hypa's float32 free run."""
    exchange = figures["model_exchange"]
    worst = max(exchange["outputs"].values(), key=lambda o: o["relative"])["relative"] if exchange["outputs"] else 0.0
    float32 = ", ".join(f"{n} {v:.2g}" for n, v in figures["float32_free_run"].items())
    seconds = figures["bare_seconds_per_step"]
    return (f"C step (float64, {figures['statements']} statements): {seconds * 1e9:.0f} ns per step compiled -O2; "
            f"model exchange max error / σ {worst:.2g}; against hypa's float32 free run (reference.csv) / σ: "
            f"{float32}")


if __name__ == "__main__":
    sys.exit(main())
