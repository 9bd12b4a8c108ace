"""Glue for the Hydra entry points: configuration nodes -> typed objects.

Only entry points (``python -m hypa.*``) import this; everything below them takes typed
arguments, never a config object.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import lightning as L
from omegaconf import DictConfig, OmegaConf

from hypa.core.errors import UserError, checked, settings
from hypa.data import HypaDataModule, datamodule_from_config
from hypa.data.from_config import data_dir_from_config
from hypa.vehicle import VehicleParameters

if TYPE_CHECKING:
    from hypa.models import ModelSpec

log = logging.getLogger(__name__)


def vehicle_from_config(node: DictConfig) -> VehicleParameters:
    """The nominal vehicle parameters (``vehicle`` group); unknown names are an error."""
    values = OmegaConf.to_container(node, resolve=True)
    unknown = set(values) - set(VehicleParameters.names())
    if unknown:
        raise UserError(
            f"unknown vehicle parameters {sorted(unknown)}; known: {', '.join(VehicleParameters.names())}"
        )
    try:
        return VehicleParameters(**{k: float(v) for k, v in values.items()})
    except ValueError as error:  # a value out of its range: vehicle.cf=-1
        raise UserError(str(error)) from None


def datamodule(cfg: DictConfig) -> HypaDataModule:
    """Resolve the data folder and build the DataModule from the ``data`` node."""
    return datamodule_from_config(cfg.data, data_dir_from_config(cfg))


@dataclass(frozen=True)
class ModelData:
    """The data for a model (:func:`model_datamodule`) and what they chose that the configuration left
    open: ``past_chosen``, the past samples chosen where ``data.past`` is null (None where it was given), and
    ``promoted``, the auxiliary channels the model reads, held as inputs. :meth:`recorded` says both as
    the configuration's keys, for a run's recorded configuration."""

    dm: HypaDataModule
    past_chosen: int | None
    promoted: tuple[str, ...] = ()

    def recorded(self) -> dict[str, Any]:
        """What the data chose as dotted keys of the configuration -> values (``data.past``,
        ``data.channels.NAME.role``): a configuration with them builds these data again."""
        chosen: dict[str, Any] = {f"data.channels.{name}.role": "input" for name in self.promoted}
        if self.past_chosen is not None:
            chosen["data.past"] = self.past_chosen
        return chosen


def model_datamodule(cfg: DictConfig, data_dir: Path, spec: ModelSpec,
                     physical_values: Mapping[str, float], auxiliary_inputs: bool = False) -> ModelData:
    """The data node's DataModule, set up, for the model ``spec``, and what it chose: where ``data.past``
    is null, as many past samples as the model's estimated starts want
    (:meth:`~hypa.models.ComposedModel.suggested_past`) and, for a network that starts from the
    measured outputs over the past, ``PAST_MARGIN`` times the past the training data's outputs
    depend on (:func:`~hypa.data.memory.linear_memory`; at most a window), 0 where nothing reads a
    past, said on one line. An auxiliary channel the model reads is held as an input
    (:func:`~hypa.data.from_config.read_as_inputs`), said on one line; ``auxiliary_inputs``: every
    varying auxiliary channel held as an input too (the diagnosis). The files are read once (a chosen
    past: :meth:`~hypa.data.HypaDataModule.with_past`); ``cfg`` is only read: a run records the choices
    in its configuration (:meth:`ModelData.recorded`)."""
    from hypa.data.from_config import read_as_inputs
    from hypa.data.memory import linear_memory
    from hypa.models import ComposedModel
    from hypa.models.composed import PAST_MARGIN

    promoted = tuple(read_as_inputs(cfg.data, spec))
    if promoted:
        print(f"data: {', '.join(promoted)} declared auxiliary, read by the model as input(s): held as input(s)",
              flush=True)
    dm = datamodule_from_config(cfg.data, data_dir, auxiliary_inputs=auxiliary_inputs, as_inputs=promoted)
    dm.setup()
    if cfg.data.past is not None:
        dm.release_files()
        return ModelData(dm, None, promoted)
    model = ComposedModel.from_data(dm, spec, physical_values)
    past, reasons = model.suggested_past(), []
    for name, n in model.past_needed().items():
        reasons.append(f"block {name!r} estimates its {model.blocks[name].model.n_states} states from the "
                       f"outputs it observes, {n + 1} sample(s) at least")
    networks = model.networks_reading_outputs()
    if networks:
        memory = linear_memory(dm.records("train"), (*dm.input_names, *dm.scheduling_names), dm.output_names,
                               int(cfg.data.window))
        past = max(past, min(PAST_MARGIN * memory.samples - 1, int(cfg.data.window)))
        which = f"network {networks[0]!r} starts" if len(networks) == 1 else \
            f"networks {', '.join(repr(n) for n in networks)} start"
        reasons.append(f"{which} from the measured outputs over the past, and a linear predictor of the next output "
                       f"on the training data needs {memory.samples} past sample(s) (its order by BIC; "
                       f"{PAST_MARGIN}x that, at most a window)")
    if past:
        print(f"data.past: {past} samples before each window ({past * dm.dt:.3g} s), chosen for the model: "
              + "; ".join(reasons) + "; set data.past to choose", flush=True)
        dm = dm.with_past(past)  # the files read once: only the records' selection and normalization again
    dm.release_files()
    return ModelData(dm, past, promoted)


def data_overrides(overrides: Sequence[str]) -> list[str]:
    """The command-line overrides that choose the data and the vehicle (``dataset``, ``data``,
    ``testbench``, ``vehicle`` groups and their keys): what ``hypa train`` needs to see the same data."""
    groups = ("dataset", "data", "testbench", "vehicle")
    return [o for o in overrides if o.lstrip("+~").split("=", 1)[0].split(".", 1)[0] in groups]


def user_config_dirs() -> list[Path]:
    """The folders given with ``--config-dir`` (a user's own datasets, models, systems' configs)."""
    from hydra.core.hydra_config import HydraConfig

    return [Path(s.path.removeprefix("file://")) for s in HydraConfig.get().runtime.config_sources
            if s.provider == "command-line" and s.schema == "file"]


def network_settings(node: Any) -> tuple[str, dict[str, Any]]:
    """The ``ann`` node: the network's name (see :func:`network_name`) and its arguments, checked."""
    hparams = dict(OmegaConf.to_container(node, resolve=True) if OmegaConf.is_config(node) else node)
    name = network_name(str(hparams.pop("name")), hparams.pop("_target_", None))
    check_ann_settings(name, hparams)
    return name, hparams


def network_name(name: str, target: Any) -> str:
    """The network of ``ann``: its config name where ``_target_`` is that name's block (``lstm``), else
    the ``_target_`` itself, the import path of a network of the user's own (``mypkg.nets.MyBlock``)."""
    from hypa.ann import ANN_BLOCKS, network_class

    if target is None:
        return name
    with settings(f"ann._target_={target}"):
        cls = network_class(str(target))
    return name if ANN_BLOCKS.get(name) is cls else str(target)


def check_ann_settings(name: str, hparams: dict[str, Any]) -> None:
    """Check the network settings ``ann=name``: a number where the network's default is one,
    then the network built alone from them (tiny sizes in and out), so that its own checks (a
    size < 1, heads that do not divide the width, an unknown name or key) report the user's
    values rather than failing deep inside the model built around them. Converts in place."""
    from hypa.ann import ann_hyperparameters, build_ann

    with settings(f"ann={name}"):
        defaults = ann_hyperparameters(name)
    for key, default in defaults.items():
        if key in hparams and isinstance(default, (int, float)) and not isinstance(default, bool):
            hparams[key] = checked(f"ann.{key}", hparams[key], type(default), optional=True)  # null: network_defaults
    with settings(f"ann={name}"):
        build_ann(name, 1, 1, **{k: v for k, v in hparams.items() if v is not None})


def user_callbacks(nodes: Mapping[str, Any]) -> list[L.Callback]:
    """The Lightning callbacks of ``callbacks`` (name -> ``_target_`` config), built by ``instantiate``."""
    from hydra.utils import instantiate

    built = []
    for name, node in (nodes or {}).items():
        with settings(f"callbacks.{name}"):
            callback = instantiate(node)
        if not isinstance(callback, L.Callback):
            raise UserError(f"callbacks.{name}: {type(callback).__name__} is not a lightning Callback")
        built.append(callback)
    return built


def flat_hparams(tree: Any, prefix: str = "") -> dict[str, Any]:
    """Nested config -> {'a/b': value} with scalars only (what TensorBoard's hparams take)."""
    if isinstance(tree, dict):
        return {k: v for key, sub in tree.items() for k, v in flat_hparams(sub, f"{prefix}{key}/").items()}
    if isinstance(tree, (int, float, str, bool)) or tree is None:
        return {prefix.rstrip("/"): "null" if tree is None else tree}
    return {prefix.rstrip("/"): str(tree)}


def from_cwd(path: str | Path) -> Path:
    """A path given on the command line, relative to where the command was run (``~`` expanded)."""
    from hydra.utils import get_original_cwd

    path = Path(str(path)).expanduser()
    return path if path.is_absolute() else Path(get_original_cwd()) / path
