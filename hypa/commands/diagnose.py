"""Diagnose what the nominal physics gets wrong, name the cause, extend the model and measure the gain.

    hypa diagnose                                          # the test bench, model=vehicle_nominal
    hypa diagnose testbench.rear_steering.enabled=false    # hide / reveal effects
    hypa diagnose dataset=racecar                          # a real log and its own nominal model
    hypa diagnose dataset=files data.dir=PATH vehicle.cf=140000
    hypa diagnose -m dataset=files data.dir=LOG1,LOG2,LOG3   # a fleet: fleet.md in the sweep folder

Works on any system: the nominal model is a hypa model config (``model=M``), its candidate causes
come from the catalogues (built-in and ``diagnosis.catalogue=[mine.yaml]``), and everything is
simulated by the one physics engine (:mod:`hypa.diagnosis.api`). Writes ``diagnosis.md``,
``diagnosis.json``, the figures and ``conf/model/diagnosed*.yaml`` into the Hydra run folder, which it
holds while it runs (:mod:`hypa.commands.output_folder`: a second command into it is refused, as is a folder
that holds a symbolic link or a training run's).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from hypa.commands.config import hydra_command, model_node
from hypa.commands.fleet import record_failures
from hypa.commands.output_folder import holding_output


@hydra_command("hypa diagnose", "diagnose")
@holding_output("hypa diagnose")  # the run folder held first: a refused job records nothing into another's
@record_failures("hypa diagnose")  # -m over many logs: a bad log is reported in the fleet summary, the others run
def main(cfg: DictConfig) -> None:
    from hypa.commands.config import DiagnoseConfig, typed
    from hypa.commands.entry import (
        data_dir_from_config,
        data_overrides,
        from_cwd,
        model_datamodule,
        user_config_dirs,
        vehicle_from_config,
    )
    from hypa.core.errors import UserError
    from hypa.diagnosis.api import diagnose_system
    from hypa.diagnosis.catalogue import load_catalogue
    from hypa.diagnosis.problem import Problem, nominal_hold
    from hypa.models.spec import parse_model_spec
    from hypa.reporting.numbers import change_text

    config = typed(cfg, DiagnoseConfig)  # every value checked (hypa.commands.config)
    if config.model is None:
        raise UserError("no nominal model: give one with model=M (a conf/model/M.yaml, e.g. model=vehicle_nominal)")
    out = Path(HydraConfig.get().runtime.output_dir)
    spec = parse_model_spec(model_node(cfg))
    hold = nominal_hold(spec, config.physics.hold)  # one that contradicts the model's own: refused before the data
    catalogue = load_catalogue([from_cwd(p) for p in config.diagnosis.catalogue])
    values = vehicle_from_config(cfg.vehicle).as_dict() if cfg.get("vehicle") else {}
    print("reading the data", flush=True)
    # data.past null: for the model; the auxiliary channels as inputs a candidate may read (unmodeled_input)
    dm = model_datamodule(cfg, data_dir_from_config(cfg), spec, values, auxiliary_inputs=True).dm
    diagnosis = config.diagnosis
    workers = {} if diagnosis.workers is None else {"workers": diagnosis.workers}
    problem = Problem(dm, values, hold=hold, horizon=config.data.window,
                      fit_seconds=diagnosis.fit_seconds, stretch_s=diagnosis.stretch_s, **workers)
    user_dirs = user_config_dirs()
    overrides = data_overrides(HydraConfig.get().overrides.task)
    trainer = None
    if config.extension.train:
        from hypa.commands.train import train_here
        from hypa.diagnosis.trained import ExtensionTrainingError, train_extension

        def train(arguments: Sequence[str], run_dir: Path) -> None:
            train_here(arguments, run_dir, "training the extended model", error=ExtensionTrainingError)

        def trainer(command: Sequence[str]):
            return train_extension(train, command, out / "extended_run", dm, list(config.extension.train_overrides),
                                   plot=config.plot, progress=lambda text: print("          " + text, flush=True))
    result = diagnose_system(spec, problem, out, overrides, plot=config.plot,
                             progress=lambda text: print(text, flush=True),
                             config_dir=user_dirs[0] if user_dirs else None, catalogue=catalogue,
                             max_causes=diagnosis.max_causes, min_gain=diagnosis.min_gain,
                             train_extension=trainer)
    figures = result.headline()  # the figures diagnosis.md's headline shows, formatted once
    print(f"named causes: {', '.join(result.causes) or 'none'}; validation error {figures['nominal']} → "
          f"{figures['extended']} of the output variance ({figures['change']}) with them applied; "
          f"unexplained: {', '.join(s.output for s in result.unexplained) or 'nothing'}; "
          f"report: {out / 'diagnosis.md'}", flush=True)
    for line in result.not_covered:
        print(f"validation data: {line}", flush=True)
    for line in result.too_short:
        print(f"too little data: {line}", flush=True)
    trained = result.extended.trained
    if trained:
        print(f"trained extension ({trained.run}): validation error {figures['trained']} of the output variance "
              f"({change_text(trained.change)} against the nominal physics)", flush=True)
        for explained in trained.explained:
            print(f"  its network {explained.block} learned: {explained.description}", flush=True)
    else:
        for name, command in result.extended.train_command.items():
            print(f"train {name} with\n  {command}", flush=True)


if __name__ == "__main__":
    sys.exit(main())
