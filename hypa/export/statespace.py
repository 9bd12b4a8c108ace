"""A physics-only model as one linear state space, continuous and discrete, SI: ``statespace.mat``, ``statespace.json``.

Every block is linear and constant (physics without scheduling or a nonlinearity); the model's
blocks, wired by named signals, are composed in their dependency order (series and parallel
connections; ``compose``)::

    continuous  dx/dt = A x + B u + e,        y = C x + D u + f
    discrete    x[k+1] = Ad x[k] + Bd u[k] + ed,   y[k] = Cd x[k] + Dd u[k] + fd

x is the blocks' states in the model's order, u the model's inputs, y its outputs; e, ed
are the blocks' drifts and f, fd the sensor offsets, zeros for most systems. The discrete
system is what hypa simulates: each block discretized under its own hold at dt, then connected
(a first-order hold in the standard form x̃[k] = x[k] - Γ_1 u[k], MATLAB's ``c2d(..., 'foh')``),
which equals the continuous system discretized at once where at most one block has states.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from hypa.export.blocks import ExportError, hold_refusal
from hypa.export.reference import Reference
from hypa.models.composed import ComposedModel

Parts = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # A, B, C, D, e, f


@dataclass
class LinearModel:
    """The composed continuous (``a``..``f``) and discrete (``ad``..``fd``, at ``dt``) systems, SI."""

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    e: np.ndarray
    f: np.ndarray
    ad: np.ndarray
    bd: np.ndarray
    cd: np.ndarray
    dd: np.ndarray
    ed: np.ndarray
    fd: np.ndarray
    dt: float
    hold: str
    state_names: list[str]
    state_units: list[str]
    input_names: list[str]
    input_units: list[str]
    output_names: list[str]
    output_units: list[str]
    parameters: dict[str, tuple[float, str]]  # name -> (value, unit), the fitted ones

    @property
    def affine(self) -> bool:
        return bool(np.any(self.e) or np.any(self.f) or np.any(self.ed) or np.any(self.fd))

    def simulate(self, x0: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The discrete system's outputs (S, p) over u (S, m) from x0, float64."""
        x, ys = np.asarray(x0, dtype=float), []
        for u_k in np.asarray(u, dtype=float):
            ys.append(self.cd @ x + self.dd @ u_k + self.fd)
            x = self.ad @ x + self.bd @ u_k + self.ed
        return np.array(ys).reshape(len(u), -1)


def refusal(model: ComposedModel) -> str | None:
    """Why ``model`` has no linear, constant state space (one line), or None when it has one."""
    for b in model.order:
        block = model.blocks[b.name]
        if b.kind == "ann":
            return f"block {b.name!r} is a network: the statespace export is for physics-only models (use onnx or fmu)"
        if b.kind == "delay":
            return f"block {b.name!r} is a dead time, which has no finite continuous state space (use onnx or fmu)"
        if b.kind != "physics":
            return f"block {b.name!r} is a {b.kind}, a nonlinear block: no linear state space (use onnx or fmu)"
        if b.scheduling:
            return (f"block {b.name!r} is scheduled by {', '.join(b.scheduling.values())}: its matrices are not "
                    "constant (use onnx or fmu)")
        if block.model.is_nonlinear:
            return (f"block {b.name!r} is nonlinear ({block.model.display_name}): no linear state space "
                    "(use onnx or fmu)")
        if block.model.has_nonlinear_output:
            return (f"block {b.name!r} has a nonlinear output ({block.model.display_name}.output_nonlinearity): "
                    "no linear state space (use onnx or fmu)")
    return hold_refusal(model)


def block_parts(block, discrete: bool) -> Parts:
    """One block's (A, B, C, D, e, f) in SI, continuous or discrete (a first-order hold in standard form)."""
    with torch.no_grad():
        ss = block.state_space(torch.float64)
        n, m = ss.b.shape if block.model.n_states else (0, len(block.model.input_names))
        c, d = ss.c.numpy(), ss.d.numpy()
        a, b = ss.a.numpy().reshape(n, n), ss.b.numpy().reshape(n, m)
        e = ss.e.numpy() if ss.e is not None else np.zeros(n)
        if discrete and n:
            system = block.discrete(torch.float64)
            phi, taps = system.phi.numpy(), [t.numpy() for t in system.taps]
            e = system.drift.numpy() if system.drift is not None else np.zeros(n)
            if len(taps) == 1:
                a, b = phi, taps[0]
            else:  # x̃[k] = x[k] - Γ_1 u[k]
                a, b, d = phi, phi @ taps[1] + taps[0], d + c @ taps[1]
    p = len(block.model.output_names)
    return a, b, c.reshape(p, n), d.reshape(p, m), e, np.zeros(p)


def compose(model: ComposedModel, parts: dict[str, Parts], u_offset: np.ndarray, y_offset: np.ndarray) -> Parts:
    """The blocks' systems connected by the model's signals, in its dependency order: each signal is
    Cs x + Ds u + fs of the stacked states x and the model's inputs u (offset by ``u_offset`` [SI]);
    the same algebra in continuous and discrete time."""
    m = len(model.input_names)
    n = sum(parts[b.name][0].shape[0] for b in model.order)
    a, b_all, e = np.zeros((n, n)), np.zeros((n, m)), np.zeros(n)
    signals = {name: (np.zeros(n), np.eye(m)[i], -u_offset[i]) for i, name in enumerate(model.input_names)}
    offset = 0
    for spec in model.order:
        a_i, b_i, c_i, d_i, e_i, f_i = parts[spec.name]
        k = a_i.shape[0]
        cu = np.stack([signals[s][0] for s in spec.inputs])  # (m_i, n)
        du = np.stack([signals[s][1] for s in spec.inputs])  # (m_i, m)
        fu = np.array([signals[s][2] for s in spec.inputs])  # (m_i,)
        rows = slice(offset, offset + k)
        a[rows, rows] += a_i
        a[rows] += b_i @ cu
        b_all[rows] = b_i @ du
        e[rows] = e_i + b_i @ fu
        select = np.zeros((k, n))
        select[:, rows] = np.eye(k)
        cy, dy, fy = c_i @ select + d_i @ cu, d_i @ du, f_i + d_i @ fu
        for j, name in enumerate(spec.outputs):
            signals[name] = (cy[j], dy[j], fy[j])
        offset += k
    outputs = model.spec.outputs
    c = np.stack([signals[o][0] for o in outputs]).reshape(len(outputs), n)
    d = np.stack([signals[o][1] for o in outputs]).reshape(len(outputs), m)
    f = np.array([signals[o][2] for o in outputs]) + y_offset
    return a, b_all, c, d, e, f


def linear_model(model: ComposedModel, units: dict[str, str], dt: float) -> LinearModel:
    """The composed state space of a physics-only model at its fitted parameters; ``ExportError`` when
    a block is not linear and constant."""
    why = refusal(model)
    if why:
        raise ExportError(f"format=statespace: {why}")
    scale = lambda names: np.array([model.scales[n][1] for n in names])  # noqa: E731
    u_offset = model.input_offset.double().numpy() * scale(model.input_names)
    y_offset = model.output_offset.double().numpy() * scale(model.spec.outputs)
    continuous = compose(model, {b.name: block_parts(model.blocks[b.name], False) for b in model.order},
                         u_offset, y_offset)
    discrete = compose(model, {b.name: block_parts(model.blocks[b.name], True) for b in model.order},
                       u_offset, y_offset)
    states, state_units = [], []
    for b in model.order:
        block = model.blocks[b.name]
        measured = dict(zip(block.model.state_names, model.starts[b.name].measured)) if b.name in model.starts else {}
        for s in block.model.state_names:
            states.append(s if sum(s in model.blocks[o.name].model.state_names for o in model.order) == 1
                          else f"{b.name}.{s}")
            state_units.append(units.get(measured.get(s, ""), "") or units.get(s, ""))
    specs = model.parameters_.specs
    parameters = {name: (value, specs[name].unit) for name, value in model.parameters_.as_floats().items()}
    return LinearModel(*continuous, *discrete, dt=dt, hold=model.hold, state_names=states, state_units=state_units,
                       input_names=list(model.input_names), input_units=[units.get(n, "") for n in model.input_names],
                       output_names=list(model.spec.outputs),
                       output_units=[units.get(n, "") for n in model.spec.outputs], parameters=parameters)


def discrete_initial_state(model: ComposedModel, reference: Reference) -> np.ndarray:
    """The discrete system's state at the reference's first exported sample, from the step's
    (``initial_state``): x[k] under a zero-order hold; under a first-order hold the step holds
    x[k-1], u[k-1], and x̃[k] = x[k] - Γ_1 u[k] = Φ x[k-1] + Γ_0 u[k-1] + γ."""
    parts, offset = [], 0
    x0 = np.asarray(reference.initial_state, dtype=float)
    for b in model.order:
        block = model.blocks[b.name]
        n, m = block.model.n_states, len(block.model.input_names)
        if not n:
            continue
        if block.hold == "zoh":
            parts.append(x0[offset : offset + n])
            offset += n
            continue
        with torch.no_grad():
            system = block.discrete(torch.float64)
        x_prev, u_prev = x0[offset : offset + n], x0[offset + n : offset + n + m]
        drift = system.drift.numpy() if system.drift is not None else 0.0
        parts.append(system.phi.numpy() @ x_prev + system.taps[0].numpy() @ u_prev + drift)
        offset += n + m
    return np.concatenate(parts) if parts else np.zeros(0)


def write_statespace(system: LinearModel, x0: np.ndarray, folder: Path) -> tuple[Path, Path]:
    """``statespace.mat`` (MATLAB: ``ss(A, B, C, D)``, ``ss(Ad, Bd, Cd, Dd, Ts)``) and ``statespace.json``
    (``load_statespace``), the same numbers."""
    from scipy.io import savemat

    cell = lambda names: np.array(names, dtype=object).reshape(-1, 1)  # noqa: E731 -- MATLAB cellstr column
    names = {"StateName": system.state_names, "StateUnit": system.state_units, "InputName": system.input_names,
             "InputUnit": system.input_units, "OutputName": system.output_names, "OutputUnit": system.output_units,
             "ParameterName": list(system.parameters),
             "ParameterUnit": [u for _, u in system.parameters.values()]}
    matrices = {"A": system.a, "B": system.b, "C": system.c, "D": system.d, "Ad": system.ad, "Bd": system.bd,
                "Cd": system.cd, "Dd": system.dd}
    affine = {"e": system.e, "f": system.f, "ed": system.ed, "fd": system.fd} if system.affine else {}
    mat = folder / "statespace.mat"
    savemat(mat, {**matrices, **{k: v.reshape(-1, 1) for k, v in affine.items()}, "Ts": system.dt,
                  "x0": x0.reshape(-1, 1), "hold": system.hold,
                  "ParameterValue": np.array([v for v, _ in system.parameters.values()]).reshape(-1, 1),
                  **{k: cell(v) for k, v in names.items()}})
    description = {"dt": system.dt, "hold": system.hold,
                   "continuous": {k.lower(): v.tolist() for k, v in matrices.items() if not k.endswith("d")},
                   "discrete": {k[0].lower(): v.tolist() for k, v in matrices.items() if k.endswith("d")},
                   "affine": {k: v.tolist() for k, v in affine.items()},
                   "x0": x0.tolist(),
                   "states": [{"name": n, "unit": u} for n, u in zip(system.state_names, system.state_units)],
                   "inputs": [{"name": n, "unit": u} for n, u in zip(system.input_names, system.input_units)],
                   "outputs": [{"name": n, "unit": u} for n, u in zip(system.output_names, system.output_units)],
                   "parameters": {k: {"value": v, "unit": u} for k, (v, u) in system.parameters.items()}}
    path = folder / "statespace.json"
    path.write_text(json.dumps(description, indent=2) + "\n")
    return mat, path


def load_statespace(path: Path | str, discrete: bool = False):
    """``statespace.json`` (or the folder holding it) as a python-control ``StateSpace`` with the
    signals' names; ``discrete``: the one at ``dt``. The affine terms (e, f; ed, fd), where the
    system has them, are in the file's ``affine``: python-control has none."""
    import control

    from hypa.core.errors import UserError
    from hypa.core.trust import read_bounded

    path = Path(path)
    path = path / "statespace.json" if path.is_dir() else path
    try:  # a file someone sent: read as data, bounded, every part checked by its shape
        description = json.loads(read_bounded(path, what="statespace.json"))
        part = description["discrete" if discrete else "continuous"]
        names = {key: [str(s["name"]) for s in description[key]] for key in ("states", "inputs", "outputs")}
        n, m, p = len(names["states"]), len(names["inputs"]), len(names["outputs"])
        matrices = [np.array(part[k], dtype=float).reshape(shape) for k, shape in
                    (("a", (n, n)), ("b", (n, m)), ("c", (p, n)), ("d", (p, m)))]
        dt = float(description["dt"])
    except (ValueError, KeyError, TypeError, IndexError, RecursionError) as error:
        raise UserError(f"{path}: not a statespace.json of hypa.export ({type(error).__name__}: "
                        f"{str(error)[:200]})") from None
    return control.ss(*matrices, *([dt] if discrete else []), states=names["states"] or None,
                      inputs=names["inputs"], outputs=names["outputs"])
