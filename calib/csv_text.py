"""Rows of CSV text from columns of numbers, formatted by numpy array operations instead of value by value.

`format_rows(columns, formats)` gives exactly the text of
``"".join(",".join(f % v for f, v in zip(formats, row)) + "\\n" for row in zip(*columns))`` for the
%-formats `%d` (integers, bools), `%s` (strings), `%g` and `%.Nf`, in a small fraction of the time: every
field is spelled digit by digit into its own slot of a (rows, characters) byte matrix whose unused bytes
are NUL, and the text is the matrix with its NULs taken out, BLOCK_ROWS rows at a time.

Fixed-point fields (`%.Nf`) are rounded as Python rounds them, to the nearest of the exact binary value
scaled by 10^N (ties to even): the scaled value v * 10^N is computed in float64, within half a unit in its
last place of the exact product, so its nearest integer is the right one unless it lies within one unit in
the last place of a half-integer. Those few values, `%g` values that are not integers below 10^6 in
magnitude and values beyond 2^50 scaled are formatted by Python itself (`_python`), as is any other format
and `%.Nf` with N > 15; NaN and the infinities are spelled as Python spells them.
"""

from __future__ import annotations

import re
from typing import Sequence

import numpy as np

_FIXED = re.compile(r"%\.(\d+)f$")
_TENS = np.repeat(np.arange(48, 58, dtype=np.uint8), 10)   # the characters of k // 10 and k % 10, k < 100
_UNITS = np.tile(np.arange(48, 58, dtype=np.uint8), 10)
_LARGEST = 2.0 ** 50   # scaled values up to this are whole numbers of float64 and int64 exactly
NUL, MINUS, DOT, COMMA, NEWLINE = 0, ord("-"), ord("."), ord(","), ord("\n")
BLOCK_ROWS = 8192      # rows formatted at once: a few MB of byte matrices, in cache and reused block after block


def _digits(n: np.ndarray, out: np.ndarray, *, leading: bool) -> None:
    """The decimal digits of non-negative integers `n` (N,), right-aligned, into `out` (N, width)
    uint8; with `leading` False the leading zeros are NUL (a zero keeps its one digit)."""
    width = out.shape[1]
    rest = n.astype(np.uint32 if width <= 9 else np.uint64)
    hundred = rest.dtype.type(100)
    for j in range(width - 2, -2, -2):                # two digits at a time, from tables of "00".."99"
        rest, pair = np.divmod(rest, hundred)
        out[:, j + 1] = _UNITS[pair]
        if j >= 0:
            out[:, j] = _TENS[pair]
    if not leading:
        for j in range(width - 1):                    # a digit before the first significant one
            out[:, j] *= n >= 10 ** (width - 1 - j)


def _integers(n: np.ndarray, negative: np.ndarray, tail: int = 0) -> np.ndarray:
    """(N, W + tail) uint8 fields: '-' where `negative`, then the digits of the magnitudes `n` (N,), then
    `tail` bytes left for the caller to fill."""
    width = len(str(int(n.max()))) if n.size else 1
    field = np.empty((n.size, 1 + width + tail), np.uint8)
    np.multiply(negative, MINUS, out=field[:, 0], casting="unsafe")
    _digits(n, field[:, 1:1 + width], leading=False)
    return field


def _fixed(values: np.ndarray, decimals: int) -> tuple[np.ndarray, np.ndarray]:
    """(fields (N, W) uint8, fallback (N,) bool) of `%.{decimals}f`; fallback: the values left to Python."""
    scaled = np.abs(values) * 10.0 ** decimals
    nearest = np.rint(scaled)
    with np.errstate(invalid="ignore"):
        # a unit in the last place of `scaled` is at most scaled * 2^-52
        fallback = (np.abs(np.abs(scaled - nearest) - 0.5) <= scaled * 2.0 ** -52) | ~(scaled < _LARGEST)
    nearest[fallback] = 0.0
    whole, fraction = np.divmod(nearest.astype(np.int64), 10 ** decimals)
    fields = _integers(whole, np.signbit(values), decimals + (decimals > 0))
    if decimals:
        fields[:, -decimals - 1] = DOT
        _digits(fraction, fields[:, -decimals:], leading=True)
    return fields, fallback


def _whole_g(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(fields, fallback) of `%g`: integers below 10^6 in magnitude spelled as integers (what %g does);
    the others (fractions, larger values, NaN, infinities) left to Python."""
    a = np.abs(values)
    with np.errstate(invalid="ignore"):
        fallback = ~((a < 1e6) & (a == np.floor(a)))
    return _integers(np.where(fallback, 0.0, a).astype(np.int64), np.signbit(values)), fallback


def _strings(values: np.ndarray) -> np.ndarray:
    """(N, W) uint8 fields of strings (bytes as they are, text in UTF-8), NUL-padded."""
    values = np.ascontiguousarray(values.ravel())
    if values.dtype.kind == "U":
        width = values.dtype.itemsize // 4
        codes = values.view(np.uint32).reshape(values.size, width)   # UCS-4 code points, NUL-padded
        if width and codes.max() < 128:
            return codes.astype(np.uint8)
        values = np.char.encode(values, "utf-8")
    width = max(values.dtype.itemsize, 1)
    return values.astype(f"S{width}").view(np.uint8).reshape(values.size, width)


def _column(values: np.ndarray, fmt: str) -> np.ndarray:
    """(N, W) uint8 fields of one column; NUL where a field is shorter than W."""
    values = np.asarray(values)
    fields = fallback = None
    if fmt == "%s" and values.dtype.kind in "SUO":
        return _strings(values.astype(str) if values.dtype.kind == "O" else values)
    if fmt == "%d" and values.dtype.kind in "biu":
        n = values.astype(np.int64)
        return _integers(np.abs(n), n < 0)
    fixed = _FIXED.match(fmt)
    fixed = fixed and int(fixed.group(1)) <= 15      # 10^N exact, and N digits of an int64
    if values.dtype.kind in "fiub" and (fixed or fmt == "%g"):
        v = np.asarray(values, np.float64)
        fields, fallback = _fixed(v, int(fmt[2:-1])) if fixed else _whole_g(v)
        fields, fallback = _non_finite(v, fields, fallback)
    if fields is None:          # any other format: Python's own
        fields, fallback = np.zeros((values.size, 0), np.uint8), np.ones(values.size, bool)
    return _python(fields, fallback, values, fmt)


def _non_finite(values: np.ndarray, fields: np.ndarray, fallback: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(fields, fallback) with NaN, inf and -inf spelled as `%g` and `%.Nf` spell them ("nan" whatever
    its sign, "inf", "-inf") in their rows of `fields` (N, W) uint8 (widened to 4 if narrower), and taken
    out of `fallback` (N,) bool."""
    bad = ~np.isfinite(values)
    if not bad.any():
        return fields, fallback
    if fields.shape[1] < 4:
        fields = np.hstack([fields, np.zeros((fields.shape[0], 4 - fields.shape[1]), np.uint8)])
    v = values[bad]
    words = np.where(np.isnan(v), b"nan", np.where(v > 0, b"inf", b"-inf")).astype("S4")
    fields[bad] = NUL
    fields[bad, :4] = words.view(np.uint8).reshape(-1, 4)
    return fields, fallback & ~bad


def _python(fields: np.ndarray, fallback: np.ndarray, values: np.ndarray, fmt: str) -> np.ndarray:
    """`fields` (N, W) uint8 with the rows where `fallback` (N,) bool replaced by Python's `fmt % value`
    (widened when those are longer)."""
    idx = np.flatnonzero(fallback)
    if idx.size == 0:
        return fields
    texts = [(fmt % v).encode("utf-8") for v in values[idx].tolist()]
    width = max(fields.shape[1], max(len(t) for t in texts))
    out = np.zeros((fields.shape[0], width), np.uint8)
    out[:, :fields.shape[1]] = fields
    out[idx] = np.array(texts, f"S{width}").view(np.uint8).reshape(idx.size, width)
    return out


def format_rows(columns: Sequence[np.ndarray], formats: Sequence[str]) -> str:
    """CSV rows: one per index of the columns, their values formatted with their %-formats, separated by
    commas, each row newline-terminated (module docstring).

    Parameters
    ----------
    columns : sequence of (N,) arrays
        Integers or bools (for `%d`), numbers (`%g`, `%.Nf`, any other %-format), strings (`%s`: str or
        object arrays as Python writes them, bytes arrays as their characters).
    formats : sequence of str
        One %-format per column.

    Returns
    -------
    text : str
        Byte for byte the text of Python's ``fmt % value`` for every value; "" for N = 0.
    """
    if len(columns) != len(formats):
        raise ValueError(f"{len(columns)} columns but {len(formats)} formats")
    n = len(columns[0]) if columns else 0
    if n == 0:
        return ""
    if n > BLOCK_ROWS:          # a block at a time: its byte matrices stay small, their memory reused
        return "".join(format_rows([c[s:s + BLOCK_ROWS] for c in columns], formats) for s in range(0, n, BLOCK_ROWS))
    parts = []
    for k, (values, fmt) in enumerate(zip(columns, formats)):
        parts.append(_column(values, fmt))
        parts.append(np.full((n, 1), NEWLINE if k == len(columns) - 1 else COMMA, np.uint8))
    text = np.hstack(parts)
    return text[text != NUL].tobytes().decode("utf-8")
