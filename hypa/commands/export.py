"""Export a trained run as a one-step model that runs without hypa.

    python -m hypa.export run=outputs/train/v2-lstm/2026-11-22_10-00-00
    python -m hypa.export run=RUN format=onnx record=1

Writes ``model.onnx``, ``reference.csv`` and ``export.json`` into the Hydra run folder
(``outputs/export/<time>/``) and succeeds only when onnxruntime reproduces hypa's free run of
the reference record (:mod:`hypa.export` holds what it builds and checks).
"""

from __future__ import annotations

from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from hypa.commands.config import ExportConfig, typed
from hypa.errors import hydra_command


@hydra_command("hypa.export", "export")
def main(cfg: DictConfig) -> None:
    from hypa.commands.entry import from_cwd
    from hypa.evaluation.evaluation import run_datamodule
    from hypa.evaluation.runs import load_run
    from hypa.export import export_run, formats_to_build

    config = typed(cfg, ExportConfig)
    formats_to_build(config.format)  # a format not built yet fails before the run is read
    run = load_run(from_cwd(config.run))
    out = Path(HydraConfig.get().runtime.output_dir)
    export = export_run(run, run_datamodule(run), out, config.format, config.record, config.tolerance)
    sizes = ", ".join(f"{name} {size / 1024:.1f} KiB" for name, size in export.sizes().items())
    print(f"{run.label}: one step, {export.state_size} states; {sizes}", flush=True)
    print(export.check.summary(), flush=True)
    print(f"export: {out}", flush=True)


if __name__ == "__main__":
    main()
