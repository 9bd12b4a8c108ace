"""Simulate the nominal vehicle physics on measured data and report how far off it is.

    python -m hypa.simulate                               # default test-bench data
    python -m hypa.simulate physics.hold=foh vehicle.cf=140000
    python -m hypa.simulate dataset=files data.dir=PATH data.channels.steering_wheel_angle.unit=deg

The entry point only reads the settings; :func:`hypa.vehicle.simulation.simulate_records` runs
the physics (windowed and free-running on each validation record) and writes
``simulation.json`` and a figure per record into the Hydra run folder.
"""

from __future__ import annotations

from pathlib import Path

import hydra
import numpy as np
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from hypa.errors import setting, settings, user_errors


@hydra.main(config_path="../conf", config_name="simulate", version_base="1.3")
@user_errors("hypa.simulate")
def main(cfg: DictConfig) -> float:
    from hypa.data import datamodule_from_config
    from hypa.entry import data_dir_from_config, vehicle_from_config
    from hypa.physics import HOLDS
    from hypa.vehicle.simulation import REAR_STEERING, simulate_records

    hold = setting(cfg, "physics.hold", str, choices=HOLDS)
    rear = setting(cfg, "physics.rear_steering", str, choices=REAR_STEERING)
    with settings("vehicle"):
        vehicle = vehicle_from_config(cfg.vehicle)
    with settings("testbench"):  # the test bench's settings build its data (files: a folder only)
        data_dir = data_dir_from_config(cfg)
    dm = datamodule_from_config(cfg.data, data_dir)
    out = Path(HydraConfig.get().runtime.output_dir)
    results = simulate_records(dm, vehicle, hold, rear, out, plot=bool(cfg.plot))
    print(f"results and figures in {out}")
    return float(np.mean([m["nrmse"] for m in results["windowed (100 steps)"].values()]))


if __name__ == "__main__":
    main()
