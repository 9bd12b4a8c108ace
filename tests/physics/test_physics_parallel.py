"""A long nonlinear run solved for every sample at once is the step-by-step recursion's own result.

``hypa.physics.parallel.solve_recursion`` (Newton over the sequence) against the loop it
replaces, on the nonlinear blocks hypa ships (a steep Coulomb friction, a partly cubic one, a
hard Duffing spring) and on maps where Newton cannot get there in time (a chaotic map): there it
must say so (``None``) and the block must fall back to the loop, never return another answer.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from hypa.physics import lure
from hypa.physics.friction import MassWithCoulombFriction, MassWithCubicFriction
from hypa.physics.lti import LTIBlock
from hypa.physics.mass_spring_damper import DuffingOscillator
from hypa.physics.parallel import solve_recursion
from hypa.physics.parameters import PhysicalParameters


def _runs(model, values: dict, u: torch.Tensor, dt: float, monkeypatch) -> tuple[torch.Tensor, torch.Tensor]:
    """The states of one run solved at once and of the same run stepped sample by sample."""
    block = LTIBlock(model, PhysicalParameters(model.parameter_specs(values)), dt=dt, horizon=100, hold="foh")
    x0 = torch.zeros(u.shape[0], model.n_states, dtype=u.dtype)
    threshold = lure.PARALLEL_STEPS
    with torch.no_grad():
        solved = block.states(x0, u)
        monkeypatch.setattr(lure, "PARALLEL_STEPS", 10**9)
        stepped = block.states(x0, u)
        monkeypatch.setattr(lure, "PARALLEL_STEPS", threshold)
    return solved, stepped


def _force(samples: int, amplitude: float, seed: int, batch: int = 1, dtype=torch.float64) -> torch.Tensor:
    rng = np.random.default_rng(seed)
    t = np.arange(samples) * 1e-3
    rows = [sum(amplitude * rng.uniform(0.3, 1) * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
                for f in rng.uniform(0.2, 3.0, 5)) for _ in range(batch)]
    return torch.tensor(np.array(rows), dtype=dtype)[..., None]


@pytest.mark.parametrize("seed", [0, 1])
def test_the_emps_axes_match_the_loop_to_round_off(seed: int, monkeypatch) -> None:
    u = _force(5000, 80.0, seed, batch=2)  # reverses every few hundred samples: the steep tanh is crossed often
    for model, values in ((MassWithCoulombFriction(), {}), (MassWithCubicFriction(), {"cubic_share": 0.6})):
        solved, stepped = _runs(model, values, u, 1e-3, monkeypatch)
        spread = stepped.std(dim=(0, 1))
        assert float(((solved - stepped).abs() / spread).max()) < 1e-9, type(model).__name__
        assert float(stepped[..., 1].abs().max()) > 0.05  # the axis moves well beyond the friction's smoothing


def test_a_hard_duffing_spring_matches_the_loop_and_single_precision_keeps_the_loop(monkeypatch) -> None:
    values = {"mass": 1.0, "stiffness": 400.0, "damping": 2.0, "offset_force": 0.0, "hardening": 8.0}
    u = _force(4000, 300.0, 3)
    solved, stepped = _runs(DuffingOscillator(), values, u, 2e-3, monkeypatch)
    assert float(((solved - stepped).abs() / stepped.std(dim=(0, 1))).max()) < 1e-9
    calls = []
    monkeypatch.setattr(lure, "solve_recursion", lambda *args: calls.append(1))
    _runs(DuffingOscillator(), values, u.float(), 2e-3, monkeypatch)
    assert not calls  # float32: the loop, bit for bit what the exported step computes


def test_newton_reaches_the_fixed_point_of_a_contracting_map() -> None:
    steps = 3000
    c = torch.linspace(-1, 1, steps, dtype=torch.float64)[None, :, None]

    def step(x: torch.Tensor) -> torch.Tensor:
        return 0.9 * torch.sin(x) + c

    x0 = torch.tensor([[0.3]], dtype=torch.float64)
    unit = torch.ones(1, dtype=torch.float64)
    solved = solve_recursion(step, x0, torch.zeros(1, steps, 1, dtype=torch.float64), unit)
    x, loop = 0.3, []
    for k in range(steps):
        x = 0.9 * math.sin(x) + float(c[0, k, 0])
        loop.append(x)
    assert solved is not None
    assert np.allclose(solved[0, :, 0].numpy(), loop, rtol=0, atol=1e-12)


def test_a_chaotic_map_is_refused_not_approximated() -> None:
    """The logistic map at r = 3.9: every iteration fixes a few more samples, far too few for 2000."""
    steps = 2000

    def step(x: torch.Tensor) -> torch.Tensor:
        return 3.9 * x * (1 - x)

    x0 = torch.tensor([[0.2]], dtype=torch.float64)
    guess = torch.full((1, steps, 1), 0.5, dtype=torch.float64)
    assert solve_recursion(step, x0, guess, torch.ones(1, dtype=torch.float64)) is None


def test_inside_inference_mode_as_lightning_validates(monkeypatch) -> None:
    """Lightning validates and predicts under ``torch.inference_mode``, where no graph can be made."""
    model = MassWithCoulombFriction()
    block = LTIBlock(model, PhysicalParameters(model.parameter_specs({})), dt=1e-3, horizon=100, hold="foh")
    u, x0 = _force(3000, 80.0, 5), torch.zeros(1, 2, dtype=torch.float64)
    with torch.inference_mode():
        solved = block.states(x0, u)
    _, stepped = _runs(model, {}, u, 1e-3, monkeypatch)
    assert float(((solved - stepped).abs() / stepped.std(dim=(0, 1))).max()) < 1e-9


def test_newton_that_stalls_at_the_steps_own_round_off_is_accepted() -> None:
    """F sums terms far larger than the states (((a x + c) + B) - B, B = 1e4: its round-off is about 2e-12 of
    states of size 1, above the 64 epsilons the states alone would allow). Newton reaches that floor and no
    closer, as the loop itself; the solution is accepted and is the loop's to that floor, not refused."""
    generator = torch.Generator().manual_seed(5)
    steps, big = 3000, 1.0e4
    c = torch.randn(1, steps, 1, generator=generator, dtype=torch.float64)

    def step(x: torch.Tensor) -> torch.Tensor:
        return ((0.9 * torch.tanh(x) + c) + big) - big

    x0 = torch.zeros(1, 1, dtype=torch.float64)
    one = torch.ones(1, dtype=torch.float64)
    solved = solve_recursion(step, x0, torch.zeros(1, steps, 1, dtype=torch.float64), one)
    assert solved is not None
    x, loop = x0, []
    for k in range(steps):
        x = ((0.9 * torch.tanh(x) + c[:, k]) + big) - big
        loop.append(x)
    assert float((solved - torch.stack(loop, 1)).abs().max()) < 1e-9


def test_a_run_newton_cannot_solve_whole_is_solved_in_halves_and_equals_the_loop(monkeypatch) -> None:
    """Where Newton refuses a long span (here: any of more than 1 200 samples), its halves are solved
    on their own, each from the end of the one before, at most ``HALVINGS`` times; what is left to the
    loop is stepped. The states are the loop's to round-off."""
    u = _force(5000, 80.0, 2)
    spans = []
    real = lure.solve_recursion

    def refuse_long(step, x0, guess, scale, *args):
        spans.append(guess.shape[1])
        return None if guess.shape[1] > 1200 else real(step, x0, guess, scale, *args)

    monkeypatch.setattr(lure, "solve_recursion", refuse_long)
    solved, stepped = _runs(MassWithCubicFriction(), {"cubic_share": 0.6}, u, 1e-3, monkeypatch)
    whole = spans[0]  # the run's steps (a first-order hold reads one input more)
    assert spans[:3] == [whole, whole // 2, whole // 4]
    assert sum(s for s in spans if s <= 1200) == whole and len(spans) == 1 + 2 + 4 + 8  # solved in eighths
    assert float(((solved - stepped).abs() / stepped.std(dim=(0, 1))).max()) < 1e-9
    spans.clear()
    monkeypatch.setattr(lure, "HALVINGS", 1)  # halved once: the 2 500-sample halves are stepped
    again, _ = _runs(MassWithCubicFriction(), {"cubic_share": 0.6}, u, 1e-3, monkeypatch)
    assert spans == [whole, whole // 2, whole - whole // 2]
    assert float(((again - stepped).abs() / stepped.std(dim=(0, 1))).max()) < 1e-9
