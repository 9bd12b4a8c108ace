"""The batched fast path of ``per_sample_matrices``: taken only where verified, equal to vmap, else vmap."""

import logging
from collections.abc import Mapping

import pytest
import torch
from torch import Tensor

import hypa.physics.scheduled as scheduled_module
from hypa.physics import LTIBlock, LTIModel, SchedulingError, StateSpace
from hypa.physics.scheduled import batch_decisions, per_sample_matrices
from hypa.vehicle import SingleTrack, vehicle_parameters
from hypa.vehicle.physics import SingleTrackRelaxation

from test_physics_block import DT, VP, vehicle_scaling
from test_physics_scheduled import AcceleratedMass, velocity_profile

F64 = torch.float64


def fixed_values(model: LTIModel, scheduled: str, dtype: torch.dtype = F64, trainable=("cf", "cr")) -> dict:
    values = {**VP.as_dict(), "relaxation_length": 0.3}
    return {k: torch.tensor(values[k], dtype=dtype, requires_grad=k in trainable)
            for k in model.parameter_names if k != scheduled}


def loop_reference(model: LTIModel, fixed: Mapping[str, Tensor], name: str, rho: Tensor) -> list[Tensor]:
    """A, B, C, D, e at every sample by a python loop over 0-d values: no vmap, no batching."""
    flat, mats = rho.reshape(-1), []
    for r in flat.unbind():
        ss = model.matrices({**fixed, name: r})
        mats.append((ss.a, ss.b, ss.c, ss.d, ss.e if ss.e is not None else ss.a.new_zeros(ss.a.shape[-1])))
    return [torch.stack(m).reshape(*rho.shape[:-1], *m[0].shape) for m in zip(*mats)]


def as_list(ss: StateSpace) -> list[Tensor]:
    return [ss.a, ss.b, ss.c, ss.d, ss.e]


def vmap_only(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(scheduled_module, "batch_layout", lambda *args: None)


def no_vmap(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*args):
        raise AssertionError("vmap was used")
    monkeypatch.setattr(scheduled_module, "_vmapped", refuse)


@pytest.mark.parametrize("make", [SingleTrack, lambda: SingleTrack(rear_steering=False), SingleTrackRelaxation],
                         ids=["single_track", "front_steering", "relaxation"])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_batched_path_is_taken_and_equals_vmap(make, dtype: torch.dtype, monkeypatch: pytest.MonkeyPatch) -> None:
    model = make()
    fixed = fixed_values(model, "velocity", dtype)
    rho = velocity_profile(4, 25, 0).to(dtype)  # (4, 25, 1): K = 100
    ours = as_list(per_sample_matrices(model, fixed, ["velocity"], rho))
    assert list(batch_decisions(model).values()) == [True]
    ref = loop_reference(model, fixed, "velocity", rho)
    with monkeypatch.context() as patch:
        vmap_only(patch)
        vmapped = as_list(per_sample_matrices(model, fixed, ["velocity"], rho))
    eps = torch.finfo(dtype).eps
    for o, v, r in zip(ours, vmapped, ref):
        assert o.shape == v.shape == r.shape and o.dtype == dtype
        torch.testing.assert_close(o, v, rtol=4 * eps, atol=4 * eps * float(r.detach().abs().max()))
        torch.testing.assert_close(o, r, rtol=4 * eps, atol=4 * eps * float(r.detach().abs().max()))
    # gradients with respect to the fixed trainable parameters and the scheduling signal, against vmap's
    rho = rho.clone().requires_grad_()
    weights = [torch.rand(m.shape, generator=torch.Generator().manual_seed(i), dtype=dtype) for i, m in enumerate(ref)]
    inputs = [rho, fixed["cf"], fixed["cr"]]

    def grads() -> tuple[Tensor, ...]:
        mats = as_list(per_sample_matrices(model, fixed, ["velocity"], rho))
        return torch.autograd.grad(sum((w * m).sum() for w, m in zip(weights, mats)), inputs)

    with monkeypatch.context() as patch:
        no_vmap(patch)
        fast = grads()
    with monkeypatch.context() as patch:
        vmap_only(patch)
        slow = grads()
    for f, s in zip(fast, slow):
        assert bool(s.abs().max() > 0)
        torch.testing.assert_close(f, s, rtol=64 * eps, atol=64 * eps * float(s.abs().max()))


def test_gradcheck_through_the_batched_path(monkeypatch: pytest.MonkeyPatch) -> None:
    model = SingleTrack()
    fixed = fixed_values(model, "velocity", trainable=())
    rho = velocity_profile(2, 7, 3).requires_grad_()  # K = 14
    cf_cr = torch.tensor([1.0, 1.0], dtype=F64, requires_grad=True)  # cf, cr relative to nominal

    def fn(scale: Tensor, rho: Tensor) -> tuple[Tensor, Tensor]:
        values = {**fixed, "cf": fixed["cf"] * scale[0], "cr": fixed["cr"] * scale[1]}
        ss = per_sample_matrices(model, values, ["velocity"], rho)
        return ss.a, ss.b

    fn(cf_cr, rho)
    assert list(batch_decisions(model).values()) == [True]
    no_vmap(monkeypatch)  # from here on the batched path alone
    assert torch.autograd.gradcheck(fn, (cf_cr, rho))


def test_scheduled_block_forward_and_gradient_equal_the_vmap_block(monkeypatch: pytest.MonkeyPatch) -> None:
    def run(vmap: bool) -> tuple[Tensor, ...]:
        params = vehicle_parameters(VP, trainable=["cf", "izz"])
        block = LTIBlock(SingleTrack(), params, DT, horizon=20, hold="foh", scaling=vehicle_scaling(),
                         scheduled=["velocity"])
        g = torch.Generator().manual_seed(5)
        x0 = torch.randn(3, 2, generator=g, dtype=F64, requires_grad=True)
        u = torch.randn(3, 21, 2, generator=g, dtype=F64, requires_grad=True)
        v = velocity_profile(3, 21, 6).requires_grad_()
        if not vmap:
            block(x0, u, v)  # decides (with vmap as the reference)
            assert list(batch_decisions(block.model).values()) == [True]
        with monkeypatch.context() as patch:
            (vmap_only if vmap else no_vmap)(patch)
            y = block(x0, u, v)
            grads = torch.autograd.grad(y.square().sum(), (params.raw["cf"], params.raw["izz"], x0, u, v))
        return y, *grads

    for ours, ref in zip(run(vmap=False), run(vmap=True)):
        torch.testing.assert_close(ours, ref, rtol=1e-13, atol=1e-13 * float(ref.detach().abs().max()))


class ReshapedMass(AcceleratedMass):
    """Scalar code that vmap batches but a batched call cannot: ``reshape(2, 1)`` of a stacked column."""


class BranchOnVelocity(SingleTrack):
    """A python branch on the scheduled value: vmap refuses it, and so must the fast path."""

    def matrices(self, p):
        if p["velocity"] > 10:
            return super().matrices(p)
        return super().matrices({**p, "velocity": p["velocity"] * 2})


class FloatVelocity(SingleTrack):
    """``float()`` of the scheduled value: per sample only."""

    def matrices(self, p):
        return super().matrices({**p, "velocity": p["velocity"] * (1.0 + 0.0 * float(p["velocity"]))})


class MatmulAxles(SingleTrack):
    """A matmul of two stacked matrices: right per sample, mixes samples and rows in a batch
    ((2, 2, K) @ (2, 2, K) fails, or at K = 2 silently multiplies the wrong slices)."""

    def matrices(self, p):
        ss = super().matrices(p)
        slip = torch.stack([torch.stack([p["lf"] / p["velocity"], torch.ones_like(p["lf"])]),
                            torch.stack([-p["lr"] / p["velocity"], torch.ones_like(p["lr"])])])
        path = torch.stack([torch.stack([p["lf"] * 0, p["lf"] * 0]), torch.stack([p["lf"] * 0 + 1, p["lf"] * 0])])
        return StateSpace(-(ss.b @ slip) - path, ss.b, ss.c, ss.d)


class MeanVelocity(SingleTrack):
    """A reduction over the samples: a no-op per sample (v floored at the mean of one value, v), in a
    batch shapes that fit and wrong values, which only the comparison with vmap sees."""

    def matrices(self, p):
        return super().matrices({**p, "velocity": torch.maximum(p["velocity"], p["velocity"].mean())})


@pytest.mark.parametrize("model_class", [ReshapedMass, MatmulAxles, MeanVelocity])
@pytest.mark.parametrize("samples", [(4, 25), (1, 2), (2, 3), (1, 1)])
def test_code_that_is_not_batch_safe_falls_back_to_vmap(model_class: type, samples: tuple[int, int],
                                                        caplog: pytest.LogCaptureFixture) -> None:
    model = model_class()
    name = "stiffness" if model_class is ReshapedMass else "velocity"
    fixed = ({k: torch.tensor(v, dtype=F64) for k, v in model.nominal_values().items() if k != name}
             if model_class is ReshapedMass else fixed_values(model, name))
    g = torch.Generator().manual_seed(1)
    rho = (40.0 if name == "stiffness" else 5.0) + 20 * torch.rand(*samples, 1, generator=g, dtype=F64)
    with caplog.at_level(logging.DEBUG, logger="hypa.physics.scheduled"):
        ours = as_list(per_sample_matrices(model, fixed, [name], rho))
    ref = loop_reference(model, fixed, name, rho)
    for o, r in zip(ours, ref):
        torch.testing.assert_close(o, r, rtol=1e-14, atol=1e-14 * float(r.detach().abs().max()))
    if samples[0] * samples[1] >= 2:  # K = 1 never asks
        assert list(batch_decisions(model).values()) == [False]
        assert f"{model_class.__name__}.matrices is evaluated per sample with vmap" in caplog.text
        if model_class is MeanVelocity:
            assert "A differs from vmap's" in caplog.text
    else:
        assert batch_decisions(model) == {}


@pytest.mark.parametrize("model_class", [BranchOnVelocity, FloatVelocity])
def test_code_vmap_refuses_is_refused_not_batched(model_class: type) -> None:
    """Where vmap cannot evaluate the code, neither path guesses: the usual one-line SchedulingError."""
    model = model_class()
    rho = velocity_profile(2, 10, 2)
    with pytest.raises(SchedulingError, match=f"{model_class.__name__}.matrices cannot be evaluated per sample"):
        per_sample_matrices(model, fixed_values(model, "velocity"), ["velocity"], rho)
    assert list(batch_decisions(model).values()) == [False]


def test_the_decision_is_kept_per_model_scheduled_names_and_dtype(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = []
    verify = scheduled_module._verify
    monkeypatch.setattr(scheduled_module, "_verify", lambda *args: calls.append(args[3].dtype) or verify(*args))
    model, other = SingleTrack(), SingleTrack()
    rho = velocity_profile(2, 10, 2)
    for _ in range(3):
        per_sample_matrices(model, fixed_values(model, "velocity"), ["velocity"], rho)
    assert calls == [F64]  # decided once
    per_sample_matrices(model, fixed_values(model, "velocity", torch.float32), ["velocity"], rho.float())
    per_sample_matrices(model, fixed_values(model, "mass"), ["mass"], 1500 + 100 * rho)
    per_sample_matrices(other, fixed_values(model, "velocity"), ["velocity"], rho)
    assert calls == [F64, torch.float32, F64, F64]
    assert {(key[0], key[2]) for key in batch_decisions(model)} == {
        (("mass",), F64), (("velocity",), F64), (("velocity",), torch.float32)}
    assert all(batch_decisions(model).values()) and len(batch_decisions(other)) == 1


def test_a_reduction_over_a_fixed_parameter_is_batched_only_where_it_is_fixed() -> None:
    """The same model, two scheduled names: the decision follows the key, not the class."""

    class MeanMass(SingleTrack):
        def matrices(self, p):
            return super().matrices({**p, "mass": p["mass"].mean()})

    model = MeanMass()
    rho = velocity_profile(2, 10, 2)
    for name, signal in (("velocity", rho), ("mass", 1500 + 100 * rho)):
        fixed = fixed_values(model, name)
        ours = as_list(per_sample_matrices(model, fixed, [name], signal))
        for o, r in zip(ours, loop_reference(model, fixed, name, signal)):
            torch.testing.assert_close(o, r, rtol=1e-14, atol=1e-14 * float(r.detach().abs().max()))
    decided = {key[0]: batched for key, batched in batch_decisions(model).items()}
    assert decided == {("velocity",): True, ("mass",): False}


def test_a_failure_after_the_verification_falls_back_for_good() -> None:
    class Flaky(SingleTrack):
        fail = False

        def matrices(self, p):
            if self.fail and p["velocity"].dim() == 1:
                raise RuntimeError("not today")
            return super().matrices(p)

    model = Flaky()
    fixed, rho = fixed_values(model, "velocity"), velocity_profile(2, 10, 2)
    first = per_sample_matrices(model, fixed, ["velocity"], rho)
    assert list(batch_decisions(model).values()) == [True]
    model.fail = True
    again = per_sample_matrices(model, fixed, ["velocity"], rho)
    assert list(batch_decisions(model).values()) == [False]
    for a, b in zip(as_list(first), as_list(again)):
        torch.testing.assert_close(a, b, rtol=1e-14, atol=0.0)


def test_the_decision_needs_no_gradients_and_leaves_the_global_random_stream_alone() -> None:
    model = SingleTrack()
    state = torch.random.get_rng_state()
    with torch.inference_mode():  # inference tensors, no graph: the check still compares gradients
        fixed, rho = fixed_values(model, "velocity"), velocity_profile(2, 10, 2)
        ours = as_list(per_sample_matrices(model, fixed, ["velocity"], rho))
    assert torch.equal(torch.random.get_rng_state(), state)
    assert list(batch_decisions(model).values()) == [True]
    for o, r in zip(ours, loop_reference(model, fixed, "velocity", rho)):
        torch.testing.assert_close(o, r, rtol=1e-15, atol=1e-15 * float(r.detach().abs().max()))


def test_a_dead_model_takes_its_decisions_with_it() -> None:
    model = SingleTrack()
    per_sample_matrices(model, fixed_values(model, "velocity"), ["velocity"], velocity_profile(2, 10, 2))
    key = id(model)
    assert key in scheduled_module._DECISIONS
    del model
    assert key not in scheduled_module._DECISIONS
