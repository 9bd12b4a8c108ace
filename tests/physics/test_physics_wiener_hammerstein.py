"""The Wiener–Hammerstein circuit (``wiener_hammerstein``) against scipy: each filter built from its
transfer function (``tf2ss``, not hypa's matrices), the knee between them, the input linear between
samples, integrated by ``solve_ivp``; second order in the sample time, and the knee's two slopes."""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.integrate import solve_ivp
from scipy.signal import tf2ss
from scipy.special import lambertw

from hypa.physics import LTIBlock, PhysicalParameters
from hypa.physics.systems import resolve_system
from hypa.physics.wiener_hammerstein import WienerHammerstein, lambert_w_exp

VALUES = {"first_frequency_hz": 45.0, "first_damping": 0.3, "first_pole_hz": 27.0, "slope": 0.9,
          "slope_change": -0.8, "knee": 0.5, "knee_width": 0.08, "second_frequency_hz": 17.0,
          "second_damping": 0.45, "second_pole_hz": 16.0, "notch_frequency_hz": 60.0, "notch_damping": -0.05,
          "output_offset": 0.02}


def drive(t: np.ndarray) -> np.ndarray:
    """A smooth multisine that crosses the knee now and then."""
    return 0.5 * np.sin(2 * np.pi * 3.1 * t) + 0.35 * np.sin(2 * np.pi * 11.7 * t + 1.0) + 0.1


def diode(z: float) -> float:
    """The diode's part of the knee from scipy's Lambert W: w W(exp((z - knee) / w))."""
    w = VALUES["knee_width"]
    return float(w * lambertw(np.exp((z - VALUES["knee"]) / w)).real)


def reference(t: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The circuit from its transfer functions, the input linear between samples, from rest."""
    v = VALUES
    w1, a1 = 2 * np.pi * v["first_frequency_hz"], 2 * np.pi * v["first_pole_hz"]
    w2, a2, wz = (2 * np.pi * v[k] for k in ("second_frequency_hz", "second_pole_hz", "notch_frequency_hz"))
    g1 = tf2ss([w1 * w1 * a1], np.polymul([1, 2 * v["first_damping"] * w1, w1 * w1], [1, a1]))
    g2 = tf2ss(np.array([1 / wz**2, 2 * v["notch_damping"] / wz, 1]) * w2 * w2 * a2,
               np.polymul([1, 2 * v["second_damping"] * w2, w2 * w2], [1, a2]))
    n1 = g1[0].shape[0]

    def rhs(time: float, x: np.ndarray) -> np.ndarray:
        z = float((g1[2] @ x[:n1])[0])
        f = v["slope"] * z + v["slope_change"] * diode(z)
        return np.concatenate([g1[0] @ x[:n1] + g1[1][:, 0] * np.interp(time, t, u), g2[0] @ x[n1:] + g2[1][:, 0] * f])

    x = solve_ivp(rhs, (t[0], t[-1]), np.zeros(n1 + g2[0].shape[0]), t_eval=t, rtol=1e-10, atol=1e-12,
                  method="DOP853", max_step=float(t[1] - t[0])).y
    return (g2[2] @ x[n1:])[0] + v["output_offset"]


def simulated(dt: float, seconds: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    system = WienerHammerstein()
    t = np.arange(0.0, seconds + dt / 2, dt)
    u = drive(t)
    sim = LTIBlock(system, PhysicalParameters(system.parameter_specs(VALUES)), dt=dt, horizon=64, hold="foh")
    with torch.no_grad():
        start = torch.tensor([[0, 0, 0, 0, 0, VALUES["output_offset"]]], dtype=torch.float64)  # at rest: y = offset
        x = sim.states(start, torch.tensor(u, dtype=torch.float64)[None, :, None])
    # x_1 .. x_{T-1}: under a first-order hold the last input only ends the last sample
    y = np.concatenate([[VALUES["output_offset"]], x[0, : len(t) - 1, 5].numpy()])  # x_k at t_k (y: the last state)
    return t, u, y


def test_against_scipy_and_second_order_in_the_sample_time() -> None:
    errors = []
    for dt in (1 / 1000, 1 / 4000, 1 / 8000):
        t, u, y = simulated(dt, 1.0)
        ref = reference(t, u)
        assert np.ptp(ref) > 0.5  # the run crosses the knee: its slope above is 0.1, below 0.9
        errors.append(float(np.abs(y - ref).max() / np.abs(ref).max()))
    assert errors[0] < 5e-4, errors  # 1.6e-4 at 22 samples a period of the faster resonance
    assert 3.2 < errors[1] / errors[2] < 4.8, errors


def test_the_knee_bends_the_static_gain_as_a_diode_and_the_filters_pass_dc_unchanged() -> None:
    """In steady state z = u (G1's unit gain) and y = f(u) (G2's): the static gain's slope is the knee's,
    slope + slope_change W / (1 + W), from `slope` well below the knee towards slope + slope_change above."""
    system = resolve_system("wiener_hammerstein", "circuit")
    assert system.parameter_names[0] == "circuit/first_frequency_hz" and system.is_nonlinear
    p = {f"circuit/{k}": torch.tensor(v, dtype=torch.float64) for k, v in VALUES.items()}
    ss, feedback = system.matrices(p), system.feedback(p)

    def steady_output(u: float) -> float:
        x = torch.tensor([[0, 0, u, 0, 0, 0]], dtype=torch.float64)  # φ reads z only
        w = system.nonlinearity(x, torch.tensor([[u]], dtype=torch.float64), p)[0]
        state = -torch.linalg.solve(ss.a, ss.b[:, 0] * u + feedback @ w + ss.e)
        assert math.isclose(float(state[2]), u, rel_tol=1e-9, abs_tol=1e-12)  # G1 passes DC unchanged
        return float(ss.c[0] @ state)

    # far below the knee: the slope's line, shifted by the output's offset
    assert math.isclose(steady_output(-3.0), -3.0 * VALUES["slope"] + VALUES["output_offset"], rel_tol=1e-9)
    slopes = []
    for level in (-2.0, 0.3, VALUES["knee"], 0.7, 3.0):
        slope = (steady_output(level + 1e-6) - steady_output(level - 1e-6)) / 2e-6
        shape = float(lambertw(np.exp((level - VALUES["knee"]) / VALUES["knee_width"])).real)
        assert math.isclose(slope, VALUES["slope"] + VALUES["slope_change"] * shape / (1 + shape), rel_tol=1e-6)
        slopes.append(slope)
    assert math.isclose(slopes[0], VALUES["slope"], rel_tol=1e-9)
    assert slopes == sorted(slopes, reverse=True) and slopes[-1] < 0.15  # towards 0.9 - 0.8 above the knee


def test_the_diode_s_lambert_w_matches_scipy_and_its_derivative_far_into_both_tails() -> None:
    s = torch.linspace(-60.0, 60.0, 2401, dtype=torch.float64, requires_grad=True)
    w = lambert_w_exp(s)
    exact = lambertw(np.exp(s.detach().numpy())).real
    np.testing.assert_allclose(w.detach().numpy(), exact, rtol=1e-13)
    w.sum().backward()
    np.testing.assert_allclose(s.grad.numpy(), exact / (1 + exact), rtol=1e-6, atol=1e-30)
    assert lambert_w_exp(torch.tensor([800.0], dtype=torch.float64)).isfinite().all()  # e^800 overflows; W does not
