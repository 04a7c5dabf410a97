"""Numbers for people: printed to the precision they carry, never as "-0".

`fixed(x, decimals)` rounds to a number of decimals (a stage position to the micrometre: fixed(z, 3)
mm); `significant(x, digits)` keeps that many significant digits (a figure whose size varies). Both
print a value that rounds to zero as "0" with no sign, and NaN as "nan".
"""

from __future__ import annotations

import math


def fixed(x: float, decimals: int) -> str:
    """`x` with `decimals` decimals: fixed(-0.00183035, 3) -> '-0.002', fixed(-0.00004, 3) -> '0.000'."""
    x = float(x)
    if math.isnan(x):
        return "nan"
    text = f"{x:.{decimals}f}"
    return text[1:] if text.startswith("-") and float(text) == 0 else text


def significant(x: float, digits: int = 4) -> str:
    """`x` to `digits` significant digits (the `g` format): significant(0.000123456, 3) -> '0.000123',
    significant(-1e-20, 3) -> '-1e-20', significant(-0.0, 3) -> '0'."""
    x = float(x)
    if math.isnan(x):
        return "nan"
    text = f"{x:.{digits}g}"
    return text[1:] if text.startswith("-") and float(text) == 0 else text
