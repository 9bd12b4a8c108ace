"""The data for a model (``hypa.commands.entry.model_datamodule``): a null ``data.past`` chosen for the
model and an auxiliary channel the model reads held as an input, from one read of the files, the
command's configuration left as it was; ``hypa train`` records both choices in the run's
``config.yaml``, from which ``hypa evaluate`` builds the same data.

The system: a heated zone that loses heat to the outside, C dT/dt = -g (T - T_out) + P, its one
state estimated from the measured temperature (3 past samples chosen: ``PAST_MARGIN`` x 1 - 1), the
outside temperature declared ``auxiliary`` by the data and read by the model.
"""

from __future__ import annotations

import copy
import json
import os
from pathlib import Path

import pytest
import torch
import yaml
from omegaconf import OmegaConf

import hypa.data.dataset
from hypa.commands.entry import ModelData, model_datamodule
from hypa.data import HypaDataModule
from hypa.data.from_config import datamodule_from_config
from hypa.models.spec import parse_model_spec

from cli_helpers import hypa_run
from data_helpers import importable, user_dataset, user_project
from test_data_with_past import assert_same_data
from test_diagnose_time_scales import _files
from test_diagnose_unmodeled_input import TRUE, data_config, zone_truth

ZONE_SYSTEM = '''
import torch
from hypa.physics import LTIModel, ParameterSpec, StateSpace


class Zone(LTIModel):
    """C dT/dt = -g (T - T_out) + P: a heated zone's temperature, T measured."""
    state_names = ("temperature",)
    input_names = ("heat", "outside")
    output_names = ("temperature",)
    parameters = (ParameterSpec("capacity", 1e7, "J/K"), ParameterSpec("conductance", 500.0, "W/K"))

    def matrices(self, p):
        c, g = p["capacity"], p["conductance"]
        return StateSpace((-g / c).reshape(1, 1), torch.stack([1 / c, g / c]).reshape(1, 2),
                          torch.ones(1, 1, dtype=c.dtype), c.new_zeros(1, 2))
'''
MODEL = {"name": "zone", "hold": "zoh", "blocks": {"zone": {
    "kind": "physics", "system": "zone:Zone", "inputs": ["heat", "outside"], "outputs": ["temperature"],
    "initial_state": "estimate", "trainable": ["conductance"]}}, "outputs": ["temperature"]}
PAST = 3  # PAST_MARGIN x (1 state / 1 measured output) - 1


@pytest.fixture
def zone(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The data folder (4 days to train on, 2 to validate), the system importable while the test runs."""
    folder = tmp_path / "data"
    folder.mkdir()
    _files(folder, {"train": zone_truth(1, 4.0, 1.0), "val": zone_truth(2, 2.0, 1.0)})
    for _ in importable(tmp_path, monkeypatch, {"zone": ZONE_SYSTEM}):
        yield folder


@pytest.fixture
def reads(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The files read (``hypa.data.dataset.load_record``'s calls)."""
    read, original = [], hypa.data.dataset.load_record

    def counted(path, *args, **kwargs):
        read.append(Path(path).name)
        return original(path, *args, **kwargs)

    monkeypatch.setattr(hypa.data.dataset, "load_record", counted)
    return read


def rebuilt(cfg, data: ModelData, folder: Path) -> HypaDataModule:
    """The data built again from ``cfg`` with what ``data`` chose recorded in it (a run's ``config.yaml``)."""
    recorded = copy.deepcopy(cfg)
    for key, value in data.recorded().items():
        OmegaConf.update(recorded, key, value)
    dm = datamodule_from_config(recorded.data, folder)
    dm.setup()
    return dm


def test_a_null_past_is_chosen_from_one_read_of_the_files_and_the_config_is_left_as_it_was(
        zone: Path, reads: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    cfg = OmegaConf.create({"data": {**data_config(zone), "past": None}})
    before = OmegaConf.to_yaml(cfg)
    data = model_datamodule(cfg, zone, parse_model_spec(MODEL), TRUE)
    assert sorted(reads) == ["train.csv", "val.csv"]  # once each, although the past was chosen after reading them
    assert OmegaConf.to_yaml(cfg) == before  # neither data.past nor the channel's role written into it
    assert (data.past_chosen, data.promoted, data.dm.past) == (PAST, ("outside",), PAST)
    assert data.dm.input_names == ("heat", "outside")
    assert data.recorded() == {"data.past": PAST, "data.channels.outside.role": "input"}
    out = capsys.readouterr().out
    assert "data: outside declared auxiliary, read by the model as input(s): held as input(s)" in out
    assert f"data.past: {PAST} samples before each window ({PAST * 300:.3g} s), chosen for the model" in out
    assert_same_data(data.dm, rebuilt(cfg, data, zone))  # what a run records builds the same data


def test_a_given_past_is_kept_and_only_the_read_channel_is_recorded(zone: Path, reads: list[str]) -> None:
    cfg = OmegaConf.create({"data": {**data_config(zone), "past": 5}})
    data = model_datamodule(cfg, zone, parse_model_spec(MODEL), TRUE)
    assert sorted(reads) == ["train.csv", "val.csv"]
    assert (data.past_chosen, data.dm.past) == (None, 5)
    assert data.recorded() == {"data.channels.outside.role": "input"}
    assert cfg.data.channels.outside.role == "auxiliary" and cfg.data.past == 5
    fresh = rebuilt(cfg, data, zone)
    assert_same_data(data.dm, fresh)
    assert torch.equal(data.dm.normalization.mean, fresh.normalization.mean)


def test_train_records_the_chosen_past_and_the_read_channel_and_evaluate_builds_on_them(tmp_path: Path) -> None:
    dataset = user_dataset({
        "time": {"column": "time", "unit": "s"}, "sample_rate_hz": 1 / 300, "rate_hz": None,
        "channels": {"heat": {"role": "input", "unit": "W"}, "temperature": {"role": "output", "unit": "K"},
                     "outside": {"role": "auxiliary", "unit": "K"}},
        "window": 100, "past": None, "stride": 10, "eval_stride": 50})
    (tmp_path / "user").mkdir()
    user = user_project(tmp_path / "user", "zone", ZONE_SYSTEM, "zone", dataset,
                        {"zone": "# @package model\n" + yaml.safe_dump(MODEL)})
    _files(user / "data", {"train": zone_truth(1, 4.0, 1.0), "val": zone_truth(2, 2.0, 1.0)})
    env = {**os.environ, "PYTHONPATH": str(user)}

    def run(*args: str) -> str:
        result = hypa_run(args, env=env)
        assert result.returncode == 0, result.stderr[-3000:]
        return result.stdout

    out = run("train", "--config-dir", str(user / "conf"), "dataset=zone", "model=zone", f"data.dir={user / 'data'}",
              "trainer.max_epochs=1", "trainer.enable_progress_bar=false", f"hydra.run.dir={tmp_path / 'train'}")
    assert f"data.past: {PAST} samples before each window" in out and "data: outside declared auxiliary" in out, out
    recorded = yaml.safe_load((tmp_path / "train" / "config.yaml").read_text())["data"]
    assert recorded["past"] == PAST and recorded["channels"]["outside"]["role"] == "input", recorded
    hydra = yaml.safe_load((tmp_path / "train" / ".hydra" / "config.yaml").read_text())["data"]
    assert hydra["past"] is None and hydra["channels"]["outside"]["role"] == "auxiliary"  # as composed
    run("evaluate", f"run={tmp_path / 'train'}", "trust=[zone]", "tensorboard=false",
        f"hydra.run.dir={tmp_path / 'evaluate'}")
    metrics = json.loads((tmp_path / "train" / "evaluation" / "metrics.json").read_text())
    assert metrics["splits"]["val"]["free_run"]["all"]["temperature"]["r2"] > 0.99, metrics["splits"]["val"]
