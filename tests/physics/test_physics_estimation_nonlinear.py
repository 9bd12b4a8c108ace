"""A nonlinear (Lur'e) block's state estimate: refined on its own steps where its linear part is blind.

Two cascaded tanks: the pump fills the upper tank, whose outflow k2 √h1 fills the measured lower
one. The linear part (A = 0) does not couple them at all, so from the lower level alone it cannot
see the upper one; only the feedback w = √h does. The reference is scipy's ODE solver, not hypa.
"""

import numpy as np
import pytest
import torch
from scipy.integrate import solve_ivp

from hypa.physics import LTIBlock, LTIModel, ParameterSpec, PhysicalParameters, Scaling, StateSpace

DT = 4.0  # [s]
K = {"k1": 0.055, "k2": 0.048, "k3": 0.06, "k4": 0.034}


class Tanks(LTIModel):
    state_names = ("upper", "lower")
    input_names = ("pump",)
    output_names = ("level",)
    parameters = tuple(ParameterSpec(name, value, "1/s") for name, value in K.items())

    def matrices(self, p):
        k4 = p["k4"]
        z, one = torch.zeros_like(k4), torch.ones_like(k4)
        return StateSpace(torch.stack([torch.stack([z, z]), torch.stack([z, z])]), torch.stack([k4, z]).reshape(2, 1),
                          torch.stack([z, one]).reshape(1, 2), k4.new_zeros(1, 1))

    def feedback(self, p):
        z = torch.zeros_like(p["k1"])
        return torch.stack([torch.stack([-p["k1"], z]), torch.stack([p["k2"], -p["k3"]])])

    def nonlinearity(self, x, u, p):
        return torch.sqrt(x.clamp_min(1e-6))


def truth(h0: np.ndarray, pump: np.ndarray) -> np.ndarray:
    """Levels h at the samples (L + 1, 2) under a zero-order-held pump voltage, by scipy."""
    def rates(_t, h, u):
        root = np.sqrt(np.maximum(h, 0.0))
        return [-K["k1"] * root[0] + K["k4"] * u, K["k2"] * root[0] - K["k3"] * root[1]]

    levels = [h0]
    for u in pump:
        levels.append(solve_ivp(rates, (0.0, DT), levels[-1], args=(u,), rtol=1e-10, atol=1e-12).y[:, -1])
    return np.array(levels)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_unmeasured_upper_tank_is_estimated_from_the_lower_level(seed: int) -> None:
    rng = np.random.default_rng(seed)
    past, windows = 8, 4
    h0 = rng.uniform([4.0, 2.0], [12.0, 7.0], size=(windows, 2))  # the upper tank anywhere in its range
    pump = rng.uniform(3.0, 7.0, size=(windows, past))
    levels = np.stack([truth(h, u) for h, u in zip(h0, pump)])  # (W, P + 1, 2)
    model = Tanks()
    scaling = Scaling(torch.tensor([6.0, 4.0]), torch.tensor([3.0, 1.5]), torch.tensor([5.0]), torch.tensor([1.0]),
                      torch.tensor([4.0]), torch.tensor([1.5]))
    block = LTIBlock(model, PhysicalParameters(model.parameters), DT, horizon=20, scaling=scaling)
    u = (torch.tensor(pump)[..., None] - 5.0) / 1.0
    u = torch.cat([u, u[:, -1:]], 1)  # (W, P + 1, 1): the input of sample P is not read by the states
    y = (torch.tensor(levels[..., 1:]) - 4.0) / 1.5
    estimate = block.estimate_state(u, y, [True]) * block.state_std + block.state_mean  # (W, 2) at sample P
    np.testing.assert_allclose(estimate.numpy(), levels[:, -1], rtol=2e-3)


def test_where_the_linear_part_sees_everything_the_estimate_is_kept() -> None:
    """A Duffing oscillator without hardening is its linear part: the refinement changes nothing."""
    from hypa.physics.mass_spring_damper import DuffingOscillator

    model = DuffingOscillator()
    values = {"mass": 5.1e-6, "stiffness": 0.98, "damping": 2.2e-4, "offset_force": 0.0, "hardening": 0.0}
    scaling = Scaling(torch.tensor([0.0, 0.0]), torch.tensor([0.1, 40.0]), torch.tensor([0.0]), torch.tensor([0.1]),
                      torch.tensor([0.0]), torch.tensor([0.1]))
    block = LTIBlock(model, PhysicalParameters(model.parameter_specs(values)), 1 / 610.35, horizon=20,
                     scaling=scaling)
    generator = torch.Generator().manual_seed(0)
    u, x0 = torch.randn(3, 11, 1, generator=generator, dtype=torch.float64), torch.randn(3, 2, generator=generator,
                                                                                         dtype=torch.float64)
    states = torch.cat([x0[:, None], block.states(x0, u[:, :10])], 1)  # x̂_0..x̂_10
    y = block.output(states, u)
    torch.testing.assert_close(block.estimate_state(u, y, [True]), states[:, -1], rtol=1e-6, atol=1e-6)
