"""The explanation ladder on blocks whose law is known: does it find the law, and only the law?

The true outputs are simulated independently of hypa.explain: scipy's ``lsim`` on a grid ten
times finer than the records' sample time, then sampled, with the delay applied by
interpolation on the fine grid. Inputs are smooth random signals that start at zero, so the
truth starts at rest like the fitted forms (a steady start).
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import signal

from hypa.core.errors import UserError
from hypa.core.units import unit_ratio
from hypa.explain import Recording, explain
from hypa.explain.signals import delayed, filtered, lag_filter, second_order_filters

DT = 0.01  # [s] the records' sample time
FINE = 10  # the truth is simulated on DT / FINE
SAMPLES = 1500  # per record (15 s)
UNITS = {"front_angle": "rad", "yaw_rate": "rad/s", "rear_angle": "rad"}


def smooth(rng: np.random.Generator, hz: float, std: float) -> np.ndarray:
    """A random signal on the fine grid, low-passed at ``hz``, starting at zero (0.5 s ramp)."""
    n = SAMPLES * FINE
    b, a = signal.butter(2, hz, fs=FINE / DT)
    x = signal.filtfilt(b, a, rng.standard_normal(n + 4000))[2000:-2000]
    x = std * x / x.std()
    return x * np.minimum(np.arange(n) / (0.5 * FINE / DT), 1.0)


def truth(u: np.ndarray, num: list[float], den: list[float], delay: float = 0.0) -> np.ndarray:
    """num(s)/den(s) e^(-s delay) applied to ``u`` on the fine grid, from rest (scipy lsim)."""
    t = np.arange(len(u)) * DT / FINE
    u = np.interp(t - delay, t, u, left=0.0)
    return signal.lsim((num, den), u, t)[1]


def records(law, seed: int, count: int, noise: float = 0.0, amplitude: float = 0.05) -> list[Recording]:
    """Records of ``law(front_angle, yaw_rate)`` (fine grid), sampled every DT, plus white noise [rad]."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(count):
        u, r = smooth(rng, 2.0, amplitude), smooth(rng, 0.7, 0.2)
        y = law(u, r)[::FINE] + noise * rng.standard_normal(SAMPLES)
        out.append(Recording(f"r{i}", {"front_angle": u[::FINE], "yaw_rate": r[::FINE], "rear_angle": y}))
    return out


def run(law, seed: int = 0, noise: float = 0.0, extra: tuple[str, ...] = (), amplitude: float = 0.05):
    train = records(law, seed, 2, noise, amplitude)
    val = records(law, seed + 100, 1, noise, amplitude)
    return explain(train, val, DT, "rear_angle", ["front_angle"], extra, units=UNITS)


# --- the ladder finds the law --------------------------------------------------------------------

@pytest.mark.parametrize(("gain", "seed"), [(0.12, 0), (-2.5, 1)])
def test_a_pure_gain_is_explained_as_a_gain_not_a_lag(gain, seed):
    result = run(lambda u, r: gain * u, seed, noise=0.002 * abs(gain) / 0.12)
    assert result.best.form.name == "gain"
    assert result.best.value("gain", "front_angle").value == pytest.approx(gain, rel=0.01)
    assert result.best.value("gain", "front_angle").unit == "-"


@pytest.mark.parametrize("seed", [0, 1])
def test_a_lag_of_70_ms_recovers_gain_and_time_constant(seed):
    result = run(lambda u, r: truth(u, [0.12], [0.07, 1.0]), seed, noise=0.0005)
    assert result.best.form.name == "lag"
    assert result.best.value("gain", "front_angle").value == pytest.approx(0.12, rel=0.02)
    assert result.best.value("lag").value == pytest.approx(0.07, rel=0.10)
    assert (", lag 70 ms" in result.describe() or ", lag 69 ms" in result.describe()
            or ", lag 71 ms" in result.describe())


def test_a_lag_with_40_ms_dead_time_recovers_all_three():
    result = run(lambda u, r: truth(u, [0.12], [0.07, 1.0], delay=0.04), noise=0.0005)
    assert result.best.form.name == "lag and delay"
    assert result.best.value("gain", "front_angle").value == pytest.approx(0.12, rel=0.02)
    assert result.best.value("lag").value == pytest.approx(0.07, rel=0.10)
    assert result.best.value("delay").value == pytest.approx(0.04, abs=0.005)


def test_a_phase_reversal_law_is_found_by_the_second_order_rung():
    """The bench's ECU: (k + (k - k_t) τ_t s) / ((1 + τ_t s)(1 + τ s)) with k_t > k, counter-phase
    right after a change (a zero in the right half plane, no dead time). The lag-and-delay form
    mimics it with a long dead time; the second-order search must not start only there."""
    k, k_t, tau_t, tau = 0.12, 0.3, 0.3, 0.07
    law = ([(k - k_t) * tau_t, k], np.polymul([tau_t, 1.0], [tau, 1.0]))
    result = run(lambda u, r: truth(u, *law), noise=0.0005)
    assert result.best.form.name == "second order"
    assert result.best.r2_val > 0.99
    assert result.best.value("gain", "front_angle").value == pytest.approx(k, rel=0.05)
    zero = result.best.value("zero", "front_angle").value
    assert zero == pytest.approx((1 - k_t / k) * tau_t, rel=0.1)  # -0.45 s
    assert result.best.value("delay").value < 0.01


def test_the_second_order_rung_stays_below_the_nyquist_frequency():
    """A plain lag is a second order with one pole infinitely fast: the search stops at the
    Nyquist frequency (a pole the samples cannot resolve) and at damping 20, and the rung
    still fits the lag; its two real poles read as two lags."""
    from hypa.explain.forms import second_order_text

    result = run(lambda u, r: truth(u, [0.12], [0.07, 1.0]), noise=0.0005)
    second = next(f for f in result.forms if f.form.name == "second order")
    assert second.value("natural_frequency").value <= 0.5 / DT * (1 + 1e-9)
    assert second.value("damping").value <= 20.0 * (1 + 1e-9)
    assert second.r2_val == pytest.approx(result.best.r2_val, abs=1e-3)
    # (1 + 0.3 s)(1 + 0.07 s) = 1 + 2ζ s/ω + s²/ω²
    omega = 1 / np.sqrt(0.3 * 0.07)
    assert second_order_text(omega / (2 * np.pi), 0.37 * omega / 2) == "lags 300 ms and 70 ms"
    assert second_order_text(1.234, 0.5) == "second order 1.2 Hz, damping 0.5"


def test_an_odd_cubic_before_a_lag_is_found_by_the_nonlinear_rung():
    cubic = 40.0  # [1/rad²]: at 0.1 rad the cubic adds 40 % to the input
    result = run(lambda u, r: truth(u + cubic * u**3, [0.12], [0.07, 1.0]), noise=0.0005)
    assert result.best.form.name == "odd nonlinearity"
    assert result.best.value("cubic", "front_angle").value == pytest.approx(cubic, rel=0.10)
    assert result.best.value("cubic", "front_angle").unit == "1/rad²"
    assert result.best.value("lag").value == pytest.approx(0.07, rel=0.10)


def test_a_dependence_on_yaw_rate_is_found_with_its_sign_and_size():
    result = run(lambda u, r: truth(u, [0.12], [0.07, 1.0]) - 0.004 * r, noise=0.0002,
                 extra=("yaw_rate",))
    assert result.best.form.name.startswith("extra signals")
    yaw = result.best.value("gain", "yaw_rate")
    assert yaw.value == pytest.approx(-0.004, rel=0.05)
    assert yaw.unit == "s"
    assert result.best.value("gain", "front_angle").value == pytest.approx(0.12, rel=0.02)
    assert result.describe().startswith("rear_angle = 0.12 · front_angle, lag 70 ms, − 0.004 s · yaw_rate; explains")
    assert result.forms[-2].r2_val < result.best.r2_val - 0.01  # the extra signal earned its place
    assert result.unresolved() is None


def test_a_yaw_rate_the_law_does_not_read_is_reported_as_not_resolved():
    result = run(lambda u, r: truth(u, [0.12], [0.07, 1.0]), noise=0.0005, extra=("yaw_rate",))
    assert result.best.form.name == "lag"
    assert result.unresolved().startswith("a dependence on yaw_rate is not resolved by these data")
    assert result.to_dict()["unresolved"] == result.unresolved()
    assert run(lambda u, r: truth(u, [0.12], [0.07, 1.0]), noise=0.0005).unresolved() is None  # none tried


# --- and nothing but the law ---------------------------------------------------------------------

@pytest.mark.parametrize("seed", [0, 1])
def test_pure_noise_explains_nothing_and_chooses_the_simplest_form(seed):
    rng = np.random.default_rng(seed + 7)
    result = run(lambda u, r: 0.01 * rng.standard_normal(len(u)), seed)
    assert result.best.form.name == "gain"
    assert result.best.r2_val < 0.02
    assert max(f.r2_val for f in result.forms) < 0.05
    assert result.remainder.share > 0.95
    assert "explains 0 %" in result.describe() or "explains nothing" in result.describe()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_freedom_alone_never_wins_a_noisy_gain(seed):
    result = run(lambda u, r: 0.12 * u, seed, noise=0.006)  # R² about 0.5
    assert 0.3 < result.best.r2_val < 0.7
    assert result.best.form.name == "gain"
    second = next(f for f in result.forms if f.form.name == "second order")
    assert second.score < result.best.score


def test_the_uncertainty_covers_the_truth_and_is_not_vacuous():
    result = run(lambda u, r: truth(u, [0.12], [0.07, 1.0]), seed=3, noise=0.003)
    gain, lag = result.best.value("gain", "front_angle"), result.best.value("lag")
    assert abs(gain.value - 0.12) < 4 * gain.std and gain.std < 0.01
    assert abs(lag.value - 0.07) < 4 * lag.std and lag.std < 0.02


def test_the_remainder_names_where_an_unmodelled_resonance_lives():
    # a lightly damped 4 Hz mode on top of a gain: a static gain cannot explain it
    law = lambda u, r: 0.12 * u + truth(smooth(np.random.default_rng(5), 8.0, 0.01), [1.0],  # noqa: E731
                                        [1 / (2 * np.pi * 4) ** 2, 0.1 / (2 * np.pi * 4), 1.0])
    result = explain(records(law, 0, 2), records(law, 100, 1), DT, "rear_angle", ["front_angle"],
                     units=UNITS, max_lag=0.02, max_delay=0.0)
    band = result.remainder.worst_band
    assert band.low <= 4.0 <= band.high
    assert sum(b.share for b in result.remainder.bands) == pytest.approx(1.0, abs=1e-6)
    assert sum(b.share for b in result.remainder.amplitudes) == pytest.approx(1.0, abs=1e-6)
    assert result.remainder.amplitude_unit == "rad"


def test_to_dict_is_json_and_names_the_chosen_form():
    result = run(lambda u, r: truth(u, [0.12], [0.07, 1.0]), noise=0.0005)
    data = json.loads(json.dumps(result.to_dict()))
    assert data["chosen_form"] == "lag"
    assert data["description"] == result.describe()
    assert {f["form"]["name"] for f in data["forms"]} >= {"gain", "lag", "second order"}
    assert data["remainder"]["bands"]


# --- the building blocks against scipy -------------------------------------------------------------

def test_the_lag_filter_is_exact_for_an_input_linear_between_samples():
    rng = np.random.default_rng(0)
    u = np.concatenate([[0.0], rng.standard_normal(300)])
    t = np.arange(len(u)) * DT
    expected = signal.lsim(([1.0], [0.07, 1.0]), u, t)[1]  # lsim interpolates linearly
    np.testing.assert_allclose(filtered(u, lag_filter(0.07, DT)), expected, atol=1e-9)


@pytest.mark.parametrize(("frequency", "damping"), [(1.5, 0.3), (4.0, 1.0), (0.5, 3.0)])
def test_the_second_order_filters_are_exact_for_an_input_linear_between_samples(frequency, damping):
    rng = np.random.default_rng(1)
    u = np.concatenate([[0.0], rng.standard_normal(300)])
    t = np.arange(len(u)) * DT
    omega = 2 * np.pi * frequency
    den = [1 / omega**2, 2 * damping / omega, 1.0]
    lowpassed, rate = second_order_filters(frequency, damping, DT)
    np.testing.assert_allclose(filtered(u, lowpassed), signal.lsim(([1.0], den), u, t)[1], atol=1e-9)
    np.testing.assert_allclose(filtered(u, rate), signal.lsim(([1.0, 0.0], den), u, t)[1], atol=1e-8)


def test_a_fractional_delay_interpolates_and_holds_the_first_sample():
    u = np.arange(6.0) + 1.0
    np.testing.assert_allclose(delayed(u, 0.025, DT), [1.0, 1.0, 1.0, 1.5, 2.5, 3.5])
    np.testing.assert_allclose(delayed(np.column_stack([u, -u]), 0.025, DT)[:, 1], -delayed(u, 0.025, DT))


@pytest.mark.parametrize(("numerator", "denominator", "unit"), [
    ("rad", "rad", "-"), ("rad", "rad/s", "s"), ("rad", "m/s^2", "rad·s²/m"), ("-", "rad", "1/rad")])
def test_units_of_a_gain(numerator, denominator, unit):
    assert unit_ratio(numerator, denominator) == unit


def test_a_free_run_becomes_a_recording_where_all_signals_exist():
    time = np.arange(10) * DT
    internal = np.arange(7.0)
    prediction = SimpleNamespace(
        record="r", time=time, inputs={"front_angle": np.ones(10)}, predicted={}, signals={"rear_angle": (internal, 3)},
        signal_on_grid=lambda name: np.concatenate([np.full(3, np.nan), internal]))
    recording = Recording.from_prediction(prediction, ["rear_angle", "front_angle"])
    np.testing.assert_array_equal(recording["rear_angle"], internal)
    assert len(recording["front_angle"]) == 7


# --- one-line errors -------------------------------------------------------------------------------

def _good() -> list[Recording]:
    return records(lambda u, r: 0.1 * u, 0, 1)


@pytest.mark.parametrize(("change", "message"), [
    (lambda kw: kw.update(train=[]), "no training recordings"),
    (lambda kw: kw.update(val=[Recording("v", {"front_angle": np.zeros(100), "rear_angle": np.zeros(99)})]),
     "different lengths"),
    (lambda kw: kw.update(inputs=["steering"]), "no signal 'steering'"),
    (lambda kw: kw.update(inputs=["rear_angle"]), "must be different signals"),
    (lambda kw: kw.update(dt=0.0), "dt must be a positive"),
    (lambda kw: kw.update(inputs=[]), "no inputs"),
    (lambda kw: kw.update(val=[Recording("v", {"front_angle": np.ones(100), "rear_angle": np.ones(100)})]),
     "constant on the validation"),
    (lambda kw: kw.update(train=[Recording("t", {"front_angle": np.ones(5), "rear_angle": np.ones(5)})]),
     "has 5 samples"),
    (lambda kw: kw.update(train=[Recording("t", {"front_angle": np.full(50, np.nan), "rear_angle": np.ones(50)})]),
     "NaN"),
])
def test_bad_input_is_one_clear_line(change, message):
    arguments = {"train": _good(), "val": _good(), "dt": DT, "output": "rear_angle", "inputs": ["front_angle"]}
    change(arguments)
    with pytest.raises(UserError, match=message) as error:
        explain(**arguments)
    assert "\n" not in str(error.value)
