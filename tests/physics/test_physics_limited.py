"""A state held at a limit (``hypa.physics.limited``): the spill, its share and the model config.

- two integrators, the first limited and spilling all of what would raise it further into the
  second: the sum of the states is the integral of the input, exactly (the limit only moves
  water between them), and the first stays at its limit;
- a tiny spill share loses what spills (the second state stays at 0), and a share is positive;
- against scipy's ODE solver on the same equations (a limit time of ten samples), and a state well
  inside its limit is the system as it was;
- a lower limit, the spec's checks (a side that is not upper or lower, a state the system lacks)
  and the model config's round trip.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.integrate import solve_ivp

from hypa.models.spec import ModelSpecError, parse_model_spec, spec_config
from hypa.physics import LTIModel, ParameterSpec, StateSpace
from hypa.physics.contract import SystemContractError
from hypa.physics.limited import Limited
from hypa.physics.lti import LTIBlock
from hypa.physics.parameters import PhysicalParameters

DT = 0.5


class TwoIntegrators(LTIModel):
    """dx1/dt = g u, dx2/dt = 0 (optionally a leak -a x2), y = (x1, x2)."""

    state_names = ("top", "bottom")
    input_names = ("u",)
    output_names = ("top", "bottom")
    parameters = (ParameterSpec("g", 1.0, "1/s"), ParameterSpec("leak", 0.0, "1/s", positive=False))

    def matrices(self, p):
        g = p["g"]
        z = torch.zeros_like(g)
        a = torch.stack([torch.stack([z, z]), torch.stack([z, -p["leak"]])])
        return StateSpace(a, torch.stack([g, z]).reshape(2, 1), torch.eye(2, dtype=g.dtype), g.new_zeros(2, 1))


def _block(side: str = "upper", limit: float = 1.0, share: float = 1.0, time: float = DT, width: float = 1e-3,
           leak: float = 0.0) -> LTIBlock:
    system = Limited(TwoIntegrators(), {"top": side})
    values = {"g": 1.0, "leak": leak, "top_limit": limit, "top_limit_time": time, "top_limit_width": width,
              "spill_top_to_bottom": share}
    return LTIBlock(system, PhysicalParameters(system.parameter_specs(values)), DT, hold="zoh")


def _run(block: LTIBlock, u: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        x = block.simulate_physical(torch.zeros(1, 2, dtype=torch.float64),
                                    torch.tensor(u, dtype=torch.float64).reshape(1, -1, 1))
    return x[0].numpy()


def test_a_full_spill_moves_what_would_pass_the_limit_into_the_other_state_exactly() -> None:
    u = np.full(400, 0.2)  # the top would reach 40; it stops at 1 and the rest goes on to the bottom
    x = _run(_block(share=1.0), u)
    integral = DT * np.cumsum(u)
    np.testing.assert_allclose(x[:, 0] + x[:, 1], integral, rtol=0, atol=1e-10)
    over = 0.2 * DT  # the spill takes the excess out within a limit time (a sample): a sample's inflow
    assert np.all(x[:, 0] < 1.0 + over + 1e-3), x[:, 0].max()
    assert x[-1, 0] == pytest.approx(1.0 + over, abs=1e-3)
    assert x[-1, 1] == pytest.approx(integral[-1] - 1.0 - over, abs=1e-3)


def test_a_tiny_spill_share_is_lost_and_a_state_inside_its_limit_is_the_system_as_it_was() -> None:
    u = np.full(200, 0.2)
    lost = _run(_block(share=1e-12), u)
    assert np.abs(lost[:, 1]).max() < 1e-12 * DT * u.sum() and lost[-1, 0] == pytest.approx(1.0 + 0.2 * DT, abs=1e-3)
    with pytest.raises(ValueError, match=r"spill_top_to_bottom.* must be positive, got 0"):  # adds, never drains
        _block(share=0.0)
    inside = _run(_block(limit=1e3), u)
    np.testing.assert_allclose(inside[:, 0], DT * np.cumsum(u), rtol=1e-12)


def test_the_limited_system_against_scipys_ode_solver() -> None:
    """The same equations with a smooth limit (width 0.05, limit time 10 samples) and a leak on the
    bottom state: hypa's step (the linear part exact, the spill second order in dt) against RK45."""
    limit, time, width, share, leak = 1.0, 10 * DT, 0.05, 0.6, 0.05
    rng = np.random.default_rng(3)
    u = np.repeat(rng.uniform(0.0, 0.3, 40), 10)  # held for 10 samples at a time

    def rates(t, x):
        k = min(int(t / DT), len(u) - 1)
        e = width * np.logaddexp(0.0, (x[0] - limit) / width)
        return [u[k] - e / time, -leak * x[1] + share * e / time]

    reference = [np.zeros(2)]
    for k in range(len(u)):
        reference.append(solve_ivp(rates, (k * DT, (k + 1) * DT), reference[-1], rtol=1e-10, atol=1e-12,
                                   first_step=1e-3).y[:, -1])
    x = _run(_block(limit=limit, share=share, time=time, width=width, leak=leak), u)
    np.testing.assert_allclose(x, np.array(reference[1:]), atol=2e-3)


def test_a_lower_limit_holds_the_state_from_below() -> None:
    x = _run(_block(side="lower", limit=-1.0, share=1.0), np.full(200, -0.2))
    assert x[-1, 0] == pytest.approx(-1.0 - 0.2 * DT, abs=1e-3) and np.all(x[:, 0] > -1.0 - 0.2 * DT - 1e-3)
    np.testing.assert_allclose(x[:, 0] + x[:, 1], DT * np.cumsum(np.full(200, -0.2)), atol=1e-10)


def _config(limited) -> dict:
    return {"name": "m", "blocks": {"plant": {"kind": "physics", "system": "first_order_lag", "inputs": ["u"],
                                              "outputs": ["y"], "limited": limited}}, "outputs": ["y"]}


def test_the_model_config_checks_limited_and_keeps_it() -> None:
    with pytest.raises(ModelSpecError, match="must map state names to upper or lower"):
        parse_model_spec(_config({"y": "sideways"}))
    spec = parse_model_spec(_config({"x": "upper"}))
    assert spec_config(spec)["blocks"]["plant"]["limited"] == {"x": "upper"}
    with pytest.raises(SystemContractError, match="has no state 'level'"):
        parse_model_spec(_config({"level": "upper"})).block("plant").system_model()
    system = parse_model_spec(_config(None)).block("plant").system_model()
    assert not isinstance(system, Limited)


def test_a_limit_its_state_never_reaches_is_named_with_where_it_acts() -> None:
    """``unreached``: a limit more than UNREACHED corner widths beyond the state's reach has no
    gradient; it comes back at the state's extreme (the highest for an upper limit, the lowest for a
    lower one), through a wrapper around the limited system too; a reached limit is not named."""
    from hypa.physics.curved import Curved
    from hypa.physics.limited import UNREACHED

    upper = Limited(TwoIntegrators(), {"top": "upper"}, block="b")
    values = {"b/top_limit": 10.0, "b/top_limit_width": 0.1}
    far = {"top": (-2.0, 10.0 - (UNREACHED + 1) * 0.1), "bottom": (0.0, 1.0)}
    assert upper.unreached(far, values) == {"b/top_limit": pytest.approx(8.4)}
    near = {"top": (-2.0, 10.0 - (UNREACHED - 1) * 0.1), "bottom": (0.0, 1.0)}
    assert upper.unreached(near, values) == {}
    assert upper.unreached({"bottom": (0.0, 1.0)}, values) == {}  # a state the run did not report
    lower = Limited(TwoIntegrators(), {"top": "lower"})
    assert lower.unreached({"top": (3.0, 5.0)}, {"top_limit": 1.0, "top_limit_width": 0.1}) == {"top_limit": 3.0}
    assert lower.unreached({"top": (1.5, 5.0)}, {"top_limit": 1.0, "top_limit_width": 0.1}) == {}
    wrapped = Curved(upper, {"top": "root"})
    assert wrapped.unreached(far, values) == {"b/top_limit": pytest.approx(8.4)}
    assert TwoIntegrators().unreached(far, values) == {}
