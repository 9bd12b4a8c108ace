"""The ONNX operations the C step compiles (``hypa.export.ccode``), each a handler
``(graph, inputs, attributes, outputs) -> [values]`` over arrays of scalars: numeric arrays are
constants (evaluated here, float64), object arrays hold C expressions (atoms: variables, input
elements, literals). Data movement rearranges the scalars; arithmetic emits statements through the
graph's emitter (``graph.out``); large constant products and the recurrent cells emit loops.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from hypa.export.blocks import ExportError
from hypa.export.ccode import (
    _ATOM,
    LOOP_SIZE,
    _constant,
    _ints,
    _literal,
    _numeric,
    _operand,
    _symbolic,
)

if TYPE_CHECKING:
    from hypa.export.ccode import _Graph

_UNARY: dict[str, tuple[Callable, str]] = {
    "Neg": (np.negative, "-{}"), "Abs": (np.abs, "fabs({})"), "Exp": (np.exp, "exp({})"),
    "Log": (np.log, "log({})"), "Sqrt": (np.sqrt, "sqrt({})"), "Tanh": (np.tanh, "tanh({})"),
    "Sin": (np.sin, "sin({})"), "Cos": (np.cos, "cos({})"), "Floor": (np.floor, "floor({})"),
    "Ceil": (np.ceil, "ceil({})"), "Reciprocal": (np.reciprocal, "1.0 / {}"),
    "Sigmoid": (lambda x: 1.0 / (1.0 + np.exp(-x)), "1.0 / (1.0 + exp(-{}))"),
    "Relu": (lambda x: np.maximum(x, 0), "({0} > 0.0 ? {0} : 0.0)"),
    "Sign": (np.sign, "(double)(({0} > 0.0) - ({0} < 0.0))"),
    "Softplus": (lambda x: np.logaddexp(0.0, x), "({0} > 20.0 ? {0} : log1p(exp({0})))"),
    "Erf": (np.vectorize(math.erf, otypes=[float]), "erf({})"),
    "Not": (np.logical_not, "(double)({} == 0.0)"),
    "IsNaN": (np.isnan, "(double)isnan({})"),
    "Round": (np.round, "nearbyint({})"),  # ties to even, as ONNX (the default rounding mode)
}
_BINARY: dict[str, tuple[Callable, str]] = {
    "Add": (np.add, "{} + {}"), "Sub": (np.subtract, "{} - {}"), "Mul": (np.multiply, "{} * {}"),
    "Div": (np.divide, "{} / {}"), "Pow": (np.power, "pow({}, {})"),
    "Max": (np.maximum, "fmax({}, {})"), "Min": (np.minimum, "fmin({}, {})"),
    "Less": (np.less, "(double)({} < {})"), "Greater": (np.greater, "(double)({} > {})"),
    "LessOrEqual": (np.less_equal, "(double)({} <= {})"), "GreaterOrEqual": (np.greater_equal, "(double)({} >= {})"),
    "Equal": (np.equal, "(double)({} == {})"),
    "And": (np.logical_and, "(double)({} != 0.0 && {} != 0.0)"),
    "Or": (np.logical_or, "(double)({} != 0.0 || {} != 0.0)"),
}


def _simplified(op: str, a: object, b: object) -> object | None:
    """The result of ``a op b`` without a new variable, where one operand makes it trivial, or None."""
    if op == "Add":
        return b if a == 0.0 and not isinstance(a, str) else a if b == 0.0 and not isinstance(b, str) else None
    if op == "Sub" and not isinstance(b, str) and b == 0.0:
        return a
    if op == "Mul":
        for x, other in ((a, b), (b, a)):
            if not isinstance(x, str) and x == 1.0:
                return other
            if not isinstance(x, str) and x == 0.0:
                return 0.0
    if op in ("Div", "Pow") and not isinstance(b, str) and b == 1.0:
        return a
    return None


def _elementwise(graph: _Graph, op: str, arrays: list[np.ndarray]) -> np.ndarray:
    """``op`` over broadcast ``arrays``: numpy where all are constant, else one variable per element."""
    if op in _UNARY:
        (x,) = arrays
        function, form = _UNARY[op]
        if _constant(x):
            return np.asarray(function(x))
        out = np.empty(x.shape, dtype=object)
        for index, v in np.ndenumerate(x):
            out[index] = float(function(np.float64(v))) if not isinstance(v, str) else \
                graph.out.scalar(form.format(v), [v])
        return out
    function, form = _BINARY[op]
    a, b = arrays
    if _constant(a) and _constant(b):
        if op == "Div" and np.issubdtype(a.dtype, np.integer) and np.issubdtype(b.dtype, np.integer):
            return np.trunc(a / b).astype(a.dtype)
        return np.asarray(function(a, b))
    a, b = np.broadcast_arrays(_symbolic(a), _symbolic(b))
    out = np.empty(a.shape, dtype=object)
    for index in np.ndindex(a.shape):
        x, y = a[index], b[index]
        if not isinstance(x, str) and not isinstance(y, str):
            out[index] = float(function(np.float64(x), np.float64(y)))
            continue
        simple = _simplified(op, x, y)
        out[index] = simple if simple is not None else graph.out.scalar(form.format(_operand(x), _operand(y)), [x, y])
    return out


def _variadic(op: str) -> Callable:
    def handler(graph, inputs, attributes, outputs):
        result = inputs[0]
        for other in inputs[1:]:
            result = _elementwise(graph, op, [result, other])
        return [result]
    return handler


def _unary(op: str) -> Callable:
    return lambda graph, inputs, attributes, outputs: [_elementwise(graph, op, inputs[:1])]


def _sum(graph: _Graph, terms: list[tuple[object, object]]) -> object:
    """Σ a b over ``terms`` (atoms or floats): constant products folded, zeros left out."""
    constant, parts, operands = 0.0, [], []
    for a, b in terms:
        if not isinstance(a, str) and not isinstance(b, str):
            constant += float(a) * float(b)
        elif not isinstance(a, str) or not isinstance(b, str):
            factor, symbol = (a, b) if not isinstance(a, str) else (b, a)
            if factor == 0.0:
                continue
            parts.append(symbol if factor == 1.0 else f"{_literal(factor)} * {symbol}")
            operands.append(symbol)
        else:
            parts.append(f"{a} * {b}")
            operands += [a, b]
    if not parts:
        return constant
    if constant:
        parts.append(_literal(constant))
    if len(parts) == 1 and _ATOM.match(parts[0]):
        return parts[0]
    return graph.out.scalar(" + ".join(parts), operands)


def _product(graph: _Graph, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a (n, k) @ b (k, m), either or both symbolic."""
    if _constant(b) and b.size > LOOP_SIZE:
        return np.stack([_looped(graph, row, b) for row in a])
    if _constant(a) and a.size > LOOP_SIZE:
        return np.stack([_looped(graph, column, a.T) for column in b.T]).T
    a, b = _symbolic(a), _symbolic(b)
    out = np.empty((a.shape[0], b.shape[1]), dtype=object)
    for i in range(a.shape[0]):
        for j in range(b.shape[1]):
            out[i, j] = _sum(graph, list(zip(a[i], b[:, j])))
    return out


def _looped(graph: _Graph, vector: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """vector (k,) @ matrix (k, m) with the constant matrix as a static array and a loop."""
    k, m = matrix.shape
    weights = graph.out.static(matrix)  # row j: what input j adds to each output
    x = graph.out.array(vector)
    name = graph.out.name("v")
    lines = [f"double {name}[{m}];", f"for (int i = 0; i < {m}; i++) {name}[i] = 0.0;",
             *_accumulate(name, weights, f"{x}[j]", k, m, m)]
    graph.out.add("\n    ".join(lines), [name], [x, weights])
    return np.array([f"{name}[{i}]" for i in range(m)], dtype=object)


def _accumulate(target: str, weights: str, source: str, columns: int, rows: int, stride: int,
                first: int = 0) -> list[str]:
    """target[i] += Σ_j weights[j][i] · source(j) for first <= i < rows, j < columns (weights row-major with
    ``stride`` entries a row): the inner loop runs over independent outputs, which the compiler vectorizes
    without reordering any sum."""
    return [f"for (int j = 0; j < {columns}; j++) {{",
            f"    const double s = {source};",
            f"    for (int i = {first}; i < {rows}; i++) {target}[i] += {weights}[j * {stride} + i] * s;",
            "}"]


def _matmul(graph: _Graph, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """numpy's matmul (batch broadcasting, 1-D promotion) on constant or symbolic operands."""
    if _constant(a) and _constant(b):
        return np.matmul(a, b)
    squeeze_a, squeeze_b = a.ndim == 1, b.ndim == 1
    a = a[None] if squeeze_a else a
    b = b[:, None] if squeeze_b else b
    batch = np.broadcast_shapes(a.shape[:-2], b.shape[:-2])
    a = np.broadcast_to(a, (*batch, *a.shape[-2:]))
    b = np.broadcast_to(b, (*batch, *b.shape[-2:]))
    out = np.empty((*batch, a.shape[-2], b.shape[-1]), dtype=object)
    for index in np.ndindex(*batch):
        out[index] = _product(graph, a[index], b[index])
    if squeeze_a:
        out = out[..., 0, :]
    if squeeze_b:
        out = out[..., 0]
    return out


def _gemm(graph, inputs, attributes, outputs):
    a, b = inputs[0], inputs[1]
    a = a.T if attributes.get("transA", 0) else a
    b = b.T if attributes.get("transB", 0) else b
    alpha, beta = float(attributes.get("alpha", 1.0)), float(attributes.get("beta", 1.0))
    if alpha != 1.0:
        a, b = (a * alpha, b) if _constant(a) else (a, b * alpha) if _constant(b) else \
            (_elementwise(graph, "Mul", [a, np.array(alpha)]), b)
    y = _matmul(graph, a, b)
    if len(inputs) > 2 and inputs[2].size:
        c = inputs[2] * beta if _constant(inputs[2]) else _elementwise(graph, "Mul", [inputs[2], np.array(beta)])
        y = _elementwise(graph, "Add", [y, c])
    return [y]


def _slice(graph, inputs, attributes, outputs):
    data, starts, ends = inputs[0], _ints(inputs[1]), _ints(inputs[2])
    axes = _ints(inputs[3]) if len(inputs) > 3 and inputs[3].size else list(range(len(starts)))
    steps = _ints(inputs[4]) if len(inputs) > 4 and inputs[4].size else [1] * len(starts)
    index = [slice(None)] * data.ndim
    for start, end, axis, step in zip(starts, ends, axes, steps):
        index[axis] = slice(start, end, step)
    return [data[tuple(index)]]


def _reshape(graph, inputs, attributes, outputs):
    data, shape = inputs[0], _ints(inputs[1])
    if not attributes.get("allowzero", 0):
        shape = [data.shape[i] if s == 0 else s for i, s in enumerate(shape)]
    return [data.reshape(shape)]


def _axes(inputs: list[np.ndarray], attributes: dict, position: int = 1) -> list[int] | None:
    if "axes" in attributes:
        return list(attributes["axes"])
    if len(inputs) > position and inputs[position].size:
        return _ints(inputs[position])
    return None


def _squeeze(graph, inputs, attributes, outputs):
    axes = _axes(inputs, attributes)
    data = inputs[0]
    return [np.squeeze(data, axis=tuple(axes)) if axes is not None else np.squeeze(data)]


def _unsqueeze(graph, inputs, attributes, outputs):
    return [np.expand_dims(inputs[0], tuple(_axes(inputs, attributes)))]


def _split(graph, inputs, attributes, outputs):
    data, axis = inputs[0], attributes.get("axis", 0)
    sizes = list(attributes["split"]) if "split" in attributes else \
        _ints(inputs[1]) if len(inputs) > 1 and inputs[1].size else None
    if sizes is None:
        length = data.shape[axis]
        each = -(-length // outputs)
        sizes = [min(each, length - i * each) for i in range(outputs)]
    return np.split(data, np.cumsum(sizes)[:-1], axis=axis)


def _gather(graph, inputs, attributes, outputs):
    data, indices = inputs[0], np.asarray(_ints(inputs[1])).reshape(inputs[1].shape)
    return [np.take(data, indices, axis=attributes.get("axis", 0))]


def _scatter(nd: bool) -> Callable:
    return lambda graph, inputs, attributes, outputs: _scattered(inputs, attributes, nd)


def _scattered(inputs: list[np.ndarray], attributes: dict, nd: bool) -> list[np.ndarray]:
    """ScatterElements (along ``axis``) or ScatterND ((..., k) indices): constant indices, no reduction."""
    data, updates = inputs[0], inputs[2]
    if attributes.get("reduction", b"none") not in (b"none", "none"):
        raise ExportError(f"a scatter with reduction {attributes['reduction']}")
    indices = np.asarray(_ints(inputs[1]), dtype=int).reshape(inputs[1].shape)
    out = _symbolic(data).copy() if not (_constant(data) and _constant(updates)) else data.copy()
    updates = _symbolic(updates) if out.dtype == object else updates
    if not nd:
        axis = attributes.get("axis", 0) % data.ndim
        for index in np.ndindex(indices.shape):
            target = list(index)
            target[axis] = indices[index] % data.shape[axis]
            out[tuple(target)] = updates[index]
    else:
        for index in np.ndindex(indices.shape[:-1]):
            out[tuple(indices[index])] = updates[index]
    return [out]


def _where(graph, inputs, attributes, outputs):
    condition, x, y = inputs
    if _constant(condition):
        return [np.where(condition.astype(bool), _symbolic(x), _symbolic(y)) if not (_constant(x) and _constant(y))
                else np.where(condition.astype(bool), x, y)]
    c, x, y = np.broadcast_arrays(condition, _symbolic(x), _symbolic(y))
    out = np.empty(c.shape, dtype=object)
    for index in np.ndindex(c.shape):
        out[index] = x[index] if not isinstance(c[index], str) and c[index] else \
            y[index] if not isinstance(c[index], str) else \
            graph.out.scalar(f"({c[index]} != 0.0 ? {_operand(x[index])} : {_operand(y[index])})",
                             [c[index], x[index], y[index]])
    return [out]


def cast(graph, inputs, attributes, outputs):
    from onnx import helper

    (x,), dtype = inputs, np.dtype(helper.tensor_dtype_to_np_dtype(attributes["to"]))
    if _constant(x):
        return [_numeric(x.astype(dtype))]
    if dtype == np.float64:
        return [x]
    if dtype not in (np.float32, np.bool_) and not np.issubdtype(dtype, np.integer):
        raise ExportError(f"a Cast to {dtype}")
    form = "(double)(float){}" if dtype == np.float32 else "(double)({} != 0.0)" if dtype == np.bool_ else \
        "trunc({})"
    out = np.empty(x.shape, dtype=object)
    for index, v in np.ndenumerate(x):
        out[index] = graph.out.scalar(form.format(v), [v]) if isinstance(v, str) else float(dtype.type(v))
    return [out]


def _reduce(op: str) -> Callable:
    def handler(graph, inputs, attributes, outputs):
        data, axes = inputs[0], _axes(inputs, attributes)
        if axes is None and attributes.get("noop_with_empty_axes", 0):
            return [data]
        axes = tuple(a % data.ndim for a in (axes if axes is not None else range(data.ndim)))
        keep = bool(attributes.get("keepdims", 1))
        if _constant(data):
            reduce = {"ReduceSum": np.sum, "ReduceMean": np.mean, "ReduceMax": np.max, "ReduceMin": np.min,
                      "ReduceProd": np.prod}[op]
            return [np.asarray(reduce(data, axis=axes, keepdims=keep))]
        rest = [a for a in range(data.ndim) if a not in axes]
        moved = np.transpose(data, [*rest, *axes])
        rows = moved.reshape(-1, int(np.prod([data.shape[a] for a in axes], dtype=int)))
        shape = [1 if a in axes else data.shape[a] for a in range(data.ndim)] if keep else \
            [data.shape[a] for a in rest]
        return [np.array([_reduced(graph, op, list(row)) for row in rows], dtype=object).reshape(shape)]
    return handler


def _reduced(graph: _Graph, op: str, values: list[object]) -> object:
    if op in ("ReduceSum", "ReduceMean"):
        total = _sum(graph, [(v, 1.0) for v in values])
        return total if op == "ReduceSum" else _elementwise(graph, "Div", [np.array([total], dtype=object),
                                                                           np.array(float(len(values)))])[0]
    binary = {"ReduceMax": "Max", "ReduceMin": "Min", "ReduceProd": "Mul"}[op]
    result = values[0]
    for v in values[1:]:
        result = _elementwise(graph, binary, [np.array([result], dtype=object), np.array([v], dtype=object)])[0]
    return result


def _clip(graph, inputs, attributes, outputs):
    x = inputs[0]
    low = inputs[1] if len(inputs) > 1 and inputs[1].size else np.array(attributes.get("min", -np.inf))
    high = inputs[2] if len(inputs) > 2 and inputs[2].size else np.array(attributes.get("max", np.inf))
    return [_elementwise(graph, "Min", [_elementwise(graph, "Max", [x, low]), high])]


def _constant_node(graph, inputs, attributes, outputs):
    from onnx import numpy_helper

    if "value" in attributes:
        return [_numeric(numpy_helper.to_array(attributes["value"]))]
    for key in ("value_float", "value_floats", "value_int", "value_ints"):
        if key in attributes:
            return [_numeric(np.asarray(attributes[key]))]
    raise ExportError(f"a Constant with {sorted(attributes)}")


def _constant_of_shape(graph, inputs, attributes, outputs):
    from onnx import numpy_helper

    value = numpy_helper.to_array(attributes["value"]) if "value" in attributes else np.zeros(1)
    return [_numeric(np.full(_ints(inputs[0]), value.reshape(-1)[0], dtype=value.dtype))]


def _eye_like(graph, inputs, attributes, outputs):
    rows, columns = inputs[0].shape
    return [np.eye(rows, columns, k=attributes.get("k", 0))]


def _shape(graph, inputs, attributes, outputs):
    shape = np.array(inputs[0].shape, dtype=np.int64)
    return [shape[attributes.get("start", 0) : attributes.get("end", len(shape))]]


def _expand(graph, inputs, attributes, outputs):
    data = inputs[0]
    return [np.array(np.broadcast_to(data, np.broadcast_shapes(data.shape, tuple(_ints(inputs[1])))))]


def _tile(graph, inputs, attributes, outputs):
    return [np.tile(inputs[0], _ints(inputs[1]))]


def _range(graph, inputs, attributes, outputs):
    start, limit, delta = (np.asarray(v).reshape(()) for v in inputs)
    if not all(_constant(v) for v in inputs):
        raise ExportError("a Range over the inputs")
    return [np.arange(start, limit, delta)]


def _flatten(graph, inputs, attributes, outputs):
    data, axis = inputs[0], attributes.get("axis", 1)
    axis = axis + data.ndim if axis < 0 else axis  # in [-rank, rank]: axis == rank flattens to (size, 1)
    return [data.reshape(int(np.prod(data.shape[:axis], dtype=int)), -1)]


def _rows(data: np.ndarray, axis: int) -> np.ndarray:
    """``data`` as rows over the axes from ``axis`` on: (rest, n)."""
    axis %= data.ndim
    return data.reshape(int(np.prod(data.shape[:axis], dtype=int)), -1)


def _softmax(graph, inputs, attributes, outputs):
    """exp(x - max x) / Σ exp(x - max x) along ``axis`` (opset 13: that one axis)."""
    data, axis = inputs[0], attributes.get("axis", -1) % inputs[0].ndim
    moved = np.moveaxis(data, axis, -1)
    rows = []
    for row in _rows(moved, -1):
        row = row[None]
        most = np.array([_reduced(graph, "ReduceMax", list(row[0]))], dtype=object)
        shifted = _elementwise(graph, "Sub", [row, most])
        e = _elementwise(graph, "Exp", [shifted])
        total = np.array([_reduced(graph, "ReduceSum", list(e[0]))], dtype=object)
        rows.append(_elementwise(graph, "Div", [e, total])[0])
    return [np.moveaxis(np.array(rows, dtype=object).reshape(moved.shape), -1, axis)]


def _layer_norm(graph, inputs, attributes, outputs):
    """(x - mean) / sqrt(var + ε) · scale + bias over the axes from ``axis`` on."""
    data, scale = inputs[0], inputs[1].reshape(-1)
    bias = inputs[2].reshape(-1) if len(inputs) > 2 and inputs[2].size else np.zeros(1)
    epsilon = np.array(float(attributes.get("epsilon", 1e-5)))
    rows = []
    for row in _rows(data, attributes.get("axis", -1)):
        mean = np.array([_reduced(graph, "ReduceMean", list(row))], dtype=object)
        centred = _elementwise(graph, "Sub", [row, mean])
        variance = _reduced(graph, "ReduceMean", list(_elementwise(graph, "Mul", [centred, centred])))
        spread = _elementwise(graph, "Sqrt", [_elementwise(graph, "Add", [np.array([variance], dtype=object),
                                                                          epsilon])])
        normalized = _elementwise(graph, "Div", [centred, spread])
        rows.append(_elementwise(graph, "Add", [_elementwise(graph, "Mul", [normalized, scale]), bias]))
    if outputs > 1:
        raise ExportError("a LayerNormalization whose mean or inverse deviation is used")
    return [np.array(rows, dtype=object).reshape(data.shape)]


def _recurrent(kind: str) -> Callable:
    """ONNX's LSTM (gates i, o, f, c) or GRU (z, r, h) over a sequence, forward, as loops over static weights."""
    gates = {"LSTM": 4, "GRU": 3}[kind]

    def handler(graph, inputs, attributes, outputs):
        hidden = int(attributes["hidden_size"])
        if attributes.get("direction", b"forward") not in (b"forward", "forward"):
            raise ExportError(f"a {attributes['direction']} {kind}")
        if attributes.get("layout", 0) or "clip" in attributes or attributes.get("input_forget", 0) or \
                ("activations" in attributes and
                 [a.decode() if isinstance(a, bytes) else a for a in attributes["activations"]]
                 != ["Sigmoid", "Tanh", "Tanh"][: gates - 1]):
            raise ExportError(f"an {kind} with attributes {sorted(attributes)} beyond hidden_size")
        x, w, r = inputs[0], inputs[1], inputs[2]
        if not (_constant(w) and _constant(r)) or (len(inputs) > 3 and inputs[3].size and not _constant(inputs[3])):
            raise ExportError(f"an {kind} whose weights depend on the inputs")
        if len(inputs) > 4 and inputs[4].size:
            raise ExportError(f"an {kind} with sequence lengths")
        if len(inputs) > 7 and inputs[7].size:
            raise ExportError(f"an {kind} with peepholes")
        steps, batch, width = x.shape
        if batch != 1:
            raise ExportError(f"an {kind} over a batch of {batch}")
        bias = inputs[3].reshape(2, gates * hidden) if len(inputs) > 3 and inputs[3].size else \
            np.zeros((2, gates * hidden))
        zero = np.zeros(hidden)
        h0 = inputs[5].reshape(-1) if len(inputs) > 5 and inputs[5].size else zero
        out, name = graph.out, graph.out.name(kind.lower())
        names = {key: f"{name}_{key}" for key in ("h", "c", "y")}
        arrays = [out.array(x.reshape(-1)), out.static(w[0].T, "w"), out.static(r[0].T, "w")]  # (in, gates·H)
        h_array = out.array(h0)
        declarations = [f"double {names['h']}[{hidden}];", f"double {names['y']}[{max(steps * hidden, 1)}];"]
        initial = [f"for (int i = 0; i < {hidden}; i++) {names['h']}[i] = {h_array}[i];"]
        uses = {*arrays, h_array}
        if kind == "LSTM":
            c0 = inputs[6].reshape(-1) if len(inputs) > 6 and inputs[6].size else zero
            c_array = out.array(c0)
            declarations.append(f"double {names['c']}[{hidden}];")
            initial.append(f"for (int i = 0; i < {hidden}; i++) {names['c']}[i] = {c_array}[i];")
            uses.add(c_array)
            bias_name = out.static(bias.sum(0), "w")
            body = _lstm_body(names, arrays, bias_name, hidden, width)
        else:
            bias_name = out.static(bias, "w")
            body = _gru_body(names, arrays, bias_name, hidden, width, int(attributes.get("linear_before_reset", 0)))
        uses.add(bias_name)
        text = "\n    ".join([*declarations, *initial, f"for (int t = 0; t < {steps}; t++) {{", *body, "}",
                                 f"(void){names['y']};"])  # Y may be left unread (set but not used)
        out.add(text, [names["h"], names["y"], *([names["c"]] if kind == "LSTM" else [])], uses)
        y = np.array([f"{names['y']}[{i}]" for i in range(steps * hidden)], dtype=object).reshape(steps, 1, 1, hidden)
        last = np.array([f"{names['h']}[{i}]" for i in range(hidden)], dtype=object).reshape(1, 1, hidden)
        results = [y, last]
        if kind == "LSTM":
            results.append(np.array([f"{names['c']}[{i}]" for i in range(hidden)], dtype=object).reshape(1, 1, hidden))
        return results[:outputs]
    return handler


def _gate_sums(x: str, w: str, r: str, bias: str, h: str, rows: int, hidden: int, width: int) -> list[str]:
    """g[i] = bias[i] + W[i] x_t + R[i] h for i < rows (loop-body lines; W, R stored transposed)."""
    return [f"    double g[{rows}];",
            f"    for (int i = 0; i < {rows}; i++) g[i] = {bias}[i];",
            *(f"    {line}" for line in _accumulate("g", w, f"{x}[t * {width} + j]", width, rows, rows)),
            *(f"    {line}" for line in _accumulate("g", r, f"{h}[j]", hidden, rows, rows))]


def _lstm_body(names: dict[str, str], arrays: list[str], bias: str, hidden: int, width: int) -> list[str]:
    x, w, r = arrays
    h, c, y = names["h"], names["c"], names["y"]
    return [*_gate_sums(x, w, r, bias, h, 4 * hidden, hidden, width),
            f"    for (int i = 0; i < {hidden}; i++) {{",
            "        const double in = 1.0 / (1.0 + exp(-g[i]));",
            f"        const double out = 1.0 / (1.0 + exp(-g[{hidden} + i]));",
            f"        const double forget = 1.0 / (1.0 + exp(-g[{2 * hidden} + i]));",
            f"        const double cell = tanh(g[{3 * hidden} + i]);",
            f"        {c}[i] = forget * {c}[i] + in * cell;",
            f"        {h}[i] = out * tanh({c}[i]);",
            f"        {y}[t * {hidden} + i] = {h}[i];",
            "    }"]


def _gru_body(names: dict[str, str], arrays: list[str], bias: str, hidden: int, width: int,
              linear_before_reset: int) -> list[str]:
    """h' = (1 - z) n + z h, n = tanh(W_h x + b_Wh + r (R_h h + b_Rh)) (linear before reset), or
    tanh(W_h x + b_Wh + R_h (r h) + b_Rh)."""
    x, w, r = arrays
    h, y, rows = names["h"], names["y"], 3 * hidden
    lines = [f"    double gx[{rows}], gh[{rows}], reset[{hidden}];",
             f"    for (int i = 0; i < {rows}; i++) {{ gx[i] = {bias}[i]; gh[i] = {bias}[{rows} + i]; }}",
             *(f"    {line}" for line in _accumulate("gx", w, f"{x}[t * {width} + j]", width, rows, rows)),
             *(f"    {line}" for line in _accumulate("gh", r, f"{h}[j]", hidden,
                                                     rows if linear_before_reset else 2 * hidden, rows)),
             f"    for (int i = 0; i < {hidden}; i++)",
             f"        reset[i] = 1.0 / (1.0 + exp(-(gx[{hidden} + i] + gh[{hidden} + i])));"]
    if not linear_before_reset:
        lines += [f"    {line}" for line in _accumulate("gh", r, f"reset[j] * {h}[j]", hidden, rows, rows,
                                                         2 * hidden)]
    candidate = f"gx[{2 * hidden} + i] + reset[i] * gh[{2 * hidden} + i]" if linear_before_reset else \
        f"gx[{2 * hidden} + i] + gh[{2 * hidden} + i]"
    return [*lines,
            f"    double next[{hidden}];",
            f"    for (int i = 0; i < {hidden}; i++) {{",
            "        const double update = 1.0 / (1.0 + exp(-(gx[i] + gh[i])));",
            f"        next[i] = (1.0 - update) * tanh({candidate}) + update * {h}[i];",
            "    }",
            f"    for (int i = 0; i < {hidden}; i++) {{ {h}[i] = next[i]; {y}[t * {hidden} + i] = next[i]; }}"]


OPERATIONS: dict[str, Callable] = {
    **{op: _unary(op) for op in _UNARY},
    **{op: _variadic(op) for op in _BINARY},
    "Identity": lambda g, i, a, o: [i[0]],
    "Dropout": lambda g, i, a, o: [i[0], np.ones(i[0].shape, dtype=bool)][:o],
    "Constant": _constant_node, "ConstantOfShape": _constant_of_shape, "EyeLike": _eye_like, "Shape": _shape,
    "Size": lambda g, i, a, o: [np.array(i[0].size, dtype=np.int64)],
    "Reshape": _reshape, "Squeeze": _squeeze, "Unsqueeze": _unsqueeze, "Flatten": _flatten,
    "Transpose": lambda g, i, a, o: [np.transpose(i[0], a.get("perm"))],
    "Concat": lambda g, i, a, o: [np.concatenate([_symbolic(v) for v in i] if any(not _constant(v) for v in i)
                                                 else i, axis=a["axis"])],
    "Slice": _slice, "Gather": _gather, "Split": _split, "Expand": _expand, "Tile": _tile, "Range": _range,
    "Where": _where, "Cast": cast, "Clip": _clip,
    "MatMul": lambda g, i, a, o: [_matmul(g, i[0], i[1])], "Gemm": _gemm,
    **{op: _reduce(op) for op in ("ReduceSum", "ReduceMean", "ReduceMax", "ReduceMin", "ReduceProd")},
    "LSTM": _recurrent("LSTM"), "GRU": _recurrent("GRU"), "Softmax": _softmax, "LayerNormalization": _layer_norm,
    "ScatterElements": _scatter(False), "ScatterND": _scatter(True),
}

