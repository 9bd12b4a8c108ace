"""Interpolation tables of scheduled matrices (``hypa.physics.table``): verified to round-off or not used,
never stale, never on a gradient's path."""

import logging
import math

import pytest
import torch

from hypa.physics import LTIBlock, PhysicalParameters, Scaling
from hypa.physics.scheduled import SchedulingError
from hypa.physics.table import MAX_POINTS, TOLERANCE, ScheduleTable, build
from hypa.vehicle import SingleTrack, SingleTrackRelaxation, VehicleParameters, vehicle_parameters
from hypa.vehicle.physics import parameter_spec


def _smooth(rho: torch.Tensor) -> torch.Tensor:
    """Three smooth entries of ρ (K,) -> (K, 3), float64: curvature of every order."""
    return torch.stack([torch.sin(3 * rho), torch.exp(-rho), 1 / (1 + rho**2)], 1)


@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16])
def test_a_table_equals_the_function_to_its_tolerance_between_the_points(dtype: torch.dtype) -> None:
    """(In float64 a cubic needs ~10^5 points for round-off: refused, ``test_double_precision...``.)"""
    table, line, _ = build(_smooth, -1.0, 2.0, dtype)
    assert table is not None, line
    assert str(table.points) in line and table.lo == -1.0 and table.hi == pytest.approx(2.0)
    assert table.error <= TOLERANCE * torch.finfo(dtype).eps
    rho = torch.linspace(-1.0, 2.0, 10007, dtype=torch.float64)  # not the grid, not its midpoints
    got = table(rho.to(dtype)).to(torch.float64)
    assert got.dtype == torch.float64 and got.shape == (10007, 3)
    error = float((got - _smooth(rho)).abs().max())
    assert error <= 2 * TOLERANCE * torch.finfo(dtype).eps  # the midpoints are where the check looks
    grid = torch.tensor([-1.0, 2.0], dtype=dtype)  # the ends of the range, the upper one at s = 1
    torch.testing.assert_close(table(grid).double(), _smooth(grid.double()), rtol=0,
                               atol=4 * torch.finfo(dtype).eps)


def test_the_lookup_keeps_the_signal_shape_and_a_constant_signal_is_one_exact_point() -> None:
    table, _, _ = build(_smooth, 0.5, 0.5, torch.float32)
    assert table is not None and table.points == 1 and table.covers(0.5, 0.5) and not table.covers(0.4, 0.5)
    rho = torch.full((4, 7), 0.5)
    assert torch.equal(table(rho), _smooth(torch.tensor([0.5], dtype=torch.float64)).float().expand(4, 7, 3))
    wide, _, _ = build(_smooth, 0.0, 1.0, torch.float32)
    assert wide(torch.rand(4, 7)).shape == (4, 7, 3)


def test_a_kink_is_refused_not_smoothed_and_a_pole_is_not_tabulated() -> None:
    table, line, refused = build(lambda r: (r - 0.3).abs()[:, None], 0.0, 1.0, torch.float64)  # no polynomial has it
    assert table is None and refused and f"{MAX_POINTS} points still deviate" in line
    table, line, refused = build(lambda r: (1 / r)[:, None], -1.0, 1.0, torch.float32)  # 1/0 at a grid point
    assert table is None and not refused and "not finite" in line  # this call's values: not the dtype
    table, line, refused = build(_smooth, math.nan, 1.0, torch.float32)
    assert table is None and not refused and "not finite" in line


def _block(system=None, table: bool = True, trainable=("cf", "cr")) -> LTIBlock:
    system = system or SingleTrack()
    n, m, p = system.n_states, len(system.input_names), len(system.output_names)
    t = lambda *v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    scaling = Scaling(torch.zeros(n), torch.full((n,), 0.05), torch.zeros(m), torch.full((m,), 0.02),
                      torch.zeros(p), t(0.09, 0.012)[:p])
    specs = [parameter_spec(k, v, k in trainable) for k, v in VehicleParameters().as_dict().items()]
    specs += [s for s in system.parameters if s.name not in VehicleParameters().as_dict()]  # relaxation_length
    return LTIBlock(system, PhysicalParameters(specs), dt=1 / 32, horizon=60, scaling=scaling, scheduled=("velocity",),
                    table=table)


def _signals(batch: int = 8, steps: int = 60, low: float = 6.0, high: float = 28.0, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    velocity = low + (high - low) * torch.rand(batch, steps, 1, generator=g)
    return torch.randn(batch, 2, generator=g) * 0.5, torch.randn(batch, steps, 2, generator=g), velocity


@pytest.mark.parametrize("system", [SingleTrack(), SingleTrackRelaxation()], ids=["states", "outputs"])
def test_the_table_forward_equals_the_exact_one_to_round_off(system) -> None:
    """The single track (outputs are the states) and the relaxation model (C picks 2 of 4 states: the
    output matrices come off the table too): within the exact float32 forward's own round-off."""
    exact, tabled = _block(system, table=False), _block(system)
    x0, u, velocity = _signals()
    x0 = torch.zeros(x0.shape[0], system.n_states).copy_(torch.randn(x0.shape[0], system.n_states) * 0.5)
    with torch.no_grad():
        reference = exact(x0.double(), u.double(), velocity.double())
        ours, theirs = tabled(x0, u, velocity), exact(x0, u, velocity)
    assert tabled.tables.last is not None  # the table was used
    scale = float(reference.abs().max())
    exact_error = float((theirs.double() - reference).abs().max()) / scale
    table_error = float((ours.double() - reference).abs().max()) / scale
    assert table_error <= max(4 * exact_error, 64 * torch.finfo(torch.float32).eps), (table_error, exact_error)


def test_the_table_follows_the_parameters_and_the_range_and_never_serves_a_gradient() -> None:
    block, exact = _block(), _block(table=False)
    x0, u, velocity = _signals()
    with torch.no_grad():
        block(x0, u, velocity)
        first = block.tables.last[1]
        block(x0, u, velocity * 0.99 + 0.1)  # within the range: the same table
        assert block.tables.last[1] is first and len(block.tables.lines) == 1
        block(x0, u, velocity + 5.0)  # beyond it: one table over both ranges
        wider = block.tables.last[1]
        assert wider is not first and wider.covers(first.lo, float((velocity + 5.0).max()))
        for p in block.parameters_.raw.parameters():  # a training step moved the parameters
            p.add_(0.05)
        for p in exact.parameters_.raw.parameters():
            p.add_(0.05)
        ours, theirs = block(x0, u, velocity), exact(x0, u, velocity)
    assert block.tables.last[1] is not wider  # rebuilt, not stale
    torch.testing.assert_close(ours, theirs, rtol=0, atol=2e-5 * float(theirs.abs().max()))
    built = len(block.tables.lines)
    loss = block(x0, u, velocity).square().sum()  # trainable physics with gradients on: the exact path
    loss.backward()
    assert len(block.tables.lines) == built
    assert all(p.grad is not None for p in block.parameters_.raw.parameters() if p.requires_grad)
    frozen = _block(trainable=())
    scheduling = velocity.clone().requires_grad_(True)
    frozen(x0, u, scheduling).sum().backward()  # a gradient to the scheduling signal: exact too
    assert frozen.tables.last is None and scheduling.grad is not None


def test_double_precision_keeps_its_rows_and_says_so_once(caplog) -> None:
    block, exact = _block(), _block(table=False)
    x0, u, velocity = (t.double() for t in _signals())
    with torch.no_grad(), caplog.at_level(logging.WARNING, logger="hypa.physics.table"):
        ours = block(x0, u, velocity)
        block(x0, u, velocity + 1.0)
        theirs = exact(x0, u, velocity)
    assert torch.equal(ours, theirs)  # the per-sample rows, bit for bit
    refusals = [r for r in caplog.records if "still deviate" in r.getMessage()]
    assert len(refusals) == 1 and "SingleTrack" in refusals[0].getMessage()
    assert torch.float64 in block.tables.refused


def test_a_table_needs_one_scheduled_parameter() -> None:
    params = vehicle_parameters(VehicleParameters(), trainable=[])
    with pytest.raises(SchedulingError, match="a table needs one scheduled parameter"):
        LTIBlock(SingleTrack(), params, dt=0.03, table=True)


def test_the_model_yaml_key() -> None:
    from hypa.models.spec import ModelSpecError, parse_model_spec, spec_config

    block = {"kind": "physics", "system": "single_track_front", "inputs": ["front_wheel_angle"],
             "outputs": ["yaw_rate", "side_slip"], "scheduling": {"velocity": "velocity"}, "table": True}
    spec = parse_model_spec({"name": "m", "blocks": {"st": block}, "outputs": ["yaw_rate", "side_slip"]})
    assert spec.block("st").table and spec_config(spec)["blocks"]["st"]["table"] is True
    for bad, message in (({**block, "table": "yes"}, "must be true or false"),
                         ({k: v for k, v in block.items() if k != "scheduling"}, "scheduled by one signal")):
        with pytest.raises(ModelSpecError, match=message):
            parse_model_spec({"name": "m", "blocks": {"st": bad}, "outputs": ["yaw_rate", "side_slip"]})


def test_a_table_is_a_plain_frozen_record() -> None:
    table = ScheduleTable(0.0, 2.0, torch.zeros(4, 4, 2), 1e-9)
    assert table.points == 5 and table.step == 0.5 and table.covers(0.0, 2.0) and not table.covers(-0.1, 1.0)
