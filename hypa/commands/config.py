"""The commands' configurations as typed trees: one structured config (dataclasses) per command.

Each ``conf/<command>.yaml`` extends its schema through its defaults list
(``defaults: [/hypa/<command>_schema, ..., _self_]``, Hydra's "extending a structured config"),
so a misspelt key (``trainer.max_epoch=3``, ``model.blocks.x.inptus=[u]``, in a file or an
override) and a value of the wrong type (``trainer.max_epochs=abc``) fail while Hydra composes,
in one line (:func:`hypa.core.errors.one_line`). The ranges (``optimizer.lr=-1``, ``physics.hold=xyz``)
are checked in ``__post_init__``, when a command turns its node into the typed object:
``config: TrainConfig = OmegaConf.to_object(cfg)``; the messages name the override to fix.

The nodes another schema owns are typed by it: ``data`` (:class:`hypa.data.schema.DataConfig`),
``model`` (:class:`hypa.models.schema.ModelConfig`). Nodes whose keys belong to someone else stay
open (``Any``): ``ann`` (each network's own arguments, checked by building it), ``vehicle`` (empty
for a system without one), ``testbench`` (:class:`hypa.paper.testbench.config.TestbenchConfig`
checks it when the data are built), and the ``_target_`` nodes ``early_stopping``, ``logger``,
``callbacks`` (any argument of their class).

:func:`register_configs` stores the schemas in Hydra's ConfigStore and registers the resolvers the
configurations use (``${run_name:...}``, ``${channels:...}``); it must run before Hydra composes a
command's configuration, and importing a module does not run it: each command's ``main`` calls it
(:func:`hydra_command`), and so does any other code that composes (``hydra.compose``, a test).
"""

from __future__ import annotations

import copy
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from omegaconf import MISSING, DictConfig, ListConfig, OmegaConf, open_dict

from hypa.core.errors import UserError, checked, settings
from hypa.core.errors import hydra_command as _hydra_command
from hypa.data.schema import DataConfig
from hypa.models.schema import ModelConfig
from hypa.physics.discretization import HOLDS
from hypa.training.baseline import BUDGETS, NETWORK_LR, PHYSICS_LR

if TYPE_CHECKING:
    from hypa.identification import IdentificationSettings

SCHEMA_GROUP = "hypa"  # /hypa/<command>_schema, beside /hypa/data_schema
C = TypeVar("C")


def trust_list(key: str, value: Any) -> list[str]:
    """``trust``: the import paths (``mypkg.motors:DCMotor``, ``mypkg.nets.MyBlock``) or packages
    (``mypkg``) whose code a run folder, checkpoint or model file may name, and the FMU files (or folders
    above them) it may run (:mod:`hypa.core.trust`); ``*``: any."""
    from hypa.core.trust import is_file_path

    items = [value] if isinstance(value, str) else list(value or [])
    for item in items:
        if not isinstance(item, str) or not (is_file_path(item) or
                                             re.fullmatch(r"\*|[A-Za-z_][\w.]*(:[A-Za-z_][\w.]*)?", item)):
            raise UserError(f"{key}={item} is not an import path (package.module:Class), a package name or the "
                            "path of an FMU or a folder")
    return [str(i) for i in items]


@dataclass
class HoldConfig:
    """``physics`` of the commands that simulate a physics model as it is: its hold.

    ``None`` (the default): the model's own ``hold:``, else the command's default (``zoh``;
    ``foh`` for hypa diagnose). A hold given here that contradicts the model's own is refused in
    one line (:func:`hypa.models.building.model_hold`): the hold belongs to the model.
    """

    hold: str | None = None  # zoh (as the paper) | foh | None: the model's, else the command's default

    def __post_init__(self) -> None:
        checked("physics.hold", self.hold, str, choices=HOLDS, optional=True)


@dataclass
class PhysicsConfig(HoldConfig):
    """``physics`` of hypa train: the hold and the lifted horizon."""

    horizon: int | None = None  # lifted steps per matrix product; None: the window

    def __post_init__(self) -> None:
        super().__post_init__()
        checked("physics.horizon", self.horizon, int, optional=True, minimum=1)


@dataclass
class OptimizerConfig:
    """``optimizer``: NAdam's learning rates and the networks' weight decay."""

    lr: float = NETWORK_LR  # networks
    physics_lr: float = PHYSICS_LR  # trainable physical parameters (log space)
    weight_decay: float | None = None  # None: hypa.training.baseline.network_defaults

    def __post_init__(self) -> None:
        checked("optimizer.lr", self.lr, float, positive=True)
        checked("optimizer.physics_lr", self.physics_lr, float, positive=True)
        checked("optimizer.weight_decay", self.weight_decay, float, optional=True, minimum=0.0)


@dataclass
class IdentificationConfig:
    """``identification``: physical parameters fitted by their free-run output error."""

    enabled: bool = True
    stretch_s: float | None = None  # [s] None: single shooting
    max_evaluations: int | None = None
    tolerance: float = 1.0e-8
    resolution: float | None = 0.01
    max_seconds: float | None = None
    start: str | None = None  # a hypa train run folder whose identified values start this identification

    def __post_init__(self) -> None:
        checked("identification.start", self.start, str, optional=True)
        if self.start is not None and not self.start.strip():
            raise UserError("identification.start is empty: give a hypa train run folder, or null")
        checked("identification.stretch_s", self.stretch_s, float, optional=True, positive=True)
        checked("identification.max_evaluations", self.max_evaluations, int, optional=True, minimum=1)
        checked("identification.tolerance", self.tolerance, float, positive=True)
        checked("identification.resolution", self.resolution, float, optional=True, positive=True)
        checked("identification.max_seconds", self.max_seconds, float, optional=True, positive=True)

    def settings(self) -> IdentificationSettings | None:
        """The identification's settings; ``None`` when it is not enabled."""
        from hypa.identification import IdentificationSettings

        if not self.enabled:
            return None
        with settings("identification"):
            return IdentificationSettings(stretch_s=self.stretch_s, max_evaluations=self.max_evaluations,
                                          tolerance=self.tolerance, resolution=self.resolution,
                                          max_seconds=self.max_seconds)


@dataclass
class TrainerConfig:
    """``trainer``: passed to ``lightning.Trainer`` as given (its own errors name ``trainer``)."""

    max_epochs: int | None = None  # per stage; None: hypa.training.baseline.network_defaults
    accelerator: str = "auto"
    strategy: str = "auto"  # ddp, ... (several processes)
    devices: Any = 1  # a number, a list of devices or auto
    num_nodes: int = 1
    precision: Any = "32-true"
    gradient_clip_val: float | None = 1.0
    log_every_n_steps: int = 20
    limit_train_batches: Any = 1.0  # a share (float) or a number of batches (int)
    limit_val_batches: Any = 1.0
    enable_progress_bar: bool = True
    deterministic: Any = False  # true, false or warn

    def __post_init__(self) -> None:
        checked("trainer.max_epochs", self.max_epochs, int, optional=True, minimum=1)
        checked("trainer.num_nodes", self.num_nodes, int, minimum=1)


@dataclass
class FiguresConfig:
    """``figures``: TensorBoard figures each validation epoch."""

    enabled: bool = True
    seconds: float = 30.0  # [s] validation stretch shown, free-running
    start_s: float = 10.0  # [s]
    every_n_epochs: int = 1

    def __post_init__(self) -> None:
        checked("figures.seconds", self.seconds, float, positive=True)
        checked("figures.start_s", self.start_s, float, minimum=0.0)
        checked("figures.every_n_epochs", self.every_n_epochs, int, minimum=1)


@dataclass
class TrainConfig:
    """``conf/train.yaml``: ``hypa train``."""

    model: ModelConfig = field(default_factory=ModelConfig)
    ann: dict[str, Any] = field(default_factory=dict)  # name, _target_ and the network's own arguments
    vehicle: Any = None
    testbench: Any = None
    data: DataConfig = field(default_factory=DataConfig)
    seed: int = 0
    budget: str = "short"  # the networks' epoch budget and patience where null: short | full (hypa.training.baseline)
    table1_row: str | None = None
    torch_threads: int = 1
    ckpt_path: str | None = None
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    optimizer: OptimizerConfig = field(default_factory=OptimizerConfig)
    identification: IdentificationConfig = field(default_factory=IdentificationConfig)
    trainer: TrainerConfig = field(default_factory=TrainerConfig)
    early_stopping: dict[str, Any] = field(default_factory=dict)  # _target_: a Lightning EarlyStopping
    callbacks: dict[str, Any] = field(default_factory=dict)  # name -> {_target_: ..., its arguments}
    logger: dict[str, Any] = field(default_factory=dict)  # _target_: a Lightning logger
    figures: FiguresConfig = field(default_factory=FiguresConfig)
    model_file: str | None = None  # a model YAML read as data (a diagnosis's diagnosed.yaml): replaces model
    trust: list[str] = field(default_factory=list)  # import paths a model file or a resumed checkpoint may name

    def __post_init__(self) -> None:
        self.trust = trust_list("trust", self.trust)
        checked("torch_threads", self.torch_threads, int, minimum=1)
        checked("budget", self.budget, str, choices=tuple(BUDGETS))
        self.patience: int | None = checked("early_stopping.patience", self.early_stopping.get("patience"), int,
                                            optional=True, minimum=0)  # None: see network_defaults
        self.min_delta: float = checked("early_stopping.min_delta", self.early_stopping.get("min_delta", 0.0),
                                        float, minimum=0.0)

    @property
    def horizon(self) -> int:
        """Lifted steps per matrix product: ``physics.horizon``, or the window."""
        return self.physics.horizon or self.data.window


@dataclass
class DiagnosisConfig:
    """``diagnosis``: how candidate causes are searched and scored."""

    catalogue: list[str] = field(default_factory=list)  # the user's catalogue files
    max_causes: int = 8
    min_gain: float = 0.15
    workers: int | None = None  # None: one per core (at most 4)
    stretch_s: float | None = None  # [s] None: from the nominal model's time scales
    fit_seconds: float | None = None  # [s] None: no cap (the search is budgeted in work, not seconds)

    def __post_init__(self) -> None:
        checked("diagnosis.max_causes", self.max_causes, int, minimum=0)
        checked("diagnosis.min_gain", self.min_gain, float, minimum=0.0)
        checked("diagnosis.workers", self.workers, int, optional=True, minimum=1)
        checked("diagnosis.stretch_s", self.stretch_s, float, optional=True, positive=True)
        checked("diagnosis.fit_seconds", self.fit_seconds, float, optional=True, positive=True)


@dataclass
class ExtensionConfig:
    """``extension``: the extended model hypa diagnose writes, trained now or not."""

    train: bool = False
    train_overrides: list[str] = field(default_factory=list)


@dataclass
class DiagnoseConfig:
    """``conf/diagnose.yaml``: ``hypa diagnose``."""

    vehicle: Any = None
    testbench: Any = None
    data: DataConfig = field(default_factory=DataConfig)
    model: ModelConfig | None = None  # the nominal model; None: none given
    physics: HoldConfig = field(default_factory=HoldConfig)  # None: the model's hold, else foh
    diagnosis: DiagnosisConfig = field(default_factory=DiagnosisConfig)
    extension: ExtensionConfig = field(default_factory=ExtensionConfig)
    plot: bool = True


@dataclass
class SimulateConfig:
    """``conf/simulate.yaml``: ``hypa simulate``."""

    vehicle: Any = None
    testbench: Any = None
    data: DataConfig = field(default_factory=DataConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    physics: HoldConfig = field(default_factory=HoldConfig)
    plot: bool = True


@dataclass
class EvaluateConfig:
    """``conf/evaluate.yaml``: ``hypa evaluate``."""

    run: str = MISSING  # a hypa train run folder or one of its checkpoints
    out: str | None = None  # None: <run>/evaluation
    tensorboard: bool = True
    trust: list[str] = field(default_factory=list)  # import paths the run's model may name (hypa.core.trust)

    def __post_init__(self) -> None:
        self.trust = trust_list("trust", self.trust)


@dataclass
class ExportConfig:
    """``conf/export.yaml``: ``hypa export``."""

    run: str = MISSING  # a hypa train run folder or one of its checkpoints
    format: str = "onnx"  # onnx | fmu | c (native C FMU) | statespace (physics-only) | all (every format allowed)
    record: int = 0  # the validation record of reference.csv and the check
    tolerance: float = 1e-5  # of each output's standard deviation
    trust: list[str] = field(default_factory=list)  # import paths the run's model may name (hypa.core.trust)

    def __post_init__(self) -> None:
        self.trust = trust_list("trust", self.trust)
        checked("record", self.record, int, minimum=0)
        checked("tolerance", self.tolerance, float, positive=True)


@dataclass
class ExplainConfig:
    """``conf/explain.yaml``: ``hypa explain``."""

    run: str = MISSING
    block: str | None = None  # None: every ANN block
    baseline: str | None = None
    extra: Any = None  # one signal or a list; None: the measured outputs and scheduling channels
    penalty: float = 0.002
    margin: float = 0.005
    max_lag: float = 2.0  # [s]
    max_delay: float = 0.25  # [s]
    plot: bool = True
    trust: list[str] = field(default_factory=list)  # import paths the runs' models may name (hypa.core.trust)

    def __post_init__(self) -> None:
        self.trust = trust_list("trust", self.trust)
        for key in ("penalty", "margin", "max_lag", "max_delay"):
            checked(key, getattr(self, key), float)
        if self.extra is not None:
            self.extra = tuple(str(n) for n in ([self.extra] if isinstance(self.extra, str) else self.extra))


@dataclass
class ReproduceConfig:
    """``conf/reproduce.yaml``: ``hypa reproduce``."""

    rows: Any = field(default_factory=list)  # conf/row/ names; one name alone: rows=v2
    seeds: Any = field(default_factory=lambda: [0, 1, 2])  # a list or one seed
    n_jobs: int = 2
    out: str = "results"
    skip_training: bool = False
    train_overrides: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.rows = [str(r) for r in self.rows] if isinstance(self.rows, (list, tuple)) else [str(self.rows)]
        self.seeds = ([checked(f"seeds.{i}", s, int) for i, s in enumerate(self.seeds)]
                      if isinstance(self.seeds, (list, tuple)) else [checked("seeds", self.seeds, int)])
        checked("n_jobs", self.n_jobs, int, minimum=1)


@dataclass
class SuiteConfig:
    """A data set's benchmark suite: model label -> hypa train overrides, published figures."""

    diagnose: str | None = None  # the nominal model hypa diagnose extends into model=diagnosed(_hybrid)
    models: dict[str, list[str]] = field(default_factory=dict)
    published: dict[str, Any] = field(default_factory=dict)  # test set -> output -> figure


@dataclass
class BenchmarkConfig:
    """``conf/benchmark.yaml``: ``hypa benchmark``."""

    vehicle: Any = None
    testbench: Any = None
    data: DataConfig = field(default_factory=DataConfig)
    budget: str = "quick"
    models: list[str] | None = None  # None: the suite's
    seeds: list[int] = field(default_factory=lambda: [0])
    train_overrides: list[str] = field(default_factory=list)
    diagnose: str | None = None  # the nominal model whose hypa diagnose extension model=diagnosed(_hybrid) trains
    budgets: dict[str, list[str]] = field(default_factory=dict)
    suites: dict[str, SuiteConfig] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.budgets and self.budget not in self.budgets:
            raise UserError(f"unknown budget={self.budget}; use {' or '.join(self.budgets)}")
        if not self.seeds or len(set(self.seeds)) != len(self.seeds):
            raise UserError(f"seeds must name at least one seed, each once; got {list(self.seeds)}")


@dataclass
class TestbenchCommandConfig:
    """``conf/testbench.yaml``: ``hypa testbench``."""

    __test__ = False  # not a pytest test class

    testbench: Any = None  # hypa.paper.testbench.config.TestbenchConfig
    out: str | None = None  # None: the cache
    cache_dir: str | None = None
    plot: bool = False
    plot_record: str = "val"


SCHEMAS: dict[str, type] = {
    "train": TrainConfig, "diagnose": DiagnoseConfig, "simulate": SimulateConfig, "evaluate": EvaluateConfig,
    "explain": ExplainConfig, "reproduce": ReproduceConfig, "benchmark": BenchmarkConfig,
    "testbench": TestbenchCommandConfig, "export": ExportConfig,
}


def run_name(model: str, ann: str, blocks: Any, model_file: str | None = None) -> str:
    """``${run_name:...}``: the folder name of a training run, the model and its network where it has
    one (``model_file``: the model that file holds; its own checks come when the run reads it)."""
    if model_file:
        from hypa.core.trust import read_yaml

        try:
            read = read_yaml(Path(model_file).expanduser())
            model, blocks = str(read.get("name", Path(model_file).stem)), read.get("blocks")
        except Exception:  # noqa: BLE001 -- a folder name only: the run reads the file and names what is wrong
            model, blocks = Path(str(model_file)).stem, None
    has_ann = any(hasattr(b, "get") and b.get("kind") == "ann" for b in (blocks or {}).values())  # dict or DictConfig
    name = f"{model}-{ann}" if has_ann else model
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name)[:100] or "model"


def channels(*roles: str, _root_: DictConfig) -> ListConfig:
    """``${channels:input,scheduling}``: the data set's channels with these roles, in declared order
    (so one model YAML, e.g. ``blackbox``, serves every data set). A ``ListConfig``, not a list: where
    the configuration is resolved in place (``hypa train --cfg job --resolve``) OmegaConf puts a
    container into the model's open (``Any``) node, but refuses a plain list there."""
    return ListConfig([name for name, c in _root_.data.channels.items() if c.role in roles])


RESOLVERS: dict[str, Callable[..., Any]] = {"run_name": run_name, "channels": channels}


def register_configs() -> None:
    """What Hydra needs before it composes a command's configuration: the schemas in its ConfigStore,
    ``/hypa/<command>_schema`` (package ``_global_``, the root of ``conf/<command>.yaml``) and
    ``/hypa/data_schema`` (the datasets' ``data`` node), and the resolvers :data:`RESOLVERS`.
    Idempotent, and cheap once done: the schemas are stored again only where one is missing."""
    from hydra.core.config_store import ConfigStore

    from hypa.data.schema import SCHEMA_NAME as DATA_SCHEMA
    from hypa.data.schema import register_configs as register_data_schema

    store = ConfigStore.instance()
    stored = store.repo.get(SCHEMA_GROUP, {})
    if not all(f"{name}.yaml" in stored for name in (DATA_SCHEMA, *(f"{command}_schema" for command in SCHEMAS))):
        register_data_schema()
        for command, schema in SCHEMAS.items():
            store.store(group=SCHEMA_GROUP, name=f"{command}_schema", node=schema, package="_global_")
    for name, resolver in RESOLVERS.items():
        OmegaConf.register_new_resolver(name, resolver, replace=True)


def hydra_command(command: str, config_name: str) -> Callable[[Callable[[Any], Any]], Callable[..., int]]:
    """``@hydra_command("hypa train", "train")`` on a command's job: :func:`hypa.core.errors.hydra_command`
    with :func:`register_configs` before Hydra composes (a launcher's workers get what it registered with
    Hydra's state)."""
    return _hydra_command(command, config_name, before=register_configs)


def model_node(cfg: DictConfig) -> dict[str, Any]:
    """The composed ``model`` node as a plain model mapping (``plain_model``), its FMU blocks' relative
    paths resolved against the config directories Hydra read (their ``model/`` folder first: where the
    model YAML is), else against the working directory."""
    from hypa.models.schema import plain_model

    node = plain_model(OmegaConf.to_container(cfg.model, resolve=True))
    for block in (node.get("blocks") or {}).values():
        if isinstance(block, dict) and isinstance(block.get("fmu"), str) and not Path(block["fmu"]).is_absolute():
            block["fmu"] = str(_config_file(block["fmu"]))
    return node


def _config_file(relative: str) -> Path:
    """``relative`` in the first file-based config directory of this Hydra run that holds it (or its
    ``model/`` folder), else in the working directory."""
    from hydra.core.hydra_config import HydraConfig

    sources = HydraConfig.get().runtime.config_sources if HydraConfig.initialized() else []
    folders = [Path(source.path) for source in sources if source.schema == "file" and source.path]
    for folder in folders:
        for candidate in (folder / "model" / relative, folder / relative):
            if candidate.is_file():
                return candidate.resolve()
    return Path(relative).resolve()


def typed(cfg: DictConfig, schema: type[C]) -> C:
    """A command's composed configuration as its typed object (``OmegaConf.to_object``): every value
    checked (the schemas' ``__post_init__``) before the command reads any data. A ``hydra`` node
    (``compose(..., return_hydra_config=True)``, as tests compose) is left out."""
    if "hydra" in cfg:
        cfg = copy.deepcopy(cfg)
        with open_dict(cfg):
            del cfg["hydra"]
    config = OmegaConf.to_object(cfg)
    if not isinstance(config, schema):
        raise TypeError(f"the configuration is a {type(config).__name__}, not a {schema.__name__}: does its "
                        f"defaults list start with /{SCHEMA_GROUP}/<command>_schema?")
    return config
