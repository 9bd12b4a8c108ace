"""The system contract: bounded parameters, user systems by import path, one-line contract errors.

References are independent of hypa's engine: scipy's cont2discrete and a step-by-step
recursion for a user's system, hand-written matrices for the built-ins.
"""

from __future__ import annotations

import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.signal import cont2discrete

from hypa.physics import (
    PHYSICS_SYSTEMS,
    LTIBlock,
    MassSpringDamper,
    MassWithFriction,
    ParameterSpec,
    PhysicalParameters,
    Scaling,
    SystemContractError,
    UnstablePhysicsError,
    check_system,
    resolve_system,
)
from hypa.physics.systems import build_system

from conftest import ROOT

EXAMPLE = ROOT / "examples" / "user_system"

# -- bounded parameters ----------------------------------------------------------------------


def mixed_parameters(trainable: bool = True) -> PhysicalParameters:
    return PhysicalParameters([
        ParameterSpec("mass", 2.0, "kg", trainable=trainable),
        ParameterSpec("offset", -0.4, "N", positive=False, trainable=trainable),
        ParameterSpec("ratio", 0.3, "-", bounds=(0.1, 0.5), trainable=trainable),
        ParameterSpec("torque", 0.0, "N m", positive=False, bounds=(-2.0, 1.0), trainable=trainable),
    ])


def test_bounded_values_stay_inside_under_huge_optimizer_steps() -> None:
    params = mixed_parameters()
    target = {"ratio": 10.0, "torque": -100.0}  # far outside both intervals
    optimizer = torch.optim.SGD(params.parameters(), lr=1e4)
    for _ in range(50):
        optimizer.zero_grad()
        values = params.values(("mass", "ratio", "torque"))
        loss = sum((values[k] - v) ** 2 for k, v in target.items())
        loss.backward()
        optimizer.step()
        for name, (lo, hi) in (("ratio", (0.1, 0.5)), ("torque", (-2.0, 1.0))):
            assert lo <= params.value(name).item() <= hi
            assert lo <= params.values((name,))[name].item() <= hi
    assert params.value("ratio").item() == pytest.approx(0.5, abs=1e-3)  # pushed to the bound, not past it
    assert params.value("torque").item() == pytest.approx(-2.0, abs=1e-3)
    with torch.no_grad():  # saturated raw values, even in the vectorized path with a log parameter
        params.raw["ratio"].fill_(1e4)
        params.raw["torque"].fill_(-1e4)
    optimizer.zero_grad()
    values = params.values(params.names)
    assert values["ratio"].item() == 0.5 and values["torque"].item() == -2.0
    sum(values.values()).backward()  # exp of the huge bounded raw values would make NaN gradients
    assert all(bool(torch.isfinite(p.grad).all()) for p in params.parameters())


def test_values_match_value_and_round_trip_for_all_kinds() -> None:
    params = mixed_parameters(trainable=False)
    nominal = {"mass": 2.0, "offset": -0.4, "ratio": 0.3, "torque": 0.0}
    fast = params.values(params.names)
    for name, value in nominal.items():
        assert params.value(name).item() == pytest.approx(value, abs=1e-15)
        assert fast[name].item() == pytest.approx(value, abs=1e-15)
    new = {"mass": 3.5, "offset": 1.2, "ratio": 0.4999, "torque": -1.9}
    params.set_values(new)
    assert params.as_floats() == pytest.approx(new, rel=1e-12)
    assert {k: v.item() for k, v in params.values(params.names, torch.float64).items()} == pytest.approx(new)
    with torch.no_grad():  # a raw step of 0.01 on a bounded value moves it by (hi - lo) σ'(θ̃) 0.01
        params.raw["ratio"].add_(0.01)
    assert params.value("ratio").item() > 0.4999


@pytest.mark.parametrize("kwargs, message", [
    ({"value": 0.3, "bounds": (0.5, 0.1)}, "lo < hi"),
    ({"value": 0.3, "bounds": (0.1, float("inf"))}, "finite with lo < hi"),
    ({"value": 0.6, "bounds": (0.1, 0.5)}, "strictly inside"),
    ({"value": 0.1, "bounds": (0.1, 0.5)}, "strictly inside"),
    ({"value": 0.0, "bounds": (-1.0, 1.0)}, "positive=False"),
    ({"value": 0.3, "bounds": 0.5}, "must be \\(lo, hi\\)"),
    ({"value": -1.0}, "must be positive"),
])
def test_bad_parameter_specs_are_refused(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        ParameterSpec("ratio", unit="-", **kwargs)


def test_set_values_checks_each_kind() -> None:
    params = mixed_parameters(trainable=False)
    with pytest.raises(ValueError, match="bounds"):
        params.set_values({"ratio": 0.5})
    with pytest.raises(ValueError, match="positive"):
        params.set_values({"mass": -1.0})
    with pytest.raises(KeyError, match="known"):
        params.set_values({"masss": 1.0})
    params.set_values({"offset": 0.0})  # signed: zero is fine
    assert params.value("offset").item() == 0.0


def test_parameter_specs_take_values_and_keep_units_and_constraints() -> None:
    system = MassWithFriction()
    specs = {s.name: s for s in system.parameter_specs({"mass": 80.0, "unrelated": 1.0})}
    assert specs["mass"].value == 80.0 and specs["mass"].unit == "kg" and specs["mass"].positive
    assert specs["viscous_friction"].value == 203.5  # nominal where not given
    assert not specs["offset_force"].positive
    assert system.parameter_names == ("mass", "viscous_friction", "offset_force")
    lag = resolve_system("first_order_lag", "steer")
    assert lag.parameter_names == ("steer/tau_s",)
    assert lag.parameter_specs({"steer/tau_s": 0.2})[0].value == 0.2


# -- built-in systems ------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(PHYSICS_SYSTEMS))
def test_builtin_systems_follow_the_contract(name: str) -> None:
    system = resolve_system(name, "block")
    check_system(system)
    assert all(isinstance(s, ParameterSpec) and s.unit for s in system.parameters)
    assert build_system(name, "block").parameter_names == system.parameter_names


def test_mass_spring_damper_and_mass_with_friction_matrices() -> None:
    t = lambda v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    msd = MassSpringDamper().matrices({"mass": t(2.0), "stiffness": t(50.0), "damping": t(1.5),
                                       "offset_force": t(0.4)})
    np.testing.assert_allclose(msd.a.numpy(), [[0.0, 1.0], [-25.0, -0.75]], rtol=1e-15)
    np.testing.assert_allclose(msd.b.numpy(), [[0.0], [0.5]], rtol=1e-15)
    np.testing.assert_array_equal(msd.c.numpy(), [[1.0, 0.0]])
    np.testing.assert_array_equal(msd.d.numpy(), [[0.0]])
    np.testing.assert_allclose(msd.e.numpy(), [0.0, 0.2], rtol=1e-15)  # F0 / m
    emps = MassWithFriction().matrices({"mass": t(95.0), "viscous_friction": t(190.0), "offset_force": t(-3.8)})
    np.testing.assert_allclose(emps.a.numpy(), [[0.0, 1.0], [0.0, -2.0]], rtol=1e-15)
    np.testing.assert_allclose(emps.b.numpy(), [[0.0], [1 / 95.0]], rtol=1e-15)
    np.testing.assert_array_equal(emps.c.numpy(), [[1.0, 0.0]])
    np.testing.assert_array_equal(emps.d.numpy(), [[0.0]])
    np.testing.assert_allclose(emps.e.numpy(), [0.0, -0.04], rtol=1e-15)
    # the nominal Silverbox oscillator resonates near 70 Hz, lightly damped
    k, m, d = 0.98, 5.1e-6, 2.2e-4
    nominal = {s.name: s.value for s in MassSpringDamper().parameters}
    assert nominal == {"mass": m, "stiffness": k, "damping": d, "offset_force": 0.0}
    assert np.sqrt(k / m) / (2 * np.pi) == pytest.approx(70.0, rel=0.02)


def test_an_integrator_is_stable_enough_but_a_growing_mode_is_not() -> None:
    emps = MassWithFriction()
    LTIBlock(emps, PhysicalParameters(emps.parameters), dt=1e-3).check_stable()  # λ = 0, -Fv/M
    free = PhysicalParameters(emps.parameter_specs({"viscous_friction": 1e-300}))
    LTIBlock(emps, free, dt=1e-3).check_stable()  # a double integrator (Jordan block at 0) too

    class Growing(MassWithFriction):
        def matrices(self, p):
            ss = super().matrices(p)
            return type(ss)(-ss.a, ss.b, ss.c, ss.d, ss.e)  # λ = +Fv/M: a growing velocity

    with pytest.raises(UnstablePhysicsError, match=r"unstable .*a real part > 0"):
        LTIBlock(Growing(), PhysicalParameters(emps.parameters), dt=1e-3).check_stable()


# -- a user's system by import path ----------------------------------------------------------

USER_MODULE = '''
import torch
from hypa.physics import LTIModel, ParameterSpec, StateSpace


class TwoMass(LTIModel):
    """A motor inertia driving a load through a spring-damper: x = [q1, v1, q2, v2]."""

    state_names = ("motor_position", "motor_speed", "load_position", "load_speed")
    input_names = ("force",)
    output_names = ("load_position", "motor_speed")
    parameters = (
        ParameterSpec("motor_mass", 1.5, "kg"),
        ParameterSpec("load_mass", 4.0, "kg"),
        ParameterSpec("stiffness", 900.0, "N/m"),
        ParameterSpec("damping", 6.0, "N s/m", bounds=(0.5, 20.0)),
        ParameterSpec("motor_friction", 3.0, "N s/m"),
    )

    def matrices(self, p):
        m1, m2, k, d, f = (p[n] for n in self.parameter_names)
        z = torch.zeros_like(m1)
        one = torch.ones_like(m1)
        a = torch.stack([
            torch.stack([z, one, z, z]),
            torch.stack([-k / m1, -(d + f) / m1, k / m1, d / m1]),
            torch.stack([z, z, z, one]),
            torch.stack([k / m2, d / m2, -k / m2, -d / m2]),
        ])
        b = torch.stack([z, 1 / m1, z, z]).reshape(4, 1)
        c = torch.tensor([[0.0, 0.0, 1.0, 0.0], [0.0, 1.0, 0.0, 0.0]], dtype=m1.dtype)
        return StateSpace(a, b, c, m1.new_zeros(2, 1))


class Lag(LTIModel):
    state_names = ("y",)
    input_names = ("u",)
    output_names = ("y",)

    def __init__(self, block=""):
        self.parameters = (ParameterSpec(f"{block}/tau" if block else "tau", 0.2, "s"),)

    def matrices(self, p):
        (tau,) = p.values()
        return StateSpace((-1 / tau).reshape(1, 1), (1 / tau).reshape(1, 1), torch.ones(1, 1, dtype=tau.dtype),
                          tau.new_zeros(1, 1))


class NotASystem:
    pass


class NoMatrices(LTIModel):
    state_names = ("x",)
    input_names = ("u",)
    output_names = ("x",)


class NoOutputs(TwoMass):
    output_names = ()


class TwiceNamed(TwoMass):
    state_names = ("q", "v", "q", "w")


class RawParameters(TwoMass):
    parameters = (("motor_mass", 1.5), ("load_mass", 4.0))


class Raises(TwoMass):
    def matrices(self, p):
        return super().matrices({**p, "stiffness": p["spring"]})


class WrongB(TwoMass):
    def matrices(self, p):
        ss = super().matrices(p)
        return StateSpace(ss.a, ss.b.T, ss.c, ss.d)


class WrongE(TwoMass):
    def matrices(self, p):
        ss = super().matrices(p)
        return StateSpace(ss.a, ss.b, ss.c, ss.d, torch.zeros(4, 1, dtype=ss.a.dtype))


class NotFinite(TwoMass):
    def matrices(self, p):
        return super().matrices({**p, "motor_mass": p["motor_mass"] * 0})


class Tuple(TwoMass):
    def matrices(self, p):
        ss = super().matrices(p)
        return ss.a, ss.b, ss.c, ss.d


class SensorAhead(Lag):
    """Outputs named like the states, but a C that moves with a parameter: would be ignored."""

    def __init__(self, block=""):
        self.parameters = (ParameterSpec("tau", 0.2, "s"), ParameterSpec("gain", 1.0, "-"))

    def matrices(self, p):
        tau, gain = p["tau"], p["gain"]
        return StateSpace((-1 / tau).reshape(1, 1), (1 / tau).reshape(1, 1), gain.reshape(1, 1),
                          tau.new_zeros(1, 1))


class BadInit(TwoMass):
    def __init__(self):
        raise RuntimeError("no license")
'''


@pytest.fixture
def user_module(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    """A user's module ``hypa_test_user_systems`` in a tmp folder on the Python path."""
    name = "hypa_test_user_systems"
    (tmp_path / f"{name}.py").write_text(textwrap.dedent(USER_MODULE))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, name, raising=False)
    yield name
    sys.modules.pop(name, None)


def zoh_reference(a: np.ndarray, b: np.ndarray, c: np.ndarray, dt: float, x0: np.ndarray, u: np.ndarray
                  ) -> np.ndarray:
    """y_{j+1} = C x_{j+1}, x_{j+1} = Φ x_j + Γ u_j: step by step, Φ, Γ from scipy (ZOH)."""
    phi, gamma, *_ = cont2discrete((a, b, c, np.zeros((c.shape[0], b.shape[1]))), dt, method="zoh")
    x, ys = x0, []
    for u_j in u:
        x = phi @ x + gamma @ u_j
        ys.append(c @ x)
    return np.array(ys)


@pytest.mark.parametrize("length", [50, 137])
def test_user_system_by_import_path_simulates_exactly(user_module: str, length: int) -> None:
    system = resolve_system(f"{user_module}:TwoMass", "drive")
    params = PhysicalParameters(system.parameters)
    t = lambda *v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    scaling = Scaling(t(0.1, 0.0, 0.1, 0.0), t(0.05, 0.4, 0.05, 0.3), t(0.5), t(2.0), t(0.1, 0.0), t(0.05, 0.4))
    block = LTIBlock(system, params, dt=0.01, horizon=50, scaling=scaling)
    block.check_stable()  # a free rigid-body mode: a double eigenvalue at 0
    rng = np.random.default_rng(3)
    x0, force = rng.normal(size=(2, 4)) * 0.1, rng.normal(size=(2, length, 1))
    ours = block.simulate_physical(torch.tensor(x0), torch.tensor(force)).numpy()  # (2, L, 2)
    ss = system.matrices({s.name: t(s.value)[0] for s in system.parameters})
    for i in range(2):
        ref = zoh_reference(ss.a.numpy(), ss.b.numpy(), ss.c.numpy(), 0.01, x0[i], force[i])
        np.testing.assert_allclose(ours[i], ref, rtol=1e-10, atol=1e-10)


def test_user_system_gets_the_block_name(user_module: str) -> None:
    assert resolve_system(f"{user_module}:Lag", "steer").parameter_names == ("steer/tau",)
    assert resolve_system(f"{user_module}:Lag").parameter_names == ("tau",)


@pytest.mark.parametrize("target, message", [
    ("no_such_module_xyz:Motor", "cannot import module 'no_such_module_xyz'"),
    ("{m}:Motor", "has no attribute 'Motor'; LTIModel classes there: .*TwoMass"),
    ("{m}:NotASystem", "NotASystem is not a subclass of hypa.physics.LTIModel"),
    ("{m}:NoMatrices", "NoMatrices does not define matrices"),
    ("{m}:BadInit", r"BadInit\(\) raised RuntimeError: no license"),
    ("{m}:NoOutputs", "missing output_names"),
    ("{m}:TwiceNamed", r"duplicate state names \['q'\]"),
    ("{m}:RawParameters", "parameters must be ParameterSpec.*got tuple"),
    ("{m}:Raises", r"matrices\(nominal parameters\) raised KeyError: 'spring'"),
    ("{m}:WrongB", r"B with shape \(1, 4\), expected \(4, 1\) \(states, inputs\)"),
    ("{m}:WrongE", r"e with shape \(4, 1\), expected \(4,\) \(states,\)"),
    ("{m}:NotFinite", "non-finite A"),
    ("{m}:Tuple", "must return a StateSpace"),
    ("{m}:SensorAhead", r"outputs are named like its states \['y'\].*give the measured outputs their own names"),
    ("single_trak", "unknown physics system 'single_trak'; known: .*single_track.*, or an import path"),
    (":TwoMass", "an import path is package.module:Class"),
])
def test_contract_errors_say_what_is_wrong_in_one_line(user_module: str, target: str, message: str) -> None:
    with pytest.raises(SystemContractError, match=message) as error:
        resolve_system(target.format(m=user_module), "block")
    assert "\n" not in str(error.value)
    assert isinstance(error.value, ValueError)


def test_check_system_refuses_what_is_not_a_system() -> None:
    with pytest.raises(SystemContractError, match=r"not an instance of a hypa.physics.LTIModel subclass"):
        check_system(object())


def test_example_dc_motor(monkeypatch: pytest.MonkeyPatch) -> None:
    """examples/user_system/dc_motor.py: by import path, a voltage step reaches K V / (R b + K²)."""
    monkeypatch.syspath_prepend(str(EXAMPLE))
    motor = resolve_system("dc_motor:DCMotor")
    block = LTIBlock(motor, PhysicalParameters(motor.parameters), dt=1e-3, horizon=100)
    block.check_stable()
    speed = block.simulate_physical(torch.zeros(1, 2, dtype=torch.float64),
                                    torch.full((1, 1000, 1), 12.0, dtype=torch.float64))[0, -1, 0]
    p = {s.name: s.value for s in motor.parameters}
    k = p["torque_constant"]
    assert float(speed) == pytest.approx(k * 12.0 / (p["resistance"] * p["friction"] + k * k), rel=1e-6)
    sys.modules.pop("dc_motor", None)


def test_model_spec_accepts_import_paths_and_lists_builtins() -> None:
    from hypa.models.spec import ModelSpecError, parse_model_spec

    block = {"kind": "physics", "inputs": ["force"], "outputs": ["position"]}
    spec = parse_model_spec({"blocks": {"axis": {**block, "system": "my_lab.axes:Axis"}}, "outputs": ["position"]})
    assert spec.block("axis").system == "my_lab.axes:Axis"  # resolved when the model is built
    with pytest.raises(ModelSpecError,
                       match=r"known: first_order_lag.*mass_with_friction.*single_track.*, or an import path"):
        parse_model_spec({"blocks": {"axis": {**block, "system": "mass_with_frction"}}, "outputs": ["position"]})
