"""The end-to-end network's defaults follow from its training data (hypa.training.baseline): an LSTM
with about as many weights as training values, weight decay 1 / training values, an epoch budget of U / lr optimizer
steps and a patience of 0.4 U / lr steps (U: 1 for budget=short, the default, 5 for budget=full); a value set
explicitly is kept; with the full budget a model with physics keeps the paper's settings, with no fewer epochs and
no shorter patience than the same optimizer steps."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from hypa.ann import build_ann
from hypa.data import datamodule_from_config
from hypa.training.baseline import (
    FIXED_DEFAULTS,
    lstm_weights,
    lstm_width,
    matching_width,
    network_defaults,
    training_defaults,
)

from conftest import compose_config
from data_helpers import make_data_dir

LR = 5e-4


@pytest.mark.parametrize("name, gates", [("lstm", 4), ("gru", 3)])
@pytest.mark.parametrize("h, d_in, d_out, layers", [(8, 2, 1, 1), (32, 4, 2, 1), (16, 3, 2, 2)])
def test_lstm_weights_count_the_blocks_parameters(name: str, gates: int, h: int, d_in: int, d_out: int,
                                                  layers: int) -> None:
    block = build_ann(name, d_in, d_out, hidden_size=h, num_layers=layers)
    assert lstm_weights(h, d_in, d_out, layers, gates) == sum(p.numel() for p in block.parameters())
    assert lstm_weights(matching_width(5_000, d_in, d_out, layers, gates), d_in, d_out, layers,
                        gates) == pytest.approx(5_000)


def test_lstm_width_grows_with_the_data_up_to_the_widest() -> None:
    # 2 inputs (the input and the output it starts from), 1 output; widest 64
    few, some, many = (lstm_width(v, 2, 1, 64) for v in (2_000, 20_000, 1_000_000))
    assert (few, some, many) == (16, 64, 64)
    for values in (50, 2_000, 13_492, 19_873):  # about as many weights as values: the nearest power of two
        matching = matching_width(values, 4, 2)
        assert lstm_weights(matching, 4, 2) == pytest.approx(values)
        h = lstm_width(values, 4, 2, 64)
        assert abs(math.log2(h) - math.log2(matching)) <= 0.5 or h == 64 < matching
    assert lstm_width(10, 2, 1, 64) == 1  # a handful of values: the narrowest
    assert lstm_width(10_000, 2, 1, 64, num_layers=2) < lstm_width(10_000, 2, 1, 64)  # more weights per unit
    with pytest.raises(ValueError):
        lstm_width(0, 2, 1, 64)


def test_training_defaults_count_optimizer_steps_not_epochs() -> None:
    short = training_defaults(values=20_000, batches=62, lr=LR)      # a short record: few batches per epoch
    long = training_defaults(values=2_000_000, batches=6_250, lr=LR)  # a long one: many
    assert (short.max_epochs, short.patience) == (math.ceil(5 / (LR * 62)), math.ceil(2 / (LR * 62))) == (162, 65)
    assert (long.max_epochs, long.patience) == (2, 1)  # 1.6 and 0.64 epochs: whole ones
    assert short.weight_decay == pytest.approx(1 / 20_000) and long.weight_decay == pytest.approx(1 / 2_000_000)
    assert training_defaults(values=100, batches=1, lr=1.0).max_epochs == 5  # at least one epoch, patience 1
    with pytest.raises(ValueError):
        training_defaults(values=100, batches=0, lr=LR)
    with pytest.raises(ValueError, match="budget"):
        training_defaults(values=100, batches=1, lr=LR, budget="long")


def test_the_short_budget_is_a_fifth_of_the_full_one_in_optimizer_steps() -> None:
    full = training_defaults(values=20_000, batches=118, lr=LR, budget="full")  # the test bench's 118 batches
    short = training_defaults(values=20_000, batches=118, lr=LR, budget="short")
    assert (full.max_epochs, full.patience) == (85, 34) and (short.max_epochs, short.patience) == (17, 7)
    assert training_defaults(values=20_000, batches=118, lr=LR) == full  # the library's default: the full one


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    return make_data_dir(tmp_path_factory.mktemp("defaults") / "data", duration_s=12.0)  # 384 samples at 32 Hz


def defaults(data: Path, *overrides: str, lr: float = LR) -> tuple[dict, float, int, int, object]:
    cfg = compose_config("train", ["dataset=files", f"data.dir={data}", *overrides])
    dm = datamodule_from_config(cfg.data, data)
    dm.setup()
    ann = OmegaConf.to_container(cfg.ann, resolve=True)
    name = ann.pop("name")
    return (*network_defaults(OmegaConf.to_container(cfg.model, resolve=True), name, ann, dm, lr,
                              cfg.optimizer.weight_decay, cfg.trainer.max_epochs, cfg.early_stopping.patience,
                              cfg.trainer.limit_train_batches, cfg.budget), dm)


def test_an_end_to_end_lstm_takes_its_defaults_from_the_training_data(data: Path) -> None:
    ann, weight_decay, epochs, patience, dm = defaults(data, "model=blackbox", "ann=lstm", "budget=full")
    values = sum(len(r) for r in dm.records("train")) * len(dm.output_names)  # 2 records x 384 samples x 2
    batches = math.ceil(len(dm.dataset("train")) / dm.batch_size)
    assert ann["hidden_size"] == lstm_width(values, 1 + 2, 2, 64) == 16  # steering angle + 2 outputs it starts from
    assert defaults(data, "model=blackbox", "ann=gru")[0]["hidden_size"] == lstm_width(values, 1 + 2, 2, 64, gates=3)
    assert weight_decay == pytest.approx(1 / values)
    assert (epochs, patience) == (math.ceil(5 / (LR * batches)), math.ceil(2 / (LR * batches)))
    # limit_train_batches shortens an epoch, so the budget takes more of them
    _, _, limited, _, _ = defaults(data, "model=blackbox", "trainer.limit_train_batches=2", "budget=full")
    assert limited == math.ceil(5 / (LR * 2))
    # the short budget (hypa train's default): a fifth of the steps
    assert defaults(data, "model=blackbox", "ann=lstm")[2:4] == (math.ceil(1 / (LR * batches)),
                                                                math.ceil(0.4 / (LR * batches)))


def test_a_value_set_explicitly_is_kept(data: Path) -> None:
    ann, weight_decay, epochs, patience, _ = defaults(
        data, "model=blackbox", "ann.hidden_size=128", "optimizer.weight_decay=0", "trainer.max_epochs=3",
        "early_stopping.patience=2")
    assert (ann["hidden_size"], weight_decay, epochs, patience) == (128, 0.0, 3, 2)


def test_a_model_with_physics_keeps_the_papers_settings_but_not_fewer_optimizer_steps(data: Path) -> None:
    # where 50 epochs hold 5 / lr optimizer steps (here a large lr), the paper's settings
    ann, weight_decay, epochs, patience, dm = defaults(data, "model=v1", "ann=lstm", "budget=full", lr=1.0)
    assert ann["hidden_size"] == 64
    assert (weight_decay, epochs, patience) == tuple(FIXED_DEFAULTS[k] for k in ("weight_decay", "max_epochs",
                                                                                  "patience"))
    # a short record (a few batches per epoch): the correction gets the end-to-end network's steps,
    # not its width or weight decay
    batches = math.ceil(len(dm.dataset("train")) / dm.batch_size)
    assert batches < 5 / (LR * FIXED_DEFAULTS["max_epochs"])  # the case: 50 epochs are too few steps
    ann, weight_decay, epochs, patience, _ = defaults(data, "model=v1", "ann=lstm", "budget=full")
    assert (ann["hidden_size"], weight_decay) == (64, 0.0)
    assert (epochs, patience) == (math.ceil(5 / (LR * batches)), math.ceil(2 / (LR * batches)))
    # the short budget: its own steps alone, without the paper's 50 epochs, still no weight decay
    ann, weight_decay, epochs, patience, _ = defaults(data, "model=v1", "ann=lstm", lr=1.0)
    assert (ann["hidden_size"], weight_decay, epochs, patience) == (64, 0.0, 1, 1)
    _, _, epochs, patience, _ = defaults(data, "model=v1", "ann=lstm")
    assert (epochs, patience) == (math.ceil(1 / (LR * batches)), math.ceil(0.4 / (LR * batches)))
    # a value set is kept, and a model without networks has nothing to derive
    assert defaults(data, "model=v1", "trainer.max_epochs=7", "early_stopping.patience=2")[2:4] == (7, 2)
    assert defaults(data, "model=physical")[1:4] == tuple(FIXED_DEFAULTS[k] for k in ("weight_decay", "max_epochs",
                                                                                       "patience"))
