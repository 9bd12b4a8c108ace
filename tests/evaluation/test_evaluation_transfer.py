"""H1 estimates against the analytic yaw-rate response of the paper's single-track model.

The yaw rate ψ̇ [rad/s] per steering-wheel angle δsw [rad] of ``SingleTrack(rear_steering=False)``
with ``VehicleParameters()`` (yaw mode ~1.3 Hz, ζ ~ 0.77) is driven by band-limited white
noise, simulated at 1024 Hz and decimated to the paper's 32 Hz; the same decimation filter
acts on u and y, so it cancels in H1 and the continuous response is the reference.

Tolerances (module docstring of hypa.evaluation.transfer): per bin, the random error of |H1|
(relative) and of its phase (rad) is ε = sqrt(1 - γ²) / (|γ| sqrt(2 n_d)); we allow 4 ε (a
seeded draw, but 4 σ keeps the check honest over ~60 bins rather than tuned to the seed) plus
a bias allowance of 0.5 % / 0.5° for the Hann segments' finite resolution (0.0625 Hz against
a ~1 Hz wide mode) and the first-order-hold simulation. With n_d = 74 averages and γ² > 0.9
this is at most ~5 % in magnitude and ~3° in phase over 0.1-4 Hz.
"""

import numpy as np
import pytest
import torch
from scipy import signal

from hypa.evaluation.transfer import TransferEstimate, frequency_response, h1_estimate
from hypa.vehicle import SingleTrack, VehicleParameters

FS, FINE, DURATION_S, BAND = 32.0, 1024, 600, (0.1, 4.0)


def yaw_matrices() -> tuple[np.ndarray, ...]:
    """A, B, C, D of yaw rate per steering-wheel angle (front steering through the ratio)."""
    values = VehicleParameters()
    p = {k: torch.tensor(v, dtype=torch.float64) for k, v in values.as_dict().items()}
    ss = SingleTrack(rear_steering=False).matrices(p)
    return ss.a.numpy(), ss.b.numpy() / values.steering_ratio, ss.c.numpy()[:1], ss.d.numpy()[:1]


@pytest.fixture(scope="module")
def record() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    a, b, c, d = yaw_matrices()
    lowpass = signal.butter(4, 8.0, fs=FINE, output="sos")  # band-limited well below 16 Hz
    u = np.radians(20.0) * signal.sosfilt(lowpass, rng.standard_normal(FINE * DURATION_S))
    # First-order hold: the input is smooth, so its linear interpolation is far closer than a ZOH
    # staircase (half-sample delay) to what the continuous system would see.
    ad, bd, cd, dd, _ = signal.cont2discrete((a, b, c, d), 1.0 / FINE, method="foh")
    num, den = signal.ss2tf(ad, bd, cd, dd)
    y = signal.lfilter(num[0], den, u)
    q = int(FINE / FS)
    u32, y32 = signal.resample_poly(u, 1, q), signal.resample_poly(y, 1, q)
    noise = rng.standard_normal(y32.size) * np.std(y32)
    return {"u": u32, "y": y32, "y_noisy": y32 + 0.2 * noise, "y_very_noisy": y32 + noise}


def reference(frequency_hz: np.ndarray) -> np.ndarray:
    return frequency_response(*yaw_matrices(), frequency_hz)[:, 0, 0]


def random_error(est: TransferEstimate) -> np.ndarray:
    """ε(f): relative 1σ error of |H1| and 1σ phase error [rad] (Bendat & Piersol)."""
    gamma2 = est.coherence
    return np.sqrt(1.0 - gamma2) / np.sqrt(gamma2 * 2 * est.n_averages)


@pytest.mark.parametrize("output", ["y", "y_noisy"])
def test_h1_matches_single_track_yaw_response(record, output):
    est = h1_estimate(record["u"], record[output], FS).band(*BAND)
    truth = reference(est.frequency_hz)
    assert est.n_averages == 74 and est.frequency_hz[0] == pytest.approx(0.125)
    assert np.all(est.coherence > 0.9)
    eps = random_error(est)
    magnitude_error = np.abs(est.magnitude / np.abs(truth) - 1.0)
    phase_error = np.abs(est.phase_deg - np.degrees(np.unwrap(np.angle(truth))))
    assert np.all(magnitude_error <= 4 * eps + 0.005), magnitude_error.max()
    assert np.all(phase_error <= np.degrees(4 * eps) + 0.5), phase_error.max()
    assert magnitude_error.max() < 0.05 and phase_error.max() < 3.0
    if output == "y":
        assert np.all(est.coherence > 0.99) and magnitude_error.max() < 0.01


def test_h1_is_unbiased_under_output_noise(record):
    """Output noise with the signal's own power lowers γ² but not the mean of |H1| / |H|.

    H2 = S_yy / S_yu, which charges the noise to the output, overestimates by ~1 / γ²: the check
    can tell a biased estimator from an unbiased one.
    """
    est = h1_estimate(record["u"], record["y_very_noisy"], FS).band(*BAND)
    ratio = est.magnitude / np.abs(reference(est.frequency_hz))
    assert est.coherence.min() < 0.8  # the noise is really there
    # mean over ~60 bins of nearly independent errors: its 1σ is ~ mean(ε) / sqrt(60)
    assert abs(ratio.mean() - 1.0) < 3 * random_error(est).mean() / np.sqrt(ratio.size)
    kw = {"fs": FS, "window": "hann", "nperseg": 512, "noverlap": 256}
    f, s_yy = signal.welch(record["y_very_noisy"], **kw)
    _, s_uy = signal.csd(record["u"], record["y_very_noisy"], **kw)
    keep = (f >= BAND[0]) & (f <= BAND[1])
    h2_ratio = np.abs(s_yy[keep] / np.conj(s_uy[keep])) / np.abs(reference(f[keep]))
    assert h2_ratio.mean() > 1.1 and h2_ratio.mean() == pytest.approx(np.mean(1 / est.coherence), rel=0.05)


@pytest.mark.filterwarnings("ignore::scipy.signal.BadCoefficients")  # scipy's own ss -> tf inside freqresp
def test_frequency_response_matches_scipy():
    a, b, c, d = yaw_matrices()
    f = np.array([0.05, 0.5, 1.3, 7.0])
    _, h = signal.freqresp((a, b, c, d), w=2 * np.pi * f)
    np.testing.assert_allclose(frequency_response(a, b, c, d, f)[:, 0, 0], h, rtol=1e-12)
    dt = 1 / FS
    ad, bd, cd, dd, _ = signal.cont2discrete((a, b, c, d), dt, method="zoh")
    _, hd = signal.dfreqresp((ad, bd, cd, dd, dt), w=2 * np.pi * f * dt)
    np.testing.assert_allclose(frequency_response(ad, bd, cd, dd, f, dt=dt)[:, 0, 0], hd, rtol=1e-12)
    # steady-state gain: -C A⁻¹ B
    dc = frequency_response(a, b, c, d, [0.0])[0, 0, 0]
    assert dc == pytest.approx((-c @ np.linalg.solve(a, b))[0, 0])


def test_frequency_response_shapes_and_static_gain():
    a, b, _, _ = yaw_matrices()
    h = frequency_response(a, np.hstack([b, -b]), np.eye(2), np.zeros((2, 2)), np.linspace(0.1, 1, 5))
    assert h.shape == (5, 2, 2) and np.allclose(h[:, :, 1], -h[:, :, 0])
    static = frequency_response(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), [[1 / 15]], [0.1, 1.0])
    np.testing.assert_allclose(static, np.full((2, 1, 1), 1 / 15))
    with pytest.raises(ValueError, match="inconsistent"):
        frequency_response(a, b, np.eye(3), np.zeros((3, 1)), [1.0])
    with pytest.raises(ValueError, match="dt"):
        frequency_response(a, b, np.eye(2), np.zeros((2, 1)), [1.0], dt=0.0)


def test_transfer_estimate_properties_and_band():
    f = np.arange(1, 101) / 10.0  # 0.1 ... 10 Hz; 1.0 and 2.0 exactly
    delay = TransferEstimate.analytic(f, np.exp(-2j * np.pi * f * 0.25))  # 0.25 s pure delay
    np.testing.assert_allclose(delay.magnitude, 1.0)
    np.testing.assert_allclose(delay.phase_deg, -90.0 * f, atol=1e-9)  # unwrapped past -180°
    sub = delay.band(1.0, 2.0)
    assert sub.frequency_hz.min() >= 1.0 and sub.frequency_hz.max() <= 2.0 and sub.coherence.size == 11
    with pytest.raises(ValueError, match="f_min"):
        delay.band(2.0, 1.0)
    with pytest.raises(ValueError, match="1-D"):
        TransferEstimate(f, f[:-1].astype(complex), f)


def test_h1_estimate_rejects_bad_signals():
    rng = np.random.default_rng(1)
    u = rng.standard_normal(1000)
    with pytest.raises(ValueError, match="too short"):
        h1_estimate(u[:700], u[:700], FS)  # 21.9 s < 24 s for two 16 s segments at 50 % overlap
    assert h1_estimate(u[:768], u[:768], FS).n_averages == 2
    with pytest.raises(ValueError, match="lengths differ"):
        h1_estimate(u, u[:-1], FS)
    with pytest.raises(ValueError, match="finite"):
        h1_estimate(u, np.where(np.arange(1000) == 5, np.nan, u), FS)
    with pytest.raises(ValueError, match="constant"):
        h1_estimate(np.ones(1000), u, FS)


def test_bode_and_rear_steer_figures(record):
    import matplotlib.pyplot as plt

    from hypa.evaluation.figures import bode, rear_steer

    measured = h1_estimate(record["u"], record["y_noisy"], FS)
    physics = TransferEstimate.analytic(measured.frequency_hz, reference(measured.frequency_hz))
    fig = bode({"measured": measured, "single track": physics}, coherence_min=0.5)
    gain, phase, coherence = fig.axes
    assert len(fig.axes) == 3 and len(gain.lines) == len(phase.lines) == 2
    assert gain.lines[-1].get_linestyle() == "--" and gain.lines[-1].get_color() == "k"
    assert len(coherence.lines) == 2  # γ² of the reference and the threshold
    assert gain.lines[0].get_xdata().max() <= 5.0
    plt.close(fig)
    fig = bode({"single track": physics}, reference=None, coherence_min=None)
    assert len(fig.axes) == 2 and len(fig.axes[0].lines) == 1
    plt.close(fig)
    with pytest.raises(KeyError, match="reference"):
        bode({"single track": physics})

    t = np.arange(64) / FS
    fig = rear_steer(t, np.radians(np.sin(t)), {"V1 LSTM": np.radians(0.9 * np.sin(t))}, title="val")
    (ax,) = fig.axes
    assert len(ax.lines) == 2 and np.max(ax.lines[1].get_ydata()) == pytest.approx(np.max(np.sin(t)))
    plt.close(fig)
    fig = rear_steer(t, None, {"a": np.zeros(64), "b": np.zeros(64)})
    assert len(fig.axes[0].lines) == 2
    plt.close(fig)
