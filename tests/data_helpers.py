"""Synthetic measured-data files for the hypa.data tests (written into tmp_path, no network)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from scipy.io import savemat

from hypa.paper.testbench.sensors import CHANNELS

from conftest import ROOT

SAMPLE_RATE_HZ = 1024.0
ALL_CHANNELS = CHANNELS  # every channel the test bench measures


def synthetic_channels(
    duration_s: float = 8.0,
    sample_rate_hz: float = SAMPLE_RATE_HZ,
    seed: int = 0,
    offset: float = 0.0,
    channels: tuple[str, ...] = ALL_CHANNELS,
) -> dict[str, np.ndarray]:
    """Smooth band-limited (0.2..2 Hz) signals in SI units plus ``time`` [s].

    ``offset`` is added to every channel but time, so that splits can differ in mean.
    """
    rng = np.random.default_rng(seed)
    time = np.arange(round(duration_s * sample_rate_hz)) / sample_rate_hz
    out = {"time": time}
    scale = {"steering_wheel_angle": 0.5, "yaw_rate": 0.2, "side_slip": 0.02,
             "lateral_acceleration": 4.0, "velocity": 0.3, "rear_wheel_angle": 0.01}
    for name in channels:
        freqs = rng.uniform(0.2, 2.0, size=4)
        phases = rng.uniform(0, 2 * np.pi, size=4)
        wave = np.sin(2 * np.pi * freqs[:, None] * time + phases[:, None]).sum(axis=0)
        base = 33.3 if name == "velocity" else 0.0
        out[name] = base + offset + scale[name] * wave
    return out


def write_table(path: Path, columns: dict[str, np.ndarray], mat_oned_as: str = "row") -> Path:
    """Write columns as CSV (17 significant digits), Parquet or MATLAB v5, by suffix."""
    path = Path(path)
    if path.suffix == ".csv":
        names = list(columns)
        rows = np.column_stack([np.asarray(columns[n], dtype=float) for n in names])
        np.savetxt(path, rows, fmt="%.17g", delimiter=",", header=",".join(names), comments="")
    elif path.suffix == ".parquet":
        pq.write_table(pa.table({n: np.asarray(v) for n, v in columns.items()}), path)
    elif path.suffix == ".mat":
        savemat(path, {n: np.asarray(v) for n, v in columns.items()}, oned_as=mat_oned_as)
    else:
        raise ValueError(path.suffix)
    return path


def write_csv_text(path: Path, header: list[str], rows: list[list[str]]) -> Path:
    """A hand-made CSV (for cells numpy would not write, e.g. empty or text)."""
    lines = [",".join(header)] + [",".join(row) for row in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def make_data_dir(
    root: Path,
    suffix: str = ".csv",
    n_train: int = 2,
    n_val: int = 1,
    n_test: int = 0,
    duration_s: float = 8.0,
    train_offset: float = 0.0,
    val_offset: float = 0.0,
    channels: tuple[str, ...] = ALL_CHANNELS,
) -> Path:
    """A data folder with train_*, val_* and test_* files of synthetic records."""
    root.mkdir(parents=True, exist_ok=True)
    seed = 0
    for split, count, offset in (("train", n_train, train_offset), ("val", n_val, val_offset),
                                 ("test", n_test, val_offset)):
        for i in range(count):
            seed += 1
            data = synthetic_channels(duration_s, seed=seed, offset=offset, channels=channels)
            write_table(root / f"{split}_{i:02d}{suffix}", data)
    return root


def fake_mat73(path: Path) -> Path:
    """A file whose MATLAB header says v7.3 (HDF5); scipy refuses such files."""
    text = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, HDF5 schema 1.00 ."
    header = text.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02" + b"IM"
    path.write_bytes(header + b"\x00" * 512)
    return path


USER_EXAMPLE = ROOT / "examples" / "user_system"


def make_dc_motor_data(folder: Path, seconds: float) -> dict[str, str]:
    """The DC-motor example's data (``examples/user_system/make_data.py``) in ``folder``; returns
    the environment that finds the example's system class (its folder on PYTHONPATH)."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "PYTHONPATH": str(USER_EXAMPLE)}
    made = subprocess.run([sys.executable, str(USER_EXAMPLE / "make_data.py"), str(folder), "--seconds", str(seconds)],
                          capture_output=True, text=True, timeout=120, env=env, check=False)
    assert made.returncode == 0, made.stderr[-2000:]
    return env


# the example DC motor's physics with a correction network, one stage (trained jointly after identification)
DC_MOTOR_HYBRID = """# @package model
name: dc_motor_hybrid
blocks:
  motor:
    kind: physics
    system: dc_motor:DCMotor
    inputs: [voltage]
    outputs: [speed_physics]
    observe: {speed_physics: speed}
    initial_state: estimate
    trainable: [torque_constant, friction, load_torque]
  correction:
    kind: ann
    inputs: [voltage, speed_physics]
    outputs: [speed]
    residual_of: [speed_physics]
outputs: [speed]
stages: []
"""


def importable(folder: Path, monkeypatch, modules: dict[str, str]) -> Iterator[Path]:
    """A user's modules (name -> code) written into ``folder`` and importable while the test runs
    (a fixture's body: ``yield from importable(...)``); forgotten again afterwards."""
    import sys

    for name, code in modules.items():
        (folder / f"{name}.py").write_text(code)
    monkeypatch.syspath_prepend(str(folder))
    yield folder
    for name in modules:
        sys.modules.pop(name, None)


def user_dataset(data: dict, vehicle: str = "none") -> str:
    """The YAML of a user's data set config (conf/dataset/NAME.yaml): the typed data schema with
    ``data`` (``source: files`` and ``dir: ???`` unless given), in a config folder of the user's."""
    from omegaconf import OmegaConf

    head = f"# @package _global_\ndefaults:\n  - /hypa/data_schema@data\n  - override /vehicle: {vehicle}\n  - _self_\n"
    return head + OmegaConf.to_yaml({"data": {"source": "files", "dir": "???", **data}})


def user_project(folder: Path, module: str, code: str, dataset: str, dataset_yaml: str,
                 models: dict[str, str]) -> Path:
    """A user's own project in ``folder``: ``module``.py (their systems, importable with ``folder`` on
    PYTHONPATH), conf/dataset/``dataset``.yaml, conf/model/NAME.yaml (``models``: name -> YAML) and an
    empty data/ folder for their records; returns ``folder``."""
    (folder / f"{module}.py").write_text(code)
    (folder / "conf" / "dataset").mkdir(parents=True)
    (folder / "conf" / "model").mkdir()
    (folder / "conf" / "dataset" / f"{dataset}.yaml").write_text(dataset_yaml)
    for name, text in models.items():
        (folder / "conf" / "model" / f"{name}.yaml").write_text(text)
    (folder / "data").mkdir()
    return folder


def run_user_benchmark(user: Path, dataset: str, models: list[str], out: Path, timeout: int = 900,
                       extra: list[str] | None = None) -> dict:
    """``hypa benchmark --config-dir`` on a :func:`user_project` (its data in data/, budget=full):
    benchmark.json's models of ``dataset`` (asserting the command succeeded)."""
    import json
    import os
    import subprocess
    import sys

    result = subprocess.run(
        [sys.executable, "-m", "hypa", "benchmark", "--config-dir", str(user / "conf"), f"dataset={dataset}",
         f"data.dir={user / 'data'}", "budget=full", f"models=[{','.join(models)}]", f"hydra.run.dir={out}",
         *(extra or [])],
        cwd=ROOT, capture_output=True, text=True, timeout=timeout,
        env={**os.environ, "PYTHONPATH": str(user)}, check=False)
    assert result.returncode == 0, result.stderr[-3000:]
    return json.loads((out / "benchmark.json").read_text())[dataset]["models"]
