"""The generic diagnosis engine (hypa.diagnosis.search): effects hidden in a system's data are named.

The truth is a mass-spring-damper simulated by scipy (not by hypa), driven by a random force,
with one hidden effect at a random magnitude per seed: a dead time of the force, a stiffness
that differs from the nominal, a position-sensor offset. The nominal model is hypa's built-in
``mass_spring_damper`` with its stiffness and damping declared uncertain. The engine must name
the effect, estimate it within tolerance, and name nothing on clean data.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from scipy import signal

from hypa.data import datamodule_from_config
from hypa.diagnosis.catalogue import CatalogueError, catalogue_candidates, load_catalogue
from hypa.diagnosis.edits import applied, frozen
from hypa.diagnosis.problem import Problem
from hypa.diagnosis.search import name_causes
from hypa.models.spec import parse_model_spec
from hypa.reporting.numbers import quantity

RATE = 100.0  # [Hz]
NOMINAL = {"mass": 1.0, "stiffness": 400.0, "damping": 4.0, "offset_force": 0.0}
MODEL = {
    "name": "msd",
    "blocks": {"spring": {"kind": "physics", "system": "mass_spring_damper", "inputs": ["force"],
                          "outputs": ["position"], "parameters": {}, "trainable": ["stiffness", "damping"]}},
    "outputs": ["position"],
}


def truth(seconds: float, seed: int, delay_s: float = 0.0, stiffness: float = 400.0, offset: float = 0.0,
          actuator_gain: float = 1.0, actuator_tau_s: float = 0.0, force_limit: float = 0.0,
          force_scale: float = 1.0) -> dict[str, np.ndarray]:
    """Position of the true system (scipy's lsim, linear between samples) for a smoothed random force."""
    rng = np.random.default_rng(seed)
    n = int(seconds * RATE)
    b, a = signal.butter(2, 8.0 / (RATE / 2))
    force = signal.lfilter(b, a, rng.standard_normal(n + 200))[200:] * 400.0 * force_scale  # [N], up to ~8 Hz
    t = np.arange(n) / RATE
    applied_force = np.interp(t - delay_s, t, force, left=force[0])
    if actuator_tau_s > 0:  # τ ḟ = k u - f, started in equilibrium
        _, applied_force, _ = signal.lsim(signal.lti([-1 / actuator_tau_s], [1 / actuator_tau_s], [1], [0]),
                                          applied_force, t, X0=[applied_force[0]], interp=True)
    applied_force = actuator_gain * applied_force
    if force_limit > 0:  # an actuator that cannot exceed its range: clipped hard (hypa's limit is smooth)
        applied_force = np.clip(applied_force, -force_limit, force_limit)
    system = signal.lti([[0, 1], [-stiffness / NOMINAL["mass"], -NOMINAL["damping"] / NOMINAL["mass"]]],
                        [[0], [1 / NOMINAL["mass"]]], [[1, 0]], [[0]])
    _, position, _ = signal.lsim(system, applied_force, t, interp=True)
    position = position + offset + 0.002 * np.std(position) * rng.standard_normal(n)
    return {"time": t, "force": force, "position": position}


def datamodule(folder: Path, seed: int = 0, val_scale: float = 1.0, **effect: float):
    """Training (40 s) and validation (20 s, its force at ``val_scale`` of the amplitude) records."""
    for split, seconds, s, scale in (("train", 40.0, seed, 1.0), ("val", 20.0, seed + 1, val_scale)):
        columns = truth(seconds, s, force_scale=scale, **effect)
        np.savetxt(folder / f"{split}.csv", np.column_stack(list(columns.values())), delimiter=",",
                   header=",".join(columns), comments="", fmt="%.10g")
    data = {"source": "files", "dir": str(folder), "time": {"column": "time", "unit": "s"},
            "sample_rate_hz": RATE, "rate_hz": None,
            "channels": {"force": {"role": "input", "unit": "N"}, "position": {"role": "output", "unit": "m"}},
            "splits": None, "select": [], "window": 100, "past": 10, "stride": 10, "eval_stride": 50,
            "batch_size": 32, "num_workers": 0, "seed": 0}
    dm = datamodule_from_config(data, folder)
    dm.setup()
    return dm


def diagnose(tmp_path: Path, catalogue=None, max_causes: int = 1, min_gain: float = 0.15, **effect: float):
    """The first round decides what these tests check: one cause (later rounds fit the nonlinear
    stiffening-spring candidate jointly with it, step by step: slow, and tested elsewhere)."""
    dm = datamodule(tmp_path, **effect)
    return name_causes(parse_model_spec(MODEL), Problem(dm, NOMINAL, hold="foh", horizon=100), catalogue=catalogue,
                       max_causes=max_causes, min_gain=min_gain)


USER_ENTRY = """
- id: actuator
  name: a force actuator with its own gain and bandwidth
  for_each: input
  fit: gradient
  patch:
    rewire: {"{input}": "{input}__actuated"}
    blocks:
      actuator_{input}:
        {kind: physics, system: gain_lag, inputs: ["{input}"], outputs: ["{input}__actuated"],
         parameters: {gain: 1.0, tau_s: 2 * dt}, trainable: [gain, tau_s], initial_state: [steady]}
"""


def test_a_users_own_catalogue_entry_is_fitted_and_named(tmp_path: Path) -> None:
    """A cause the built-in catalogue lacks (the force reaches the mass at 70 % through a 40 ms
    lag; no re-fit of the declared-uncertain stiffness or damping can give that), added in YAML."""
    (tmp_path / "mine.yaml").write_text(USER_ENTRY)
    data = tmp_path / "data"
    data.mkdir()
    search = diagnose(data, catalogue=load_catalogue([tmp_path / "mine.yaml"]), actuator_gain=0.7,
                      actuator_tau_s=0.04)
    first = search.named[0]
    assert (first.cause, first.target) == ("actuator", "force"), [f.describe() for f in search.rounds[0][:3]]
    assert first.values["actuator_force/gain"] == pytest.approx(0.7, rel=0.05)
    assert first.values["actuator_force/tau_s"] == pytest.approx(0.04, rel=0.2)


@pytest.mark.parametrize("entry, message", [
    ("- id: x\n  for_each: wheel\n  patch: {blocks: {}}", "for_each must be one of input, output"),
    ("- id: x\n  for_each: input\n  fit: offset", "fit: offset needs offset"),
    ("- id: x\n  for_each: input\n  colour: red", "unknown keys \\['colour'\\]"),
    ("- id: x\n  for_each: block\n  patch: {blocks: {}}", "for_each: block needs where"),
    ("id: x", "must be a list of entries"),
])
def test_a_bad_catalogue_entry_is_a_one_line_error(tmp_path: Path, entry: str, message: str) -> None:
    (tmp_path / "bad.yaml").write_text(entry.replace("\\n", "\n"))
    with pytest.raises(CatalogueError, match=message) as error:
        load_catalogue([tmp_path / "bad.yaml"])
    assert "\n" not in str(error.value)


def test_an_entry_applies_only_when_its_parameters_allow(tmp_path: Path) -> None:
    """``when: {p: nonzero}``: a vehicle declared without rear steering is not suspected of it."""
    (tmp_path / "when.yaml").write_text('- id: only_when_damped\n  when: {damping: nonzero}\n  for_each: output\n'
                                        '  fit: offset\n  offset: "{output}"\n')
    entries = [e for e in load_catalogue([tmp_path / "when.yaml"]) if e.id == "only_when_damped"]
    spec = parse_model_spec(MODEL)
    assert catalogue_candidates(entries, spec, ("force",), ("position",), (), NOMINAL, 0.01)
    assert not catalogue_candidates(entries, spec, ("force",), ("position",), (), {**NOMINAL, "damping": 0.0}, 0.01)
    vehicle = [e for e in load_catalogue() if e.id == "unmodeled_input"]
    assert vehicle and all(not e.applies({"rws_ratio": 0.0}) and e.applies({"rws_ratio": 0.1}) for e in vehicle)


def test_an_entry_that_breaks_the_model_names_itself(tmp_path: Path) -> None:
    (tmp_path / "bad.yaml").write_text(
        '- id: broken\n  for_each: input\n  patch: {blocks: {"x_{input}": {kind: physics, system: nope, '
        'inputs: ["{input}"], outputs: [y2], trainable: [k]}}}\n')
    entries = [e for e in load_catalogue([tmp_path / "bad.yaml"]) if e.id == "broken"]
    with pytest.raises(CatalogueError, match=r"entry broken on force: the edited model is not valid: .*nope"):
        catalogue_candidates(entries, parse_model_spec(MODEL), ("force",), ("position",), (), NOMINAL, 0.01)


def test_candidates_are_edits_of_the_model_and_apply_their_values() -> None:
    spec = parse_model_spec(MODEL)
    states = {"spring/position": (0.0, 0.1, -0.1, 0.1), "spring/velocity": (0.0, 2.0, -2.0, 2.0)}  # the scales
    found = {c.key: c for c in catalogue_candidates(load_catalogue(), spec, ("force",), ("position",), (), NOMINAL,
                                                    0.01, channels={"force": (200.0, "N"), "position": (0.5, "m")},
                                                    states=states)}
    assert set(found) == {"input_delay:force", "input_lag:force", "input_offset:force", "output_offset:position",
                          "input_saturation:force", "parameter_mismatch:stiffness",
                          "parameter_mismatch:damping",  # mass is not declared uncertain
                          "stiffening_spring:spring",  # the core mass-spring-damper's own entry
                          # any system's: a mode it lacks, its time constant from three starts, each named
                          "missing_mode:force, fast start", "missing_mode:force, middle start",
                          "missing_mode:force, slow start"}
    # the starts' values (dt = 10 ms; the spring's slowest mode decays in 0.5 s): 3 dt, their geometric mean, 3 slowest
    taus = [found[f"missing_mode:force, {s} start"].spec.block("spring").parameters["mode_force_tau_s"]
            for s in ("fast", "middle", "slow")]
    assert taus == pytest.approx([0.03, 0.2121, 1.5], rel=1e-3), taus
    delay = found["input_delay:force"]
    assert [b.name for b in delay.spec.blocks] == ["diagnosed_delay_force", "spring"]
    assert delay.spec.block("spring").inputs == ("force__delayed",)
    assert delay.spec.block("spring").trainable == ()  # only the knob is fitted
    written = applied(delay, {"diagnosed_delay_force/delay_s": 0.05})
    assert written.block("diagnosed_delay_force").parameters == {"delay_s": 0.05}
    assert written.block("diagnosed_delay_force").trainable == ()
    assert applied(found["parameter_mismatch:stiffness"], {"stiffness": 350.0}).parameters == {"stiffness": 350.0}
    assert applied(found["output_offset:position"], {"position": 0.01}).sensor_offsets == {"position": 0.01}
    limit = found["input_saturation:force"]  # starts at 1.5 x the peak (the catalogue's expression of peak)
    assert limit.spec.block("diagnosed_limit_force").parameters == {"limit": 1.5 * 200.0}
    assert limit.units == {"diagnosed_limit_force/limit": "N"}
    # the hardening starts where the spring is 1 % stiffer at one spread of the position (0.1 m)
    assert found["stiffening_spring:spring"].spec.parameters["hardening"] == pytest.approx(1.0)


def test_a_limit_is_linear_below_and_bounded_above() -> None:
    """The saturation element: u / (1 + |u / L|^6)^(1/6) on the physical value, signals normalized."""
    import torch

    from hypa.physics.elements import Saturation
    from hypa.physics.parameters import ParameterSpec, PhysicalParameters

    params = PhysicalParameters([ParameterSpec("lim/limit", 2.0, "N", trainable=True)])
    block = Saturation(params, "lim/limit", [(1.0, 4.0)])
    u = torch.linspace(-100.0, 100.0, 201, dtype=torch.float64)[None, :, None]  # normalized
    y = block(u) * 4.0 + 1.0
    physical = 1.0 + 4.0 * u
    assert torch.allclose(y, physical / (1.0 + (physical.abs() / 2.0) ** 6) ** (1 / 6))
    assert float(y.detach().abs().max()) <= 2.0
    assert abs(float(block(torch.zeros(1, 1, 1).double()) * 4 + 1) - 1.0) < 3e-3  # at L/2
    y.sum().backward()
    assert params.raw["lim/limit"].grad is not None and float(params.raw["lim/limit"].grad) != 0.0


@pytest.mark.parametrize("cause, effect, knob, tolerance", [
    ("input_delay", {"delay_s": 0.06}, "diagnosed_delay_force/delay_s", 0.2),
    ("parameter_mismatch", {"stiffness": 320.0}, "stiffness", 0.05),
    ("output_offset", {"offset": 0.05}, "position", 0.1),
])
def test_a_hidden_effect_is_named_with_its_estimate(tmp_path: Path, cause: str, effect: dict, knob: str,
                                                    tolerance: float) -> None:
    search = diagnose(tmp_path, **effect)
    assert search.named, [f.describe() for f in search.rounds[0][:3]]
    first = search.named[0]
    if cause == "output_offset" and first.cause == "input_offset":
        # a constant force and a position offset are one thing to a spring (static gain 1/k): the
        # diagnosis must say that the data cannot tell them apart
        assert any(a.startswith("output_offset on position") for a in first.alternatives), first.alternatives
        first = next(f for f in search.rounds[0] if f.cause == "output_offset")
    assert first.cause == cause, [f.describe() for f in search.rounds[0][:3]]
    assert first.values[knob] == pytest.approx(next(iter(effect.values())), rel=tolerance)
    assert first.gain > 0.5


@pytest.mark.parametrize("seed", [0, 1])
def test_a_hidden_actuator_limit_is_named(tmp_path: Path, seed: int) -> None:
    """The force clipped hard at 45-65 % of its peak (a random level per seed): named as
    ``input_saturation`` with its level (the smooth limit that fits a hard clip lies close to it)."""
    peak = float(np.max(np.abs(truth(40.0, 0)["force"])))
    level = np.random.default_rng(seed).uniform(0.45, 0.65) * peak
    search = diagnose(tmp_path, force_limit=level)
    first = search.named[0] if search.named else None
    assert first is not None and first.cause == "input_saturation", [f.describe() for f in search.rounds[0][:3]]
    assert first.values["diagnosed_limit_force/limit"] == pytest.approx(level, rel=0.25)
    assert first.gain > 0.5 and "N" in first.describe()


def test_clean_data_names_nothing(tmp_path: Path) -> None:
    search = diagnose(tmp_path)
    assert search.named == [], [f.describe() for f in search.named]
    assert search.nominal_score < 1e-3


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(6))
def test_hidden_effects_at_random_magnitudes_are_named(tmp_path: Path, seed: int) -> None:
    """One effect per seed at a random magnitude (hit rate over the seeds in the issue's note)."""
    rng = np.random.default_rng(100 + seed)
    cause = ("input_delay", "parameter_mismatch", "output_offset")[seed % 3]
    effect = {"input_delay": {"delay_s": rng.uniform(0.03, 0.12)},
              "parameter_mismatch": {"stiffness": 400.0 * rng.choice([rng.uniform(0.7, 0.9), rng.uniform(1.1, 1.4)])},
              "output_offset": {"offset": rng.uniform(0.03, 0.15) * rng.choice([-1, 1])}}[cause]
    search = diagnose(tmp_path, **effect)
    named = search.named[0]
    assert cause in (named.cause, *(a.split(" on ")[0] for a in named.alternatives)), [
        f.describe() for f in search.rounds[0][:3]]


def test_values_are_written_with_units() -> None:
    assert quantity(0.0612, "s") == "61.2 ms"
    assert quantity(1.234e5, "N/rad") == "1.23e+05 N/rad"
    assert quantity(3.0, "") == "3"
    assert quantity(0.00498, "rad") == "0.285 deg" and quantity(0.0017, "rad/s") == "0.0974 deg/s"


@pytest.mark.parametrize("offset", [0.0, 0.01, -0.02])
def test_an_offset_below_the_gain_floor_is_named_when_significant(tmp_path: Path, offset: float) -> None:
    """With the floor out of reach (min_gain 1: no gain reaches it), an offset is still named, marked small, when it
    sits 5 standard errors from zero; on clean data (offset 0) nothing is."""
    search = diagnose(tmp_path, min_gain=1.0, offset=offset)
    if offset == 0.0:
        assert search.named == [], [f.describe() for f in search.named]
        return
    first = search.named[0] if search.named else None
    assert first is not None and first.cause in ("output_offset", "input_offset"), [
        f.describe() for f in search.rounds[0][:3]]
    assert first.small and first.z >= 5 and 0.01 <= first.gain < 1.0
    if first.cause == "input_offset":  # a constant force and a position offset are one thing to a spring
        assert any(a.startswith("output_offset on position") for a in first.alternatives), first.alternatives
        assert first.values["force"] == pytest.approx(-NOMINAL["stiffness"] * offset, rel=0.1)
    else:
        assert first.values["position"] == pytest.approx(offset, rel=0.1)


def test_fits_on_worker_processes_give_the_results_of_one_process(tmp_path: Path) -> None:
    """A round's gradient fits on forked workers (Problem.workers) are the same fits, seeded per
    candidate: the same scores and values as in the calling process."""
    from hypa.diagnosis.workers import can_fork

    if not can_fork():
        pytest.skip("this platform cannot fork")
    dm = datamodule(tmp_path, delay_s=0.05)
    searches = [name_causes(parse_model_spec(MODEL), Problem(dm, NOMINAL, hold="foh", horizon=100, workers=n),
                            max_causes=1) for n in (1, 2)]
    # The same windows and steps; the numbers agree to round-off, not to the bit: a BLAS kernel may
    # sum in another order where a forked worker's arrays are aligned differently (seen once on CI:
    # 3e-8 relative after a Levenberg-Marquardt fit, whose finite differences amplify round-off).
    # Another seed or other windows would differ by far more.
    one, two = ({f.key: f for f in s.rounds[0]} for s in searches)
    assert sorted(one) == sorted(two)
    for key, f in one.items():
        g = two[key]
        assert (f.steps, sorted(f.values)) == (g.steps, sorted(g.values)), key
        for a, b in [(f.score, g.score), *((f.values[k], g.values[k]) for k in f.values)]:
            assert (math.isnan(a) and math.isnan(b)) or math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-12), (key, a, b)
    assert searches[1].named[0].cause == "input_delay"


def test_a_change_near_all_or_nothing_keeps_a_decimal() -> None:
    from hypa.reporting.numbers import change_text as format_change

    assert [format_change(x) for x in (-0.996, -0.93, -0.004, 0.25)] == ["-99.6 %", "-93 %", "-0.4 %", "+25 %"]


@pytest.mark.parametrize("failure", ["overflow", "runaway"])
def test_a_diverging_candidate_is_reported_and_never_ends_the_diagnosis(tmp_path: Path, monkeypatch, failure: str
                                                                        ) -> None:
    """A stiffness refit whose physics overflows (the OverflowError of a matrix exponential of a
    huge delay) or whose knob runs away (to 1e+242, as a flat direction can send an LM step): the
    search goes on, names the real cause (a dead time) and shows the refit as not converged with
    its last sane value, never the runaway one."""
    from hypa.diagnosis import fitting

    step = fitting.GradientFit._least_squares_step

    def broken(self, *args):
        if "stiffness" not in self.candidate.knobs:
            return step(self, *args)
        if self.done >= 1:
            if failure == "overflow":
                raise OverflowError("int too big to convert")
            with torch.no_grad():
                self.model.parameters_.raw["stiffness"].fill_(558.0)  # exp(558) = 2e+242 N/m
            return None
        return step(self, *args)

    monkeypatch.setattr(fitting.GradientFit, "_least_squares_step", broken)
    search = diagnose(tmp_path, delay_s=0.06)
    assert search.named and search.named[0].cause == "input_delay", [f.describe() for f in search.rounds[0][:3]]
    refit = next(f for f in search.rounds[0] if f.key == "parameter_mismatch:stiffness")
    assert refit.error.startswith("did not converge: ") and refit.gain == -math.inf, refit.error
    assert ("OverflowError" if failure == "overflow" else "left its physical range") in refit.error
    assert "e+242" not in refit.describe() and 50.0 < refit.values["stiffness"] < 5000.0, refit.describe()


def unrepresentative(folder: Path, level: float, seed: int):
    """Training data that drive the force into a hard limit at ``level``; a validation record
    driven at 30 % of the amplitude, where the limit never acts (a slow lap into the pits)."""
    return datamodule(folder, seed=seed, val_scale=0.3, force_limit=level)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_validation_record_unlike_the_training_does_not_decide(tmp_path: Path, seed: int, monkeypatch) -> None:
    """Cross-validation over blocks of all records: an actuator limit (45-65 % of the peak force,
    random per seed) that acts only in the training records is named; judged on the validation
    record alone (no folds), where it never acts, nothing would be."""
    peak = float(np.max(np.abs(truth(40.0, seed)["force"])))
    level = np.random.default_rng(seed).uniform(0.45, 0.65) * peak
    dm = unrepresentative(tmp_path, level, seed)
    search = name_causes(parse_model_spec(MODEL), Problem(dm, NOMINAL, hold="foh", horizon=100), max_causes=1)
    assert search.folds == 2 and search.blocks >= 3
    first = search.named[0] if search.named else None
    assert first is not None and first.cause == "input_saturation", [f.describe() for f in search.rounds[0][:3]]
    assert first.values["diagnosed_limit_force/limit"] == pytest.approx(level, rel=0.25)
    assert len(first.folds) == 2 and first.gain > 0.5
    monkeypatch.setattr(Problem, "folds", lambda self: [self])  # the old way: the validation record decides
    alone = name_causes(parse_model_spec(MODEL), Problem(dm, NOMINAL, hold="foh", horizon=100), max_causes=1)
    assert alone.folds == 1 and not any(f.cause == "input_saturation" for f in alone.named)


def test_a_scanned_entry_names_its_starts_not_their_values(tmp_path: Path) -> None:
    """A scan's start values move with each fold's and round's model (``slowest``); the candidates'
    keys must not (the folds pool them by key, the final model is rebuilt from them): a list of
    starts is named by position, named starts by their names; anything else is refused in one line."""
    entry = {"id": "my_mode", "for_each": "block_input", "fit": "gradient",
             "patch": {"blocks": {"{block}": {"modes": ["{block_modes}", "{mode}"], "parameters": "{mode_parameters}",
                                              "initial_state": ["estimate"],
                                              "trainable": ["mode_{mode}_tau_s", "{mode_weights}"]}}}}
    path = tmp_path / "mine.yaml"
    spec = frozen(parse_model_spec(MODEL))
    for scan, names in (([0.05, "3 * slowest"], ["start 1 of 2", "start 2 of 2"]), ({"quick": 0.05}, ["quick"])):
        path.write_text(yaml.safe_dump([{**entry, "scan": {"tau": scan}}]))
        mine = [e for e in load_catalogue([path]) if e.id == "my_mode"]
        found = catalogue_candidates(mine, spec, ("force",), ("position",), (), NOMINAL, 0.01,
                                     channels={"force": (200.0, "N"), "position": (0.5, "m")})
        assert [c.target for c in found] == [f"force, {n}" for n in names], [c.target for c in found]
    for bad in ({"tau": []}, {"tau": {"": 1.0}}, {"tau": [1.0], "width": [2.0]}, ["tau"]):
        path.write_text(yaml.safe_dump([{**entry, "scan": bad}]))
        with pytest.raises(CatalogueError, match="scan maps one variable to its start values"):
            load_catalogue([path])


def test_an_input_limit_inside_the_range_the_input_spans_says_so(tmp_path: Path) -> None:
    """A limit that bends more than a tenth of the samples is not an actuator's range reached at the
    peaks: its finding says where it sits against the input's spread; one beyond the peaks says nothing."""
    from hypa.diagnosis.finding import scored

    dm = datamodule(tmp_path)
    spec = frozen(parse_model_spec(MODEL))
    problem = Problem(dm, NOMINAL, hold="foh", horizon=100).scaled(spec)
    force = np.concatenate([r["force"] for r in dm.records("train")])
    peak = float(np.abs(force).max())
    found = catalogue_candidates([e for e in load_catalogue() if e.id == "input_saturation"], spec, ("force",),
                                 ("position",), (), NOMINAL, 0.01, channels={"force": (peak, "N")})
    knob = found[0].knobs[0]
    inside = float(np.percentile(np.abs(force), 60))
    for limit, bent in ((inside, True), (1.2 * peak, False)):
        text = scored(found[0], problem, {knob: limit}, 0.5, 1.0, 0.0).describe()
        assert ("the limit sits inside the range force spans" in text) is bent, text
        if bent:
            assert "bends 40 % of the training samples" in text, text
