"""Grey-box identification by the output error (hypa.identification): a user's system (the DC-motor
example) started 30 % off its true parameters, on data simulated from the truth."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from cli_helpers import hypa_run
from conftest import compose_config
from data_helpers import DC_MOTOR_HYBRID, USER_EXAMPLE, make_dc_motor_data

TRUE = {"torque_constant": 0.065, "friction": 3e-5, "load_torque": 0.004}  # examples/user_system/make_data.py
OFF = {"torque_constant": 0.065 * 0.7, "friction": 3e-5 * 1.3, "load_torque": 0.004 * 0.7}


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("dc_motor")
    make_dc_motor_data(folder, 20)
    return folder


def problem(data: Path, trainable: list[str], parameters: dict[str, float], samples: int = 10**9):
    """The example's model (its nominal values replaced) and its training records as whole free runs
    (or cut into stretches of ``samples``)."""
    from hypa.identification import Stretches

    model, dm = model_and_data(data, trainable, parameters)
    return model, Stretches.cut(dm, dm.records("train"), samples)


def model_and_data(data: Path, trainable: list[str], parameters: dict[str, float]):
    """The example's model (its nominal values replaced) and its data module, set up."""
    from hypa.data import datamodule_from_config
    from hypa.models.spec import parse_model_spec
    from hypa.training import HybridModule

    sys.path.insert(0, str(USER_EXAMPLE))
    cfg = compose_config("train", [f"hydra.searchpath=[file://{USER_EXAMPLE / 'conf'}]", "dataset=dc_motor",
                                   "model=dc_motor", f"data.dir={data}"])
    dm = datamodule_from_config(cfg.data, data)
    dm.setup()
    config = OmegaConf.to_container(cfg.model, resolve=True)
    config["parameters"] = parameters
    config["blocks"]["motor"]["trainable"] = trainable
    parse_model_spec(config)
    return HybridModule.from_data(dm, config, hold="zoh").model, dm


def test_parameters_started_30_percent_off_are_recovered_deterministically(data: Path) -> None:
    from hypa.identification import identify

    results = []
    for _ in range(2):
        model, stretches = problem(data, list(TRUE), OFF)
        results.append(identify(model, stretches))
    found = results[0].values()
    for name, value in TRUE.items():
        assert found[name] == pytest.approx(value, rel=0.02), (name, found)
    assert results[1].values() == found  # the same data, the same parameters, to the last bit
    assert results[0].converged and results[0].error_final < 1e-3 * results[0].error_initial
    assert results[0].warnings == ()
    for estimate in results[0].estimates:  # ± 1σ finite, and the truth within a few of them
        assert estimate.std is not None and abs(estimate.value - TRUE[estimate.name]) < 0.02 * TRUE[estimate.name]
    assert model.parameters_.as_floats()["torque_constant"] == pytest.approx(found["torque_constant"])


@pytest.mark.slow  # about 20 s on 2 cores; the Jacobian and the divergence tests below cover multiple shooting fast
def test_multiple_shooting_recovers_the_parameters_and_joins_the_stretches(data: Path) -> None:
    """Records cut into stretches with their own estimated initial states: the same truth within
    2 %, the same optimum as single shooting, continuity reached, deterministic."""
    from hypa.identification import identify

    single = identify(*problem(data, list(TRUE), OFF))
    runs = [identify(*problem(data, list(TRUE), OFF, samples=150)) for _ in range(2)]
    result = runs[0]
    assert result.shooting == "multiple" and result.stretches > 2 * single.stretches
    assert result.converged and result.continuity_defect < 1e-3, result.summary()
    assert runs[1].values() == result.values()
    for name, value in TRUE.items():
        assert result.values()[name] == pytest.approx(value, rel=0.02), (name, result.values())
        assert result.values()[name] == pytest.approx(single.values()[name], rel=0.01)
    assert "multiple shooting" in result.summary() and result.to_dict()["shooting"] == "multiple"
    assert all(e.std is not None for e in result.estimates)


@pytest.mark.parametrize("form", ["dense", "sparse"])
def test_the_multiple_shooting_jacobian_is_the_plain_finite_difference(data: Path, form: str, monkeypatch) -> None:
    """The structured Jacobian (every stretch's state probed at once) equals probing one variable at a time."""
    import numpy as np
    from scipy import sparse

    from hypa.identification import shooting as module
    from hypa.identification.output_error import coordinates
    from hypa.identification.shooting import PROBE, Shooting

    if form == "sparse":
        monkeypatch.setattr(module, "_DENSE_BYTES", 0)

    model, stretches = problem(data, list(TRUE), OFF, samples=400)
    names = list(TRUE)
    coords = coordinates(model, names)

    def set_z(z):
        model.parameters_.set_values({n: c.physical(float(v)) for n, c, v in zip(names, coords, z)})

    shooting = Shooting(model, stretches, set_z, len(names))
    assert shooting.n and shooting.junctions
    shooting.mu = 100.0
    v = shooting.start(np.array([c.z(OFF[n]) for c, n in zip(coords, names)]))
    v[shooting.p :] += 0.01 * np.sin(np.arange(v.size - shooting.p))  # defects that are not zero
    base = shooting.residual(v)
    structured = shooting.jacobian(v, base, np.full(v.size, np.inf))
    assert sparse.issparse(structured) == (form == "sparse")
    structured = structured.toarray() if form == "sparse" else structured
    plain = np.empty_like(structured)
    for j in range(v.size):
        step = PROBE * max(1.0, abs(v[j])) if j < shooting.p else PROBE
        probe = v.copy()
        probe[j] += step
        plain[:, j] = (shooting.residual(probe) - base) / step
    assert np.allclose(structured, plain, rtol=1e-6, atol=1e-9 * np.abs(plain).max())


def test_the_correlation_time_of_the_errors() -> None:
    """White errors count one by one; AR(1) errors with φ = 0.9 carry one independent error per
    (1 + φ) / (1 - φ) = 19 samples, the factor by which the estimates' variance grows."""
    import numpy as np

    from hypa.identification.shooting import correlation_time

    rng = np.random.default_rng(0)
    assert correlation_time([rng.standard_normal((4, 20000, 2))]) == pytest.approx(1.0, abs=0.1)
    white = rng.standard_normal((8, 20000, 1))
    ar = np.zeros_like(white)
    for k in range(1, white.shape[1]):
        ar[:, k] = 0.9 * ar[:, k - 1] + white[:, k]
    assert correlation_time([ar[:4], ar[4:, :15000]]) == pytest.approx(19.0, rel=0.1)


def test_one_sigma_matches_the_spread_over_noise_realizations(data: Path) -> None:
    """Coloured measurement noise (AR(1), φ = 0.95, as smooth as a free run's errors) on the output,
    eight realizations: the reported ± 1σ is the spread of the estimates within a factor of two,
    where the textbook σ² (JᵀJ)⁻¹ of independent errors would be several times too small."""
    import numpy as np
    import torch

    from hypa.identification import Stretches, identify

    model, clean = problem(data, list(TRUE), OFF)
    estimates, sigmas, taus = [], [], []
    for seed in range(8):
        rng = np.random.default_rng(seed)
        batches = []
        for b in clean.batches:
            white = rng.standard_normal(tuple(b["y"].shape))
            noise = np.zeros_like(white)
            for k in range(1, white.shape[1]):
                noise[:, k] = 0.95 * noise[:, k - 1] + white[:, k]
            noise *= 0.02 / noise.std()
            batches.append({**b, "y": b["y"] + torch.as_tensor(noise, dtype=b["y"].dtype)})
        model.parameters_.set_values(OFF)
        result = identify(model, Stretches(tuple(batches), clean.first, clean.positions))
        estimates.append(result.values()["torque_constant"])
        sigmas.append(next(e.std for e in result.estimates if e.name == "torque_constant"))
        taus.append(result.correlation_times["torque_constant"])
    spread, sigma = float(np.std(estimates, ddof=1)), float(np.mean(sigmas))
    assert 0.5 < sigma / spread < 2.0, (sigma, spread, estimates)
    assert np.mean(taus) > 9  # without τ, σ would be more than 3 times too small


def test_a_fit_stopped_at_its_time_limit_reports_its_best_point(data: Path) -> None:
    """``max_seconds``: the fit stops, keeps the best point it saw, and says it did not converge."""
    from hypa.identification import IdentificationSettings, identify

    model, stretches = problem(data, list(TRUE), OFF)
    result = identify(model, stretches, settings=IdentificationSettings(max_seconds=1e-3))
    assert not result.converged and "time limit" in result.message and result.capped == "max_seconds"
    assert result.warnings[0].startswith("stopped at the cap of 0.001 s (identification.max_seconds")
    assert "(not converged)" in result.warnings[0] and "stopped at the cap" in result.summary()
    assert result.to_dict()["capped"] == "max_seconds"


def test_the_first_iteration_says_what_the_work_cap_may_cost_and_the_cap_is_named(data: Path) -> None:
    """After its first iteration the fit says how many model runs it may still make and how long they
    take at its pace; stopped by max_evaluations, its warning and summary name the cap, not converged."""
    from hypa.identification import IdentificationSettings, identify

    model, stretches = problem(data, list(TRUE), OFF)
    lines: list[str] = []
    result = identify(model, stretches, settings=IdentificationSettings(max_evaluations=2), progress=lines.append)
    estimate = [line for line in lines if "at most" in line]
    assert len(estimate) == 1 and lines.index(estimate[0]) == 1  # once, right after the first iteration
    assert estimate[0].startswith("identification: at most 2 model runs (identification.max_evaluations), about ")
    assert "at this pace" in estimate[0] and "e+" not in estimate[0]
    assert not result.converged and result.capped == "max_evaluations"
    assert result.warnings[0] == ("stopped at the cap of 2 model runs (identification.max_evaluations; "
                                  "not converged)")
    assert "stopped at the cap of identification.max_evaluations (not converged)" in result.summary()
    assert result.error_final <= result.error_initial and all(e.std is not None for e in result.estimates)


def test_the_fit_settles_at_the_datas_resolution() -> None:
    """``settled``: converged once SETTLE iterations gained less than the share of σ² τ, the cost of
    moving the estimates by their σ; coloured errors (τ > 1) resolve less, so the same gain settles."""
    import numpy as np

    from hypa.identification.output_error import SETTLE, settled
    from hypa.identification.shooting import correlation_time

    class Problem:  # the two things settled reads from the fit's problem
        p = 3

        def output_correlation_time(self, rows):
            return correlation_time([rows.reshape(1, -1, 1)])

    rng = np.random.default_rng(0)
    white = 1e-3 * rng.standard_normal(20000)
    coloured = np.convolve(white, np.ones(50) / np.sqrt(50), mode="same")
    sigma2 = float(white @ white) / (white.size - 3)
    gain = 0.5 * 0.01 * sigma2  # half the share of a white residual's resolution, over SETTLE iterations
    costs = [1.0 + gain * (SETTLE - k) / SETTLE for k in range(SETTLE + 1)]
    assert settled(costs[:-1], white, Problem(), 0.01) is None  # too few iterations to weigh
    why = settled(costs, white, Problem(), 0.01)
    assert why is not None and why.startswith(f"converged at the data's resolution: the last {SETTLE} iterations")
    assert settled(costs, white, Problem(), 0.004) is None  # a finer share keeps going
    assert settled(costs, white, Problem(), None) is None  # null: scipy's tolerances alone
    assert settled([1.0 + 4 * gain * (SETTLE - k) / SETTLE for k in range(SETTLE + 1)], white, Problem(), 0.01) is None
    coloured *= np.sqrt(float(white @ white) / float(coloured @ coloured))  # the same σ², τ about 50
    assert correlation_time([coloured.reshape(1, -1, 1)]) > 20
    big = [1.0 + 8 * gain * (SETTLE - k) / SETTLE for k in range(SETTLE + 1)]  # 4x a white residual's share
    assert settled(big, white, Problem(), 0.01) is None
    assert settled(big, coloured, Problem(), 0.01) is not None


def test_a_fit_settled_by_the_resolution_says_so_and_keeps_its_iterate(data: Path) -> None:
    """Through identify: a share so coarse that any five iterations settle it stops the fit there,
    converged, its message naming the rule, its parameters the iterate's; null leaves scipy's rule."""
    from hypa.identification import IdentificationSettings, identify
    from hypa.identification.output_error import SETTLE

    model, stretches = problem(data, list(TRUE), OFF)
    coarse = identify(model, stretches, settings=IdentificationSettings(resolution=1e9))
    assert coarse.converged and coarse.capped is None and coarse.warnings == ()
    assert coarse.message.startswith(f"converged at the data's resolution: the last {SETTLE} iterations")
    assert "identification.resolution" in coarse.message and coarse.iterations == SETTLE + 1
    assert model.parameters_.as_floats()["torque_constant"] == pytest.approx(coarse.values()["torque_constant"])
    assert coarse.error_final < 0.1 * coarse.error_initial
    model, stretches = problem(data, list(TRUE), OFF)
    plain = identify(model, stretches, settings=IdentificationSettings(resolution=None))
    assert "resolution" not in plain.message and plain.iterations > coarse.iterations


def test_a_parameter_the_data_cannot_determine_is_flagged(data: Path) -> None:
    """With the resistance free too, the speed alone cannot tell it from the others."""
    from hypa.identification import identify

    model, stretches = problem(data, [*TRUE, "resistance"], OFF)
    result = identify(model, stretches)
    flagged = [w for w in result.warnings
               if "resistance" in w and ("cannot be told apart" in w or "not determined" in w)]
    assert flagged, result.warnings
    assert "Warnings:" in result.markdown()


def test_a_free_run_that_diverges_is_fitted_by_multiple_shooting_or_refused(data: Path, monkeypatch) -> None:
    """Free runs made to blow up beyond a length (as an unstable model's would): the fit halves the
    stretches until they are finite and says so; blowing up at every length, it is refused."""
    import torch

    from hypa.identification import IdentificationError, Stretches, identify_records

    original = Stretches.predict
    limit = {"samples": 700}

    def diverging(self, model, *args, **kwargs):
        pairs = original(self, model, *args, **kwargs)
        return [(torch.full_like(p, torch.inf) if p.shape[1] > limit["samples"] else p, y) for p, y in pairs]

    monkeypatch.setattr(Stretches, "predict", diverging)
    model, dm = model_and_data(data, list(TRUE), OFF)
    assert max(len(r) for r in dm.records("train")) > 2 * limit["samples"]
    result = identify_records(model, dm, dm.records("train"))
    assert result.shooting == "multiple"
    assert result.warnings[0].startswith("the free run over whole records is not finite")
    assert result.samples // result.stretches <= limit["samples"]
    for name, value in TRUE.items():
        assert result.values()[name] == pytest.approx(value, rel=0.02)
    limit["samples"] = 0
    model, dm = model_and_data(data, list(TRUE), OFF)
    with pytest.raises(IdentificationError, match="not finite at its starting parameters"):
        identify_records(model, dm, dm.records("train"))


def test_hypa_train_identifies_a_physics_only_model(data: Path, tmp_path: Path) -> None:
    """Through the command line: the run's checkpoint holds the identified parameters, its run.json
    and identification.md the report, and hypa evaluate scores it."""
    env = make_dc_motor_data(tmp_path / "unused", 1)
    run = tmp_path / "run"
    result = hypa_run(["train", "--config-dir", str(USER_EXAMPLE / "conf"), "dataset=dc_motor", "model=dc_motor",
                       f"data.dir={data}", "identification.enabled=true", "trainer.enable_progress_bar=false",
                       f"hydra.run.dir={run}"], env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "identified 3 parameter(s)" in result.stdout and "after identification" in result.stdout
    record = json.loads((run / "run.json").read_text())
    identified = record["identification"]
    assert identified["converged"] and identified["warnings"] == []
    for name, value in TRUE.items():
        assert identified["parameters"][name]["value"] == pytest.approx(value, rel=0.02)
    assert record["best_checkpoint"]["path"] == "checkpoints/best-identified.ckpt"
    assert "| torque_constant | 0.05 | 0.065 |" in (run / "identification.md").read_text()
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    board = EventAccumulator(str(run / "tensorboard"), size_guidance={"tensors": 0}).Reload()
    assert {"physics/torque_constant", "val/loss"} <= set(board.Tags()["scalars"])
    assert "identification/text_summary" in board.Tags()["tensors"]
    assert board.Scalars("physics/torque_constant")[0].value == pytest.approx(0.065, rel=0.02)
    evaluated = hypa_run(["evaluate", f"run={run}", f"out={tmp_path / 'eval'}", "trust=[dc_motor]",
                          "tensorboard=false", f"hydra.run.dir={tmp_path / 'hydra'}"], env=env)
    assert evaluated.returncode == 0, evaluated.stderr[-3000:]
    metrics = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    assert metrics["splits"]["val"]["free_run"]["all"]["speed"]["r2"] > 0.999
    assert "## Identification" in (tmp_path / "eval" / "summary.md").read_text()  # the run's report says how


def test_an_identification_started_from_another_runs_values_settles_at_once(data: Path, tmp_path: Path) -> None:
    """``identification.start=RUN``: the fit starts from the values RUN identified (the report's
    initial values are RUN's), settles in a few iterations and ends where RUN did."""
    from hypa.identification.output_error import SETTLE

    env = make_dc_motor_data(tmp_path / "unused", 1)
    common = ["train", "--config-dir", str(USER_EXAMPLE / "conf"), "dataset=dc_motor", "model=dc_motor",
              f"data.dir={data}", "trainer.enable_progress_bar=false", "figures.enabled=false"]
    first = hypa_run([*common, f"hydra.run.dir={tmp_path / 'first'}"], env=env)
    assert first.returncode == 0, first.stderr[-3000:]
    again = hypa_run([*common, f"identification.start={tmp_path / 'first'}", f"hydra.run.dir={tmp_path / 'again'}"],
                     env=env)
    assert again.returncode == 0, again.stderr[-3000:]
    before = json.loads((tmp_path / "first" / "run.json").read_text())["identification"]
    after = json.loads((tmp_path / "again" / "run.json").read_text())["identification"]
    assert after["converged"] and after["iterations"] <= SETTLE + 2, after
    assert after["iterations"] < before["iterations"], (before, after)
    for name, entry in after["parameters"].items():
        assert entry["initial"] == pytest.approx(before["parameters"][name]["value"], rel=1e-12)
        assert entry["value"] == pytest.approx(before["parameters"][name]["value"], rel=1e-3)
    assert after["error"]["final"] == pytest.approx(before["error"]["final"], rel=1e-3)
    resumed = hypa_run([*common, f"identification.start={tmp_path / 'first'}",
                        f"ckpt_path={tmp_path / 'first' / 'checkpoints' / 'best-identified.ckpt'}",
                        f"hydra.run.dir={tmp_path / 'resumed'}"], env=env)
    assert resumed.returncode != 0 and "identification.start with ckpt_path" in resumed.stderr


@pytest.mark.parametrize("record, message", [
    (None, "not a folder"),
    ({"best_val_loss": 1.0}, "holds no identified parameters"),
    ({"identification": {"parameters": {"k": {"value": "os.system"}}}}, "the identified value of 'k' is not a finite"),
    ({"identification": {"parameters": {"k": {"value": float("nan")}}}}, "is not a finite number"),
    ({"identification": {"parameters": {"k": {"value": True}}}}, "is not a finite number"),
    ({"identification": {"parameters": {"other": {"value": 1.0}}}}, "identified other, which this model does not"),
    ({"identification": {"parameters": {"fixed": {"value": 1.0}}}}, "identified fixed, which this model does not"),
    ({"identification": {"parameters": {"k": {"value": -2.0}}}}, "parameter 'k' must be positive"),
    ({"identification": {"parameters": {"k": {"value": 10**400}}}}, "is not a finite number"),
    ({"identification": {"parameters": {"x" * 10**5: {"value": 1.0}}}}, "identified x{80}, which this model does not"),
])
def test_a_start_that_is_not_an_identification_of_this_model_is_refused(tmp_path: Path, record, message) -> None:
    """``start_values`` reads run.json as data: a folder, finite numbers, this model's trainable
    parameters within their specs; anything else refused in one line naming identification.start."""
    from hypa.core.errors import UserError
    from hypa.physics import ParameterSpec
    from hypa.physics.parameters import PhysicalParameters
    from hypa.training.identified import start_values

    parameters = PhysicalParameters([ParameterSpec("k", 1.0, "1/s"), ParameterSpec("fixed", 2.0, "s")])
    parameters.set_trainable(None, False)
    parameters.set_trainable(["k"], True)
    folder = tmp_path / "run"
    if record is not None:
        folder.mkdir()
        (folder / "run.json").write_text(json.dumps(record))
    with pytest.raises(UserError, match=message) as error:
        start_values(folder, parameters)
    assert str(error.value).startswith(f"identification.start={folder}") and "\n" not in str(error.value)
    assert len(str(error.value)) < 400
    folder.mkdir(exist_ok=True)
    (folder / "run.json").write_text(json.dumps({"identification": {"parameters": {"k": {"value": 3.5}}}}))
    assert start_values(folder, parameters) == {"k": 3.5}


def test_a_start_whose_run_json_links_out_of_its_folder_is_refused(tmp_path: Path) -> None:
    from hypa.core.errors import UserError
    from hypa.physics import ParameterSpec
    from hypa.physics.parameters import PhysicalParameters
    from hypa.training.identified import start_values

    (tmp_path / "elsewhere.json").write_text(json.dumps({"identification": {"parameters": {"k": {"value": 3.5}}}}))
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "run.json").symlink_to(tmp_path / "elsewhere.json")
    with pytest.raises(UserError):
        start_values(tmp_path / "run", PhysicalParameters([ParameterSpec("k", 1.0, "1/s")]))


def _identification(error: float, value: float, initial: float, warnings: tuple[str, ...] = ()):
    from hypa.identification.result import Estimate, Identification

    return Identification((Estimate("limit", "V", initial, value, 0.1),), [[1.0]], True, "converged", 5, 6, 0.0,
                          1.0 if initial == 10.0 else error * 3, error, 1, 100, 2.0, warnings)


@pytest.mark.parametrize("second_error, kept", [(0.5, "second"), (0.995, "first"), (None, "first")])
def test_a_second_fit_from_where_a_limit_acts_is_kept_only_where_it_gains(monkeypatch, second_error, kept) -> None:
    """``_restarted``: the second fit kept where it gains more than KEEP of the first's error, its
    "did not move" warnings (about its own start) dropped; otherwise (or where it cannot run) the
    first fit's values back in the model. Either way the report keeps the user's start and error
    and counts both fits' work."""
    from types import SimpleNamespace

    import hypa.identification.output_error as oe
    from hypa.physics import ParameterSpec
    from hypa.physics.parameters import PhysicalParameters

    model = SimpleNamespace(parameters_=PhysicalParameters([ParameterSpec("limit", 10.0, "V", positive=False)]))
    model.parameters_.set_values({"limit": 40.0})  # where the first fit left it, out of reach
    first = _identification(1.0, 40.0, 10.0, ("limit is not determined by the data",))
    started = {}

    def second_fit(model_, stretches, settings, progress):
        started.update(model_.parameters_.as_floats())
        if second_error is None:
            raise oe.IdentificationError("the free run is not finite")
        model_.parameters_.set_values({"limit": 6.0})
        return _identification(second_error, 6.0, 5.0, ("limit did not move from 5 V: ...",))

    monkeypatch.setattr(oe, "identify", second_fit)
    result = oe._restarted(model, None, oe.IdentificationSettings(), lambda text: None, first, {"limit": 5.0})
    assert started == {"limit": 5.0}
    note = result.warnings[0]
    assert note.startswith("limit = 40 never reached by the free runs (no gradient there): a second fit from limit = 5")
    assert result.estimates[0].initial == 10.0 and result.error_initial == 1.0
    if kept == "second":
        assert note.endswith("the second is kept") and model.parameters_.as_floats()["limit"] == pytest.approx(6.0)
        assert result.error_final == 0.5 and not any("did not move" in w for w in result.warnings)
    else:
        ending = "could not run (the free run is not finite): the first is kept" if second_error is None \
            else "the first is kept (the second must gain more than 1%)"
        assert note.endswith(ending), note
        assert model.parameters_.as_floats()["limit"] == pytest.approx(40.0) and result.error_final == 1.0
        assert "limit is not determined by the data" in result.warnings
    if second_error is not None:
        assert result.iterations == 10 and result.evaluations == 12 and result.seconds == 4.0


def train_hybrid(data: Path, tmp_path: Path, *overrides: str) -> tuple[subprocess.CompletedProcess, Path, dict]:
    """``hypa train`` on the DC motor's hybrid (a tiny LSTM correction); the result, the run
    folder and its run.json."""
    env = make_dc_motor_data(tmp_path / "unused", 1)
    (tmp_path / "conf" / "model").mkdir(parents=True)
    (tmp_path / "conf" / "model" / "dc_motor_hybrid.yaml").write_text(DC_MOTOR_HYBRID)
    run = tmp_path / "run"
    result = hypa_run(["train", "--config-dir", str(USER_EXAMPLE / "conf"), "dataset=dc_motor",
                       f"hydra.searchpath=[file://{tmp_path / 'conf'}]", "model=dc_motor_hybrid", "ann=lstm",
                       "ann.hidden_size=4", f"data.dir={data}", "trainer.enable_progress_bar=false",
                       "figures.enabled=false", "optimizer.physics_lr=1e-9", *overrides, f"hydra.run.dir={run}"],
                      env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    sys.path.insert(0, str(USER_EXAMPLE))  # the system class, for loading its checkpoints here
    return result, run, json.loads((run / "run.json").read_text())


def test_a_jointly_trained_hybrid_starts_its_networks_on_identified_physics(data: Path, tmp_path: Path) -> None:
    """A hybrid without a physics-only stage: its physics is identified with the network bypassed,
    then the configured training (physics and network together, by epochs) starts from there."""
    result, run, record = train_hybrid(data, tmp_path, "trainer.max_epochs=1", "trainer.limit_train_batches=2")
    assert "identified 3 parameter(s)" in result.stdout and "after 1 epochs" in result.stdout
    for name, value in TRUE.items():
        assert record["identification"]["parameters"][name]["value"] == pytest.approx(value, rel=0.02)
    from hypa.training.checkpoints import load_module

    trained = load_module(run / record["last_checkpoint"], ["dc_motor"]).model.parameters_.as_floats()  # after it
    for name, value in TRUE.items():  # the epochs started from the identified values (and barely moved them)
        assert trained[name] == pytest.approx(value, rel=0.02)


def test_a_hybrid_whose_network_only_adds_error_keeps_its_identified_physics(data: Path, tmp_path: Path) -> None:
    """The model before the networks' first epoch (the identified physics, the correction's output zero) is
    the best checkpoint until an epoch beats it on validation: here the data are the physics' own and a
    far too large learning rate makes every epoch of the correction worse, so the run keeps the physics."""
    result, run, record = train_hybrid(data, tmp_path, "trainer.max_epochs=2", "trainer.limit_train_batches=3",
                                       "optimizer.lr=0.5")
    assert record["best_checkpoint"]["path"] == "checkpoints/best-start.ckpt"
    assert "no epoch beat the model it started from" in result.stdout
    start = float(next(line for line in (result.stdout + result.stderr).splitlines()
                       if "before the networks' first epoch" in line)
                  .rsplit(" ", 1)[1])
    assert record["best_val_loss"] == pytest.approx(start, rel=1e-4)
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["best-start.ckpt", "last.ckpt"]
    from hypa.training.checkpoints import load_module

    kept = load_module(run / record["best_checkpoint"]["path"], ["dc_motor"]).model
    head = kept.blocks["correction"].head
    assert not head.weight.detach().any() and not head.bias.detach().any()  # the correction's start: output zero
    for name, value in TRUE.items():
        assert kept.parameters_.as_floats()[name] == pytest.approx(value, rel=0.02)


@pytest.mark.parametrize("override, message", [
    ("identification.tolerance=0", "identification.tolerance=0 must be > 0"),
    ("identification.stretch_s=-1", "identification.stretch_s=-1 must be > 0"),
    ("identification.max_evaluations=0", "identification.max_evaluations=0 must be >= 1"),
    ("identification.resolution=0", "identification.resolution=0 must be > 0"),
    ("identification.enabled=maybe", "identification.enabled=maybe is not true or false"),
])
def test_bad_identification_settings_are_refused(override: str, message: str) -> None:
    """Read by hypa train before any data (its UserError is the command's one line, tests/core/test_cli_errors.py)."""
    from hydra.errors import ConfigCompositionException

    from hypa.commands.config import TrainConfig, typed
    from hypa.core.errors import UserError, one_line

    # a value of the wrong type fails while Hydra composes (hypa.commands.config), a value out of its range
    # when the command reads its typed configuration: the same one line either way
    with pytest.raises((UserError, ConfigCompositionException)) as error:
        cfg = compose_config("train", ["identification.enabled=true", override])
        typed(cfg, TrainConfig).identification.settings()
    assert message in one_line(error.value)
