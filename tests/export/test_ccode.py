"""The ONNX step compiled to C (``hypa.export.ccode``), operation by operation, against ONNX's own reference
implementation (``onnx.reference``, the standard's semantics in numpy) in float64.

Each graph is a small step of its own making, (state, u) -> (next_state, y), with random
weights; the C step, compiled with ``-std=c99 -Wall -Wextra -Werror``, runs it for several
steps (its state fed back) and must equal the reference run of the same graph to rounding.
"""

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
from onnx import TensorProto, helper, numpy_helper  # noqa: E402
from onnx.reference import ReferenceEvaluator  # noqa: E402

from hypa.export.blocks import ExportError  # noqa: E402
from hypa.export.ccode import LOOP_SIZE, c_step  # noqa: E402

pytestmark = pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler")

HARNESS = r"""
#include <stdio.h>
#include "step.c"
int main(int argc, char **argv)
{
    (void)argc;
    FILE *f = fopen(argv[1], "rb");
    long n;
    double x[HYPA_STATE_SIZE + 1], next[HYPA_STATE_SIZE + 1], u[HYPA_INPUT_SIZE + 1], y[HYPA_OUTPUT_SIZE + 1];
    if (!f || fread(&n, sizeof n, 1, f) != 1 || fread(x, sizeof(double), HYPA_STATE_SIZE, f) != HYPA_STATE_SIZE)
        return 2;
    for (long k = 0; k < n; k++) {
        if (fread(u, sizeof(double), HYPA_INPUT_SIZE, f) != HYPA_INPUT_SIZE) return 3;
        hypa_step(x, u, next, y);
        for (int i = 0; i < HYPA_STATE_SIZE; i++) x[i] = next[i];
        fwrite(y, sizeof(double), HYPA_OUTPUT_SIZE, stdout);
        fwrite(x, sizeof(double), HYPA_STATE_SIZE, stdout);
    }
    return 0;
}
"""

RNG = np.random.default_rng(0)


def _constant(name: str, value) -> onnx.NodeProto:
    value = np.asarray(value)
    return helper.make_node("Constant", [], [name], value=numpy_helper.from_array(value, name))


def _model(nodes, r: int, m: int, p: int, initializers=()) -> onnx.ModelProto:
    graph = helper.make_graph(nodes, "step", [helper.make_tensor_value_info("state", TensorProto.DOUBLE, [r]),
                                              helper.make_tensor_value_info("u", TensorProto.DOUBLE, [m])],
                              [helper.make_tensor_value_info("next_state", TensorProto.DOUBLE, [r]),
                               helper.make_tensor_value_info("y", TensorProto.DOUBLE, [p])],
                              [numpy_helper.from_array(np.asarray(v), n) for n, v in initializers])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model


def _compare(tmp_path: Path, model: onnx.ModelProto, steps: int = 12, scale: float = 1.0, reference=None,
             **kwargs) -> str:
    """The C step equals the reference over ``steps`` steps from a random state; the C source."""
    path = tmp_path / "step.onnx"
    onnx.save(model, str(path))
    code = c_step(path, **kwargs)
    (tmp_path / "step.c").write_text(code.source)
    (tmp_path / "main.c").write_text(HARNESS)
    subprocess.run(["cc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", "-o", str(tmp_path / "main"),
                    str(tmp_path / "main.c"), "-lm"], check=True, capture_output=True, text=True)
    x0 = RNG.normal(size=code.state_size) * scale
    rows = RNG.normal(size=(steps, code.input_size)) * scale
    blob = np.array([steps], np.int64).tobytes() + x0.tobytes() + rows.tobytes()
    (tmp_path / "in.bin").write_bytes(blob)
    out = subprocess.run([str(tmp_path / "main"), str(tmp_path / "in.bin")], capture_output=True, check=True).stdout
    c = np.frombuffer(out, float).reshape(steps, -1)
    session = ReferenceEvaluator(model)
    x, expected = x0, []
    for row in rows:
        x, y = reference(x, row) if reference else session.run(["next_state", "y"], {"state": x, "u": row})
        expected.append(np.concatenate([y, x]))
    np.testing.assert_allclose(c, np.array(expected), rtol=1e-10, atol=1e-10)
    return code.source


def test_elementwise_operations_and_broadcasting(tmp_path) -> None:
    """Unary and binary operations, variadic Max/Min, comparisons into Where, Cast, Clip: the state (3,)
    against a (2, 3) table of constants."""
    table = RNG.normal(size=(2, 3))
    nodes = [_constant("table", table), _constant("two", np.array(2.0)), _constant("shape", np.array([1, 3])),
             helper.make_node("Reshape", ["state", "shape"], ["x"]),
             helper.make_node("Mul", ["x", "table"], ["a"]),
             helper.make_node("Add", ["a", "two"], ["b"]),
             helper.make_node("Tanh", ["b"], ["c1"]), helper.make_node("Sigmoid", ["a"], ["c2"]),
             helper.make_node("Relu", ["a"], ["c3"]), helper.make_node("Abs", ["a"], ["c4"]),
             helper.make_node("Softplus", ["a"], ["c5"]), helper.make_node("Cos", ["a"], ["c6"]),
             helper.make_node("Sign", ["a"], ["c7"]), helper.make_node("Neg", ["a"], ["c8"]),
             helper.make_node("Exp", ["c1"], ["c9"]), helper.make_node("Log", ["c9"], ["c10"]),
             helper.make_node("Sqrt", ["c4"], ["c11"]), helper.make_node("Pow", ["c4", "two"], ["c12"]),
             helper.make_node("Max", ["c1", "c2", "c3"], ["d1"]), helper.make_node("Min", ["c5", "c6", "c7"], ["d2"]),
             helper.make_node("Less", ["a", "c8"], ["less"]),
             helper.make_node("Where", ["less", "d1", "d2"], ["e"]),
             helper.make_node("Cast", ["less"], ["f"], to=TensorProto.DOUBLE),
             helper.make_node("Clip", ["c10", "c8", "two"], ["g"]),
             helper.make_node("Floor", ["c12"], ["h"]), helper.make_node("Reciprocal", ["b"], ["i"]),
             helper.make_node("Div", ["e", "i"], ["j"]), helper.make_node("Sub", ["j", "f"], ["k"]),
             helper.make_node("Add", ["k", "g"], ["sum"]),
             helper.make_node("Add", ["sum", "h"], ["total"]),
             helper.make_node("ReduceSum", ["total", "axes0"], ["next2"], keepdims=0), _constant("axes0", [0]),
             helper.make_node("Tanh", ["next2"], ["next_state"]),
             helper.make_node("ReduceMean", ["total"], ["mean"], axes=[1], keepdims=0),
             helper.make_node("ReduceMax", ["c9"], ["most"], axes=[0, 1], keepdims=1),
             helper.make_node("Reshape", ["most", "one"], ["most1"]), _constant("one", np.array([1])),
             helper.make_node("Concat", ["mean", "most1", "u"], ["y"], axis=0)]
    nodes.sort(key=lambda n: n.op_type != "Constant")  # constants first, as an exporter writes them
    _compare(tmp_path, _model(nodes, 3, 2, 5))


def test_erf_is_libm_s(tmp_path) -> None:
    """Erf (a GELU's), against math.erf: onnx.reference's own is a float32 approximation."""
    import math

    nodes = [helper.make_node("Erf", ["state"], ["next_state"]), helper.make_node("Erf", ["u"], ["y"])]
    erf = np.vectorize(math.erf)
    _compare(tmp_path, _model(nodes, 2, 1, 1), reference=lambda x, u: (erf(x), erf(u)))


def test_data_movement_costs_nothing(tmp_path) -> None:
    """Slice (negative steps), Gather (negative indices), Split, Transpose, Squeeze, Unsqueeze, Expand, Tile,
    Concat, Shape -> ConstantOfShape: pure rearrangements that compile to assignments."""
    nodes = [_constant("starts", [-1]), _constant("ends", [-100]), _constant("axes", [0]), _constant("steps", [-2]),
             _constant("index", [[-1, 0], [2, 1]]), _constant("zero", [0]), _constant("sizes", [2, 4]),
             _constant("shape", [2, 3]), _constant("reps", [2]), _constant("wide", [2, 6]),
             helper.make_node("Slice", ["state", "starts", "ends", "axes", "steps"], ["odd"]),  # state[5], [3], [1]
             helper.make_node("Gather", ["state", "index"], ["picked"], axis=0),  # (2, 2)
             helper.make_node("Split", ["state", "sizes"], ["head", "tail"], axis=0),
             helper.make_node("Flatten", ["picked"], ["flat2"], axis=0),
             helper.make_node("Unsqueeze", ["odd", "zero"], ["row"]),  # (1, 3)
             helper.make_node("Expand", ["row", "shape"], ["grid"]),  # (2, 3)
             helper.make_node("Transpose", ["grid"], ["gridT"], perm=[1, 0]),
             helper.make_node("Shape", ["gridT"], ["gshape"]),
             helper.make_node("ConstantOfShape", ["gshape"], ["ones"],
                              value=numpy_helper.from_array(np.array([1.5]))),
             helper.make_node("Mul", ["gridT", "ones"], ["scaled"]),
             helper.make_node("Tile", ["u", "reps"], ["uu"]),
             helper.make_node("Squeeze", ["flat2", "zero"], ["four"]),
             helper.make_node("Reshape", ["scaled", "minus"], ["six"]), _constant("minus", [-1]),
             helper.make_node("Concat", ["tail", "head"], ["next_state"], axis=0),
             helper.make_node("Concat", ["four", "six", "uu"], ["y"], axis=0)]
    nodes.sort(key=lambda n: n.op_type != "Constant")
    source = _compare(tmp_path, _model(nodes, 6, 2, 14))
    body = source[source.index("{", source.index("hypa_step(")):]
    assert body.count("const double") == 3  # the Mul by 1.5 of the three sliced entries; the moves are assignments


@pytest.mark.parametrize("size", [3, 40])
def test_products_unrolled_or_looped(tmp_path, size: int) -> None:
    """MatMul and Gemm with a constant matrix (its zeros left out when unrolled, a loop over a static array
    beyond LOOP_SIZE entries), a product of two inputs, batched MatMul."""
    weights = RNG.normal(size=(size, size))
    weights[0, :] = 0.0
    gemm_b = RNG.normal(size=(2, size))
    bias = RNG.normal(size=(size,))
    nodes = [_constant("row", [1, size]), _constant("col", [size, 1]), _constant("pair", [2, 1, 1]),
             _constant("usq", [2, 1]), _constant("minus", [-1]), _constant("one", [1]),
             helper.make_node("Reshape", ["state", "row"], ["x"]),
             helper.make_node("MatMul", ["x", "W"], ["xw"]),
             helper.make_node("Reshape", ["u", "usq"], ["u2"]),
             helper.make_node("Gemm", ["u2", "B", "bias"], ["ub"], transA=1, alpha=0.5, beta=2.0),
             helper.make_node("Add", ["xw", "ub"], ["z"]),
             helper.make_node("Tanh", ["z"], ["zt"]),
             helper.make_node("Reshape", ["zt", "minus"], ["next_state"]),
             helper.make_node("Reshape", ["state", "col"], ["xc"]),
             helper.make_node("MatMul", ["xc", "x"], ["outer"]),  # (size, size), two inputs
             helper.make_node("ReduceSum", ["outer"], ["total"], keepdims=0),
             helper.make_node("Reshape", ["u", "pair"], ["ub3"]),
             helper.make_node("Transpose", ["ub3"], ["ub3T"], perm=[0, 2, 1]),
             helper.make_node("MatMul", ["ub3", "ub3T"], ["batched"]),  # (2, 1, 1) @ (2, 1, 1)
             helper.make_node("Reshape", ["batched", "minus"], ["bflat"]),
             helper.make_node("Reshape", ["total", "one"], ["total1"]),
             helper.make_node("Concat", ["total1", "bflat"], ["y"], axis=0)]
    model = _model(nodes, size, 2, 3, [("W", weights), ("B", gemm_b), ("bias", bias)])
    source = _compare(tmp_path, model, scale=0.3)
    assert ("for (int i = 0;" in source) == (size * size > LOOP_SIZE)


def _recurrent(kind: str, hidden: int, width: int, before_reset: int = 1) -> onnx.ModelProto:
    gates = {"LSTM": 4, "GRU": 3}[kind]
    w = RNG.normal(size=(1, gates * hidden, width)) * 0.5
    r = RNG.normal(size=(1, gates * hidden, hidden)) * 0.5
    b = RNG.normal(size=(1, 2 * gates * hidden)) * 0.5
    states = 2 if kind == "LSTM" else 1
    nodes = [_constant("x_shape", [1, 1, width]), _constant("h_shape", [1, 1, hidden]), _constant("flat", [-1]),
             _constant("h_start", [0]), _constant("h_end", [hidden]), _constant("c_end", [2 * hidden]),
             helper.make_node("Reshape", ["u", "x_shape"], ["x"]),
             helper.make_node("Slice", ["state", "h_start", "h_end"], ["h_flat"]),
             helper.make_node("Reshape", ["h_flat", "h_shape"], ["h0"])]
    extra = {"linear_before_reset": before_reset} if kind == "GRU" else {}
    inputs = ["x", "W", "R", "B", "", "h0"]
    if kind == "LSTM":
        nodes += [helper.make_node("Slice", ["state", "h_end", "c_end"], ["c_flat"]),
                  helper.make_node("Reshape", ["c_flat", "h_shape"], ["c0"])]
        inputs.append("c0")
    outputs = ["Y", "Y_h", "Y_c"][: 1 + states]
    nodes += [helper.make_node(kind, inputs, outputs, hidden_size=hidden, **extra),
              helper.make_node("Reshape", ["Y_h", "flat"], ["h1"]),
              *([helper.make_node("Reshape", ["Y_c", "flat"], ["c1"])] if kind == "LSTM" else []),
              helper.make_node("Concat", ["h1", "c1"] if kind == "LSTM" else ["h1"], ["next_state"], axis=0),
              helper.make_node("Reshape", ["Y", "flat"], ["y0"]),
              helper.make_node("Mul", ["y0", "gain"], ["y"]), _constant("gain", np.array(1.5))]
    nodes.sort(key=lambda n: n.op_type != "Constant")
    return _model(nodes, states * hidden, width, hidden, [("W", w), ("R", r), ("B", b)])


@pytest.mark.parametrize("kind, before_reset", [("LSTM", 1), ("GRU", 1), ("GRU", 0)])
def test_recurrent_cells(tmp_path, kind: str, before_reset: int) -> None:
    """ONNX's LSTM (gates i, o, f, c) and GRU (z, r, h; torch's linear-before-reset, and the other form) as
    loops over static weights, their state carried through the step's."""
    source = _compare(tmp_path, _recurrent(kind, 5, 3, before_reset), steps=20)
    assert "static const double" in source


def test_attention_and_normalization(tmp_path) -> None:
    """Softmax, LayerNormalization (a Transformer's, S4's), ScatterElements and ScatterND with constant indices
    (Mamba's state update through torch's dynamo exporter)."""
    scale, bias = RNG.normal(size=4), RNG.normal(size=4)
    nodes = [_constant("shape", [2, 4]), _constant("flat", [-1]), _constant("where", [[1, 0, 3, 2]]),
             _constant("cells", [[0, 1], [1, 3]]),
             helper.make_node("Reshape", ["state", "shape"], ["x"]),
             helper.make_node("Softmax", ["x"], ["soft"], axis=0),
             helper.make_node("LayerNormalization", ["soft", "scale", "bias"], ["normal"], axis=-1, epsilon=1e-3),
             helper.make_node("Slice", ["x", "zero", "one", "zero"], ["first"]), _constant("zero", [0]),
             _constant("one", [1]),
             helper.make_node("ScatterElements", ["normal", "where", "first"], ["scattered"], axis=1),
             helper.make_node("ScatterND", ["scattered", "cells", "u"], ["put"]),
             helper.make_node("Reshape", ["put", "flat"], ["next_state"]),
             helper.make_node("Softmax", ["u"], ["y"])]
    nodes.sort(key=lambda n: n.op_type != "Constant")
    _compare(tmp_path, _model(nodes, 8, 2, 2, [("scale", scale), ("bias", bias)]))


def test_an_operation_without_a_c_form_is_refused_naming_the_block(tmp_path) -> None:
    nodes = [helper.make_node("Einsum", ["state"], ["next_state"], name="/attention/layers/Einsum", equation="i->i"),
             helper.make_node("Identity", ["u"], ["y"], name="/Identity")]
    path = tmp_path / "step.onnx"
    onnx.save(_model(nodes, 3, 1, 1), str(path))
    with pytest.raises(ExportError) as caught:
        c_step(path, {"attention": "TransformerBlock network"})
    message = str(caught.value)
    assert "\n" not in message
    assert "block 'attention' (TransformerBlock network) uses the ONNX operation Einsum" in message
    assert "format=fmu" in message


def test_an_input_of_another_name_or_shape_is_refused(tmp_path) -> None:
    graph = helper.make_graph([helper.make_node("Identity", ["state"], ["next_state"]),
                               helper.make_node("Identity", ["u"], ["y"])], "step",
                              [helper.make_tensor_value_info("state", TensorProto.DOUBLE, [2, 2]),
                               helper.make_tensor_value_info("u", TensorProto.DOUBLE, [1])],
                              [helper.make_tensor_value_info("next_state", TensorProto.DOUBLE, [2, 2]),
                               helper.make_tensor_value_info("y", TensorProto.DOUBLE, [1])])
    path = tmp_path / "step.onnx"
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]), str(path))
    with pytest.raises(ExportError, match="each a vector of fixed size"):
        c_step(path)
