"""Parameter values with units: converted to the unit a ParameterSpec declares, refused in one line otherwise."""

import pytest

from hypa.core.units import GivenQuantity, given_value, value_in
from hypa.physics import ParameterSpec


@pytest.mark.parametrize(("given", "declared", "expected"), [
    ("2.5 Ah", "C", 9000.0), ("40 mOhm", "ohm", 0.04), ("40 mΩ", "ohm", 0.04),
    ({"value": 1.5, "unit": "kF"}, "F", 1500.0),
    ("25 degC", "K", 298.15), ("30 deg", "rad", 0.5235987755982988), ("2 kN/m", "N/m", 2000.0), (3, "C", 3.0),
    ("4.5", "C", 4.5), ("1 day", "s", 86400.0),
])
def test_values_are_converted_to_the_declared_unit(given, declared, expected) -> None:
    assert value_in(given, declared, "p") == pytest.approx(expected, rel=1e-12)
    assert ParameterSpec("p", given, declared, positive=False).value == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize(("given", "declared", "message"), [
    ("2.5 V", "C", "capacity: 2.5 V is not a charge (the class declares C)"),
    ("1 deg", "-", "capacity: 1 deg is not dimensionless (the class declares -)"),
    ("2 foo", "C", "capacity: unknown unit 'foo' in '2 foo'"),
    ("abc", "C", "capacity: cannot read 'abc' as a number with a unit"),
    ({"value": 1}, "C", "capacity: a value with a unit is {value: <number>, unit: <unit>}"),
    ("2 Ah", "zorks", "capacity: 2 Ah has a unit, but the class declares"),
])
def test_a_wrong_unit_is_one_line(given, declared, message) -> None:
    with pytest.raises(ValueError) as error:
        ParameterSpec("capacity", given, declared)
    assert str(error.value).startswith(message) and "\n" not in str(error.value)


def test_a_configured_value_keeps_how_it_was_given() -> None:
    given = given_value("2.5 Ah", "parameters.capacity")
    assert isinstance(given, GivenQuantity) and float(given) == 9000.0 and str(given) == "2.5 Ah"
    assert given_value(2.5, "x") == 2.5 and type(given_value("2.5", "x")) is float
    assert ParameterSpec("capacity", given, "C").value == 9000.0
