"""Derived channels: safe expressions over a file's columns and scalars, never `eval`."""

from __future__ import annotations

import numpy as np
import pytest

from hypa.data import ChannelSpec, DataError, Expression, load_record

from data_helpers import write_table


def test_arithmetic_functions_constants_and_backticked_columns():
    values = {"vx(m/s)": np.array([1.0, 2.0, -1.0]), "vy(m/s)": np.array([0.0, 2.0, 1.0]),
              "gain": 2.5, "x": np.array([1.0, 4.0, 9.0])}
    beta = Expression("arctan2(`vy(m/s)`, `vx(m/s)`)", "side_slip")
    assert beta.names == ("vy(m/s)", "vx(m/s)")
    np.testing.assert_allclose(beta.evaluate(values), np.arctan2(values["vy(m/s)"], values["vx(m/s)"]))
    expr = Expression("-gain * sqrt(x) ** 2 / 2 + abs(-x) % 4 + deg2rad(180) - pi", "y")
    assert expr.names == ("gain", "x")
    expected = -2.5 * values["x"] / 2 + values["x"] % 4
    np.testing.assert_allclose(expr.evaluate(values), expected, atol=1e-12)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("__import__('os').system('true')", r"calls \"__import__\('os'\).system\", which is not allowed"),
        ("x.real", r"holds 'x.real' \(Attribute\), which is not allowed"),
        ("x[0]", r"\(Subscript\), which is not allowed"),
        ("x if x else 1", r"\(IfExp\)"),
        ("x < 3", r"\(Compare\)"),
        ("(lambda: 1)()", r"calls 'lambda: 1'"),
        ("eval('1')", r"calls 'eval', which is not allowed.*functions: abs, sqrt"),
        ("clip(x, a_min=0)", r"keyword arguments are not allowed"),
        ("'text'", r"\(Constant\)"),
        ("x +", r"is not valid"),
    ],
)
def test_disallowed_constructs_are_refused_before_any_file_is_read(text, message):
    with pytest.raises(DataError, match=message) as error:
        ChannelSpec("c", "input", "-", expression=text)
    assert "channel 'c'" in str(error.value) and "\n" not in str(error.value)


def test_huge_powers_fail_cleanly():
    with pytest.raises(DataError, match="fails"):
        Expression("9 ** 9 ** 9", "c").evaluate({})


def test_unknown_name_names_the_file_and_the_closest_column(tmp_path):
    path = write_table(tmp_path / "run.csv", {"time": np.arange(4) / 10, "vx(m/s)": np.ones(4),
                                              "vy(m/s)": np.zeros(4), "u": np.arange(4.0)})
    spec = ChannelSpec("side_slip", "output", "rad", expression="arctan2(vy, vx)")
    with pytest.raises(DataError, match=r"run.csv: expression of channel 'side_slip' uses 'vy', which the "
                                        r"file does not have \(did you mean `vy\(m/s\)`\?\)"):
        load_record(path, [ChannelSpec("u", "input", "-"), spec], sample_rate_hz=10.0)


def test_mat_scalars_are_usable_and_the_result_is_converted_to_si(tmp_path):
    """EMPS-like: force = gtau * vir, gtau a 1x1 MATLAB variable; the result's unit is kN here."""
    vir = np.linspace(-1, 1, 50)
    path = write_table(tmp_path / "a.mat", {"t": np.arange(50) / 1000, "vir": vir, "qm": vir ** 3,
                                            "gtau": np.array([[35.0]])}, mat_oned_as="column")
    channels = [ChannelSpec("force", "input", "kN", expression="gtau * vir"),
                ChannelSpec("position", "output", "m", column="qm")]
    record = load_record(path, channels, time_column="t", sample_rate_hz=1000.0)
    np.testing.assert_allclose(record["force"], 35.0 * vir * 1e3)
    assert record.names == ("force", "position")


def test_non_finite_expression_result_names_the_channel_and_row(tmp_path):
    path = write_table(tmp_path / "a.csv", {"time": np.arange(5) / 10, "x": np.array([1.0, 2, 0, 4, 5])})
    channels = [ChannelSpec("u", "input", "-", column="x"),
                ChannelSpec("y", "output", "-", expression="1 / x")]
    with pytest.raises(DataError, match=r"a.csv: channel 'y' \(1 / x\) has 1 missing or non-finite.*row 2"):
        load_record(path, channels, sample_rate_hz=10.0)
