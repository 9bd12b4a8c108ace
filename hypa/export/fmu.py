"""The ONNX step as an FMI 2.0 co-simulation FMU (``pythonfmu``), checked with ``fmpy``.

The FMU's slave is Python: it runs ``model.onnx`` (in the FMU's resources) with onnxruntime,
one call per sample of ``dt``, so the importing tool needs a Python 3 with numpy and onnxruntime
(``requirements.txt`` in the resources, beside ``spec.json``: names, units, start values, which each
instance reads from its own resources, so that two such FMUs of one model name load into one process;
pythonfmu's own Python part travels in the FMU, its binaries, linux64 and win64, load the Python the
tool runs or finds). Variables:

* inputs: the model's inputs and scheduling signals, SI, with their units;
* outputs: its outputs, SI, with their units, y(t) = the step's output from the state at t and
  the inputs set at t (direct feedthrough, as FMI means it);
* parameters ``initial_state[i]``: the step's state at the first ``doStep``, starting at the
  export's initial state (``export.json``'s ``state`` names each entry);
* calculated parameters ``parameter.<name>``: the physical parameters at their fitted values,
  with units, read-only: the step has them baked into its matrices.

``doStep(t, h)`` advances h / dt samples (h a whole multiple of dt, inputs held).
"""

from __future__ import annotations

import json
import shutil
import tempfile
import time
import zipfile
from pathlib import Path
from xml.etree import ElementTree

import numpy as np

from hypa.export.blocks import ExportError, StateSlot
from hypa.export.native import c_identifier
from hypa.export.reference import Reference

SLAVE = '''"""hypa's exported step as an FMI 2.0 co-simulation slave (pythonfmu): model.onnx, run by onnxruntime."""

import json
from pathlib import Path

import numpy as np
import onnxruntime
from pythonfmu import DefaultExperiment, Fmi2Causality, Fmi2Slave, Fmi2Variability, Real

class {name}(Fmi2Slave):
    author = "hypa"
    description = {description!r}

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        # this instance's spec.json, read from its own resources: a tool that loads two such FMUs of the same
        # model name into one process imports this module once, for both
        self.spec = SPEC = json.loads((Path(self.resources) / "spec.json").read_text())
        self.default_experiment = DefaultExperiment(start_time=SPEC["start_time"], step_size=SPEC["dt"])
        self.u = np.array(SPEC["u_start"], dtype=np.float32)
        self.x0 = np.array(SPEC["initial_state"], dtype=np.float32)
        self.state, self._revision, self._cache, self._session = self.x0.copy(), 0, None, None
        for i, (name, unit) in enumerate(SPEC["inputs"]):
            self.register_variable(Real(name, causality=Fmi2Causality.input, variability=Fmi2Variability.continuous,
                                        start=float(self.u[i]), getter=self._get_u(i),
                                        setter=self._set_u(i)))
        for i, (name, unit) in enumerate(SPEC["outputs"]):
            self.register_variable(Real(name, causality=Fmi2Causality.output, variability=Fmi2Variability.continuous,
                                        getter=self._get_y(i)))
        for i, (text, unit) in enumerate(SPEC["state"]):
            self.register_variable(Real(f"initial_state[{{i + 1}}]", causality=Fmi2Causality.parameter,
                                        variability=Fmi2Variability.fixed, start=float(self.x0[i]), description=text,
                                        getter=self._get_x0(i), setter=self._set_x0(i)))
        for name, (value, unit) in SPEC["parameters"].items():
            self.register_variable(Real(f"parameter.{{name}}", causality=Fmi2Causality.calculatedParameter,
                                        variability=Fmi2Variability.fixed,
                                        description="fitted value, read-only: the step has it baked in",
                                        getter=(lambda v=value: v)))

    def _get_u(self, i):
        return lambda: float(self.u[i])

    def _set_u(self, i):
        def set_u(value):
            self.u[i] = value
        return set_u

    def _get_y(self, i):
        return lambda: float(self._run()[1][i])

    def _get_x0(self, i):
        return lambda: float(self.x0[i])

    def _set_x0(self, i):
        def set_x0(value):
            self.x0[i] = value
        return set_x0

    def _run(self):
        """(next_state, y) from the state and the inputs now, computed once per state and inputs."""
        key = (self._revision, self.u.tobytes())
        if self._cache is None or self._cache[0] != key:
            if self._session is None:
                options = onnxruntime.SessionOptions()
                options.intra_op_num_threads = options.inter_op_num_threads = 1
                self._session = onnxruntime.InferenceSession(str(Path(self.resources) / "model.onnx"), options,
                                                            providers=["CPUExecutionProvider"])
            self._cache = (key, self._session.run(["next_state", "y"], {{"state": self.state, "u": self.u}}))
        return self._cache[1]

    def exit_initialization_mode(self):
        self.state, self._revision = self.x0.copy(), self._revision + 1

    def do_step(self, current_time, step_size):
        samples = step_size / self.spec["dt"]
        if abs(samples - round(samples)) > 1e-6 or round(samples) < 1:
            self.log(f"step size {{step_size}} s is not a whole multiple of dt = {{self.spec['dt']}} s")
            return False
        for _ in range(round(samples)):
            self.state = self._run()[0]
            self._revision += 1
        return True
'''




def build_fmu(onnx: Path, path: Path, description: dict, reference: Reference, slots: list[StateSlot],
              parameters: dict[str, tuple[float, str]]) -> Path:
    """Write the co-simulation FMU of ``onnx`` to ``path``; ``description``: ``export.json``'s contents."""
    try:
        from pythonfmu import FmuBuilder
    except ImportError as error:
        raise ExportError(f"format=fmu needs pythonfmu: pip install -e '.[export]' ({error})") from None
    name = c_identifier(description["model"])
    signals = lambda key: [(s["name"], s["unit"]) for s in description[key]]  # noqa: E731
    spec = {"description": f"hypa model {description['model']}: one step of {description['dt']:g} s (model.onnx)",
            "dt": description["dt"], "start_time": float(reference.time[reference.first]),
            "u_start": reference.u[reference.first].tolist(), "initial_state": reference.initial_state.tolist(),
            "inputs": signals("inputs"), "outputs": signals("outputs"),
            "state": [(f"{s.block}: {s.name} ({s.kind})", s.unit) for s in slots],
            "parameters": {k: list(v) for k, v in parameters.items()}}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        script = folder / f"{name}.py"
        script.write_text(SLAVE.format(description=spec["description"], name=name))
        (folder / "spec.json").write_text(json.dumps(spec))
        shutil.copy(onnx, folder / "model.onnx")
        (folder / "requirements.txt").write_text("numpy\nonnxruntime\n")  # for ``pythonfmu deploy -f model.fmu``
        built = FmuBuilder.build_FMU(script, dest=folder / "out",
                                     project_files=[folder / "model.onnx", folder / "spec.json",
                                                    folder / "requirements.txt"])
        units = dict((*spec["inputs"], *spec["outputs"]))
        units.update({f"initial_state[{i + 1}]": u for i, (_, u) in enumerate(spec["state"])})
        units.update({f"parameter.{k}": u for k, (_, u) in parameters.items()})
        add_units(Path(built), path, units)
    return path


def add_units(fmu: Path, path: Path, units: dict[str, str]) -> None:
    """Copy ``fmu`` to ``path`` with each variable's ``unit``, the ``UnitDefinitions`` they name and
    the ``InitialUnknowns`` (the outputs and calculated parameters), which pythonfmu does not write."""
    with zipfile.ZipFile(fmu) as source:
        root = ElementTree.fromstring(source.read("modelDescription.xml"))
        unknowns = []
        for index, variable in enumerate(root.iter("ScalarVariable"), 1):
            unit = units.get(variable.get("name"), "")
            real = variable.find("Real")
            if unit and real is not None:
                real.set("unit", unit)
            if variable.get("causality") in ("output", "calculatedParameter"):
                unknowns.append(index)
        structure = root.find("ModelStructure")
        if unknowns and structure is not None and structure.find("InitialUnknowns") is None:
            initial = ElementTree.SubElement(structure, "InitialUnknowns")
            for index in unknowns:
                ElementTree.SubElement(initial, "Unknown", {"index": str(index)})
        used = sorted({u for u in units.values() if u})
        if used:
            definitions = ElementTree.Element("UnitDefinitions")
            for unit in used:
                ElementTree.SubElement(definitions, "Unit", {"name": unit})
            position = [child.tag for child in root].index("ModelVariables")
            position = min([position] + [i for i, c in enumerate(root) if c.tag in ("DefaultExperiment",
                                                                                     "VendorAnnotations",
                                                                                     "TypeDefinitions",
                                                                                     "LogCategories")])
            root.insert(position, definitions)
        xml = ElementTree.tostring(root, encoding="utf-8", xml_declaration=True)
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as target:
            for item in source.infolist():
                data = xml if item.filename == "modelDescription.xml" else source.read(item.filename)
                target.writestr(item, data)


def run_fmu(path: Path, reference: Reference) -> tuple[np.ndarray, float]:
    """The FMU through fmpy over the reference record from the sample ``first`` on: set the inputs of
    sample k, read the outputs, ``doStep`` one dt. Outputs (S, p) and the seconds per sample."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    description = read_model_description(str(path))
    refs = {v.name: v.valueReference for v in description.modelVariables}
    inputs = [refs[n] for n in reference.input_names]
    outputs = [refs[n] for n in reference.output_names]
    unzipped = extract(str(path))
    try:
        slave = FMU2Slave(guid=description.guid, unzipDirectory=unzipped,
                          modelIdentifier=description.coSimulation.modelIdentifier, instanceName="check")
        slave.instantiate()
        dt = float(description.defaultExperiment.stepSize)
        t = float(reference.time[reference.first])
        slave.setupExperiment(startTime=t)
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        ys = []
        rows = reference.u[reference.first :]
        started = time.perf_counter()
        for k, u in enumerate(rows):
            slave.setReal(inputs, [float(v) for v in u])
            ys.append(slave.getReal(outputs))
            slave.doStep(currentCommunicationPoint=t + k * dt, communicationStepSize=dt)
        seconds = (time.perf_counter() - started) / max(len(rows), 1)
        slave.terminate()
        slave.freeInstance()
    finally:
        shutil.rmtree(unzipped, ignore_errors=True)
    return np.array(ys, dtype=float).reshape(len(rows), -1), seconds
