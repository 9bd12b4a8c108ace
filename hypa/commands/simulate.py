"""Simulate a physics model at its configured values on measured data and report how far off it is.

    hypa simulate                                  # the vehicle physics, default test bench
    hypa simulate physics.hold=foh vehicle.cf=140000
    hypa simulate model=vehicle_nominal            # front steering only
    hypa simulate dataset=silverbox                # its own model (<dataset>_physical)
    hypa simulate dataset=files data.dir=PATH data.channels.<input>.unit=deg

The entry point only reads the settings; :func:`hypa.evaluation.nominal.simulate_nominal` runs
the model (windowed and free-running on each validation record, through the same engine as
training) and writes ``simulation.json`` and a figure per record into the Hydra run folder. A free
run that sits at a level the data never reach is one warning line naming the output and the
likely state (:func:`hypa.models.rollout.free_run_levels`).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from hypa.commands.config import SimulateConfig, hydra_command, model_node, typed
from hypa.core.errors import settings


@hydra_command("hypa simulate", "simulate")
def main(cfg: DictConfig) -> float:
    from hypa.commands.entry import data_dir_from_config, model_datamodule, vehicle_from_config
    from hypa.evaluation.nominal import nominal_module, report, simulate_nominal
    from hypa.models.building import model_hold
    from hypa.models.rollout import free_run, free_run_levels
    from hypa.models.spec import parse_model_spec

    config = typed(cfg, SimulateConfig)  # every value checked (hypa.commands.config)
    hold = config.physics.hold
    model_config = model_node(cfg)
    spec = parse_model_spec(model_config)  # the model, parsed once
    model_hold(spec, hold, "physics.hold")  # against the model's own: refused before the data
    with settings("vehicle"):
        values = vehicle_from_config(cfg.vehicle).as_dict() if cfg.vehicle else {}
    with settings("testbench"):  # the test bench's settings build its data (files: a folder only)
        data_dir = data_dir_from_config(cfg)
    dm = model_datamodule(cfg, data_dir, spec, values).dm  # data.past null: chosen for the model
    module = nominal_module(spec, values, dm, hold)
    out = Path(HydraConfig.get().runtime.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    results = simulate_nominal(module, dm, out, plot=config.plot)
    # the hold the physics ran with: the model's own where it fixes one (silverbox_physical: foh)
    print(report(results, dm, f"model {model_config['name']} at its configured values (hold={module.model.hold}) "
                              "against the validation data:"))
    runs = [free_run(module.model, dm, record) for record in dm.records("val")]
    for line in free_run_levels(runs, dm.output_names, module.model, {n: dm.channels[n].unit for n in dm.output_names}):
        print(f"warning: {line}")  # a level no data reach: one line naming the output and the likely state
    print(f"results and figures in {out}")
    return float(np.mean([m["nrmse"] for label, r in results.items() if label.startswith("windowed")
                          for m in r.values()]))


if __name__ == "__main__":
    sys.exit(main())
