"""The one-step export: trained runs as ONNX, checked by onnxruntime against hypa's own free run."""

import json
import os
from pathlib import Path

import numpy as np
import pytest
import torch

from hypa.ann.base import SequenceBlock
from hypa.conf import CONF

from cli_helpers import hypa_run
from test_train import run_train

pytest.importorskip("onnxruntime")

TINY = ["trainer.max_epochs=1", "trainer.limit_train_batches=2", "trainer.limit_val_batches=2",
        "trainer.enable_progress_bar=false", "figures.enabled=false", "data.batch_size=8"]


def _train(tmp_path_factory, name: str, overrides: list[str]) -> Path:
    folder = tmp_path_factory.mktemp(name)
    run_train(folder, overrides)
    return folder


@pytest.fixture(scope="module")
def physical(tmp_path_factory, hypa_cache) -> Path:
    return _train(tmp_path_factory, "physical", ["model=physical", *TINY, "identification.max_seconds=5"])


def _export(folder: Path, out: Path, **kwargs):
    from hypa.evaluation.api import run_datamodule
    from hypa.evaluation.runs import load_run
    from hypa.export import export_run

    run = load_run(folder)
    return export_run(run, run_datamodule(run), out, **kwargs)


def _check_files(export, tolerance: float = 1e-5) -> dict:
    """The check passed, every output within ``tolerance`` of its σ, and the files say the same."""
    assert export.check.passed
    for name, check in export.check.outputs.items():
        assert check.relative <= tolerance, (name, check)
    description = json.loads(export.files["export.json"].read_text())
    assert description["check"]["passed"] and len(description["state"]) == len(description["initial_state"])
    header = export.files["reference.csv"].read_text().splitlines()[0].split(",")
    assert header == ["time", *(s["name"] for s in description["inputs"]), *(s["name"] for s in description["outputs"])]
    return description


def _replay(folder: Path) -> np.ndarray:
    """The export run with nothing but onnxruntime, numpy and the files, as docs/export.md shows: the largest
    |ONNX - hypa| over the predicted samples, per output, relative to the σ in export.json."""
    import onnxruntime

    description = json.loads((folder / "export.json").read_text())
    table = np.genfromtxt(folder / "reference.csv", delimiter=",", names=True)
    u = np.stack([table[s["name"]] for s in description["inputs"]], -1).astype(np.float32)
    expected = np.stack([table[s["name"]] for s in description["outputs"]], -1)
    session = onnxruntime.InferenceSession(str(folder / "model.onnx"))
    state, first, ys = np.array(description["initial_state"], np.float32), description["reference"]["first_sample"], []
    for row in u[first:]:
        state, y = session.run(None, {"state": state, "u": row})
        ys.append(y)
    std = np.array([description["check"]["outputs"][s["name"]]["std"] for s in description["outputs"]])
    return np.abs(np.array(ys) - expected[first:]).max(0) / std


def test_physical_model_exported_by_the_command_line(physical, hypa_cache, tmp_path) -> None:
    env = {**os.environ, "HYPA_CACHE_DIR": str(hypa_cache)}
    out = tmp_path / "export"
    result = hypa_run(["export", f"run={physical}", f"hydra.run.dir={out}"], env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "per ONNX step" in result.stdout and f"export: {out}" in result.stdout
    description = json.loads((out / "export.json").read_text())
    assert description["check"]["passed"] and description["dt"] > 0
    assert [s["name"] for s in description["state"]] == ["yaw_rate", "side_slip"]  # the single track's states
    assert [s["unit"] for s in description["outputs"]] == ["rad/s", "rad"]
    assert (_replay(out) <= 1e-5).all()


def test_v2_with_lstm_networks_is_exact(tmp_path_factory, hypa_cache, tmp_path) -> None:
    import torch

    from hypa.evaluation.api import run_datamodule
    from hypa.evaluation.runs import load_run
    from hypa.export import export_run

    folder = _train(tmp_path_factory, "v2", ["model=v2", "ann=lstm", "ann.hidden_size=8", *TINY,
                                             "identification.max_seconds=5"])
    run = load_run(folder)
    generator = torch.Generator().manual_seed(0)
    with torch.no_grad():  # heads far from their zero start, so the networks' states show in the outputs
        for name in ("rear_steering", "correction"):
            head = run.module.model.blocks[name].head
            head.weight.copy_(0.3 * torch.randn(head.weight.shape, generator=generator))
    export = export_run(run, run_datamodule(run), tmp_path)
    description = _check_files(export)
    kinds = {s["block"]: s["kind"] for s in description["state"]}
    assert kinds == {"rear_steering": "network", "single_track": "physics", "correction": "network"}
    assert export.state_size == 2 + 2 * 2 * 8  # the single track's 2 states, two LSTMs' h and c


@pytest.mark.parametrize("name, hparams", [("lstm", {"hidden_size": 8}),
                                           ("s4", {"d_model": 8, "d_state": 4, "n_layers": 2}),
                                           ("mamba", {"d_model": 8, "d_state": 4, "n_layers": 2}),
                                           ("transformer", {"d_model": 8, "n_heads": 2, "n_layers": 2,
                                                            "dim_feedforward": 8, "context": 12})])
def test_network_steps_chain_to_the_networks_forward(name: str, hparams: dict) -> None:
    """Each network's step form, from its state after a first chunk, continues the sequence exactly."""
    import torch

    from hypa.ann import build_ann
    from hypa.export.blocks import NetworkStep

    torch.manual_seed(0)
    network = build_ann(name, 3, 2, **hparams).eval()
    x = torch.randn(1, 40, 3)
    with torch.no_grad():
        whole, _ = network(x)
        state = network(x[:, :5])[1]  # a Transformer's cache fills up over the steps
        form = NetworkStep("net", network, network.default_state(1, None, torch.float32))
        flat, ys = form.initial(state), []
        for k in range(5, 40):
            y, flat = form(x[:, k], None, flat)
            ys.append(y)
    assert (torch.cat(ys) - whole[0, 5:]).abs().max() < 1e-5 * whole.abs().max()


@pytest.mark.parametrize("ann, hparams", [("s4", ["ann.d_model=8", "ann.d_state=4", "ann.n_layers=1"]),
                                          ("mamba", ["ann.d_model=8", "ann.d_state=4", "ann.n_layers=1"]),
                                          ("transformer", ["ann.d_model=8", "ann.n_heads=2", "ann.n_layers=1",
                                                           "ann.dim_feedforward=16", "ann.context=21"])])
def test_v1_with_every_other_network_is_exact(ann: str, hparams: list[str], tmp_path_factory, hypa_cache,
                                              tmp_path) -> None:
    """S4 (its real step), Mamba (through the dynamo exporter, its weights inside model.onnx), the Transformer
    (its context as state): every format, the pythonfmu FMU and the C one among them."""
    from hypa.evaluation.api import run_datamodule
    from hypa.evaluation.runs import load_run
    from hypa.export import export_run

    folder = _train(tmp_path_factory, f"v1-{ann}", ["model=v1", f"ann={ann}", *hparams, *TINY,
                                                     "identification.max_seconds=5"])
    run = load_run(folder)
    with torch.no_grad():  # a head far from its zero start, so the network's state shows in the outputs
        head = run.module.model.blocks["rear_steering"].head
        head.weight.copy_(0.3 * torch.randn(head.weight.shape, generator=torch.Generator().manual_seed(0)))
    export = export_run(run, run_datamodule(run), tmp_path, format="all")
    description = _check_files(export)
    assert "network" in {s["kind"] for s in description["state"]}
    assert {"fmu", "c"} <= set(export.checks) and all(c.passed for c in export.checks.values())
    assert not list(tmp_path.glob("*.data"))  # one file: the FMU carries model.onnx alone


CHAIN = """# @package model
name: chain
blocks:
  limit: {kind: saturation, inputs: [steering_wheel_angle], outputs: [limited], parameters: {limit: 1.0}}
  lag:
    kind: physics
    system: lead_lag
    inputs: [limited]
    outputs: [lagged]
    initial_state: steady
    scale_as: [steering_wheel_angle]
    parameters: {gain: 1.0, transient: 0.5, transient_tau_s: 0.2, tau_s: 0.05}
  delay: {kind: delay, inputs: [lagged], outputs: [delayed], parameters: {delay_s: 0.033}}
  front_steering: {kind: physics, system: front_steering, inputs: [delayed], outputs: [front_wheel_angle]}
  rear_steering:
    {kind: physics, system: rear_steering, inputs: [steering_wheel_angle], outputs: [rear_wheel_angle],
     scale_as: [steering_wheel_angle]}
  single_track:
    {kind: physics, system: single_track, inputs: [front_wheel_angle, rear_wheel_angle],
     outputs: [yaw_rate, side_slip], trainable: [cf, cr]}
outputs: [yaw_rate, side_slip]
stages: []
"""


def test_first_order_hold_with_a_steady_lead_lag_a_dead_time_and_a_limit(tmp_path_factory, hypa_cache,
                                                                         tmp_path) -> None:
    """Under a first-order hold the state carries the previous sample; a lead-lag started in equilibrium,
    a fractional dead time and a limit in the chain."""
    configs = tmp_path_factory.mktemp("configs")
    (configs / "model").mkdir()
    (configs / "model" / "chain.yaml").write_text(CHAIN)
    folder = _train(tmp_path_factory, "chain", [f"hydra.searchpath=[file://{configs}]", "model=chain",
                                                "physics.hold=foh", *TINY, "identification.max_seconds=5"])
    description = _check_files(_export(folder, tmp_path))
    kinds = {}
    for s in description["state"]:
        kinds.setdefault(s["block"], []).append(s["kind"])
    assert kinds["lag"] == ["physics", "physics", "held_input"]
    assert kinds["single_track"] == ["physics", "physics", "held_input", "held_input"]
    assert set(kinds["delay"]) == {"delay"} and "limit" not in kinds
    assert all(s["name"].endswith("[k-1]") for s in description["state"] if s["kind"] != "delay")


@pytest.mark.shared_data("racecar")
def test_scheduled_race_car_with_dead_time(tmp_path_factory, hypa_cache, tmp_path) -> None:
    """Velocity-scheduled single track after a steering dead time; nominal physics (a run without identification)."""
    folder = _train(tmp_path_factory, "racecar", ["dataset=racecar", "model=racecar_physical", *TINY,
                                                  "identification.enabled=false"])
    export = _export(folder, tmp_path, format="c")
    description = _check_files(export)
    assert export.checks["c"].passed  # the scheduled exponential with its squarings, in C
    assert [s["role"] for s in description["inputs"]] == ["input", "scheduling"]
    assert {s["kind"] for s in description["state"]} == {"delay", "physics"}
    assert description["scheduled_squarings"]["single_track"]["squarings"] >= 1


@pytest.mark.shared_data("emps")
def test_nonlinear_coulomb_friction(tmp_path_factory, hypa_cache, tmp_path) -> None:
    """The EMPS axis with Coulomb friction (a Lur'e feedback): Heun's step needs the next input, so the state
    carries the previous sample. In C (float64) against hypa's float64 free run; hypa's float32 run differs
    from both by its own rounding, integrated by the axis."""
    folder = _train(tmp_path_factory, "emps", ["dataset=emps", "model=emps_physical", *TINY,
                                               "identification.enabled=false"])
    export = _export(folder, tmp_path, format="c")
    description = _check_files(export)
    assert [s["kind"] for s in description["state"]] == ["physics", "physics", "held_input"]
    assert export.checks["c"].passed and export.checks["c"].outputs["position"].relative < 1e-9
    assert 0 < description["c"]["float32_free_run"]["position"] < 1e-3


def test_tampered_model_or_wrong_state_is_caught(physical, hypa_cache, tmp_path) -> None:
    import onnx
    from onnx import numpy_helper

    from hypa.evaluation.api import run_datamodule
    from hypa.evaluation.runs import load_run
    from hypa.export import ExportError, check_onnx
    from hypa.export.api import build_step

    export = _export(physical, tmp_path / "good")
    run = load_run(physical)
    _, reference = build_step(run, run_datamodule(run))
    assert check_onnx(export.files["model.onnx"], reference).passed
    model = onnx.load(str(export.files["model.onnx"]))
    tensors = [*model.graph.initializer, *(a.t for node in model.graph.node if node.op_type == "Constant"
                                           for a in node.attribute if a.name == "value")]
    weights = max((t for t in tensors if t.data_type == onnx.TensorProto.FLOAT), key=lambda t: np.prod(t.dims))
    values = numpy_helper.to_array(weights).copy()  # the physics' matrices: the largest constant
    weights.CopyFrom(numpy_helper.from_array(values * np.float32(1.001), weights.name))  # 0.1 % off
    tampered = tmp_path / "tampered.onnx"
    onnx.save(model, str(tampered))
    assert not check_onnx(tampered, reference).passed
    wrong = reference.initial_state + 0.01 * np.abs(reference.initial_state).max()
    assert not check_onnx(export.files["model.onnx"], reference, state=wrong).passed
    with pytest.raises(ExportError, match="does not reproduce hypa's free run") as error:
        _export(physical, tmp_path / "strict", tolerance=1e-12)
    assert "\n" not in str(error.value)


class ComplexStateBlock(SequenceBlock):
    """A network whose state is complex and which has no step form (``step``, ``step_state``)."""

    def __init__(self, d_in: int, d_out: int, *, zero_init: bool = False) -> None:
        super().__init__(d_in, d_out, zero_init=zero_init)
        self.head = self._make_head(d_in)

    def forward(self, x, state=None):
        state = self.default_state(x.shape[0], x.device, x.dtype) if state is None else state
        return self.head(x), state + x[:, -1].sum()

    def default_state(self, batch, device, dtype):
        return torch.zeros(batch, 2, dtype=torch.complex64, device=device)


def test_refusals_are_one_line(hypa_cache, tmp_path) -> None:
    """A network without a real step form and an unknown format: one line each, saying why."""
    from omegaconf import OmegaConf

    from hypa.export import ExportError, ModelStep, formats_to_build
    from hypa.models.composed import ComposedModel
    from hypa.models.spec import parse_model_spec

    spec = parse_model_spec(OmegaConf.to_container(OmegaConf.load(CONF / "model" / "v1.yaml")))
    scale = dict.fromkeys(("steering_wheel_angle", "yaw_rate", "side_slip"), (0.0, 1.0))
    build = lambda ann, hparams: ComposedModel(  # noqa: E731
        spec, None, ["steering_wheel_angle"], ["yaw_rate", "side_slip"], scale, scale, 0.01, horizon=10,
        ann_name=ann, ann_hparams=hparams).to(torch.float32)
    transformer = ModelStep(build("transformer", {"d_model": 8, "n_heads": 2, "n_layers": 1, "dim_feedforward": 8,
                                                  "context": 5}))
    assert transformer.state_size == 2 * 4 * 8 + 1 + 2  # keys and values of 4 steps, their count, the single track
    with pytest.raises(ExportError, match=r"rear_steering.*not a structure of real tensors") as error:
        ModelStep(build("test_export.ComplexStateBlock", {}))
    assert "\n" not in str(error.value)
    assert formats_to_build("all") == ("onnx", "fmu", "c", "statespace")
    with pytest.raises(ExportError, match="format=mat is not one of onnx, fmu, c, statespace, all"):
        formats_to_build("mat")
    env = {**os.environ, "HYPA_CACHE_DIR": str(hypa_cache)}
    result = hypa_run(["export", "run=nowhere", "format=mat", f"hydra.run.dir={tmp_path}"], env=env)
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert "is not one of" in result.stderr.strip().splitlines()[-1]

