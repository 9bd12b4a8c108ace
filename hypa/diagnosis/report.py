"""diagnosis.md: the engineer's report of a ``python -m hypa.diagnose`` run, from its result dict
(the content of diagnosis.json) and the figure file names. Text only; it computes nothing."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from hypa.vehicle.display import DEG, DISPLAY_UNITS

UNITS = {name: (DISPLAY_UNITS[name], DEG) for name in ("yaw_rate", "side_slip")}  # the states
WHAT = {
    "parameter_mismatch": "a nominal vehicle parameter is wrong",
    "input_delay": "a dead time between the measured steering-wheel angle and the front wheels",
    "unmodeled_lag": "a first-order lag between the steering wheel and the front wheels",
    "sensor_offset": "a constant sensor bias",
    "discretization": "the zero-order hold's half-sample lag (the input is smooth: a first-order hold fits)",
    "saturation": "the axles saturate at large lateral acceleration (the physics is linear)",
    "unmodeled_input": "an input the physics does not know acts through the rear axle (rear-wheel steering)",
    "none": "nothing the catalogue can name: the physics explains the held-out data down to the noise",
}


def _metrics_table(baseline: Mapping, extended: Mapping, gain: Mapping, name: str = "extended") -> list[str]:
    lines = [f"| subset | channel | RMSE nominal | RMSE {name} | MSE change | R² nominal | R² {name} |",
             "|---|---|---|---|---|---|---|"]
    for subset in ("all", "high_ay"):
        before, after = baseline.get(subset), extended.get(subset)
        if before is None or after is None:
            continue
        for channel in (*UNITS, "overall"):
            unit, k = UNITS.get(channel, ("(SI, mean over states)", 1.0))
            rmse_b, rmse_a = np.sqrt(before[channel]["mse"]) * k, np.sqrt(after[channel]["mse"]) * k
            change = gain[subset].get(channel)
            change_text = "" if change is None else f"{100 * change:+.1f} %"
            lines.append(f"| {subset} | {channel} | {rmse_b:.4g} {unit} | {rmse_a:.4g} {unit} | {change_text} | "
                         f"{before[channel]['r2']:.4f} | {after[channel]['r2']:.4f} |")
    return lines


def markdown(result: Mapping, figures: Mapping[str, str | list[str]]) -> str:
    """The report. ``figures`` maps a figure's role (``time_series``, ``error_vs_ay``, ``transfer``,
    ``correlations``, ``mean_error``, ``transfer_gain``, ``rear_wheel_angle``) to file name(s)."""
    def fig(role: str, caption: str) -> list[str]:
        names = figures.get(role)
        if not names:
            return []
        names = [names] if isinstance(names, str) else names
        return [f"![{caption}]({name})" for name in names] + [""]

    nominal, residuals = result["nominal"], result["residuals"]
    named = result["candidates"][: len(result["causes"])] or [{"cause": "none", "estimate": {}}]
    lines = ["# Diagnosis: what the physics gets wrong", "",
             f"Nominal physics: linear single track, hold = {nominal['hold']}, rear steering = "
             f"{nominal['rear_steering']}; data: {result['data']['train_records']} training and "
             f"{result['data']['val_records']} validation records at {1 / result['data']['dt']:.4g} Hz.", "",
             "## 1. What is wrong", ""]
    for row in named:
        lines.append(f"- **{row['cause']}**: {WHAT.get(row['cause'], row['cause'])}. Estimate: `{row['estimate']}`.")
    lines += ["", "## 2. Why we think so", "",
              "The nominal model free-runs over each validation record from its first measured state. "
              "Its residual e = ŷ - y per channel:", "",
              "| channel | mean error | RMSE | NRMSE |", "|---|---|---|---|"]
    for channel, m in residuals["channels"].items():
        unit, k = UNITS.get(channel, ("SI", 1.0))
        lines.append(f"| {channel} | {m['mean'] * k:.4g} {unit} | {m['rmse'] * k:.4g} {unit} | {m['nrmse']:.4f} |")
    lines += ["",
              f"Transfer function δsw → yaw rate over the coherent band (γ² ≥ 0.8): measured / model gain "
              f"ratio {residuals['gain_ratio']:.3f}, phase difference {residuals['phase_difference_deg']:+.1f}° "
              "(a phase lag growing with frequency at unchanged gain points at a delay or lag; a gain ratio ≠ 1 "
              "at a parameter or an unmodeled input).", ""]
    lines += fig("time_series", "measured and simulated over time")
    lines += fig("transfer", "transfer function measured vs nominal")
    lines += fig("error_vs_ay", "error against |a_y|")
    lines += ["Residual correlations against the 99 % band of white noise: share of lags outside "
              + ", ".join(f"{s}: ρ_ee {100 * residuals['autocorrelation_outside'][s]:.0f} %, ρ_ue "
                          f"{100 * residuals['cross_correlation_outside'][s]:.0f} % (peak at "
                          f"{1000 * residuals['cross_correlation_peak_lag_s'][s]:.0f} ms)"
                          for s in residuals["channels"])
              + ". A white residual that is independent of the input would leave ~1 % outside.", ""]
    lines += fig("correlations", "residual autocorrelation and input-residual cross-correlation")
    lines += fig("mean_error", "mean error per channel")
    lines += ["Each catalogue cause was fitted on the training records and scored on the validation records "
              "(greedy search, penalized held-out gain and a signed-rank test; see `hypa/diagnosis/naming.py`):", "",
              "| cause | score (share of nominal error explained) | estimate | evidence |", "|---|---|---|---|"]
    for i, row in enumerate(result["candidates"]):
        mark = "**" if i < len(result["causes"]) else ""
        lines.append(f"| {mark}{row['cause']}{mark} | {row['score']:.3f} | `{row['estimate']}` | {row['evidence']} |")
    extended, gain = result["extended"], result["gain"]
    lines += ["", "## 3. What we changed", ""]
    if not result["causes"]:
        lines += ["Nothing: no cause was named, so the extended model is the nominal one.", ""]
    else:
        lines += ["The nominal model with every named cause applied at its jointly re-fitted estimate "
                  "(the parametric extension; section 4 measures it):", "", f"`{extended['spec']}`", ""]
    if extended.get("config"):
        lines += ["As a hypa model (the same physics; an ANN where the cause calls for a HyPA-Net variant: "
                  "V1-style on an unmodeled input, a V2-style correction for saturation), written to "
                  f"`{extended['config']}`:", ""]
        lines += [f"- {line}" for line in extended.get("config_blocks", [])]
        lines += ["", "Train it (then `python -m hypa.evaluate run=<its run folder>`) with", "",
                  f"    {extended['train_command']}", ""]
    lines += ["## 4. What it gained", "",
              f"Free runs over the validation records; high |a_y|: |a_y| ≥ {gain['high_ay_threshold']:g} m/s² "
              f"({gain['high_ay_samples']} samples). MSE change = (extended - nominal) / nominal.", ""]
    lines += _metrics_table(result["baseline"]["metrics"], extended["metrics"], gain)
    trained = extended.get("trained")
    if trained:
        lines += ["", f"The hypa model above, trained (`{trained['run']}`), free-running over the same records:", ""]
        lines += _metrics_table(result["baseline"]["metrics"], trained["metrics"], trained["gain"], "trained")
        if trained.get("rear_wheel_angle"):
            rear = trained["rear_wheel_angle"]
            lines += ["", f"Its learned rear-wheel angle against the measured one: correlation {rear['correlation']:.3f}, "
                          f"RMSE {rear['rmse'] * DEG:.3f} deg."]
    transfer = gain.get("transfer", {})
    if transfer:
        lines += ["", "Transfer function (measured / model over the coherent band): "
                  + "; ".join(f"{name} gain ratio {t['gain_ratio']:.3f}, phase {t['phase_difference_deg']:+.1f}°"
                              for name, t in transfer.items()) + ".", ""]
    lines += fig("transfer_gain", "transfer function before and after")
    rear = extended.get("rear_wheel_angle")
    if rear:
        lines += [f"Recovered rear-wheel angle against the measured `rear_wheel_angle` (never used by the fit): "
                  f"correlation {rear['correlation']:.3f}, RMSE {rear['rmse'] * DEG:.3f} deg.", ""]
        lines += fig("rear_wheel_angle", "recovered vs measured rear-wheel angle")
    return "\n".join(lines) + "\n"
