"""A user's own simulator as physics: an FMI 2.0 or 3.0 FMU, model exchange or co-simulation, run with fmpy.

``read_fmu`` reads what an FMU declares (its Real inputs, outputs, parameters with their units and
bounds, its continuous states and what it offers), bounding the sizes before anything is read or
extracted. ``FMUSimulator`` runs it on a data grid t_k = t_0 + k dt:

* **model exchange**: hypa integrates the FMU's derivatives from sample to sample with the classic
  Runge-Kutta method (order 4), its inputs held as the block's hold says (zero order: u_k over
  [t_k, t_k+1); first order: the line from u_k to u_k+1). The substep comes from the model: the
  spectral radius ρ of the state Jacobian at the start (the FMU's directional derivatives where it
  provides them, else forward differences of its derivatives) and the local error (ρ h)^5 / 120
  of the method held below ``LOCAL_ERROR``. The start state is set (``fmi2SetContinuousStates``).
  Each sample ends a completed integrator step (``fmi2CompletedIntegratorStep``), and the event
  indicators are watched: a change of sign (a state event), or the FMU asking for event mode, stops
  the run in one line with the time;
* **co-simulation**: the FMU steps itself, ``fmi2DoStep(t_k, dt)`` with the inputs of sample k
  (a first-order hold by ``fmi2SetRealInputDerivatives`` where the FMU can interpolate inputs; FMI 3.0
  has no input derivatives). A start state is set before its initialization where the FMU lets it (the
  state variables it declares, initial exact or approx), else the FMU's own initialization stands, said
  in one line.

FMI 3.0 runs the same way through ``hypa.physics.fmu_instance`` (its Float64 variables are the Real
ones). The outputs of sample k are read after its inputs are set, from the state at t_k (direct
feedthrough, as FMI means it). What this does not handle is refused in one line: state and time
events in model exchange, FMI 1.0, arrays and clocks of FMI 3.0.
"""

from __future__ import annotations

import contextlib
import ctypes
import dataclasses
import functools
import logging
import math
import os
import shutil
import tempfile
import weakref
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hypa.core.errors import UserError
from hypa.physics.parameters import ParameterSpec

log = logging.getLogger(__name__)

MAX_DESCRIPTION_BYTES = 64 * 2**20  # modelDescription.xml
MAX_FMU_BYTES = 2 * 2**30  # everything in the FMU, uncompressed
LOCAL_ERROR = 1e-9  # RK4's local error (ρ h)^5 / 120 per substep, relative to the state
INTERFACES = ("auto", "model_exchange", "co_simulation")


class FMUError(UserError):
    """An FMU that cannot be read or run as a physics block (said in one line)."""


@dataclass(frozen=True)
class FMUVariable:
    """One Real variable of an FMU: its name, value reference, causality, unit ('' where none), start
    value (None where none) and bounds."""

    name: str
    reference: int
    causality: str
    variability: str
    unit: str = ""
    start: float | None = None
    minimum: float | None = None
    maximum: float | None = None
    initial: str | None = None
    description: str = ""


@dataclass(frozen=True)
class FMUDescription:
    """What an FMU declares: ``exchange`` / ``cosimulation`` (the model identifiers, None where the FMU
    lacks the interface), its Real ``inputs``, ``outputs``, ``parameters`` (causality parameter,
    variability fixed or tunable), continuous ``states`` with their ``derivatives`` (same order)."""

    path: Path
    name: str
    guid: str  # FMI 3.0's instantiationToken
    exchange: str | None
    cosimulation: str | None
    inputs: tuple[FMUVariable, ...]
    outputs: tuple[FMUVariable, ...]
    parameters: tuple[FMUVariable, ...]
    states: tuple[FMUVariable, ...]
    derivatives: tuple[FMUVariable, ...]
    event_indicators: int
    directional: dict[str, bool]  # interface -> provides directional derivatives
    interpolates_inputs: bool  # co-simulation: canInterpolateInputs
    step: float | None  # DefaultExperiment stepSize
    version: int = 2  # the FMI version: 2 or 3

    @property
    def input_names(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.inputs)

    @property
    def output_names(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.outputs)

    @property
    def state_names(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.states)

    def parameter_specs(self, given: Mapping[str, float] | None = None) -> list[ParameterSpec]:
        """Its parameters as hypa's ``ParameterSpec`` (value: ``given``, else the FMU's start; bounds: its
        min and max)."""
        given = dict(given or {})
        unknown = sorted(set(given) - {p.name for p in self.parameters})
        if unknown:
            raise FMUError(f"FMU {self.path.name}: {unknown} are not its Real parameters; it has "
                           f"{', '.join(p.name for p in self.parameters) or 'none'}")
        specs = []
        for p in self.parameters:
            if p.start is None and p.name not in given:
                raise FMUError(f"FMU {self.path.name}: parameter {p.name!r} has no start value; give it in the "
                               "block's parameters")
            bounds = (p.minimum, p.maximum) if p.minimum is not None and p.maximum is not None else None
            start = float(p.start if p.start is not None else given[p.name])
            positive = bounds is None and p.minimum is not None and p.minimum >= 0 and start > 0  # as it declares
            try:  # a value given with a unit ("2.5 Ah") converted to the FMU's, as a class's
                spec = ParameterSpec(p.name, start, p.unit, positive=positive, bounds=bounds)
                spec = dataclasses.replace(spec, value=given[p.name]) if p.name in given else spec
            except (ValueError, TypeError) as error:
                raise FMUError(f"FMU {self.path.name}: parameter {p.name!r}: {error}") from None
            if not math.isfinite(spec.value):
                raise FMUError(f"FMU {self.path.name}: parameter {p.name!r} is {spec.value}; give a finite value")
            specs.append(spec)
        return specs

    def interface(self, wanted: str = "auto") -> str:
        """``model_exchange`` or ``co_simulation``: the one asked for, else model exchange where the FMU has
        it, continuous states to integrate and no event indicators, else co-simulation where it has it (a
        discrete-time FMU, hypa's own ``native.fmu`` among them, steps itself; one with state events handles
        them itself). Model exchange with event indicators runs while none changes sign (refused where one
        does, with the time)."""
        if wanted not in INTERFACES:
            raise FMUError(f"interface={wanted} is not one of {', '.join(INTERFACES)}")
        have = {"model_exchange": self.exchange is not None, "co_simulation": self.cosimulation is not None}
        if wanted != "auto":
            if not have[wanted]:
                raise FMUError(f"FMU {self.path.name} has no {wanted.replace('_', ' ')} interface")
            return wanted
        if have["model_exchange"] and not ((self.event_indicators or not self.states) and have["co_simulation"]):
            return self.interface("model_exchange")
        return self.interface("co_simulation")


def _real(variable) -> FMUVariable:
    number = lambda v: None if v in (None, "") else float(v)  # noqa: E731
    return FMUVariable(variable.name, int(variable.valueReference), str(variable.causality),
                       str(variable.variability), variable.unit or "", number(variable.start),
                       number(variable.min), number(variable.max), variable.initial, variable.description or "")


def read_fmu(path: Path | str) -> FMUDescription:
    """What the FMU at ``path`` declares; ``FMUError`` in one line for what hypa cannot run. Read once per
    process while the file stays the same (its size and modification time)."""
    path = Path(path)
    if not path.is_file():
        raise FMUError(f"FMU {path}: no such file")
    stat = path.stat()  # a file replaced keeps neither its inode nor its change time
    return _read_fmu(path.resolve(), (stat.st_size, stat.st_mtime_ns, stat.st_ctime_ns, stat.st_ino))


@functools.lru_cache(maxsize=64)
def _read_fmu(path: Path, version: tuple[int, ...]) -> FMUDescription:
    from fmpy import read_model_description

    try:
        with zipfile.ZipFile(path) as archive:
            entries = archive.infolist()
    except (zipfile.BadZipFile, OSError) as error:
        raise FMUError(f"FMU {path}: not a zip archive ({error})") from None
    sizes = {e.filename: e.file_size for e in entries}
    if "modelDescription.xml" not in sizes:
        raise FMUError(f"FMU {path}: no modelDescription.xml")
    if sizes["modelDescription.xml"] > MAX_DESCRIPTION_BYTES or sum(sizes.values()) > MAX_FMU_BYTES:
        raise FMUError(f"FMU {path}: {sum(sizes.values()) / 2**20:.0f} MiB uncompressed, its model description "
                       f"{sizes['modelDescription.xml'] / 2**20:.1f} MiB: more than hypa reads "
                       f"({MAX_FMU_BYTES / 2**30:.0f} GiB, {MAX_DESCRIPTION_BYTES / 2**20:.0f} MiB)")
    try:
        model = read_model_description(str(path), validate=True)
    except Exception as error:  # noqa: BLE001 -- fmpy's own parse and validation errors, in one line
        raise FMUError(f"FMU {path}: its model description cannot be read ({str(error).splitlines()[0][:200]})") \
            from None
    version = str(model.fmiVersion)
    if not version.startswith(("2.", "3.")):
        raise FMUError(f"FMU {path} is FMI {version}; hypa runs FMI 2.0 and 3.0 FMUs")
    reals = [v for v in model.modelVariables if v.type in ("Real", "Float64") and not getattr(v, "dimensions", None)]
    pick = lambda causality: tuple(_real(v) for v in reals if v.causality == causality)  # noqa: E731
    parameters = tuple(_real(v) for v in reals if v.causality == "parameter" and v.variability in ("fixed", "tunable"))
    derivatives = [u.variable for u in model.derivatives]
    shaped = [v.name for d in derivatives for v in (d, d.derivative) if getattr(v, "dimensions", None)]
    if shaped:  # an array state's elements would not be counted: refused before anything else reads them
        raise FMUError(f"FMU {path}: its continuous state {shaped[0]!r} is an array; hypa runs FMUs with scalar "
                       "states")
    exchange, cosim = model.modelExchange, model.coSimulation
    flag = lambda interface, name: bool(interface) and str(getattr(interface, name, False)).lower() in ("true", "1")  # noqa: E731
    directional = {"model_exchange": flag(exchange, "providesDirectionalDerivative"),
                   "co_simulation": flag(cosim, "providesDirectionalDerivative")}
    if version.startswith("3."):  # fmpy does not keep FMI 3.0's providesDirectionalDerivatives: read it here
        found = _fmi3_directional(path)
        directional = {"model_exchange": found.get("ModelExchange", False),
                       "co_simulation": found.get("CoSimulation", False)}
    return FMUDescription(
        path=path.resolve(), name=model.modelName, guid=model.guid, version=int(version[0]),
        exchange=exchange.modelIdentifier if exchange else None, cosimulation=cosim.modelIdentifier if cosim else None,
        inputs=pick("input"), outputs=pick("output"), parameters=parameters,
        states=tuple(_real(d.derivative) for d in derivatives), derivatives=tuple(_real(d) for d in derivatives),
        event_indicators=int(model.numberOfEventIndicators or 0),
        directional=directional,
        interpolates_inputs=version.startswith("2.") and flag(cosim, "canInterpolateInputs"),  # none in FMI 3.0
        step=float(model.defaultExperiment.stepSize) if model.defaultExperiment and
        model.defaultExperiment.stepSize else None)


def _fmi3_directional(path: Path) -> dict[str, bool]:
    """FMI 3.0's providesDirectionalDerivatives of each interface element, from the model description (its size
    bounded by ``read_fmu``; entities not resolved, nothing fetched)."""
    from lxml import etree

    with zipfile.ZipFile(path) as archive:
        data = archive.read("modelDescription.xml")
    root = etree.fromstring(data, parser=etree.XMLParser(resolve_entities=False, no_network=True, huge_tree=False))
    return {tag: root.find(tag).get("providesDirectionalDerivatives", "false").lower() in ("true", "1")
            for tag in ("ModelExchange", "CoSimulation") if root.find(tag) is not None}


@dataclass(frozen=True)
class FMURun:
    """A run of an FMU over a grid: outputs y (T, p) [SI], states x (T, n) where the interface shows them
    (model exchange), and whether it started from the given state or its own initialization."""

    y: np.ndarray
    x: np.ndarray | None
    started_from_data: bool
    substeps: int = 1


@dataclass(frozen=True)
class Sensitivities:
    """Per sample k: ∂y_k/∂x_k (T, p, n), ∂y_k/∂u_k (T, p, m), ∂x_k+1/∂x_k (T, n, n), ∂x_k+1/∂u_k (T, n, m),
    ∂x_k+1/∂u_k+1 (T, n, m) (a first-order hold's; zero under a zero-order hold), all SI."""

    y_x: np.ndarray
    y_u: np.ndarray
    x_x: np.ndarray
    x_u: np.ndarray
    x_u_next: np.ndarray

    def input_gradient(self, y_bar: np.ndarray) -> np.ndarray:
        """dL/du (T, m) from dL/dy (T, p) by the adjoint recursion λ_k = y_x_kᵀ ȳ_k + x_x_kᵀ λ_k+1 backwards
        over the record (the start state given: no gradient reaches it)."""
        steps, n = self.x_x.shape[0], self.x_x.shape[1]
        u_bar, after = np.zeros((steps, self.y_u.shape[2])), np.zeros(n)  # λ_k+1
        for k in range(steps - 1, -1, -1):
            u_bar[k] += self.y_u[k].T @ y_bar[k] + self.x_u[k].T @ after
            if k + 1 < steps:
                u_bar[k + 1] += self.x_u_next[k].T @ after
            after = self.y_x[k].T @ y_bar[k] + self.x_x[k].T @ after
        return u_bar


_EXTRACTED: dict[Path, int] = {}  # folders this process (or the one it was forked from) extracted -> by which pid


def _extracted(path: Path) -> Path:
    """The FMU unzipped into a private temporary folder (0700; :func:`_remove` removes it)."""
    from fmpy import extract

    folder = Path(tempfile.mkdtemp(prefix="hypa-fmu-"))
    _EXTRACTED[folder] = os.getpid()
    try:
        extract(str(path), str(folder))
    except BaseException:
        _remove(folder)
        raise
    return folder


def _remove(folder: Path) -> None:
    """An extracted folder removed, by the process that extracted it only: a forked worker that lets
    go of a simulator it inherited leaves the folder to its parent, which still runs from it."""
    if _EXTRACTED.get(folder) == os.getpid():
        shutil.rmtree(folder, ignore_errors=True)
        _EXTRACTED.pop(folder, None)


def remove_extracted_here() -> None:
    """Every folder this process extracted, removed: what a forked worker does before it ends (it
    ends by ``os._exit``, where no finalizer runs; the diagnosis' workers build the candidates'
    FMU blocks themselves)."""
    for folder in [f for f, pid in _EXTRACTED.items() if pid == os.getpid()]:
        _remove(folder)


class FMUSimulator:
    """One instance of an FMU for repeated runs (``run``), on one interface; ``close()`` frees it."""

    def __init__(self, description: FMUDescription, interface: str = "auto", instance: str = "hypa",
                 native: bool | None = None) -> None:
        """``native``: run the sample loops in C (``hypa.physics.fmu_loop``; None: where it compiles here,
        False: the Python loops, the same arithmetic)."""
        from hypa.physics import fmu_loop
        from hypa.physics.fmu_instance import Instance

        self.description, self.interface = description, description.interface(interface)
        identifier = description.exchange if self.interface == "model_exchange" else description.cosimulation
        self.folder = _extracted(description.path)
        self._cleanup = weakref.finalize(self, _remove, self.folder)
        try:
            self.fmu = Instance(description.version, self.interface, description.guid, str(self.folder),
                                identifier or "", instance)
        except Exception as error:  # noqa: BLE001 -- a missing binary for this platform, a failing instantiate
            raise FMUError(f"FMU {description.path.name} cannot be instantiated for {self.interface.replace('_', ' ')}"
                           f" here: {str(error).splitlines()[0][:200]}") from None
        self.n, self.events = len(description.states), description.event_indicators
        self._x = (ctypes.c_double * max(self.n, 1))()
        self._dx = (ctypes.c_double * max(self.n, 1))()
        self._z = (ctypes.c_double * max(self.events, 1))()
        self._fresh = True
        self.native = fmu_loop.available() if native is None else native
        if self.native and not fmu_loop.available():
            raise FMUError("native=True: the FMU block's C loop does not compile here (no cc, gcc or clang)")
        self._loops: dict[tuple[tuple[int, ...], tuple[int, ...]], fmu_loop.FMULoop] = {}

    def _loop(self, inputs: Sequence[int], outputs: Sequence[int]):
        """The C loops for these inputs and outputs (value references), None where they do not run here."""
        if not self.native:
            return None
        from hypa.physics.fmu_loop import FMULoop

        key = (tuple(inputs), tuple(outputs))
        if key not in self._loops:
            self._loops[key] = FMULoop(self.fmu, self.description.version, self.n, list(inputs), list(outputs),
                                       self.events, completed=self.interface == "model_exchange")
        return self._loops[key]

    @contextlib.contextmanager
    def _calls(self, t0: float, dt: float):
        """A failed call of the C loops, or an event that stopped them, as ``FMUError`` in one line with the time."""
        from hypa.physics.fmu_loop import LoopError

        try:
            yield
        except LoopError as error:
            raise self._stopped(error.what, t0 + error.sample * dt) from None

    def _stopped(self, what: str, t: float) -> FMUError:
        return FMUError(f"FMU {self.description.path.name}: at t = {t:g} s, {what}")

    def close(self) -> None:
        self.fmu.close()
        self._cleanup()

    def run(self, parameters: Mapping[str, float], fed: Sequence[str], u: np.ndarray, t0: float, dt: float,
            x0: np.ndarray | None = None, hold: str = "zoh", read: Sequence[str] | None = None) -> FMURun:
        """The FMU over u (T, len(fed)) [SI] on t_k = t0 + k dt from x0 (its states, SI; None: its own
        initialization), ``parameters`` by name [SI]; the inputs not in ``fed`` keep their start values. Every
        output is returned; those of ``read`` (None: all) must stay finite."""
        with self._fmpy_calls():
            run = self._run(parameters, fed, u, t0, dt, x0, hold)
        d = self.description
        columns = [i for i, v in enumerate(d.outputs) if read is None or v.name in read]
        bad = ~np.isfinite(run.y[:, columns]).all(1)
        if bad.any():
            raise FMUError(f"FMU {d.path.name}: its outputs are not finite by t = {t0 + dt * int(np.argmax(bad)):g} s")
        return run

    @contextlib.contextmanager
    def _fmpy_calls(self):
        """A call that fails inside fmpy (the Python loops, the initialization) as ``FMUError`` in one line."""
        from fmpy.fmi1 import FMICallException

        try:
            yield
        except FMICallException as error:
            raise FMUError(f"FMU {self.description.path.name}: {str(error).splitlines()[0][:200]}") from None

    def _run(self, parameters: Mapping[str, float], fed: Sequence[str], u: np.ndarray, t0: float, dt: float,
             x0: np.ndarray | None, hold: str) -> FMURun:
        d = self.description
        refs = {v.name: v.reference for v in (*d.inputs, *d.parameters)}
        self._start(parameters, refs, t0)
        started = self._initialize(x0)
        u = np.asarray(u, dtype=float)
        inputs = [refs[n] for n in fed]
        outputs = [v.reference for v in d.outputs]
        if self.interface == "model_exchange":
            return self._exchange(inputs, outputs, u, t0, dt, hold, started)
        return self._cosimulate(inputs, outputs, u, t0, dt, hold, started)

    def _start(self, parameters: Mapping[str, float], refs: Mapping[str, int], t0: float) -> None:
        if not self._fresh:
            self.fmu.reset()
        self._fresh = False
        self._last_z: np.ndarray | None = None  # the event indicators at the last completed step
        names = [n for n in parameters if n in refs]
        if len(names) != len(parameters):
            raise FMUError(f"FMU {self.description.path.name}: {sorted(set(parameters) - set(names))} are not its "
                           "parameters or inputs")
        if names:
            self.fmu.set_reals([refs[n] for n in names], [float(parameters[n]) for n in names])
        self.fmu.initialize(t0)

    def _initialize(self, x0: np.ndarray | None) -> bool:
        """Leave the initialization; True where the state x0 was set."""
        d, started = self.description, False
        if x0 is not None and self.interface == "co_simulation":
            try:
                self.fmu.set_reals([s.reference for s in d.states], [float(v) for v in x0])
                started = True
            except Exception:  # noqa: BLE001 -- the FMU refuses to set its states: its own initialization
                started = False
        self.fmu.exit_initialization()
        if self.interface == "model_exchange":
            self._events()
            self.fmu.enter_continuous_time_mode()
            if x0 is not None:
                self._x[: self.n] = [float(v) for v in x0]
                self.fmu.set_states(self._x, self.n)
                started = True
        return started

    def _events(self) -> None:
        """The event iteration after the initialization (the FMU is in event mode): refused where the FMU
        schedules time events."""
        while True:
            needed, terminate, timed, at = self.fmu.discrete_states()
            if terminate:
                raise FMUError(f"FMU {self.description.path.name} asked to terminate at its initialization")
            if timed:
                raise FMUError(f"FMU {self.description.path.name} schedules a time event at {at:g} s: hypa integrates "
                               "model exchange without events; use its co-simulation interface")
            if not needed:
                return

    def _derivatives(self, t: float, x: np.ndarray, refs: list[int], u: np.ndarray) -> np.ndarray:
        self.fmu.set_time(t)
        self._x[: self.n] = x.tolist()
        self.fmu.set_states(self._x, self.n)
        if refs:
            self.fmu.set_reals(refs, u.tolist())
        self.fmu.get_derivatives(self._dx, self.n)
        return np.frombuffer(self._dx, dtype=float, count=self.n).copy()

    def jacobian(self, t: float, x: np.ndarray, refs: list[int], u: np.ndarray) -> np.ndarray:
        """∂ẋ/∂x (n, n) at (t, x, u): the FMU's directional derivatives where it provides them, else forward
        differences of its derivatives."""
        d = self.description
        if d.directional[self.interface]:
            self._derivatives(t, x, refs, u)
            unknowns = [v.reference for v in d.derivatives]
            columns = [self.fmu.directional(unknowns, [s.reference], [1.0]) for s in d.states]
            return np.array(columns, dtype=float).T
        base = self._derivatives(t, x, refs, u)
        columns = []
        for j in range(self.n):
            step = math.sqrt(np.finfo(float).eps) * max(abs(x[j]), 1.0)
            moved = x.copy()
            moved[j] += step
            columns.append((self._derivatives(t, moved, refs, u) - base) / step)
        return np.array(columns, dtype=float).T if columns else np.zeros((0, 0))

    def modes(self, parameters: Mapping[str, float], t0: float = 0.0) -> np.ndarray:
        """The eigenvalues [1/s] of the state Jacobian at the FMU's own initial state and input start values
        (model exchange; its time scales, as a class's linear part gives them); empty without states or model
        exchange."""
        with self._fmpy_calls():
            return self._modes(parameters, t0)

    def _modes(self, parameters: Mapping[str, float], t0: float) -> np.ndarray:
        if self.interface != "model_exchange" or not self.n:
            return np.zeros(0, dtype=complex)
        d = self.description
        self._start(parameters, {v.name: v.reference for v in (*d.inputs, *d.parameters)}, t0)
        self._initialize(None)
        self.fmu.get_states(self._x, self.n)
        x = np.frombuffer(self._x, dtype=float, count=self.n).copy()
        return np.linalg.eigvals(self._finite_jacobian(t0, x, [], np.zeros(0)))

    def _finite_jacobian(self, t: float, x: np.ndarray, refs: list[int], u: np.ndarray) -> np.ndarray:
        jacobian = self.jacobian(t, x, refs, u)
        if not np.isfinite(jacobian).all():
            raise FMUError(f"FMU {self.description.path.name}: its state Jacobian is not finite at t = {t:g} s")
        return jacobian

    def substeps(self, t: float, x: np.ndarray, refs: list[int], u: np.ndarray, dt: float) -> int:
        """RK4 substeps per sample: (ρ h)^5 / 120 <= LOCAL_ERROR with ρ the state Jacobian's spectral radius."""
        if not self.n:
            return 1
        radius = float(np.abs(np.linalg.eigvals(self._finite_jacobian(t, x, refs, u))).max())
        longest = (120.0 * LOCAL_ERROR) ** 0.2 / radius if radius > 0 else math.inf
        return max(1, math.ceil(dt / longest)) if math.isfinite(longest) else 1

    def _exchange(self, inputs, outputs, u, t0, dt, hold, started) -> FMURun:
        n, steps = self.n, len(u)
        self.fmu.get_states(self._x, n)
        x = np.frombuffer(self._x, dtype=float, count=n).copy()
        count = self.substeps(t0, x, inputs, u[0] if steps else np.zeros(0), dt)
        loop = self._loop(inputs, outputs)
        if loop is not None:
            with self._calls(t0, dt):
                ys, xs = loop.exchange(u, t0, dt, count, hold == "foh", x)
        else:
            ys, xs = self._exchange_in_python(inputs, outputs, u, t0, dt, hold, x, count)
        return FMURun(ys, xs, started, count)

    def _exchange_in_python(self, inputs, outputs, u, t0, dt, hold, x, count) -> tuple[np.ndarray, np.ndarray]:
        steps = len(u)
        ys, xs = np.empty((steps, len(outputs))), np.empty((steps, self.n))
        for k in range(steps):
            ys[k], xs[k] = self._outputs(t0 + k * dt, x, inputs, u[k], outputs, completed=k > 0), x
            if k + 1 < steps:
                x = self._step(t0 + k * dt, x, inputs, u[k], u[k + 1] if hold == "foh" else u[k], dt, count)
        return ys, xs

    def _outputs(self, t: float, x: np.ndarray, inputs: list[int], u: np.ndarray, outputs: list[int],
                 completed: bool | None = None) -> list:
        """The outputs at (t, x, u) (model exchange). ``completed`` (a free run's sample): True where a step ends
        here (``fmi2/3CompletedIntegratorStep``), False at the first sample; then the event indicators are read
        and a change of sign stops the run, as does the FMU asking for event mode or to terminate."""
        self.fmu.set_time(t)
        if self.n:
            self._x[: self.n] = x.tolist()
            self.fmu.set_states(self._x, self.n)
        if inputs:
            self.fmu.set_reals(inputs, u.tolist())
        if completed is not None:
            self._completed(t, completed)
        return self.fmu.get_reals(outputs)

    def _completed(self, t: float, step: bool) -> None:
        """A free run's sample: the step completed (where ``step``), the event indicators watched."""
        from hypa.physics.fmu_loop import EVENTS

        if step:
            event, terminate = self.fmu.completed_step()
            if terminate or event:
                raise self._stopped(EVENTS[12 if terminate else 11], t)
        if self.events:
            self.fmu.get_event_indicators(self._z, self.events)
            now = np.frombuffer(self._z, dtype=float, count=self.events) > 0
            if step and self._last_z is not None and (now != self._last_z).any():
                raise self._stopped(EVENTS[10], t)
            self._last_z = now

    def _step(self, t: float, x: np.ndarray, inputs: list[int], u: np.ndarray, u_next: np.ndarray, dt: float,
              count: int) -> np.ndarray:
        """x at t + dt from x at t by ``count`` RK4 substeps, the inputs the line from u to u_next (equal:
        a zero-order hold)."""
        h = dt / count
        held = lambda s: u + s * (u_next - u)  # noqa: E731
        for i in range(count):
            a, s = t + i * h, i / count
            k1 = self._derivatives(a, x, inputs, held(s))
            k2 = self._derivatives(a + h / 2, x + h / 2 * k1, inputs, held(s + 0.5 / count))
            k3 = self._derivatives(a + h / 2, x + h / 2 * k2, inputs, held(s + 0.5 / count))
            k4 = self._derivatives(a + h, x + h * k3, inputs, held(s + 1.0 / count))
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return x

    def sensitivities(self, fed: Sequence[str], u: np.ndarray, run: FMURun, t0: float, dt: float,
                      hold: str = "zoh") -> Sensitivities:
        """Per sample k of ``run`` (model exchange, after it on this instance): how its outputs y_k = g(x_k, u_k)
        and its next state x_k+1 = Φ(x_k, u_k, u_k+1) move with x_k, u_k and (first-order hold) u_k+1, by
        forward differences (steps √ε relative, errors of that order) from the run's own y_k and x_k+1: one
        output evaluation and one RK4 step per state and input."""
        with self._fmpy_calls():
            return self._sensitivities(fed, u, run, t0, dt, hold)

    def _sensitivities(self, fed: Sequence[str], u: np.ndarray, run: FMURun, t0: float, dt: float,
                       hold: str) -> Sensitivities:
        if self.interface != "model_exchange" or run.x is None:
            raise FMUError(f"FMU {self.description.path.name}: gradients through it need its model exchange "
                           "interface (hypa integrates it); its co-simulation steps alone")
        d = self.description
        refs = {v.name: v.reference for v in d.inputs}
        inputs, outputs = [refs[n] for n in fed], [v.reference for v in d.outputs]
        steps, n, m = len(u), self.n, u.shape[1]
        loop = self._loop(inputs, outputs)
        if loop is not None:
            with self._calls(t0, dt):
                return Sensitivities(*loop.sensitivities(u, t0, dt, run.substeps, hold == "foh", run.x, run.y))
        out = Sensitivities(np.zeros((steps, len(outputs), n)), np.zeros((steps, len(outputs), m)),
                            np.zeros((steps, n, n)), np.zeros((steps, n, m)), np.zeros((steps, n, m)))
        for k in range(steps):
            t, x, now = t0 + k * dt, run.x[k], u[k]
            later = u[k + 1] if k + 1 < steps else now
            stepped = k + 1 < steps
            for i in range(n + m + (m if hold == "foh" and stepped else 0)):
                which, column = (0, i) if i < n else (1, i - n) if i < n + m else (2, i - n - m)
                base = (x, now, later)[which]
                delta = math.sqrt(np.finfo(float).eps) * max(abs(base[column]), 1.0)
                values = [x, now, later]
                values[which] = base + delta * np.eye(len(base))[column]
                if which < 2:  # the outputs read x_k and u_k only
                    dy = (np.asarray(self._outputs(t, values[0], inputs, values[1], outputs)) - run.y[k]) / delta
                    (out.y_x if which == 0 else out.y_u)[k][:, column] = dy
                if stepped:
                    after = self._step(t, values[0], inputs, values[1], values[2] if hold == "foh" else values[1],
                                       dt, run.substeps)
                    (out.x_x, out.x_u, out.x_u_next)[which][k][:, column] = (after - run.x[k + 1]) / delta
        return out

    def _cosimulate(self, inputs, outputs, u, t0, dt, hold, started) -> FMURun:
        d = self.description
        if hold == "foh" and not d.interpolates_inputs:
            raise FMUError(f"FMU {d.path.name}: its co-simulation cannot interpolate inputs (canInterpolateInputs "
                           "is false), which a first-order hold needs: use physics.hold=zoh")
        loop = self._loop(inputs, outputs)
        if loop is not None:
            with self._calls(t0, dt):
                return FMURun(loop.cosimulate(u, t0, dt, hold == "foh"), None, started)
        steps = len(u)
        ys = np.empty((steps, len(outputs)))
        for k in range(steps):
            if inputs:
                self.fmu.set_reals(inputs, u[k].tolist())
                if hold == "foh" and k + 1 < steps:
                    self.fmu.set_input_derivatives(inputs, ((u[k + 1] - u[k]) / dt).tolist())
            ys[k] = self.fmu.get_reals(outputs)
            if k + 1 < steps:
                stopped = self.fmu.do_step(t0 + k * dt, dt)
                if stopped:
                    raise self._stopped(stopped, t0 + k * dt)
        return FMURun(ys, None, started)
