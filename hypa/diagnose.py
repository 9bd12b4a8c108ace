"""Diagnose what the nominal physics gets wrong, name the cause, fix it and measure the gain.

    python -m hypa.diagnose                                          # default test-bench data
    python -m hypa.diagnose testbench.rear_steering.enabled=false    # hide / reveal effects
    python -m hypa.diagnose dataset=files data.dir=PATH vehicle.cf=140000
    python -m hypa.diagnose -m dataset=files data.dir=LOG1,LOG2,LOG3   # a fleet: fleet.md in the sweep folder

Writes into the Hydra run folder ``diagnosis.md`` (the report), ``diagnosis.json`` (the
numbers), the figures and ``conf/model/diagnosed.yaml``. Steps: (1) residuals of the nominal
free run (error per channel, against |a_y|, correlations, transfer function), (2) the named
causes with estimates (:func:`hypa.diagnosis.name_causes`), (3) the extended model as a hypa
model config (:mod:`hypa.diagnosis.config`) with the command that trains it, (4) the gain of
the nominal model with the named causes applied on the validation records.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import hydra
import numpy as np
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from hypa.data import Record
from hypa.diagnosis.fleet import record_failures
from hypa.diagnosis.trained import TrainedExtension
from hypa.errors import UserError, user_error_types, user_errors
from hypa.physics import LTIBlock, UnstablePhysicsError
from hypa.vehicle import SingleTrack, VehicleParameters, vehicle_parameters

log = logging.getLogger(__name__)

COHERENT = 0.8  # γ² above which a transfer-function bin enters the summary (as in step 1)


def check_nominal(vehicle: VehicleParameters, dt: float, hold: str, rear_steering: str) -> None:
    """Raise ``UnstablePhysicsError`` (naming the parameters) if the nominal single track is unstable."""
    track = LTIBlock(SingleTrack(rear_steering=rear_steering == "fixed"), vehicle_parameters(vehicle), dt, 100,
                     hold=hold)
    try:
        track.check_stable()
    except UnstablePhysicsError:
        from hypa.diagnosis.model import continuous_matrices

        eigenvalues = ", ".join(f"{e:.4g}" for e in np.linalg.eigvals(continuous_matrices(vehicle)[0]))
        nominal = ", ".join(f"{k}={v:g}" for k, v in vehicle.as_dict().items())
        raise UnstablePhysicsError(
            f"the nominal single track is unstable with vehicle parameters {nominal} (eigenvalues of A: "
            f"{eigenvalues} 1/s), nothing to diagnose. Check vehicle.cf, vehicle.cr, vehicle.lf, vehicle.lr "
            "(an axle balance cf*lf vs cr*lr that oversteers beyond its critical speed) and vehicle.velocity."
        ) from None


def transfer_mismatch(measured, model) -> dict[str, float]:
    """Median |H_measured / H_model| and arg of it [deg] over the bins with measured γ² ≥ 0.8."""
    good = measured.coherence >= COHERENT
    if not good.any():
        return {"gain_ratio": float("nan"), "phase_difference_deg": float("nan")}
    relative = measured.response[good] / model.response[good]
    return {"gain_ratio": float(np.median(np.abs(relative))),
            "phase_difference_deg": float(np.degrees(np.median(np.angle(relative))))}


def _spec_dict(spec) -> dict:
    out = dataclasses.asdict(spec)
    out["vehicle"] = spec.vehicle.as_dict()
    out["mu"] = None if math.isinf(spec.mu) else spec.mu  # JSON has no infinity: null = linear axles
    return out


def diagnose(train: Sequence[Record], val: Sequence[Record], vehicle: VehicleParameters, dt: float, out: Path,
             hold: str = "foh", rear_steering: str = "none", high_ay: float = 4.0, plot: bool = True,
             unmodeled_input: str = "ann", train_overrides: Sequence[str] = (),
             train_extension: Callable[[Path], TrainedExtension] | None = None,
             progress: Callable[[str], None] = print) -> dict:
    """Steps 1-4 over decimated SI records; writes diagnosis.json, diagnosis.md, figures and the
    extended model's config (``conf/model/diagnosed.yaml``) into ``out``.

    ``high_ay`` [m/s²]: |a_y| from which samples count as "high" in the gain.
    ``unmodeled_input``: ``ann`` (V1-style network) or ``physics`` (the fitted ratio and lag) in
    the written model. ``train_overrides``: command-line overrides that select the same data and
    vehicle for ``hypa.train`` (printed in the train command). ``train_extension``: given the
    written config's folder, trains it and free-runs it over ``val`` (``hypa.diagnosis.trained``);
    its gain joins the report. Returns the result dict (the content of diagnosis.json).
    """
    from hypa.diagnosis import ModelSpec, analyze_residuals, name_causes
    from hypa.diagnosis.config import describe, extension_model, train_command, write_model
    from hypa.diagnosis.extension import (extended_spec, free_runs, gain_metrics, rear_angle_agreement,
                                          recovered_rear_angle, relative_change, transfer_functions)
    from hypa.diagnosis.report import markdown
    from hypa.diagnosis.residuals import AY_EDGES

    out.mkdir(parents=True, exist_ok=True)
    states = ("yaw_rate", "side_slip")
    started = time.perf_counter()
    progress("step 1/4: residuals of the nominal physics on the validation records")
    analysis = analyze_residuals(val, vehicle, dt, hold=hold, rear_steering=rear_steering)
    progress(f"step 2/4: naming the causes (fits every catalogue cause on {len(train)} training records; "
             "takes a few seconds to a minute)")
    diagnosis = name_causes(train, val, vehicle, dt, hold=hold, rear_steering=rear_steering)
    progress(f"          named: {', '.join(diagnosis.causes) or 'none'} ({time.perf_counter() - started:.0f} s)")
    progress("step 3/4: the extended model (the nominal one with the named causes) as a hypa model")
    nominal = ModelSpec(vehicle, hold=hold, rear_ratio=vehicle.rws_ratio if rear_steering == "fixed" else 0.0)
    extended = extended_spec(nominal, diagnosis)
    model = extension_model(diagnosis.named, hold, rear_steering, unmodeled_input)
    command = train_command(out / "conf", train_overrides)
    header = [f"hypa.diagnose: the nominal single track (hold {hold}, rear steering {rear_steering}) extended by",
              *(f"  {row['cause']}: {row['evidence']}" for row in diagnosis.named), "Train: " + command]
    config_path = write_model(model, out / "conf", header)
    progress(f"          {config_path}")
    trained = None
    if train_extension is not None:
        progress("          training it with hypa.train (progress below)")
        trained = train_extension(config_path.parent.parent)
    progress("step 4/4: the extended model against the nominal one on the validation records")
    runs = free_runs({"nominal": nominal, "extended": extended}, val, dt, vehicle.velocity)
    if trained is not None:
        runs.simulated["trained"] = np.concatenate(trained.states)
    metrics = gain_metrics(runs, high_ay, AY_EDGES)
    before, after = metrics["models"]["nominal"], metrics["models"]["extended"]
    transfer = transfer_functions(runs, dt)

    def change(model: dict) -> dict:
        return {"all": relative_change(before["all"], model["all"]),
                "high_ay": (relative_change(before["high_ay"], model["high_ay"])
                            if before["high_ay"] is not None else {})}

    gain = {**change(after),
            "high_ay_threshold": float(high_ay), "high_ay_samples": metrics["high_ay_samples"],
            "transfer": {name: transfer_mismatch(transfer["measured"], transfer[name]) for name in runs.simulated}}
    result = {**diagnosis.to_dict(),
              "nominal": {"vehicle": vehicle.as_dict(), "hold": hold, "rear_steering": rear_steering},
              "data": {"dt": dt, "train_records": len(train), "val_records": len(val)},
              "residuals": {
                  "channels": analysis.channels,
                  "gain_ratio": analysis.gain_ratio, "phase_difference_deg": analysis.phase_difference_deg,
                  "autocorrelation_outside": {s: c.outside for s, c in analysis.autocorrelation.items()},
                  "cross_correlation_outside": {s: c.outside for s, c in analysis.cross_correlation.items()},
                  "cross_correlation_peak_lag_s": {s: c.peak_lag * dt for s, c in analysis.cross_correlation.items()},
              },
              "baseline": {"metrics": before},
              "extended": {"config": str(config_path), "train_command": command,
                           "config_blocks": describe(model), "spec": _spec_dict(extended), "metrics": after},
              "gain": gain}
    if trained is not None:
        result["extended"]["trained"] = {"run": str(trained.folder), "metrics": metrics["models"]["trained"],
                                         "gain": change(metrics["models"]["trained"])}

    rear_rows = []
    if "unmodeled_input" in diagnosis.causes:
        rear_rows = [(r, recovered_rear_angle(extended, r, dt)) for r in val if "rear_wheel_angle" in r]
        if rear_rows:
            recovered = np.concatenate([a for _, a in rear_rows])
            measured_rear = np.concatenate([r["rear_wheel_angle"] for r, _ in rear_rows])
            result["extended"]["rear_wheel_angle"] = rear_angle_agreement(recovered, measured_rear)
    if trained is not None:
        pairs = [(r["rear_wheel_angle"], a) for r, a in zip(val, trained.rear_wheel_angle)
                 if a is not None and "rear_wheel_angle" in r]
        if pairs:
            measured_rear, learned = (np.concatenate(x) for x in zip(*pairs))
            ok = np.isfinite(learned)
            result["extended"]["trained"]["rear_wheel_angle"] = rear_angle_agreement(learned[ok], measured_rear[ok])

    figures: dict[str, list[str] | str] = {}
    if plot:
        progress("          figures")
        figures = _figures(out, val, runs, analysis, metrics, transfer, rear_rows, dt, states)
    result["figures"] = figures
    (out / "diagnosis.json").write_text(json.dumps(result, indent=2, default=float))
    (out / "diagnosis.md").write_text(markdown(result, figures))
    return result


def _figures(out, val, runs, analysis, metrics, transfer, rear_rows, dt, states) -> dict:
    import matplotlib.pyplot as plt

    from hypa.diagnosis import plots
    from hypa.evaluation.plots import bode, rear_steer
    from hypa.plots import time_series
    from hypa.vehicle.display import DEG

    names: dict[str, list[str] | str] = {}

    def save(fig, name: str) -> str:
        fig.savefig(out / name, dpi=100)
        plt.close(fig)
        return name

    starts = np.concatenate([[0], runs.record_ends[:-1]])
    names["time_series"] = []
    for record, start, end in zip(val, starts, runs.record_ends):
        fig = time_series(runs.time[start:end], {s: runs.measured[start:end, i] for i, s in enumerate(states)},
                          {m: {s: sim[start:end, i] for i, s in enumerate(states)}
                           for m, sim in runs.simulated.items()},
                          units=plots.UNITS, scale={s: DEG for s in states},
                          title=f"measured vs simulated (free run) over {record.name}")
        names["time_series"].append(save(fig, f"time_series_{Path(record.name).stem}.png"))
    rmse = {m: entry["ay_bin_rmse"] for m, entry in metrics["models"].items()}
    names["error_vs_ay"] = save(plots.error_vs_ay(analysis.ay_edges, rmse, analysis.ay_counts), "error_vs_ay.png")
    names["transfer"] = save(bode({"measured": analysis.measured, "nominal (analytic)": analysis.model},
                                  title="δsw → yaw rate: measured (H1) vs nominal"), "transfer_nominal.png")
    auto = {s: (c.lags, c.rho) for s, c in analysis.autocorrelation.items()}
    cross = {s: (c.lags, c.rho) for s, c in analysis.cross_correlation.items()}
    bound = next(iter(analysis.autocorrelation.values())).bound
    names["correlations"] = save(plots.correlations(auto, cross, bound, dt), "correlations.png")
    means = {m: {s: float(np.mean(sim[:, i] - runs.measured[:, i])) for i, s in enumerate(states)}
             for m, sim in runs.simulated.items()}
    names["mean_error"] = save(plots.mean_error(means), "mean_error.png")
    names["transfer_gain"] = save(bode(transfer, title="δsw → yaw rate before / after (same input, free runs)"),
                                  "transfer_before_after.png")
    if rear_rows:
        record, angle = rear_rows[0]
        names["rear_wheel_angle"] = save(
            rear_steer(np.arange(len(record)) * dt, record["rear_wheel_angle"], {"recovered (unmodeled_input)": angle},
                       title=f"rear-wheel angle over {record.name}"), "rear_wheel_angle.png")
    return names


@hydra.main(config_path="../conf", config_name="diagnose", version_base="1.3")
@user_errors("hypa.diagnose")
@record_failures("hypa.diagnose")  # -m over many logs: a bad log is reported in the fleet summary, the others run
def main(cfg: DictConfig) -> None:
    from hypa.entry import datamodule, vehicle_from_config

    out = Path(HydraConfig.get().runtime.output_dir)
    if cfg.get("model") is not None:
        return diagnose_model(cfg, out)
    hold, rear = str(cfg.physics.hold), str(cfg.physics.rear_steering)
    try:
        vehicle = vehicle_from_config(cfg.vehicle)
        check_nominal(vehicle, 1.0 / float(cfg.data.rate_hz), hold, rear)  # before any data is generated or read
        print("reading the data", flush=True)
        dm = datamodule(cfg)
        dm.setup()
    except ValueError as error:
        if isinstance(error, user_error_types()):
            raise
        # a configured value that a library rejects with a plain ValueError (vehicle.cf=-1, a test-bench key)
        raise UserError(str(error)) from error

    def progress(text: str) -> None:
        print(text, flush=True)

    overrides = data_overrides(HydraConfig.get().overrides.task)
    trainer = None
    if cfg.extension.train:
        from hypa.diagnosis.trained import train_extension

        def trainer(config_dir: Path) -> TrainedExtension:
            return train_extension(config_dir, out / "extended_run", dm, overrides,
                                   [str(o) for o in cfg.extension.train_overrides])
    result = diagnose(dm.records("train"), dm.records("val"), vehicle, dm.dt, out, hold=hold, rear_steering=rear,
                      high_ay=float(cfg.high_ay), plot=bool(cfg.plot),
                      unmodeled_input=str(cfg.extension.unmodeled_input), train_overrides=overrides,
                      train_extension=trainer, progress=progress)
    change = result["gain"]["all"].get("overall")
    change_text = "" if change is None else f", validation MSE {100 * change:+.1f} % with them applied"
    print(f"named causes: {', '.join(result['causes']) or 'none'} (estimate {result['estimate']}){change_text}; "
          f"report: {out / 'diagnosis.md'}", flush=True)
    trained = result["extended"].get("trained")
    if trained:
        print(f"trained extension ({trained['run']}): validation MSE {100 * trained['gain']['all']['overall']:+.1f} % "
              "against the nominal physics", flush=True)
    else:
        print(f"extended model: {result['extended']['config']}; train it with\n  {result['extended']['train_command']}",
              flush=True)


def diagnose_model(cfg: DictConfig, out: Path) -> None:
    """``model=M``: the diagnosis of any system from its nominal hypa model (:mod:`hypa.diagnosis.system`)."""
    from omegaconf import OmegaConf

    from hypa.diagnosis.catalogue import load_catalogue
    from hypa.diagnosis.engine import Problem
    from hypa.diagnosis.system import diagnose_system
    from hypa.entry import datamodule, vehicle_from_config
    from hypa.models.spec import parse_model_spec

    spec = parse_model_spec(OmegaConf.to_container(cfg.model, resolve=True))
    catalogue = load_catalogue([_from_cwd(p) for p in cfg.diagnosis.catalogue])
    values = vehicle_from_config(cfg.vehicle).as_dict() if cfg.get("vehicle") else {}
    print("reading the data", flush=True)
    dm = datamodule(cfg)
    dm.setup()
    problem = Problem(dm, values, hold=str(cfg.physics.hold), horizon=int(cfg.data.window))
    user_dirs = [Path(s.path.removeprefix("file://")) for s in HydraConfig.get().runtime.config_sources
                 if s.provider == "command-line" and s.schema == "file"]
    result = diagnose_system(spec, problem, out, data_overrides(HydraConfig.get().overrides.task),
                             plot=bool(cfg.plot), progress=lambda text: print(text, flush=True),
                             config_dir=user_dirs[0] if user_dirs else None, catalogue=catalogue,
                             max_causes=int(cfg.diagnosis.max_causes), min_gain=float(cfg.diagnosis.min_gain))
    change = result["gain"]["all"]["overall"]
    print(f"named causes: {', '.join(result['causes']) or 'none'}; validation error {100 * change:+.0f} % with them "
          f"applied; unexplained: {', '.join(s['output'] for s in result['unexplained']) or 'nothing'}; "
          f"report: {out / 'diagnosis.md'}", flush=True)


def _from_cwd(path: str) -> Path:
    """A path given on the command line, relative to where the command was run."""
    from hydra.utils import get_original_cwd

    path = Path(str(path)).expanduser()
    return path if path.is_absolute() else Path(get_original_cwd()) / path


def data_overrides(overrides: Sequence[str]) -> list[str]:
    """The command-line overrides that choose the data and the vehicle (``dataset``, ``data``,
    ``testbench``, ``vehicle`` groups and their keys): what ``hypa.train`` needs to see the same data."""
    groups = ("dataset", "data", "testbench", "vehicle")
    return [o for o in overrides if o.lstrip("+~").split("=", 1)[0].split(".", 1)[0] in groups]


if __name__ == "__main__":
    main()
