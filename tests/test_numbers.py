"""One rule for numbers people read: measures to three significant figures with their unit,
instants of a run to 10 ms (cellsim.numbers), in the terminal, the report and the dashboard alike."""

from __future__ import annotations

import pytest

from cellsim.numbers import instant, measure, percent, sig3


@pytest.mark.parametrize("value, text", [
    (0, "0"), (3.2, "3.20"), (12.345, "12.3"), (0.04567, "0.0457"), (123456.0, "1.23e+05"), (-2.5, "-2.50"),
    (7, "7.00"), (999.6, "1000"), ("welding", "welding"), (True, "true"), (float("nan"), "nan"),
    # rounding that crosses a power of ten keeps three figures, not four
    (0.9996, "1.00"), (99.96, "100"), (99999.6, "1.00e+05"), (0.00099996, "0.00100"),
])
def test_measures_have_three_significant_figures(value, text):
    assert sig3(value) == text


def test_units_follow_with_a_space_but_factors_and_shares_attach():
    assert measure(0.8261, "s") == "0.826 s"
    assert measure(36.27, "x") == "36.3x"
    assert percent(0.98888) == "98.9%" and percent(None) == "n/a"


def test_an_instant_keeps_ten_milliseconds_so_half_second_windows_read_true():
    assert instant(12.84) == "12.84 s" and instant(13.34) == "13.34 s" and instant(0) == "0.00 s"
