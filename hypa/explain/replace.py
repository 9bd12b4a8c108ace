"""A learned block replaced by its explanation: the form as hypa physics blocks.

A form of rungs 1-4 with one input is an LTI system: a gain (``gain``), a gain through a lag
(``gain_lag``), either behind a dead time (a ``delay`` block), or a second-order form
(``second_order``). The network block is swapped for those blocks, with the fitted values as
their parameters; the rest of the trained model (its physics, its other networks) stays as
trained. The replaced model is written as a model YAML (``hypa train model=...`` trains it on)
and free-run over the validation records beside the trained one, so the gain or loss of the
replacement is measured. Forms that no physics block holds (an odd cubic, extra signals that
are the model's own outputs fed back, several inputs, a correction's) are not written; the best
form that is, if any, is, and the report says which and why.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

from hypa.data import HypaDataModule
from hypa.evaluation.runs import TrainedRun
from hypa.explain.forms import FittedForm
from hypa.models import ComposedModel
from hypa.models.rollout import Prediction, free_run, free_run_metrics
from hypa.models.spec import BlockSpec, ModelSpec, spec_config

SYSTEMS = {"static": "gain", "lag": "gain_lag", "lag_delay": "gain_lag", "second_order": "second_order"}


def unwritable(fitted: FittedForm, block: BlockSpec, inputs: Sequence[str], corrects: object) -> str | None:
    """Why the form cannot be written as physics blocks (None: it can)."""
    if corrects:
        return "a correction network adds to the physics; its explanation is not a block of its own"
    if len(inputs) != 1 or len(block.outputs) != 1:
        return "the block has several inputs or outputs"
    if fitted.form.cubic:
        return "an odd cubic term, which no linear block holds"
    if fitted.form.extra != "none":
        return "extra signals, the model's own outputs fed back"
    return None


def writable_form(forms: Sequence[FittedForm], chosen: int, block: BlockSpec, inputs: Sequence[str],
                  corrects: object) -> tuple[FittedForm | None, str]:
    """The chosen form if it can be written, else the best-scoring one that can; and a note."""
    reason = unwritable(forms[chosen], block, inputs, corrects)
    if reason is None:
        return forms[chosen], ""
    candidates = [f for f in forms if unwritable(f, block, inputs, corrects) is None]
    if not candidates:
        return None, reason
    best = max(candidates, key=lambda f: f.score)
    return best, (f"the chosen {forms[chosen].form.name} is not written as physics ({reason}); "
                  f"the best form that is, the {best.form.name}, replaces the network")


def form_blocks(block: BlockSpec, fitted: FittedForm) -> tuple[BlockSpec, ...]:
    """The physics blocks that compute ``fitted`` from the block's input into its output."""
    (source,), value = block.inputs, lambda kind, signal="": fitted.value(kind, signal)
    blocks = []
    delay = value("delay")
    if delay is not None and delay.value > 0:
        delayed = f"{block.name}_delayed"
        blocks.append(BlockSpec(name=f"{block.name}_delay", kind="delay", inputs=(source,), outputs=(delayed,),
                                parameters={"delay_s": float(delay.value)}))
        source = delayed
    gain = float(value("gain", block.inputs[0]).value)
    dynamics = fitted.form.dynamics
    if dynamics == "static":
        parameters = {"gain": gain}
    elif dynamics in ("lag", "lag_delay"):
        parameters = {"gain": gain, "tau_s": float(value("lag").value)}
    else:
        zero = value("zero", block.inputs[0])
        parameters = {"gain": gain, "zero_s": float(zero.value) if zero is not None else 0.0,
                      "natural_frequency_hz": float(value("natural_frequency").value),
                      "damping": float(value("damping").value)}
    start = () if dynamics == "static" else ("steady",)
    blocks.append(BlockSpec(name=block.name, kind="physics", system=SYSTEMS[dynamics], inputs=(source,),
                            outputs=block.outputs, parameters=parameters, initial_state=start,
                            scale_as=block.scale_as))
    return tuple(blocks)


def replaced_spec(spec: ModelSpec, block: str, fitted: FittedForm) -> ModelSpec:
    """The model with the network ``block`` replaced by the form's blocks (no training stages left
    for it: a stage that trained it now trains nothing)."""
    blocks = []
    for b in spec.blocks:
        blocks += form_blocks(b, fitted) if b.name == block else [b]
    stages = tuple(dataclasses.replace(s, train=tuple(n for n in s.train if n != block),
                                       bypass=tuple(n for n in s.bypass if n != block)) for s in spec.stages)
    stages = tuple(s for s in stages if s.train)
    return dataclasses.replace(spec, name=f"{spec.name}_explained", blocks=tuple(blocks), stages=stages)


def build_like(run: TrainedRun, spec: ModelSpec) -> ComposedModel:
    """``spec`` built by the run's own module class and settings (its data scales, sample time,
    horizon, hold, network settings), with the run's trained physical values and the trained
    weights of the networks that remain."""
    trained = run.module.model
    hp = {**run.module.hparams, "model_config": spec_config(spec), "physical_values": trained.parameters_.as_floats()}
    model = type(run.module)(**hp).model
    own = model.state_dict()
    model.load_state_dict({k: v for k, v in trained.state_dict().items() if k.startswith("blocks.")
                           and k in own and own[k].shape == v.shape}, strict=False)
    return model.eval()


def validation_errors(predictions: Sequence[Prediction], outputs: Sequence[str]) -> dict[str, dict[str, float]]:
    """Per output over the free runs: ``rms`` [SI] and ``r2`` (:func:`hypa.models.rollout.free_run_metrics`)."""
    return {n: {"rms": m["rmse"], "r2": m["r2"]} for n, m in free_run_metrics(predictions, outputs).items()}


def replace_and_score(run: TrainedRun, dm: HypaDataModule, block: str, fitted: FittedForm,
                      learned: Sequence[Prediction], out: Path) -> dict:
    """Write ``<model>_explained.yaml`` into ``out`` and free-run it over the validation records;
    returns the form, the config path and the validation errors of the learned and the replaced model."""
    import yaml

    spec = replaced_spec(run.module.model.spec, block, fitted)
    path = out / f"{spec.name}.yaml"
    path.write_text("# @package model\n" + yaml.safe_dump(spec_config(spec), sort_keys=False))
    model = build_like(run, spec)
    replaced = [free_run(model, dm, record) for record in dm.records("val")]
    outputs = dm.output_names
    return {"form": fitted.form.name, "config": str(path), "units": {n: dm.channels[n].unit for n in outputs},
            "learned": validation_errors(learned, outputs), "explained": validation_errors(replaced, outputs)}
