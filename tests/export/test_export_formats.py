"""The other export formats: a physics-only model's state space (MATLAB, python-control) and the FMU (fmpy)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import ROOT
from test_export import TINY, _train, physical  # noqa: F401 -- physical: the module's fixture

pytest.importorskip("onnxruntime")
control = pytest.importorskip("control")
fmpy = pytest.importorskip("fmpy")
pytest.importorskip("pythonfmu")


@pytest.fixture(scope="module")
def v2(tmp_path_factory, hypa_cache) -> Path:
    return _train(tmp_path_factory, "v2", ["model=v2", "ann=lstm", "ann.hidden_size=8", *TINY,
                                           "identification.max_seconds=5"])


def _export(folder: Path, out: Path, heads: tuple[str, ...] = (), **kwargs):
    """``export_run`` of a trained run, its networks' ``heads`` set far from their zero start (so that the
    networks show in the outputs); the export and the model."""
    from hypa.evaluation.api import run_datamodule
    from hypa.evaluation.runs import load_run
    from hypa.export import export_run

    run = load_run(folder)
    generator = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for name in heads:
            head = run.module.model.blocks[name].head
            head.weight.copy_(0.3 * torch.randn(head.weight.shape, generator=generator))
    return export_run(run, run_datamodule(run), out, **kwargs), run.module.model


def _reference(folder: Path) -> tuple[dict, np.ndarray, np.ndarray, np.ndarray]:
    """export.json, and from the first exported sample on: the inputs (S, m + q), hypa's outputs (S, p)
    and their σ (p,)."""
    description = json.loads((folder / "export.json").read_text())
    table = np.genfromtxt(folder / "reference.csv", delimiter=",", names=True)
    first = description["reference"]["first_sample"]
    u = np.stack([table[s["name"]] for s in description["inputs"]], -1)[first:]
    y = np.stack([table[s["name"]] for s in description["outputs"]], -1)[first:]
    std = np.array([description["check"]["outputs"][s["name"]]["std"] for s in description["outputs"]])
    return description, u, y, std


def test_statespace_of_a_physical_run(physical, tmp_path) -> None:  # noqa: F811
    """The composed matrices are the blocks' own, the .mat file and load_statespace hold them, and the
    discrete system from x0 reproduces hypa's free run."""
    from scipy.io import loadmat
    from scipy.signal import cont2discrete

    from hypa.export import load_statespace

    export, model = _export(physical, tmp_path, format="statespace")
    assert set(export.files) == {"model.onnx", "reference.csv", "export.json", "statespace.mat", "statespace.json"}
    assert export.checks["statespace"].passed and "fmu" not in export.checks
    with torch.no_grad():
        track = model.blocks["single_track"].state_space(torch.float64)
        gains = torch.cat([model.blocks[b].state_space(torch.float64).d for b in ("front_steering", "rear_steering")])
    a, b = track.a.numpy(), (track.b @ gains).numpy()  # the steering ratios in series with the single track
    dt = json.loads(export.files["export.json"].read_text())["dt"]
    ad, bd = cont2discrete((a, b, np.eye(2), np.zeros((2, 1))), dt, "zoh")[:2]

    mat = loadmat(export.files["statespace.mat"])
    np.testing.assert_allclose(mat["A"], a, rtol=1e-12)
    np.testing.assert_allclose(mat["B"], b, rtol=1e-12)
    np.testing.assert_array_equal(mat["C"], np.eye(2))
    np.testing.assert_array_equal(mat["D"], np.zeros((2, 1)))
    np.testing.assert_allclose(mat["Ad"], ad, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(mat["Bd"], bd, rtol=1e-9, atol=1e-12)
    assert mat["Ts"].item() == dt and "e" not in mat  # no drift: no affine terms
    assert [str(n[0]) for n in mat["StateName"][:, 0]] == ["yaw_rate", "side_slip"]
    assert [str(n[0]) for n in mat["OutputUnit"][:, 0]] == ["rad/s", "rad"]
    names = [str(n[0]) for n in mat["ParameterName"][:, 0]]
    assert mat["ParameterValue"][names.index("cf"), 0] == pytest.approx(
        model.parameters_.as_floats()["cf"], rel=1e-12)

    continuous = load_statespace(export.folder)
    discrete = load_statespace(export.files["statespace.json"], discrete=True)
    np.testing.assert_array_equal(continuous.A, mat["A"])
    assert discrete.dt == dt and continuous.input_labels == ["steering_wheel_angle"]
    assert continuous.output_labels == ["yaw_rate", "side_slip"]
    description, u, y, std = _reference(export.folder)
    x0 = json.loads(export.files["statespace.json"].read_text())["x0"]
    simulated = control.forced_response(discrete, U=u.T, X0=x0).outputs.T  # python-control's own simulation
    assert (np.abs(simulated - y).max(0) / std <= 1e-5).all()
    assert description["checks"]["statespace"]["passed"]
    assert (np.abs(simulated - y).max(0) / std > 0).all()  # the figures are real: not the reference itself


def test_statespace_under_a_first_order_hold(tmp_path_factory, hypa_cache, tmp_path) -> None:
    """Under a first-order hold the discrete system is MATLAB's and scipy's standard form (x̃ = x - Γ_1 u,
    a feedthrough Dd), and its x0 comes from the step's x[k-1], u[k-1]."""
    from scipy.io import loadmat
    from scipy.signal import cont2discrete

    folder = _train(tmp_path_factory, "foh", ["model=physical", "physics.hold=foh", *TINY,
                                              "identification.max_seconds=5"])
    export, _ = _export(folder, tmp_path, format="statespace")
    assert export.checks["statespace"].passed
    mat = loadmat(export.files["statespace.mat"])
    expected = cont2discrete((mat["A"], mat["B"], mat["C"], mat["D"]), mat["Ts"].item(), "foh")[:4]
    for name, value in zip(("Ad", "Bd", "Cd", "Dd"), expected):
        np.testing.assert_allclose(mat[name], value, rtol=1e-8, atol=1e-12, err_msg=name)
    assert np.abs(mat["Dd"]).max() > 0 and str(mat["hold"][0]) == "foh"


def test_statespace_refused_for_a_hybrid_run(v2, tmp_path) -> None:
    from hypa.export import ExportError

    with pytest.raises(ExportError, match=r"format=statespace: block 'rear_steering' is a network") as error:
        _export(v2, tmp_path, format="statespace")
    assert "\n" not in str(error.value) and not list(tmp_path.iterdir())  # nothing written


def _check_fmu(path: Path, description: dict, u: np.ndarray, y: np.ndarray, std: np.ndarray,
               feedthrough: bool = False) -> np.ndarray:
    """The FMU in fmpy over the reference inputs: the largest |FMU - hypa| / σ per output. fmpy's
    ``simulate_fmu`` reads the outputs after a ``doStep`` before it sets the next inputs, so a model
    with ``feedthrough`` is stepped by hand: set the inputs of sample k, read the outputs, ``doStep``."""
    model = fmpy.read_model_description(str(path))
    variables = {v.name: v for v in model.modelVariables}
    for signal in (*description["inputs"], *description["outputs"]):
        assert variables[signal["name"]].unit == (signal["unit"] or None)
    starts = [float(variables[f"initial_state[{i + 1}]"].start) for i in range(len(description["state"]))]
    np.testing.assert_allclose(starts, description["initial_state"], rtol=1e-6, atol=1e-12)
    assert float(model.defaultExperiment.stepSize) == description["dt"]
    dt, t0 = description["dt"], description["reference"]["first_time"]
    names = [s["name"] for s in description["inputs"]]
    signals = np.zeros(len(u), dtype=[("time", float), *((n, float) for n in names)])
    signals["time"] = t0 + dt * np.arange(len(u))
    for i, n in enumerate(names):
        signals[n] = u[:, i]
    outputs = [s["name"] for s in description["outputs"]]
    if not feedthrough:
        result = fmpy.simulate_fmu(str(path), start_time=t0, stop_time=t0 + dt * (len(u) - 1), step_size=dt,
                                   output_interval=dt, input=signals, output=outputs)
        simulated = np.stack([result[n] for n in outputs], -1)
    else:
        fmu = fmpy.instantiate_fmu(fmpy.extract(str(path), path.parent / "unzipped"), model)
        fmu.setupExperiment(startTime=t0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        rows = []
        for k, u_k in enumerate(u):
            fmu.setReal([variables[n].valueReference for n in names], list(u_k))
            rows.append(fmu.getReal([variables[n].valueReference for n in outputs]))
            fmu.doStep(currentCommunicationPoint=t0 + k * dt, communicationStepSize=dt)
        fmu.terminate()
        fmu.freeInstance()
        simulated = np.array(rows)
    assert simulated.shape == y.shape
    return np.abs(simulated - y).max(0) / std


def test_fmu_of_a_physical_run(physical, tmp_path) -> None:  # noqa: F811
    export, _ = _export(physical, tmp_path, format="fmu")
    assert export.checks["fmu"].passed and "statespace" not in export.checks
    description, u, y, std = _reference(export.folder)
    assert (_check_fmu(export.files["model.fmu"], description, u, y, std) <= 1e-5).all()
    variables = {v.name: v for v in fmpy.read_model_description(str(export.files["model.fmu"])).modelVariables}
    assert variables["parameter.cf"].unit == "N/rad" and variables["parameter.cf"].causality == "calculatedParameter"
    assert fmpy.validation.validate_fmu(str(export.files["model.fmu"])) == []


def test_every_format_of_a_hybrid_run(v2, tmp_path) -> None:
    """format=all of V2 (LSTM networks): ONNX and the FMU, the state space skipped with its reason; the FMU's
    step (a network's feedthrough) checked by hypa's own loop and by fmpy's."""
    export, _ = _export(v2, tmp_path, heads=("rear_steering", "correction"), format="all")
    assert set(export.checks) == {"onnx", "fmu"} and all(c.passed for c in export.checks.values())
    assert "network" in export.skipped["statespace"] and "statespace.mat" not in export.files
    description, u, y, std = _reference(export.folder)
    assert description["skipped"] == export.skipped and "model.fmu" in description["files"]
    assert description["checks"]["fmu"]["passed"]
    errors = _check_fmu(export.files["model.fmu"], description, u, y, std, feedthrough=True)
    assert (errors <= 1e-5).all() and (errors > 0).all()


@pytest.mark.slow
def test_every_format_of_a_physical_run_from_the_command_line(physical, hypa_cache, tmp_path) -> None:  # noqa: F811
    env = {**os.environ, "HYPA_CACHE_DIR": str(hypa_cache)}
    out = tmp_path / "export"
    result = subprocess.run([sys.executable, "-m", "hypa", "export", f"run={physical}", "format=all",
                             f"hydra.run.dir={out}"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300,
                            check=False)
    assert result.returncode == 0, result.stderr[-3000:]
    for engine in ("ONNX", "FMU (fmpy)", "state space (numpy)"):
        assert f"per {engine} step" in result.stdout
    assert "skipped" not in result.stdout
    assert {p.name for p in out.iterdir()} >= {"model.onnx", "model.fmu", "statespace.mat", "statespace.json",
                                               "reference.csv", "export.json"}
