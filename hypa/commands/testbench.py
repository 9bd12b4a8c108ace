"""Generate (or find cached) test-bench data: ``hypa testbench [overrides]``.

Examples::

    hypa testbench                                   # default data, cached
    hypa testbench out=data/testbench plot=true      # into a folder, with PNGs
    hypa testbench testbench.rear_steering.enabled=false
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import numpy as np
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig
from scipy.signal import welch

from hypa.commands.config import TestbenchCommandConfig, hydra_command, typed
from hypa.core.errors import UserError, settings
from hypa.paper.testbench.config import TestbenchConfig
from hypa.paper.testbench.dataset import ensure_dataset, generate_dataset, load_description
from hypa.paper.testbench.plots import plot_axle_characteristics, plot_record, plot_spectrum
from hypa.paper.testbench.records import read_record
from hypa.paper.testbench.truth import axle_characteristic, static_axle_loads

log = logging.getLogger(__name__)


def summarize(folder: Path) -> str:
    """A readable table of the files in a dataset folder (maxima of the measured signals)."""
    description = load_description(folder)
    lines = [
        f"test-bench data in {Path(folder).resolve()}  (config hash {description['config_hash']})",
        (f"{'file':<16}{'duration':>10}{'samples':>10}{'rate':>9}{'max|sw|':>10}"
        f"{'max|ay|':>11}{'max|rear|':>11}  segments"),
    ]
    for file, info in description["files"].items():
        columns = read_record(Path(folder) / file)
        rate = 1.0 / np.mean(np.diff(columns["time"]))
        segments = ", ".join(s["name"] for s in info["segments"])
        lines.append(
            f"{file:<16}{info['duration_s']:>8.1f} s{info['samples']:>10d}{rate:>6.0f} Hz"
            f"{np.degrees(np.max(np.abs(columns['steering_wheel_angle']))):>6.1f} deg"
            f"{np.max(np.abs(columns['lateral_acceleration'])):>6.2f} m/s2"
            f"{np.degrees(np.max(np.abs(columns['rear_wheel_angle']))):>7.2f} deg  {segments}"
        )
    return "\n".join(lines)


def write_plots(folder: Path, record: str, config: TestbenchConfig, plot_dir: Path) -> list[Path]:
    """PNG overviews: one record's time histories, excitation spectra, axle characteristics."""
    description = load_description(folder)
    plot_dir.mkdir(parents=True, exist_ok=True)
    fs = description["sample_rate_hz"]
    info = description["files"][f"{record}.parquet"]
    columns = read_record(folder / f"{record}.parquet")
    segments = [(s["name"], s["start_s"], s["end_s"]) for s in info["segments"]]
    figures = {
        f"{record}_overview.png": plot_record(
            columns["time"],
            columns["steering_wheel_angle"],
            columns["yaw_rate"],
            columns["side_slip"],
            columns["lateral_acceleration"],
            columns["rear_wheel_angle"],
            segments,
            title=f"{record}.parquet",
        ),
    }
    psd = {}
    for file, file_info in description["files"].items():
        stochastic = file_info["segments"][0]
        end = int(round(stochastic["end_s"] * fs))
        sw = read_record(folder / file)["steering_wheel_angle"][:end]
        segment_length = min(len(sw), int(16 * fs))  # 1/16 Hz resolution
        frequency, psd[f"{file} steering wheel angle"] = welch(sw, fs, nperseg=segment_length)
    figures["excitation_spectra.png"] = plot_spectrum(
        frequency,
        psd,
        config.records[record].break_frequency_hz,
        config.excitation.stochastic.cutoff_hz,
    )
    load_f, load_r = static_axle_loads(config.vehicle)
    alpha = np.linspace(-0.25, 0.25, 501)
    figures["axle_characteristics.png"] = plot_axle_characteristics(
        alpha,
        {
            "front (truth)": axle_characteristic(alpha, config.vehicle.cf, load_f, config.tires),
            "rear (truth)": axle_characteristic(alpha, config.vehicle.cr, load_r, config.tires),
            "front linear c_f alpha": config.vehicle.cf * alpha,
            "rear linear c_r alpha": config.vehicle.cr * alpha,
        },
    )
    paths = []
    for name, figure in figures.items():
        figure.savefig(plot_dir / name, dpi=110)
        paths.append(plot_dir / name)
    return paths


@hydra_command("hypa testbench", "testbench")
def main(cfg: DictConfig) -> None:
    command = typed(cfg, TestbenchCommandConfig)  # every value checked (hypa.commands.config)
    with settings("testbench"):  # the settings, and generating the records from them
        config = TestbenchConfig.from_hydra(cfg.testbench)
        if command.out is not None:
            folder = generate_dataset(config, Path(command.out))
        else:
            cache_dir = Path(command.cache_dir) if command.cache_dir is not None else None
            folder = ensure_dataset(config, cache_dir)
    if command.plot and f"{command.plot_record}.parquet" not in load_description(folder)["files"]:
        raise UserError(f"plot_record={command.plot_record} is not a record of the test bench; "
                        f"records: {', '.join(config.records)}")
    print(summarize(folder))
    if command.plot:
        plot_dir = Path(HydraConfig.get().runtime.output_dir)
        for path in write_plots(folder, command.plot_record, config, plot_dir):
            print(f"plot: {path}")


if __name__ == "__main__":
    sys.exit(main())
