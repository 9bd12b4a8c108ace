"""The diagnosis names a friction law that is not linear in the speed, on an axis nobody tuned for.

A positioning axis (a mass with Coulomb friction and an offset force, like EMPS but lighter and
with other frictions) runs in closed loop; its viscous friction is partly cubic in the speed, by a
share drawn at random. The engineer's model has the right values for everything but the law. The
data come from a fine Euler recursion of the friction law written out here, not from hypa. The
catalogue's expressions read the model's own values: the pivot speed of ``cubic_friction`` is
``coulomb_friction / viscous_friction`` at this round's values.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hypa.diagnosis.catalogue import catalogue_candidates, load_catalogue
from hypa.models import parse_model_spec
from hypa.models.spec import spec_config

from conftest import ROOT
from data_helpers import user_dataset

TRUE = {"mass": 60.0, "viscous_friction": 150.0, "offset_force": 2.0, "coulomb_friction": 15.0}

DATASET = user_dataset({
    "time": {"column": "time", "unit": "s"}, "sample_rate_hz": 1000.0,
    "channels": {"force": {"role": "input", "unit": "N"}, "position": {"role": "output", "unit": "m"}},
    "splits": {"train": [{"file": "train.csv", "start": 0.0, "stop": 0.8}],
               "val": [{"file": "train.csv", "start": 0.8, "stop": 1.0}]},
    "window": 200, "past": 20, "stride": 10})

MODEL = """# @package model
name: axis
blocks:
  axis:
    kind: physics
    system: mass_with_coulomb_friction
    inputs: [force]
    outputs: [position]
    initial_state: estimate
    trainable: [mass, viscous_friction, offset_force, coulomb_friction]
outputs: [position]
parameters: {parameters}
stages: []
"""


def closed_loop(share: float, seed: int, seconds: float = 20.0) -> np.ndarray:
    """(time, force, position) rows at 1 kHz: a PD controller tracking random sines, the axis
    integrated by semi-implicit Euler at 10 kHz with the friction law written out."""
    m, fv, fc, f0 = TRUE["mass"], TRUE["viscous_friction"], TRUE["coulomb_friction"], TRUE["offset_force"]
    pivot = fc / fv
    rng = np.random.default_rng(seed)
    dt, n = 1e-3, round(seconds * 1e3)
    t = np.arange(n) * dt
    reference = sum(rng.uniform(0.02, 0.06) * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
                    for f in rng.uniform(0.1, 0.8, 6))
    q = v = 0.0
    rows = np.empty((n, 3))
    for k in range(n):
        u = 4000 * (reference[k] - q) - 300 * v + rng.normal(0, 5)
        rows[k] = t[k], u, q
        for _ in range(10):
            friction = fv * (1 - share) * v + fv * share * v**3 / pivot**2 + fc * math.tanh(v / 0.005) - f0
            v += 1e-4 * (u - friction) / m
            q += 1e-4 * v
    rows[:, 2] += rng.normal(0, 2e-5, n)
    return rows


def test_the_pivot_speed_is_read_from_the_model_values_of_this_round() -> None:
    spec = parse_model_spec(json.loads(json.dumps({
        "name": "axis", "outputs": ["position"], "stages": [], "parameters": {"coulomb_friction": 12.0},
        "blocks": {"axis": {"kind": "physics", "system": "mass_with_coulomb_friction", "inputs": ["force"],
                            "outputs": ["position"], "trainable": ["viscous_friction", "coulomb_friction"]}}})))
    channels = {"force": (100.0, "N"), "position": (0.1, "m")}
    cubic = [c for c in catalogue_candidates(load_catalogue(), spec, ["force"], ["position"], [], {}, 1e-3,
                                             channels=channels)
             if c.cause == "cubic_friction"]
    assert len(cubic) == 1
    block = cubic[0].spec.blocks[0]
    assert block.system == "mass_with_cubic_friction" and set(block.trainable) == {"viscous_friction", "cubic_share"}
    assert cubic[0].spec.parameters["cubic_speed"] == pytest.approx(12.0 / 203.5)  # the fitted Fc, the nominal Fv


@pytest.mark.slow
@pytest.mark.parametrize("seed", [7, 11])
def test_names_a_partly_cubic_friction_at_its_share(tmp_path: Path, seed: int) -> None:
    rng = np.random.default_rng(seed)
    share = float(rng.uniform(0.3, 0.8))
    folder = tmp_path / "user"
    (folder / "conf" / "dataset").mkdir(parents=True)
    (folder / "conf" / "model").mkdir()
    (folder / "data").mkdir()
    (folder / "conf" / "dataset" / "axis.yaml").write_text(DATASET)
    (folder / "conf" / "model" / "axis.yaml").write_text(MODEL.format(parameters=json.dumps(TRUE)))
    np.savetxt(folder / "data" / "train.csv", closed_loop(share, seed=int(rng.integers(1000))), fmt="%.12g",
               delimiter=",", header="time,force,position", comments="")
    out = tmp_path / "diagnosis"
    result = subprocess.run(
        [sys.executable, "-m", "hypa", "diagnose", "--config-dir", str(folder / "conf"), "dataset=axis", "model=axis",
         f"data.dir={folder / 'data'}", "plot=false", f"hydra.run.dir={out}"],
        cwd=ROOT, capture_output=True, text=True, timeout=600, env=dict(os.environ), check=False)
    assert result.returncode == 0, result.stderr[-3000:]
    named = json.loads((out / "diagnosis.json").read_text())["named"]
    assert (named[0]["cause"], named[0]["target"]) == ("cubic_friction", "axis"), result.stdout[-2000:]
    assert named[0]["values"]["cubic_share"] == pytest.approx(share, abs=0.05)
    assert named[0]["values"]["viscous_friction"] == pytest.approx(TRUE["viscous_friction"], rel=0.05)


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3])
def test_the_core_entries_start_from_the_data_not_from_constants(scale: float) -> None:
    """The Coulomb force starts at a tenth of the largest drive force (of the measured input, or of
    a force between blocks by its scaling), the Duffing hardening where the spring is 1 % stiffer at
    one spread of the position: a stage of millinewtons and one of kilonewtons start alike."""
    friction = parse_model_spec({
        "name": "axis", "outputs": ["position"], "stages": [],
        "blocks": {"axis": {"kind": "physics", "system": "mass_with_friction", "inputs": ["force"],
                            "outputs": ["position"]}}})
    channels = {"force": (150.0 * scale, "N"), "position": (0.1, "m")}
    coulomb = next(c for c in catalogue_candidates(load_catalogue(), friction, ["force"], ["position"], [], {}, 1e-3,
                                                   channels=channels) if c.cause == "coulomb_friction")
    assert coulomb.spec.parameters["coulomb_friction"] == pytest.approx(15.0 * scale)
    between = {"force": (0.0, "N"), "drive": (150.0 * scale, "")}  # a drive force written by a block before it
    rewired = parse_model_spec({**spec_config(friction), "blocks": {"axis": {
        **spec_config(friction)["blocks"]["axis"], "inputs": ["drive"]}, "amplifier": {
        "kind": "physics", "system": "gain", "inputs": ["force"], "outputs": ["drive"]}}})
    coulomb = next(c for c in catalogue_candidates(load_catalogue(), rewired, ["force"], ["position"], [], {}, 1e-3,
                                                   channels=between) if c.cause == "coulomb_friction")
    assert coulomb.spec.parameters["coulomb_friction"] == pytest.approx(15.0 * scale)
    spring = parse_model_spec({
        "name": "oscillator", "outputs": ["position"], "stages": [],
        "blocks": {"oscillator": {"kind": "physics", "system": "mass_spring_damper", "inputs": ["force"],
                                  "outputs": ["position"]}}})
    states = {"oscillator/position": (0.0, 0.04 * scale, -0.05 * scale, 0.05 * scale),
              "oscillator/velocity": (0.0, 1.0, -1.0, 1.0)}
    hardening = next(c for c in catalogue_candidates(load_catalogue(), spring, ["force"], ["position"], [], {}, 1e-3,
                                                     channels=channels, states=states)
                     if c.cause == "stiffening_spring")
    assert hardening.spec.parameters["hardening"] == pytest.approx(0.01 / (0.04 * scale) ** 2)
