"""The same data with another past (``HypaDataModule.with_past``): the files read once, the records'
preparation (cut, decimated, selected for ``past + window + 1`` samples) and the normalization again,
the result the one a data module built with that past gives."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from torch.utils.data import default_collate

import hypa.data.dataset
from hypa.data import ChannelSpec, HypaDataModule, Normalization, load_dataset
from hypa.data.dataset import prepare_dataset, read_files
from hypa.paper.testbench.sensors import TESTBENCH_CHANNELS

from data_helpers import make_data_dir

WINDOW, PAST = 20, 30
CHANNELS = (*TESTBENCH_CHANNELS, ChannelSpec("velocity", "auxiliary", "m/s"))
SELECT = ["velocity > 32.6"]  # stretches of 1 to 10 s: a longer past leaves fewer of them


@pytest.fixture
def data_dir(tmp_path: Path) -> Path:
    return make_data_dir(tmp_path / "data", n_train=2, n_val=1, n_test=1, duration_s=20.0)


@pytest.fixture
def reads(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The files read (``hypa.data.dataset.load_record``'s calls), in order."""
    read, original = [], hypa.data.dataset.load_record

    def counted(path, *args, **kwargs):
        read.append(Path(path).name)
        return original(path, *args, **kwargs)

    monkeypatch.setattr(hypa.data.dataset, "load_record", counted)
    return read


def module(data_dir: Path, past: int, **kwargs) -> HypaDataModule:
    dm = HypaDataModule(data_dir, CHANNELS, window=WINDOW, past=past, stride=3, eval_stride=7,
                        select=SELECT, **kwargs)
    dm.setup()
    return dm


def windows(dm: HypaDataModule, split: str) -> dict[str, torch.Tensor]:
    dataset = dm.dataset(split)
    return default_collate([dataset[i] for i in range(len(dataset))])


def assert_same_data(built: HypaDataModule, fresh: HypaDataModule) -> None:
    assert built.past == fresh.past and built.signature.past == fresh.past
    assert (built.input_names, built.output_names, built.scheduling_names, built.eval_names) == \
        (fresh.input_names, fresh.output_names, fresh.scheduling_names, fresh.eval_names)
    assert built.normalization.names == fresh.normalization.names
    assert torch.equal(built.normalization.mean, fresh.normalization.mean)
    assert torch.equal(built.normalization.std, fresh.normalization.std)
    assert built.files == fresh.files and built.splits == fresh.splits
    for split in fresh.splits:
        assert [(r.name, len(r)) for r in built.records(split)] == [(r.name, len(r)) for r in fresh.records(split)]
        ours, theirs = windows(built, split), windows(fresh, split)
        assert ours.keys() == theirs.keys()
        for key in ours:
            assert torch.equal(ours[key], theirs[key]), (split, key)


def test_another_past_reads_no_file_again_and_equals_a_fresh_module(data_dir: Path, reads: list[str]) -> None:
    dm = module(data_dir, 0)
    files = sorted(p.name for p in data_dir.glob("*.csv"))
    assert sorted(reads) == files  # each file read once
    longer = dm.with_past(PAST)
    assert sorted(reads) == files  # and not again
    assert dm.past == 0 and len(dm.records("train")) > len(longer.records("train"))  # selected again for the past
    fresh = module(data_dir, PAST)
    assert_same_data(longer, fresh)
    assert not torch.equal(longer.normalization.mean, dm.normalization.mean)  # fitted again on what was selected


def test_a_given_normalization_and_auxiliary_inputs_are_kept_as_a_fresh_module_keeps_them(data_dir: Path) -> None:
    other = module(data_dir, 0)
    given = Normalization.fit(other.records("val"), other.normalized_names)  # not the training records'
    dm = module(data_dir, 0, normalization=given)
    assert_same_data(dm.with_past(PAST), module(data_dir, PAST, normalization=given))
    assert dm.with_past(PAST).normalization is given
    dm = module(data_dir, 0, auxiliary_inputs=True)
    assert dm.auxiliary_names == ("velocity",)
    assert_same_data(dm.with_past(PAST), module(data_dir, PAST, auxiliary_inputs=True))


def test_released_files_are_read_again_and_load_dataset_is_both_steps(data_dir: Path, reads: list[str]) -> None:
    dm = module(data_dir, 0)
    dm.release_files()
    n = len(reads)
    assert_same_data(dm.with_past(PAST), module(data_dir, PAST))
    assert len(reads) == 3 * n  # with_past read them again, and so did the fresh module
    channels = {c.name: c for c in CHANNELS}
    whole = load_dataset(data_dir, channels, rate_hz=32.0, window=WINDOW, past=PAST)
    files = read_files(data_dir, channels)
    for past in (PAST, 0):
        steps = prepare_dataset(files, rate_hz=32.0, window=WINDOW, past=past)
        assert steps.files == whole.files and steps.metadata == whole.metadata
        for split in ("train", "val", "test"):
            assert [(r.name, len(r)) for r in steps[split]] == [(r.name, len(r)) for r in whole[split]]
