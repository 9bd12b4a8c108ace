"""A model is built from what the data module knows (``DataSignature``), checkpoints written before
``HybridModule.from_data`` existed still load, and the hold is the model's (a conflict is one line)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from hypa.core.errors import UserError
from hypa.data import ChannelSpec, DataError, DataSignature, HypaDataModule
from hypa.diagnosis import Problem
from hypa.models import ComposedModel, parse_model_spec
from hypa.physics.systems import build_system
from hypa.training import HybridModule
from hypa.training.checkpoints import load_module

RATE = 100.0  # Hz
LSTM = {"hidden_size": 8, "num_layers": 1, "dropout": 0.0, "input_proj": None}
OSCILLATOR = {
    "name": "oscillator",
    "blocks": {"oscillator": {"kind": "physics", "system": "mass_spring_damper", "inputs": ["force"],
                              "outputs": ["position"], "initial_state": "estimate", "trainable": ["stiffness"]}},
    "outputs": ["position"],
    "hold": "foh",
}
HYBRID = {
    "name": "oscillator_hybrid",
    "blocks": {"oscillator": {**OSCILLATOR["blocks"]["oscillator"], "outputs": ["position_physics"],
                              "observe": {"position_physics": "position"}},
               "correction": {"kind": "ann", "inputs": ["force", "position_physics"], "outputs": ["position"],
                              "residual_of": ["position_physics"]}},
    "outputs": ["position"],
    "hold": "foh",
}


@pytest.fixture(scope="module")
def dm(tmp_path_factory) -> HypaDataModule:
    """Two short records of a lightly damped oscillator (1 kg, 100 N/m) driven by random steps."""
    folder = tmp_path_factory.mktemp("oscillator")
    rng = np.random.default_rng(0)
    for split, seconds in (("train", 20), ("val", 10)):
        n, dt = int(seconds * RATE), 1 / RATE
        force = np.repeat(rng.normal(size=n // 20 + 1), 20)[:n]
        q, v, position = 0.0, 0.0, np.empty(n)
        for i, f in enumerate(force):
            position[i] = q
            v += dt * (f - 0.5 * v - 100.0 * q)
            q += dt * v
        np.savetxt(folder / f"{split}.csv", np.column_stack([np.arange(n) * dt, force, position]), delimiter=",",
                   header="time,force,position", comments="")
    module = HypaDataModule(folder, [ChannelSpec("force", "input", "N"), ChannelSpec("position", "output", "m")],
                            sample_rate_hz=RATE, rate_hz=None, window=40, past=4, stride=20, eval_stride=20)
    module.setup()
    return module


def old_hparams(dm: HypaDataModule, model_config: dict) -> dict:
    """The 16 settings as the train command wrote them into every checkpoint before ``from_data``:
    copied from the data module one by one, the run's ``physics.hold`` even where the model fixes its own."""
    return {"model_config": model_config, "physical_values": {}, "normalization": dm.normalization.state_dict(),
            "input_names": dm.input_names, "output_names": dm.output_names, "eval_names": dm.eval_names,
            "scheduling_names": dm.scheduling_names, "past": dm.past, "dt": dm.dt, "horizon": dm.window,
            "hold": "zoh", "ann_name": "lstm", "ann_hparams": LSTM, "lr": 5e-4, "physics_lr": 1e-2,
            "weight_decay": 0.0}


def predict(module: HybridModule, dm: HypaDataModule) -> torch.Tensor:
    batch = next(iter(dm.val_dataloader()))
    with torch.no_grad():
        return module.eval()(batch["u"], batch["y"][:, : dm.past + 1], batch.get("s"))


def test_the_signature_is_what_the_data_module_knows(dm: HypaDataModule) -> None:
    data = dm.signature
    assert (data.input_names, data.output_names, data.eval_names, data.scheduling_names) == \
        (("force",), ("position",), (), ())
    assert (data.dt, data.window, data.past) == (pytest.approx(0.01), 40, 4) and data.normalization == dm.normalization
    mean, std = (float(x) for x in (dm.normalization.mean[1], dm.normalization.std[1]))
    assert data.scale(["position"]) == {"position": (mean, std)}
    with pytest.raises(DataError, match=r"no statistics for \['speed'\]"):
        DataSignature(["force"], ["speed"], dm.normalization, dm.dt, window=40)


def test_from_data_builds_what_the_hand_copied_settings_built(dm: HypaDataModule) -> None:
    torch.manual_seed(0)
    module = HybridModule.from_data(dm, HYBRID, ann_hparams=LSTM)
    torch.manual_seed(0)
    by_hand = HybridModule(**{**old_hparams(dm, HYBRID), "hold": "foh"})
    plain = lambda hparams: {k: list(v) if isinstance(v, tuple) else v for k, v in hparams.items()}  # noqa: E731
    assert plain(module.hparams) == {**plain(by_hand.hparams), "physical_values": None}  # None: the systems' own
    assert torch.equal(predict(module, dm), predict(by_hand, dm))
    # no physical values given: the system's own nominal ones; given: those
    nominal = build_system("mass_spring_damper", "oscillator").nominal_values()
    assert ComposedModel.from_data(dm, OSCILLATOR).parameters_.as_floats() == pytest.approx(nominal)
    given = ComposedModel.from_data(dm, OSCILLATOR, {"mass": 2.5}).parameters_.as_floats()
    assert given == pytest.approx({**nominal, "mass": 2.5})


def test_a_checkpoint_of_the_old_settings_loads(dm: HypaDataModule, tmp_path: Path) -> None:
    """Checkpoints hold the 16 hand-copied settings (names as tuples, the run's ``hold: zoh`` beside a
    model's ``hold: foh``): they load through ``load_module`` and ``load_from_checkpoint`` alike."""
    import lightning

    hparams = old_hparams(dm, HYBRID)
    trained = HybridModule(**hparams)
    with torch.no_grad():
        trained.model.parameters_.raw["stiffness"].add_(0.1)  # "trained": not the nominal value
    path = tmp_path / "old.ckpt"
    torch.save({"state_dict": trained.state_dict(), "hyper_parameters": hparams,
                "pytorch-lightning_version": lightning.__version__}, path)
    expected = predict(trained, dm)
    for module in (load_module(path), HybridModule.load_from_checkpoint(path, map_location="cpu", weights_only=True)):
        assert module.model.hold == "foh"  # the model's own, as it was trained
        assert module.model.parameters_.as_floats() == pytest.approx(trained.model.parameters_.as_floats())
        assert torch.allclose(predict(module, dm), expected)


def test_a_checkpoint_from_before_a_system_gained_a_parameter_loads_with_its_value_now(
        dm: HypaDataModule, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """A system that gains a parameter (a circuit's output offset, 0: the system as it was) still loads
    the checkpoints saved before: the new parameter at the model's value, said in one warning; a
    network's missing weight is still refused."""
    import lightning

    hparams = old_hparams(dm, HYBRID)
    trained = HybridModule(**hparams)
    with torch.no_grad():
        trained.model.parameters_.raw["stiffness"].add_(0.1)
    weights = {k: v for k, v in trained.state_dict().items() if k != "model.parameters_.raw.damping"}  # "new"
    path = tmp_path / "before.ckpt"
    torch.save({"state_dict": weights, "hyper_parameters": hparams,
                "pytorch-lightning_version": lightning.__version__}, path)
    with caplog.at_level("WARNING"):
        loaded = load_module(path).model.parameters_.as_floats()
    assert loaded["stiffness"] == pytest.approx(trained.model.parameters_.as_floats()["stiffness"])
    assert loaded["damping"] == pytest.approx(HybridModule(**hparams).model.parameters_.as_floats()["damping"])
    assert "predates the physical parameter(s) damping" in caplog.text
    network = next(k for k in weights if k.startswith("model.blocks.") and "weight" in k)
    torch.save({"state_dict": {k: v for k, v in weights.items() if k != network}, "hyper_parameters": hparams,
                "pytorch-lightning_version": lightning.__version__}, path)
    with pytest.raises(UserError, match="its weights do not fit its model"):
        load_module(path)


def test_the_hold_is_the_models_and_a_conflict_is_one_line(dm: HypaDataModule) -> None:
    assert HybridModule.from_data(dm, OSCILLATOR).model.hold == "foh"
    assert HybridModule.from_data(dm, OSCILLATOR, hold="foh").hparams.hold == "foh"
    unfixed = {k: v for k, v in OSCILLATOR.items() if k != "hold"}
    assert HybridModule.from_data(dm, unfixed).model.hold == "zoh"
    assert ComposedModel.from_data(dm, unfixed, hold="foh").hold == "foh"
    for build in (lambda: HybridModule.from_data(dm, OSCILLATOR, hold="zoh"),
                  lambda: ComposedModel.from_data(dm, OSCILLATOR, hold="zoh"),
                  lambda: Problem(dm, hold="zoh", workers=1).build(parse_model_spec(OSCILLATOR))):
        with pytest.raises(UserError, match="model 'oscillator' fixes hold: foh, but hold=zoh was given") as error:
            build()
        assert "\n" not in str(error.value)


def test_the_problem_defaults_to_the_data_modules_window_and_nominal_values(dm: HypaDataModule) -> None:
    problem = Problem(dm, workers=1)
    assert (problem.horizon, problem.physical_values, problem.hold) == (dm.window, {}, None)
    assert problem.build(parse_model_spec(OSCILLATOR)).hold == "foh"
    assert Problem(dm, {"mass": 2.0}, horizon=10, workers=1).horizon == 10


def test_the_data_layer_imports_no_model() -> None:
    code = ("import sys, hypa.data.signature, hypa.data.datamodule; "
            "print(sorted(m for m in sys.modules if m.startswith(('hypa.models', 'hypa.training'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
