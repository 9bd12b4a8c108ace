"""hypa.reporting.numbers.change_text: one rule for the relative change of an error in every report, and a fit
that diverged reads "did not converge", never "-8.5e19 %"; the reports' JSON holds null, not NaN."""

import json
import math

import numpy as np
import pytest

from hypa.reporting.markdown import json_ready
from hypa.reporting.numbers import DIVERGED, change_text, percent_change, r_squared, share_text


@pytest.mark.parametrize("change, text", [
    (-0.95, "-95 %"), (0.032, "+3.2 %"), (-0.004, "-0.4 %"), (-0.0042, "-0.42 %"), (0.05, "+5 %"),
    (1.5, "+150 %"), (0.0996, "+10 %"), (0.099, "+9.9 %"), (-0.8, "-80 %"), (12.345, "+1234 %"),
    (0.0, "0 %"), (1e-7, "0 %"),
    (-0.996, "-99.6 %"), (-0.9996, "-99.96 %"), (-1.0, "-100 %"),  # a drop reads -100 % only where it is one
])
def test_two_significant_digits_at_least_whole_percent(change: float, text: str) -> None:
    assert change_text(change) == text


@pytest.mark.parametrize("change", [8.5e17, 1.1e23, DIVERGED, math.inf, -math.inf, math.nan])
def test_a_diverged_error_did_not_converge(change: float) -> None:
    text = change_text(change)
    assert text.startswith("did not converge") and "e+" not in text and "%" not in text


def test_the_cap_is_a_factor_of_the_error_and_none_is_unknown() -> None:
    assert change_text(DIVERGED - 1) == "+9900 %"  # 100 times the error: still a number
    assert change_text(DIVERGED - 0.5).startswith("did not converge")
    assert change_text(None) == "–"


def test_percent_change_of_two_errors() -> None:
    assert percent_change(2.0, 2.1) == "+5 %" and percent_change(2.0, 0.1) == "-95 %"
    assert percent_change(1.0, 8.5e19) == "did not converge (error more than 100×)"
    assert percent_change(0.0, 0.0) == "0 %" and percent_change(0.0, 1.0) == "did not converge"


def test_a_share_of_the_variance() -> None:
    assert share_text(0.015) == "1.5 %" and share_text(1.2) == "120 %"
    assert share_text(8.5e17) == "did not converge" and share_text(math.nan) == "did not converge"


def test_json_ready_writes_null_for_what_is_not_finite() -> None:
    value = {"a": [1.0, math.nan, (math.inf, -math.inf)], "b": {"c": np.float64(np.nan), "d": np.float32(0.5)},
             "e": "text", "f": True, "g": None, "h": 3}
    ready = json_ready(value)
    assert ready == {"a": [1.0, None, [None, None]], "b": {"c": None, "d": 0.5}, "e": "text", "f": True, "g": None,
                     "h": 3}
    json.dumps(ready, allow_nan=False)  # valid JSON: no NaN or Infinity


def test_the_formats_markdown_re_exported_are_found_with_a_deprecation_warning() -> None:
    import pytest

    from hypa.reporting import markdown, numbers

    with pytest.warns(DeprecationWarning, match="hypa.reporting.numbers.change_text"):
        assert markdown.change_text is numbers.change_text
    with pytest.raises(AttributeError):
        markdown.no_such_format  # noqa: B018


def test_r_squared_never_reads_one_while_it_is_not() -> None:
    """4 decimals, or as many as show 1 - R² to two significant digits (a near-perfect fit of the
    Wiener-Hammerstein circuit, 0.9999963, read 1.0000 in the benchmark's table)."""
    assert [r_squared(v) for v in (0.9842, 0.99934, 0.9999963, 1.0, -3.2, 0.999)] == [
        "0.9842", "0.99934", "0.9999963", "1.0000", "-3.2000", "0.9990"]
    assert r_squared(float("nan")) == r_squared(None) == "–"
    assert r_squared(1 - 1e-12) == "1.00000000"  # at most 8 decimals
