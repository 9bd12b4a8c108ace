"""The `dataset` config group: composed with Hydra, checked by the schema, built into a DataModule."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from hydra.errors import ConfigCompositionException
from omegaconf import OmegaConf

from hypa.conf import CONF
from hypa.data import DataError, HypaDataModule, datamodule_from_config, decimate
from hypa.data.from_config import data_dir_from_config, validated
from hypa.paper.testbench.sensors import TESTBENCH_CHANNELS

from conftest import ROOT, compose_config
from data_helpers import synthetic_channels, write_table

DATASETS = ("testbench", "files", "silverbox", "emps", "racecar")


def _compose(*overrides: str, config: str = "train"):
    return compose_config(config, overrides)


@pytest.mark.parametrize("name", DATASETS)
def test_every_dataset_composes_and_passes_the_schema(name):
    cfg = _compose(f"dataset={name}")
    data = validated(cfg.data)
    assert data.source == ("testbench" if name == "testbench" else "files")
    roles = {c.role for c in data.channels.values()}
    assert {"input", "output"} <= roles
    assert OmegaConf.to_container(cfg.data.channels)  # the lead's ${channels:...} resolver reads it


def test_testbench_and_files_declare_the_same_channels():
    bench, files = _compose("dataset=testbench").data, _compose("dataset=files").data
    assert OmegaConf.to_container(bench.channels) == OmegaConf.to_container(files.channels)
    for key in ("sample_rate_hz", "rate_hz", "window", "past", "stride", "eval_stride", "batch_size"):
        assert bench[key] == files[key], key


def test_data_sets_choose_their_vehicle_and_the_command_line_wins():
    assert OmegaConf.to_container(_compose("dataset=silverbox").vehicle) == {}
    assert OmegaConf.to_container(_compose("dataset=emps").vehicle) == {}
    assert _compose("dataset=racecar").vehicle.mass == 790.0
    assert _compose("dataset=testbench").vehicle.mass == 1900.0
    assert _compose("dataset=racecar", "vehicle=sedan").vehicle.mass == 1900.0
    # a primary config without a vehicle default composes too (the benchmark's)
    assert _compose("dataset=racecar", config="benchmark").vehicle.mass == 790.0


def test_files_dataset_with_overrides_reads_degrees(tmp_path):
    data_dir = tmp_path / "d"
    data_dir.mkdir()
    for seed, file_name in enumerate(("train_deg.parquet", "val_deg.csv")):
        data = synthetic_channels(5.0, seed=seed)
        deg = dict(data, steering_wheel_angle=np.degrees(data["steering_wheel_angle"]))
        write_table(data_dir / file_name, deg)
    cfg = _compose("dataset=files", f"data.dir={data_dir}", "data.window=20",
                   "data.channels.steering_wheel_angle.unit=deg")
    dm = datamodule_from_config(cfg.data, data_dir_from_config(cfg))
    dm.setup("fit")
    assert dm.window == 20 and dm.rate_hz == 32.0
    np.testing.assert_allclose(
        dm.records("train")[0]["steering_wheel_angle"],
        decimate(synthetic_channels(5.0, seed=0)["steering_wheel_angle"], 32), rtol=1e-12, atol=1e-14,
    )


def test_relative_data_dir_is_taken_from_where_the_command_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = _compose("dataset=files", "data.dir=my/data")
    assert data_dir_from_config(cfg) == tmp_path / "my" / "data"
    with pytest.raises(ValueError, match=r"needs the folder of your files: data.dir=PATH"):
        data_dir_from_config(_compose("dataset=files"))
    monkeypatch.setenv("HYPA_DATA", "/elsewhere")
    assert data_dir_from_config(_compose("dataset=silverbox")) == Path("/elsewhere/silverbox")


def test_a_misspelled_key_is_an_error_naming_it():
    with pytest.raises(ConfigCompositionException, match=r"data\.windw"):
        _compose("dataset=silverbox", "data.windw=50")
    with pytest.raises(ConfigCompositionException, match=r"data\.channels\.u\.unitt"):
        _compose("dataset=silverbox", "data.channels.u.unitt=mV")
    # what Hydra lets through (+key) or a plain YAML brings is caught when the module is built
    cfg = _compose("dataset=silverbox", "+data.windw=50")
    with pytest.raises(DataError, match=r"^data\.windw: unknown key; data has the keys source, dir"):
        datamodule_from_config(cfg.data, Path("."))


def _node(**changes) -> dict:
    node = OmegaConf.to_container(_compose("dataset=silverbox").data, resolve=True)
    for key, value in changes.items():
        target = node
        *path, last = key.split("__")
        for part in path:
            target = target[part]
        target[last] = value
    return node


BAD = [  # (changes to the silverbox node, the expected one-line error)
    ({"channels__u__unitt": "V"},
     r"^data\.channels\.u\.unitt: unknown key; data\.channels\.u has the keys role, "),
    ({"channels__z": {"role": "output"}}, r"^data\.channels\.z\.unit is missing"),
    ({"channels__u__role": "inptu"},
     r"channel 'u' has the unknown role 'inptu' \(did you mean 'input'\?\); roles: input, output"),
    ({"channels__u__unit": "Volts"}, r"unknown unit 'Volts' of channel 'u'"),
    ({"channels__y__display_unit": "deg"}, r"display unit 'deg' of channel 'y' is a unit of angle"),
    ({"splits__test__multisine": [{"fille": "SNLS80mV.csv"}]},
     r"^data\.splits\.test\.multisine\.0\.fille: unknown key"),
    ({"splits__train": [{"file": "SNLS80mV.csv", "start": 0.5, "stop": 0.25}]},
     r"piece SNLS80mV\.csv\[0\.5:0\.25\]: is empty"),
    ({"splits__val": [{"file": "SNLS80mV.csv", "start": "a"}]},
     r"start must be an int \(sample index\), a float"),
    ({"window": "long"}, r"^data\.window: "),
    ({"select": ["speed > 5"]},
     r"select condition 'speed > 5' names 'speed', which is not a declared channel"),
    ({"select": ["u >> 5"]}, r"select condition 'u >> 5' is not of the form"),
    ({"channels__u__expression": "__import__('os')", "channels__u__column": None},
     r"calls '__import__', which is not allowed"),
]


@pytest.mark.parametrize(("changes", "message"), BAD)
def test_bad_declarations_fail_with_one_line(changes, message):
    with pytest.raises(DataError, match=message) as error:
        datamodule_from_config(_node(**changes), Path(".")).setup()
    assert "\n" not in str(error.value)


def test_testbench_dataset_loads_as_before(hypa_cache):
    """The default data set through the config: the test bench's files at 1024 Hz, decimated to
    32 Hz, windows of 101 samples every 5 (train) / 50 (val), scaled with training statistics."""
    import pyarrow.parquet as pq

    from conftest import SHORT_OVERRIDES

    cfg = _compose(*SHORT_OVERRIDES)
    folder = data_dir_from_config(cfg)
    dm = datamodule_from_config(cfg.data, folder)
    dm.setup()
    default = HypaDataModule(folder, TESTBENCH_CHANNELS)  # the constructor's other defaults are the test bench's
    default.setup()
    assert dm.normalization == default.normalization
    names = ("steering_wheel_angle", "yaw_rate", "side_slip")
    decimated = {p.stem: {n: decimate(pq.read_table(p).column(n).to_numpy(), 32) for n in names}
                 for p in sorted(folder.glob("*.parquet"))}
    train = np.concatenate([np.stack([decimated[r][n] for n in names], -1) for r in ("train_1", "train_2")])
    np.testing.assert_allclose(dm.normalization.mean.numpy(), train.mean(0), rtol=1e-12)
    np.testing.assert_allclose(dm.normalization.std.numpy(), train.std(0), rtol=1e-12)
    for split, stride, files in (("train", 5, ["train_1", "train_2"]), ("val", 50, ["val"])):
        dataset, other = dm.dataset(split), default.dataset(split)
        assert [r.name for r in dm.records(split)] == [f"{f}.parquet" for f in files]
        expected_index = [(i, s) for i, f in enumerate(files)
                          for s in range(0, len(decimated[f][names[0]]) - 100, stride)]
        assert dataset.index == other.index == expected_index
        for item in (0, len(dataset) // 2, len(dataset) - 1):
            record, start = dataset.index[item]
            si = np.stack([decimated[files[record]][n] for n in names], -1)[start:start + 101]
            window = np.concatenate([dataset[item]["u"].numpy(), dataset[item]["y"].numpy()], -1)
            np.testing.assert_allclose(window, dm.normalization.normalize(si, names), rtol=1e-5, atol=1e-6)
            assert all(torch.equal(dataset[item][k], other[item][k]) for k in dataset[item])


def test_the_docs_example_dataset_loads(tmp_path):
    """The `my_rig` declaration of docs/data.md ("Your measured data"), on generated files."""
    import re
    import shutil

    page = (ROOT / "docs" / "data.md").read_text()
    pattern = r"```yaml\n(# @package _global_\n# conf/dataset/my_rig\.yaml.*?)```"
    block = re.search(pattern, page, re.DOTALL).group(1)
    conf = tmp_path / "conf"
    shutil.copytree(CONF, conf)
    (conf / "dataset" / "my_rig.yaml").write_text(block.replace("/path/to/my_rig", str(tmp_path / "rig")))
    rng = np.random.default_rng(0)
    (tmp_path / "rig").mkdir()
    for name, n in (("run1.csv", 3000), ("run2.csv", 1500), ("run3.parquet", 10000)):
        write_table(tmp_path / "rig" / name, {
            "t": np.arange(n) * 1.0, "voltage": rng.normal(size=n), "gain": np.full(n, 3.0),
            "pos_mm": np.cumsum(rng.normal(size=n)), "v(km/h)": 40 + 10 * np.sin(np.arange(n) / 50),
            "T": np.full(n, 20.0), "ref": rng.normal(size=n)})
    cfg = compose_config("train", ["dataset=my_rig"], config_dir=conf)
    dm = datamodule_from_config(cfg.data, data_dir_from_config(cfg))
    dm.setup()
    assert (dm.input_names, dm.output_names, dm.scheduling_names) == (("force",), ("position",), ("speed",))
    assert list(dm.test_sets()) == ["step", "sweep"] and dm.eval_names == ("reference",)
    assert dm.dataset("val")[0]["u"].shape == (20 + 100 + 1, 1)
