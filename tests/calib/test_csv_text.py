"""calib.csv_text against Python's own %-formatting (CPython's correctly rounded dtoa), value by value."""

import numpy as np
import pytest

from calib.csv_text import format_rows


def python_rows(columns, formats) -> str:
    """The independent reference: one Python %-format per value."""
    return "".join(",".join(f % v for f, v in zip(formats, row)) + "\n"
                   for row in zip(*(np.asarray(c).tolist() for c in columns)))


def near_ties(rng, decimals: int, n: int) -> np.ndarray:
    """Values at, just below and just above the halfway points between two `decimals`-digit numbers
    (the doubles nearest to (k + 1/2) / 10^decimals and their neighbours), either sign."""
    k = rng.integers(0, 10 ** min(decimals + 3, 15), n)
    tie = (k + 0.5) / 10.0 ** decimals
    v = np.concatenate([tie, np.nextafter(tie, 0), np.nextafter(tie, np.inf)])
    return v * rng.choice([-1.0, 1.0], v.size)


SPECIAL = [0.0, -0.0, np.nan, -np.nan, np.inf, -np.inf, 0.5, 1.5, 2.5, -0.5, 0.125, 0.375, 1e-300, -1e-300,
           5e-324, 1e15, 1e20, -1e20, 2.0 ** 50 / 1e6, 2.0 ** 53, 123456.5, 999999.9999995, 0.0000005, -0.0000005,
           1.0000005, 2.675, 1.005]


@pytest.mark.parametrize("decimals", [0, 1, 4, 5, 6, 7, 12, 15, 16, 20])
def test_fixed_point_matches_python_on_random_values_ties_and_specials(decimals):
    rng = np.random.default_rng(decimals)
    values = np.concatenate([rng.normal(0, 1, 3000), rng.normal(0, 1e4, 3000) * rng.random(3000) ** 8,
                             rng.uniform(-1e-6, 1e-6, 1000), near_ties(rng, decimals, 2000), SPECIAL])
    fmt = f"%.{decimals}f"
    assert format_rows([values], [fmt]) == python_rows([values], [fmt])


def test_fixed_point_of_float32_integer_and_bool_columns():
    rng = np.random.default_rng(1)
    columns = [rng.normal(0, 3, 2000).astype(np.float32), rng.integers(-10 ** 6, 10 ** 6, 2000),
               rng.random(2000) < 0.5]
    formats = ["%.6f", "%.3f", "%.2f"]
    assert format_rows(columns, formats) == python_rows(columns, formats)


def test_g_on_whole_numbers_fractions_large_and_special_values():
    rng = np.random.default_rng(2)
    values = np.concatenate([rng.integers(-10 ** 7, 10 ** 7, 3000).astype(float), rng.normal(0, 100, 1000),
                             [999999.0, 1e6, -999999.0, -1e6, 1e-5, 123.5, 0.1], SPECIAL])
    assert format_rows([values], ["%g"]) == python_rows([values], ["%g"])
    ints = rng.integers(-10 ** 7, 10 ** 7, 1000)
    assert format_rows([ints], ["%g"]) == python_rows([ints], ["%g"])


def test_d_on_signed_unsigned_and_bool_columns():
    rng = np.random.default_rng(3)
    columns = [rng.integers(-2 ** 62, 2 ** 62, 2000), rng.integers(-9, 10, 2000).astype(np.int8),
               rng.integers(0, 2 ** 31, 2000).astype(np.uint32), rng.random(2000) < 0.3,
               np.array([0, -1, 10, -10, 99, 100, -100, 10 ** 18] * 250)]
    formats = ["%d"] * len(columns)
    assert format_rows(columns, formats) == python_rows(columns, formats)


def test_strings_of_every_kind_and_formats_left_to_python():
    rng = np.random.default_rng(4)
    words = np.array(["ok", "no_texture", "", "left:diverged", "ray_gap"])
    pick = rng.integers(0, len(words), 500)
    text = words[pick]
    objects = text.astype(object)
    accented = np.array(["déformé", "ok"])[pick % 2]
    numbers = rng.normal(0, 1e3, 500)
    columns = [text, objects, accented, numbers, numbers, numbers]
    formats = ["%s", "%s", "%s", "%.3e", "%8.2f", "%.4E"]
    assert format_rows(columns, formats) == python_rows(columns, formats)
    assert format_rows([text.astype("S")], ["%s"]) == python_rows([text], ["%s"])  # bytes: their characters


def test_a_dic_row_layout_with_nan_where_not_converged():
    rng = np.random.default_rng(5)
    n = 20_000
    ok = rng.random(n) < 0.9
    u = np.where(ok, rng.normal(2.3, 0.5, n), np.nan)
    columns = [np.full(n, 3), rng.integers(10, 2038, n).astype(float), rng.integers(10, 2038, n).astype(float), u,
               -u, np.where(ok, rng.random(n), np.nan), ok, np.where(ok, "ok", "low_zncc"), rng.integers(0, 40, n),
               rng.random(n) * 0.02]
    formats = ["%d", "%g", "%g", "%.6f", "%.6f", "%.6f", "%d", "%s", "%d", "%.5f"]
    assert format_rows(columns, formats) == python_rows(columns, formats)


def test_empty_columns_and_a_mismatch_of_columns_and_formats():
    assert format_rows([np.zeros(0), np.zeros(0, int)], ["%.6f", "%d"]) == ""
    with pytest.raises(ValueError):
        format_rows([np.zeros(3)], ["%d", "%d"])


@pytest.mark.parametrize("fmt", ["%.0f", "%.1f", "%.6f", "%g"])
def test_columns_of_nan_and_infinities_alone_and_among_narrow_values(fmt):
    """NaN and the infinities are spelled by the formatter itself (not left to Python): a column of nothing
    else, whose fields are narrower than "-inf", and float32 ones."""
    special = np.array([np.nan, -np.nan, np.inf, -np.inf] * 5)
    small = np.array([0.0, 1.0, -2.0, np.nan, 3.0, np.inf, -0.0, -np.inf])
    for values in (special, small, special.astype(np.float32), np.array([7.0, np.nan])):
        assert format_rows([values, values], [fmt, fmt]) == python_rows([values, values], [fmt, fmt])
