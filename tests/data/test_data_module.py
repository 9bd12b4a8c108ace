"""The DataModule: train-only statistics, exact round trip, windows, batch format, state."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from hypa.conf import CONF
from hypa.data import (
    ChannelSpec,
    DataError,
    HypaDataModule,
    Normalization,
    decimate,
    load_record,
)
from hypa.paper.testbench.sensors import TESTBENCH_CHANNELS

from data_helpers import make_data_dir, synthetic_channels, write_table

WINDOW, STRIDE, EVAL_STRIDE = 20, 3, 7
DATASETS = CONF / "dataset"


def _module(data_dir: Path, **kwargs) -> HypaDataModule:
    options = {"window": WINDOW, "stride": STRIDE, "eval_stride": EVAL_STRIDE, "batch_size": 4}
    options.update(kwargs)
    dm = HypaDataModule(data_dir, TESTBENCH_CHANNELS, **options)
    dm.setup("fit")
    return dm


@pytest.fixture
def data_dir(tmp_path) -> Path:
    return make_data_dir(tmp_path / "data", n_train=2, n_val=2, n_test=1, duration_s=6.0,
                         train_offset=3.0, val_offset=-3.0)


def test_statistics_come_from_the_training_split_only(data_dir):
    dm = _module(data_dir)
    norm = dm.normalization
    assert norm.names == ("steering_wheel_angle", "yaw_rate", "side_slip")
    for i, name in enumerate(norm.names):
        train = np.concatenate([r[name] for r in dm.records("train")])
        everything = np.concatenate([r[name] for s in ("train", "val") for r in dm.records(s)])
        assert norm.mean[i].item() == pytest.approx(train.mean(), rel=1e-12)
        assert norm.std[i].item() == pytest.approx(train.std(), rel=1e-12)
        assert train.mean() > 2.0 and abs(everything.mean() - train.mean()) > 1.0
    # val windows are scaled with the training statistics, hence far from zero mean
    val_u = torch.cat([b["u"] for b in dm.val_dataloader()])
    assert val_u.mean().item() < -2.0


def test_round_trip_file_to_windows_to_si_equals_decimated_file(data_dir):
    dm = _module(data_dir)
    names = dm.input_names + dm.output_names
    specs = [c for c in TESTBENCH_CHANNELS if c.name in names]
    for split in ("train", "val"):
        paths = sorted(data_dir.glob(f"{split}_*.csv"))
        expected = [
            {n: decimate(load_record(p, specs)[n], 32) for n in names} for p in paths
        ]
        dataset = dm.dataset(split)
        for item, (record, start) in enumerate(dataset.index):
            sample = dataset[item]
            u = dm.normalization.denormalize(sample["u"].double(), dm.input_names)
            y = dm.normalization.denormalize(sample["y"].double(), dm.state_names)
            span = slice(start, start + WINDOW + 1)
            si = {**dict(zip(dm.input_names, u.T)), **dict(zip(dm.state_names, y.T))}
            for name in names:  # float32 rounding of values of order 1..10
                np.testing.assert_allclose(si[name], expected[record][name][span],
                                           rtol=1e-6, atol=1e-7)


def test_windows_count_stride_and_never_cross_records(data_dir):
    dm = _module(data_dir)
    for split, stride in (("train", STRIDE), ("val", EVAL_STRIDE), ("test", EVAL_STRIDE)):
        records, dataset = dm.records(split), dm.dataset(split)
        lengths = [len(r) for r in records]
        assert all(n == 6 * 32 for n in lengths)
        per_record = [len(range(0, n - WINDOW, stride)) for n in lengths]
        counted = sum((n - WINDOW - 1) // stride + 1 for n in lengths)
        assert len(dataset) == sum(per_record) == counted
        for r, n in enumerate(lengths):
            starts = [s for rec, s in dataset.index if rec == r]
            assert starts == list(range(0, n - WINDOW, stride))
            assert starts[-1] + WINDOW <= n - 1  # last window ends inside its own record
        sample = dataset[len(dataset) - 1]
        assert sample["u"].shape == (WINDOW + 1, 1) and sample["y"].shape == (WINDOW + 1, 2)


def test_batch_format(data_dir):
    dm = _module(data_dir)
    train = next(iter(dm.train_dataloader()))
    assert set(train) == {"u", "y", "s"}
    assert train["u"].shape == (4, WINDOW + 1, 1) and train["y"].shape == (4, WINDOW + 1, 2)
    assert train["s"].shape == (4, WINDOW + 1, 0)  # the test bench schedules nothing
    assert train["u"].dtype == train["y"].dtype == train["s"].dtype == torch.float32
    val = next(iter(dm.val_dataloader()))
    assert set(val) == {"u", "y", "s", "eval", "record", "start"}
    assert dm.eval_names == ("rear_wheel_angle", "lateral_acceleration")
    assert val["eval"].shape == (4, WINDOW + 1, 2) and val["eval"].dtype == torch.float32
    # eval channels are SI and locate back to the decimated record
    for b in range(4):
        record = dm.records("val")[val["record"][b].item()]
        start = val["start"][b].item()
        expected = record.stack(dm.eval_names)[start : start + WINDOW + 1]
        np.testing.assert_allclose(val["eval"][b].numpy(), expected, rtol=1e-6, atol=1e-7)
    assert dm.dt == pytest.approx(1 / 32)
    assert set(next(iter(dm.test_dataloader()))) == set(val)


def test_rear_wheel_angle_never_reaches_training(data_dir):
    dm = _module(data_dir)
    assert all("rear_wheel_angle" not in r for r in dm.records("train"))
    assert all("rear_wheel_angle" in r for r in dm.records("val"))
    assert not dm.dataset("train").with_eval and dm.dataset("train").eval_names == ()
    for batch in dm.train_dataloader():
        assert set(batch) == {"u", "y", "s"}
    # a training channel reading the evaluation channel's column is refused
    leak = [*TESTBENCH_CHANNELS, ChannelSpec("rear", "input", "rad", column="rear_wheel_angle")]
    with pytest.raises(DataError, match=r"evaluation channel 'rear_wheel_angle' is used as input "
                                        r"by channel 'rear'"):
        HypaDataModule(data_dir, channels=leak)
    leak = [*TESTBENCH_CHANNELS, ChannelSpec("rear", "scheduling", "rad",
                                             expression="2 * rear_wheel_angle")]
    with pytest.raises(DataError, match="evaluation channel 'rear_wheel_angle' is used as scheduling"):
        HypaDataModule(data_dir, channels=leak)


def test_eval_channels_missing_from_a_file_are_left_out(tmp_path):
    data_dir = make_data_dir(tmp_path / "d", n_val=1, duration_s=4.0,
                             channels=("steering_wheel_angle", "yaw_rate", "side_slip"))
    dm = _module(data_dir)
    assert dm.eval_names == ()
    assert next(iter(dm.val_dataloader()))["eval"].shape == (4, WINDOW + 1, 0)
    with pytest.raises(DataError, match="no test"):
        dm.test_dataloader()


def test_shuffling_is_seeded_and_only_for_training(data_dir):
    first = [b["u"] for b in _module(data_dir, seed=1).train_dataloader()]
    again = [b["u"] for b in _module(data_dir, seed=1).train_dataloader()]
    other = [b["u"] for b in _module(data_dir, seed=2).train_dataloader()]
    assert all(torch.equal(a, b) for a, b in zip(first, again))
    assert not all(torch.equal(a, b) for a, b in zip(first, other))
    dm = _module(data_dir)
    batches = list(dm.val_dataloader())
    located = zip(torch.cat([b["record"] for b in batches]).tolist(),
                  torch.cat([b["start"] for b in batches]).tolist())
    assert list(located) == dm.dataset("val").index  # in file and time order


def test_constant_normalized_channel_is_named(tmp_path):
    data_dir = make_data_dir(tmp_path / "d", duration_s=4.0)
    for path in data_dir.glob("train_*.csv"):
        data = synthetic_channels(4.0)
        data["side_slip"] = np.full_like(data["time"], 0.01)
        write_table(path, data)
    with pytest.raises(DataError, match=r"'side_slip' is constant.*train_00.csv"):
        _module(data_dir)


def test_record_shorter_than_one_window_says_how_long_it_must_be(tmp_path):
    data_dir = make_data_dir(tmp_path / "d", duration_s=4.0)
    write_table(data_dir / "val_99.csv", synthetic_channels(0.5))
    with pytest.raises(DataError) as error:
        _module(data_dir)
    message = str(error.value)
    assert "val_99.csv" in message and "16 samples at 32 Hz" in message
    assert "window + 1 = 21 samples" in message and "641 samples at 1024 Hz" in message


def test_state_dict_round_trip_keeps_the_training_scaling(data_dir, tmp_path):
    dm = _module(data_dir)
    path = tmp_path / "dm.pt"
    torch.save(dm.state_dict(), path)
    state = torch.load(path, weights_only=True)
    # new data with a different mean: a checkpoint must scale it like the training data
    other_dir = make_data_dir(tmp_path / "other", duration_s=6.0, train_offset=-7.0)
    restored = _module(other_dir)  # setup() first, as Lightning does before restoring
    assert restored.normalization != dm.normalization
    restored.load_state_dict(state)
    assert restored.normalization == dm.normalization
    u = restored.dataset("train")[0]["u"]
    first = restored.records("train")[0].stack(dm.input_names)
    expected = dm.normalization.normalize(first, dm.input_names)
    np.testing.assert_allclose(u.numpy(), expected[: WINDOW + 1], rtol=1e-6, atol=1e-6)
    given = _module(other_dir, normalization=dm.normalization)
    assert given.normalization == dm.normalization
    assert torch.equal(given.dataset("val")[0]["u"], restored.dataset("val")[0]["u"])
    assert Normalization.from_state_dict(dm.normalization.state_dict()) == dm.normalization


def test_given_normalization_must_cover_the_channels(data_dir):
    partial = Normalization(["steering_wheel_angle"], [0.0], [1.0])
    with pytest.raises(DataError, match=r"no statistics for \['yaw_rate', 'side_slip'\]"):
        HypaDataModule(data_dir, TESTBENCH_CHANNELS, normalization=partial)


def test_state_names_alias_and_checkpoint_state(data_dir):
    dm = _module(data_dir, past=4)
    assert dm.state_names == dm.output_names == ("yaw_rate", "side_slip")
    state = dm.state_dict()
    assert state["output_names"] == ["yaw_rate", "side_slip"] and state["past"] == 4
    assert state["scheduling_names"] == [] and state["input_names"] == ["steering_wheel_angle"]
    assert dm.dataset("train")[0]["u"].shape == (4 + WINDOW + 1, 1)
