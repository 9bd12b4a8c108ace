"""The frozen physics' outputs kept per window while networks train (hypa.models.memo): the same
outputs and gradients as without it, and nothing kept that the blocks would not compute now."""

import copy

import pytest
import torch

from hypa.models.memo import ENTRY_OVERHEAD, FrozenMemo

from test_models import build, load, normalized_window

ROUND_OFF = {"rtol": 1e-5, "atol": 1e-6}  # a batch of another size may sum in another order


def hybrid() -> dict:
    """The physical vehicle (steering gains, the single track: states) with a correction network."""
    config = copy.deepcopy(load("physical"))
    config["name"] = "physical_hybrid"
    config["blocks"]["single_track"]["outputs"] = ["yaw_rate_physics", "side_slip_physics"]
    config["blocks"]["correction"] = {"kind": "ann", "inputs": ["yaw_rate_physics", "side_slip_physics",
                                                                "steering_wheel_angle"],
                                      "outputs": ["yaw_rate", "side_slip"],
                                      "residual_of": ["yaw_rate_physics", "side_slip_physics"]}
    return config


def windows(batch: int = 4, seed: int = 0):
    _swa, _x0, u, x0_hat, *_ = normalized_window(length=60, batch=batch, seed=seed)
    return u.float(), x0_hat.float()


def networks_gradient(model, u, y_past) -> torch.Tensor:
    model.zero_grad()
    model(u, y_past).square().sum().backward()
    return torch.cat([p.grad.flatten() for p in model.blocks["correction"].parameters()])


def test_only_frozen_physics_is_kept_and_it_changes_nothing() -> None:
    torch.manual_seed(0)
    model = build(hybrid()).eval()
    with torch.no_grad():  # a correction that is not zero, so that its gradient reads the physics
        for p in model.blocks["correction"].parameters():
            p.normal_(0.0, 0.3)
    u, y_past = windows()
    model.set_stage(None)  # the physics trains: nothing is frozen
    assert model.frozen_blocks() == ()
    model.set_stage(["correction"])
    assert model.frozen_blocks() == ("front_steering", "rear_steering", "single_track")
    with torch.no_grad():
        plain = model.signals(u, y_past)
    gradient = networks_gradient(model, u, y_past)

    model.memo = memo = FrozenMemo()
    for calls in (1, 2):  # computed, then read
        with torch.no_grad():
            kept = model.signals(u, y_past)
        assert (memo.misses, memo.hits) == (4, 4 * (calls - 1))
        assert kept.keys() == plain.keys()
        for name, (values, start) in plain.items():
            assert kept[name][1] == start
            torch.testing.assert_close(kept[name][0], values, rtol=0, atol=0)
    torch.testing.assert_close(networks_gradient(model, u, y_past), gradient, rtol=1e-5, atol=1e-7)
    assert memo.hits == 8

    # a batch of windows partly seen: the new ones computed, each row where it belongs
    u2, y2 = windows(batch=3, seed=1)
    mixed_u, mixed_y = torch.cat([u2[:1], u[2:3], u2[1:], u[:1]]), torch.cat([y2[:1], y_past[2:3], y2[1:], y_past[:1]])
    with torch.no_grad():
        kept = model.signals(mixed_u, mixed_y)
        model.memo = None
        fresh = model.signals(mixed_u, mixed_y)
        model.memo = memo
    assert (memo.misses, memo.hits) == (7, 10)
    torch.testing.assert_close(kept["yaw_rate"][0], fresh["yaw_rate"][0], **ROUND_OFF)


@pytest.mark.parametrize("change", ["value", "one_sample", "bypass", "dtype", "trains"])
def test_what_would_compute_otherwise_is_never_read_from_the_memo(change: str) -> None:
    model = build(hybrid()).eval()
    model.set_stage(["correction"])
    u, y_past = windows()
    model.memo = memo = FrozenMemo()
    with torch.no_grad():
        model.signals(u, y_past)
        if change == "value":  # the best epoch's weights restored, a later identification
            model.parameters_.set_values({"cf": 0.8 * float(model.parameters_.value("cf"))})
        elif change == "one_sample":
            u = u.clone()
            u[2, 30, 0] += 1e-3
        elif change == "bypass":
            model.set_stage(["correction"], ["correction"])
        elif change == "trains":  # a stage that trains the physics again: nothing read, nothing kept
            model.set_stage(None)
        else:
            model, u, y_past = model.double(), u.double(), y_past.double()
        kept = model.signals(u, y_past)
        model.memo = None
        fresh = model.signals(u, y_past)
    torch.testing.assert_close(kept["yaw_rate"][0], fresh["yaw_rate"][0], **ROUND_OFF)
    assert memo.hits == (3 if change == "one_sample" else 0)
    if change == "trains":
        assert not memo.entries and memo.kept == 0


def test_inputs_that_need_a_gradient_run_the_blocks() -> None:
    """A gradient to the inputs (a network in front of the data, an attack on the inputs) needs the blocks' graph."""
    model = build(hybrid()).eval()
    model.set_stage(["correction"])
    model.memo = memo = FrozenMemo()
    u, y_past = windows()
    with torch.no_grad():
        model.signals(u, y_past)
    u = u.clone().requires_grad_(True)
    model(u, y_past).sum().backward()
    assert memo.hits == 0 and u.grad is not None and float(u.grad.abs().sum()) > 0


def test_the_budget_bounds_what_is_kept_and_the_results_stay() -> None:
    model = build(hybrid()).eval()
    model.set_stage(["correction"])
    u, y_past = windows(batch=6)
    one = 2 * (60 - 1) * 4 + 2 * 60 * 4 + 4 * ENTRY_OVERHEAD  # a window's: the physics' two outputs, the gains' two
    model.memo = memo = FrozenMemo(budget=2 * one + one // 2)
    with torch.no_grad():
        first = model.signals(u, y_past)["yaw_rate"][0]
        second = model.signals(u, y_past)["yaw_rate"][0]
    assert len(memo.entries) == 2 and memo.kept <= memo.budget
    assert memo.hits == 2
    torch.testing.assert_close(second, first, **ROUND_OFF)


def test_a_model_without_stepping_frozen_blocks_keeps_nothing() -> None:
    model = build(load("v2")).eval()  # stage 2: the frozen front steering is a gain; the single track follows a network
    model.set_stage(["correction"])
    model.memo = memo = FrozenMemo()
    u, y_past = windows()
    with torch.no_grad():
        model.signals(u, y_past)
    assert model.frozen_blocks() == ("front_steering",)
    assert memo.hits == memo.misses == 0 and not memo.entries
