"""Step 3 as a hypa model: the named causes written as a model YAML that ``hypa.train`` trains.

Each cause becomes what the issue's catalogue says it is, on top of the nominal composition
(front steering gain -> single track, with a fixed-ratio rear steering if the nominal has one):

    parameter_mismatch  the re-fitted value in the model's ``parameters`` (overrides the vehicle
                        config), trainable on the block that reads it
    input_delay         a ``delay`` block (dead time ``delay_s``) on the front-wheel path, trainable
    unmodeled_lag       a ``first_order_lag`` block (``tau_s``) on the front-wheel path, trainable
    sensor_offset       the model's ``sensor_offsets`` (fixed: measured - true, per channel)
    discretization      the model's ``hold: foh``
    unmodeled_input     V1-style: an ANN drives the rear-wheel angle from the steering wheel
                        (``unmodeled_input: physics`` instead writes the fitted ratio and lag)
    saturation          V2-style: a correction ANN on the single track's outputs, trained in a
                        second stage after the rest

Every model written has something to train: if no named cause brings a trainable parameter
or a network (``none``, ``sensor_offset``, ``discretization``), the single track's cf, cr and
izz are re-fitted as in the ``physical`` baseline.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import yaml

MODEL_NAME = "diagnosed"
REFIT = ("cf", "cr", "izz")  # what the `physical` baseline fits
UNMODELED_INPUT = ("ann", "physics")


def _block(kind: str, inputs: Sequence[str], outputs: Sequence[str], **extra) -> dict:
    return {"kind": kind, "inputs": list(inputs), "outputs": list(outputs), **{k: v for k, v in extra.items() if v}}


def extension_model(named: Sequence[Mapping], hold: str, rear_steering: str, unmodeled_input: str = "ann") -> dict:
    """The model config (plain dict, the ``model`` group's schema) of the nominal physics with
    the ``named`` causes applied: rows ``{"cause": <id>, "estimate": {...}}`` as
    ``Diagnosis.named`` gives them (SI; ``sensor_offset`` once per biased channel).

    ``hold`` / ``rear_steering``: the nominal the diagnosis assumed (``none`` | ``fixed``); the
    vehicle parameters the rows do not re-fit come from the ``vehicle`` config at training.
    """
    if unmodeled_input not in UNMODELED_INPUT:
        raise ValueError(f"unmodeled_input must be one of {UNMODELED_INPUT}, got {unmodeled_input!r}")
    if rear_steering not in ("none", "fixed"):
        raise ValueError(f"rear_steering must be 'none' or 'fixed', got {rear_steering!r}")
    named = [row for row in named if row["cause"] != "none"]
    causes = [str(row["cause"]) for row in named]
    estimates = {}
    for row in named:
        estimates.setdefault(row["cause"], row["estimate"])
    model: dict = {"name": MODEL_NAME, "hold": hold, "blocks": {}, "outputs": ["yaw_rate", "side_slip"],
                   "stages": []}
    blocks, parameters, offsets = model["blocks"], {}, {}
    trainable_track: list[str] = []

    front = "front_wheel_angle"
    path = [name for name in ("input_delay", "unmodeled_lag") if name in causes]
    blocks["front_steering"] = _block("physics", ["steering_wheel_angle"],
                                      [f"{front}_command" if path else front], system="front_steering")
    signal = f"{front}_command" if path else front
    front_scale = [signal]  # the rear angle is scaled like the front one (written first in order)
    if "input_delay" in causes:
        out = front if path[-1] == "input_delay" else f"{front}_delayed"
        blocks["dead_time"] = _block("delay", [signal], [out], trainable=["delay_s"],
                                     parameters={"delay_s": float(estimates["input_delay"]["delay_s"])})
        signal = out
    if "unmodeled_lag" in causes:
        blocks["steering_lag"] = _block("physics", [signal], [front], system="first_order_lag",
                                        initial_state=["steady"], trainable=["tau_s"],
                                        parameters={"tau_s": float(estimates["unmodeled_lag"]["tau_s"])})

    rear_inputs: list[str] = []
    if "unmodeled_input" in causes:
        estimate = estimates["unmodeled_input"]
        rear_inputs = ["rear_wheel_angle"]
        if unmodeled_input == "ann":
            blocks["rear_steering"] = _block("ann", ["steering_wheel_angle"], rear_inputs,
                                             scale_as=front_scale)
        else:
            parameters["rws_ratio"] = float(estimate["ratio"])
            lagged = float(estimate.get("tau_s", 0.0)) > 0
            blocks["rear_steering"] = _block("physics", ["steering_wheel_angle"],
                                             ["rear_wheel_angle_command" if lagged else "rear_wheel_angle"],
                                             system="rear_steering", scale_as=front_scale,
                                             trainable=["rws_ratio"])
            if lagged:
                blocks["rear_lag"] = _block("physics", ["rear_wheel_angle_command"], rear_inputs,
                                            system="first_order_lag", initial_state=["steady"],
                                            scale_as=front_scale, trainable=["tau_s"],
                                            parameters={"tau_s": float(estimate["tau_s"])})
    elif rear_steering == "fixed":
        rear_inputs = ["rear_wheel_angle"]
        blocks["rear_steering"] = _block("physics", ["steering_wheel_angle"], rear_inputs, system="rear_steering",
                                         scale_as=front_scale)

    if "parameter_mismatch" in causes:
        estimate = estimates["parameter_mismatch"]
        name = str(estimate["parameter"])
        parameters[name] = float(estimate["value"])
        reader = "front_steering" if name == "steering_ratio" else "single_track"
        if reader == "single_track":
            trainable_track.append(name)
        else:
            blocks[reader]["trainable"] = [name]
    if "sensor_offset" in causes:
        for row in named:
            if row["cause"] == "sensor_offset":
                offsets[str(row["estimate"]["channel"])] = float(row["estimate"]["offset"])
    if "discretization" in causes:
        model["hold"] = str(estimates["discretization"].get("hold", "foh"))

    saturating = "saturation" in causes
    states = ["yaw_rate_physics", "side_slip_physics"] if saturating else ["yaw_rate", "side_slip"]
    has_network = "unmodeled_input" in causes and unmodeled_input == "ann"
    trains_something = has_network or any(b.get("trainable") for b in blocks.values()) or trainable_track
    if not trains_something:
        trainable_track = list(REFIT)
    blocks["single_track"] = _block("physics", [front, *rear_inputs], states,
                                    system="single_track" if rear_inputs else "single_track_front",
                                    trainable=trainable_track)
    if saturating:
        blocks["correction"] = _block("ann", [*states, "steering_wheel_angle"], ["yaw_rate", "side_slip"],
                                      residual_of=states)
        first = [name for name in blocks if name != "correction"]
        model["stages"] = [{"name": "physics", "train": first, "bypass": ["correction"]},
                           {"name": "correction", "train": ["correction"]}]
    if parameters:
        model["parameters"] = parameters
    if offsets:
        model["sensor_offsets"] = offsets
    return model


def write_model(model: Mapping, folder: Path, header: Sequence[str] = ()) -> Path:
    """Write ``model`` as ``<folder>/model/<name>.yaml`` (a config group ``hypa.train`` finds
    with ``--config-dir <folder>``), with ``header`` as comment lines; returns the path."""
    path = Path(folder) / "model" / f"{model['name']}.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    comments = "".join(f"# {line}\n" for line in header)
    path.write_text("# @package model\n" + comments + yaml.safe_dump(dict(model), sort_keys=False, default_flow_style=None, width=110))
    return path


def train_arguments(config_dir: Path, overrides: Sequence[str] = ()) -> list[str]:
    """``python -m hypa.train`` arguments that train the written model on the diagnosed data."""
    return ["--config-dir", str(config_dir), f"model={MODEL_NAME}", *overrides]


def train_command(config_dir: Path, overrides: Sequence[str] = ()) -> str:
    """The shell command that trains the written model on the diagnosed data."""
    return " ".join(["python -m hypa.train", *(_quote(word) for word in train_arguments(config_dir, overrides))])


def _quote(word: str) -> str:
    safe = all(ch.isalnum() or ch in "=._-/:+,@" for ch in word)
    return word if safe else "'" + word.replace("'", "'\"'\"'") + "'"


def describe(model: Mapping) -> list[str]:
    """One line per block of ``model`` (what it is, its wiring, its fixed and trained values), and
    the model-level settings: for diagnosis.md."""
    lines = []
    for name, block in model["blocks"].items():
        what = f"{block['kind']}: {block['system']}" if block.get("system") else block["kind"]
        text = f"`{name}` ({what}): {', '.join(block['inputs'])} → {', '.join(block['outputs'])}"
        if block.get("parameters"):
            text += "; " + ", ".join(f"{k} = {v:.4g}" for k, v in block["parameters"].items())
        if block.get("trainable"):
            text += f"; trains {', '.join(block['trainable'])}"
        if block.get("residual_of"):
            text += f"; adds its output to {', '.join(block['residual_of'])}"
        lines.append(text)
    settings = [f"hold = {model['hold']}"]
    if model.get("parameters"):
        settings.append("parameters " + ", ".join(f"{k} = {v:.6g}" for k, v in model["parameters"].items()))
    if model.get("sensor_offsets"):
        settings.append("sensor offsets " + ", ".join(f"{k} = {v:.4g}" for k, v in model["sensor_offsets"].items()))
    if model.get("stages"):
        settings.append("stages " + " then ".join(f"{s['name']} ({', '.join(s['train'])})" for s in model["stages"]))
    lines.append("; ".join(settings))
    return lines
