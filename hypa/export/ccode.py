"""The exported step (``model.onnx``) as C99 that needs nothing but libm: ``c_step``.

The step's ONNX graph has static shapes (a batch of one, a fixed state), so it compiles into
straight-line C: every tensor of the graph becomes an array of scalars, each a literal (a value
known when exporting), an input element (``state[i]``, ``u[i]``) or a C variable. What moves data
(Slice, Gather, Concat, Reshape, Transpose, ...) costs nothing at run time: it rearranges the
scalars while compiling. What depends only on constants (shapes, the normalization, a constant
block's matrices) is evaluated while compiling, in float64. What remains is arithmetic on the
inputs: one ``const double`` per element of an elementwise operation, one sum per element of a
small product with the zeros of its constant factor left out, and plain loops over static weight
arrays for the products with large constant matrices and for the recurrent cells (ONNX's LSTM
and GRU). Arithmetic is float64 throughout, the weights the exported float32 values.

The operations live in ``hypa.export.ccode_ops``. An operation without a C form there is refused
in one line naming it and the block whose node it is (``ExportError``); the ONNX and pythonfmu
FMU remain for such a model.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hypa.export.blocks import ExportError

LOOP_SIZE = 256  # a product with a constant matrix of more entries runs as a loop over a static array
INPUTS = ("state", "u")  # the step's arguments: the graph's inputs, by name
OUTPUTS = ("next_state", "y")

_ATOM = re.compile(r"^([A-Za-z_]\w*)(\[\d+\])?$")


@dataclass(frozen=True)
class CStep:
    """C99 source of ``static void hypa_step(const double *state, const double *u, double *next_state,
    double *y)`` with ``HYPA_STATE_SIZE``, ``HYPA_INPUT_SIZE``, ``HYPA_OUTPUT_SIZE``; ``next_state``
    must not alias ``state``. ``statements``: assignments and loops in the step's body."""

    source: str
    state_size: int
    input_size: int
    output_size: int
    statements: int


@dataclass
class _Statement:
    text: str
    defines: tuple[str, ...]
    uses: frozenset[str]


@dataclass
class _Emitter:
    """The step's body under construction: statements, static arrays and fresh names."""

    statements: list[_Statement] = field(default_factory=list)
    statics: dict[str, str] = field(default_factory=dict)  # name -> its definition
    known: dict[str, str] = field(default_factory=dict)  # expression -> the variable that holds it
    shared: dict[bytes, str] = field(default_factory=dict)  # a static array's values -> its name
    count: int = 0

    def name(self, prefix: str = "t") -> str:
        self.count += 1
        return f"{prefix}{self.count}"

    def add(self, text: str, defines: Iterable[str], uses: Iterable[str]) -> None:
        self.statements.append(_Statement(text, tuple(defines), frozenset(uses)))

    def scalar(self, expression: str, operands: Iterable[object]) -> str:
        """A variable holding ``expression`` of ``operands`` (atoms or literals): a new one, or the one that
        already holds the same expression (every variable is assigned once, so equal text is equal value)."""
        if expression not in self.known:
            self.known[expression] = name = self.name()
            self.add(f"const double {name} = {expression};", [name], _uses(operands))
        return self.known[expression]

    def static(self, values: np.ndarray, prefix: str = "w") -> str:
        """A static const array of ``values`` (flattened, row-major): float where every value is a float32 one
        (the weights of a model trained in float32: exact, half the memory a step streams), else double; the
        arithmetic is double either way."""
        flat = np.asarray(values, dtype=float).reshape(-1)
        key = flat.tobytes()  # one array for each distinct matrix (a product row by row, batched, ...)
        if key in self.shared:
            return self.shared[key]
        name = self.shared[key] = self.name(prefix)
        single = bool(np.isfinite(flat).all() and (flat.astype(np.float32).astype(float) == flat).all())
        literal = (lambda v: np.format_float_scientific(np.float32(v), unique=True) + "f") if single else _literal
        rows = ",\n    ".join(", ".join(literal(v) for v in flat[i : i + 6]) for i in range(0, len(flat), 6))
        self.statics[name] = (f"static const {'float' if single else 'double'} {name}[{max(len(flat), 1)}] = "
                              f"{{\n    {rows or '0.0'}\n}};")
        return name

    def array(self, values: np.ndarray) -> str:
        """The name of an array holding ``values`` (object or numeric) in row-major order: an existing
        one where the values are exactly its elements in order, else a new local one."""
        flat = list(np.asarray(values, dtype=object).reshape(-1))
        if flat and all(isinstance(v, str) for v in flat):
            match = _ATOM.match(flat[0])
            base = match.group(1) if match else None
            if base and all(v == f"{base}[{i}]" for i, v in enumerate(flat)):
                return base
        name = self.name("v")
        items = ", ".join(v if isinstance(v, str) else _literal(v) for v in flat) or "0.0"
        self.add(f"double {name}[{max(len(flat), 1)}] = {{{items}}};", [name], _uses(flat))
        return name


def _literal(value: object) -> str:
    v = float(value)
    if math.isnan(v):
        return "NAN"
    if math.isinf(v):
        return "INFINITY" if v > 0 else "(-INFINITY)"
    text = repr(v)
    return f"({text})" if v < 0 else text


def _uses(operands: Iterable[object]) -> set[str]:
    names = set()
    for value in operands:
        if isinstance(value, str):
            match = _ATOM.match(value)
            if match and match.group(1) not in INPUTS and match.group(1) not in OUTPUTS:
                names.add(match.group(1))
    return names


def _constant(value: np.ndarray) -> bool:
    return value.dtype != object


def _symbolic(value: np.ndarray) -> np.ndarray:
    """``value`` as an object array whose constants are floats."""
    if _constant(value):
        return np.asarray(value, dtype=float).astype(object)
    return value


def _settle(value: np.ndarray) -> np.ndarray:
    """An object array without a symbol back to a float one (it became a constant)."""
    if _constant(value) or any(isinstance(v, str) for v in value.reshape(-1)):
        return value
    return np.array(value.tolist(), dtype=float).reshape(value.shape)


def _operand(value: object) -> str:
    return value if isinstance(value, str) else _literal(value)


# Elementwise operations: numpy for constants, C for symbols. Unary ones: C format of one operand.
class _Graph:
    """Compiles one ONNX graph into an ``_Emitter``'s statements."""

    def __init__(self, model, blocks: Mapping[str, str]) -> None:
        from onnx import numpy_helper

        self.model, self.blocks, self.out = model, dict(blocks), _Emitter()
        self.types: dict[str, int] | None = None  # element types as ONNX infers them, once asked
        self.values: dict[str, np.ndarray] = {"": np.zeros(0)}
        for tensor in model.graph.initializer:
            self.values[tensor.name] = _numeric(numpy_helper.to_array(tensor))
        for graph_input in model.graph.input:
            if graph_input.name in self.values:
                continue
            dims = [d.dim_value for d in graph_input.type.tensor_type.shape.dim]
            if graph_input.name not in INPUTS or len(dims) != 1 or dims[0] < 0:
                raise ExportError(f"the ONNX step has an input {graph_input.name!r} of shape {dims}; "
                                  f"the C step takes {' and '.join(INPUTS)}, each a vector of fixed size")
            self.values[graph_input.name] = np.array([f"{graph_input.name}[{i}]" for i in range(dims[0])],
                                                     dtype=object)

    def node_block(self, node) -> str:
        """Where a node comes from: ``block 'name' (kind)`` or ``the step``."""
        parts = [p for p in node.name.split("/") if p]
        if len(parts) > 1 and parts[0] in self.blocks:
            return f"block {parts[0]!r} ({self.blocks[parts[0]]})"
        return "the step"

    def integer(self, node, inputs: list[np.ndarray]) -> bool:
        """Whether ``node``'s output is an integer tensor (an operand an integer constant, or the type ONNX infers)."""
        from onnx import helper, shape_inference

        if any(_constant(v) for v in inputs):  # an operand of the type
            return any(_constant(v) and np.issubdtype(v.dtype, np.integer) for v in inputs)
        if self.types is None:
            try:
                typed = shape_inference.infer_shapes(self.model).graph
                self.types = {v.name: v.type.tensor_type.elem_type for v in typed.value_info}
            except Exception:  # noqa: BLE001 -- no inferred types: taken as floats
                self.types = {}
        kind = self.types.get(node.output[0], 0)
        return bool(kind) and np.issubdtype(helper.tensor_dtype_to_np_dtype(kind), np.integer)

    def run(self) -> None:
        from onnx import TensorProto, helper

        from hypa.export.ccode_ops import OPERATIONS, cast

        for node in self.model.graph.node:
            attributes = {a.name: helper.get_attribute_value(a) for a in node.attribute}
            inputs = [self.values[name] for name in node.input]
            handler = OPERATIONS.get(node.op_type)
            if handler is None or node.domain not in ("", "ai.onnx"):
                raise ExportError(f"{self.node_block(node)} uses the ONNX operation {node.op_type}, which has no C "
                                  "form in hypa: export it with format=fmu (the ONNX step in a pythonfmu FMU)")
            try:
                used = max((i + 1 for i, name in enumerate(node.output) if name), default=0)  # "": left out
                outputs = handler(self, inputs, attributes, used)
                if node.op_type == "Div" and not _constant(outputs[0]) and self.integer(node, inputs):
                    outputs = cast(self, outputs, {"to": TensorProto.INT64}, 1)  # ONNX's integer Div truncates
            except ExportError:
                raise
            except Exception as error:  # noqa: BLE001 -- a form the compiler does not cover, said in one line
                raise ExportError(f"{self.node_block(node)}: its ONNX {node.op_type} ({node.name}) has no C form "
                                  f"in hypa ({type(error).__name__}: {error}); export it with format=fmu") from None
            for name, value in zip(node.output, outputs):
                if not name:  # an optional output left out ("" stays the optional input left out)
                    continue
                value = value if isinstance(value, np.ndarray) else \
                    np.array(value, dtype=object if isinstance(value, str) else None)  # an element taken alone
                self.values[name] = value if _constant(value) else _settle(value)


def _numeric(array: np.ndarray) -> np.ndarray:
    """An initializer or constant: floats as float64, integers and booleans as they are."""
    return array.astype(np.float64) if np.issubdtype(array.dtype, np.floating) else np.asarray(array)


def _ints(value: np.ndarray) -> list[int]:
    if not _constant(value):
        raise ExportError("a shape, an axis or an index that depends on the inputs")
    return [int(v) for v in np.asarray(value).reshape(-1)]


def c_step(onnx_path: Path, blocks: Mapping[str, str] | None = None) -> CStep:
    """Compile the ONNX step at ``onnx_path`` (inputs ``state``, ``u``; outputs ``next_state``, ``y``)
    into C (``CStep``). ``blocks``: a label for each block name (e.g. ``'LSTMBlock network'``), for
    the one-line refusal of an operation without a C form."""
    import onnx

    model = onnx.load(str(onnx_path))
    graph = _Graph(model, blocks or {})
    graph.run()
    results = {}
    for graph_output in model.graph.output:
        if graph_output.name not in OUTPUTS:
            raise ExportError(f"the ONNX step has an output {graph_output.name!r}; the C step writes "
                              f"{' and '.join(OUTPUTS)}")
        results[graph_output.name] = np.asarray(graph.values[graph_output.name]).reshape(-1)
    sizes = {name: len(results.get(name, ())) for name in OUTPUTS}
    inputs = {name: len(graph.values[name]) if name in graph.values else 0 for name in INPUTS}
    writes = [f"{name}[{i}] = {_operand(v)};" for name in OUTPUTS for i, v in enumerate(results.get(name, ()))]
    body = _live(graph.out, results)
    used = set().union(*(s.uses for s in body)) if body else set()
    used |= _uses(v for r in results.values() for v in r)
    statics = [text for name, text in graph.out.statics.items() if name in used]
    source = "\n".join([
        "/* hypa's exported step in C99 (hypa.export.ccode): float64, libm only. */",
        "#include <math.h>",
        "",
        f"#define HYPA_STATE_SIZE {inputs['state']}",
        f"#define HYPA_INPUT_SIZE {inputs['u']}",
        f"#define HYPA_OUTPUT_SIZE {sizes['y']}",
        "",
        *statics,
        "",
        "/* y[k] and state[k+1] from state[k] and u[k], all SI; next_state must not alias state. */",
        "static void hypa_step(const double *state, const double *u, double *next_state, double *y)",
        "{",
        "    (void)state; (void)u; (void)next_state; (void)y;",
        *(f"    {s.text}" for s in body),
        *(f"    {w}" for w in writes),
        "}",
        ""])
    if sizes["next_state"] != inputs["state"]:
        raise ExportError(f"the ONNX step takes {inputs['state']} states and returns {sizes['next_state']}")
    return CStep(source, inputs["state"], inputs["u"], sizes["y"], len(body))


def _live(out: _Emitter, results: Mapping[str, np.ndarray]) -> list[_Statement]:
    """The statements the outputs need, in order (what only fed shapes or unused outputs is dropped)."""
    live = _uses(v for r in results.values() for v in r)
    kept = []
    for statement in reversed(out.statements):
        if live.intersection(statement.defines):
            kept.append(statement)
            live |= statement.uses
    return kept[::-1]
