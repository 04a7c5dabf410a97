"""A testing machine's load joined to the states of a DIC result: stress and stress-strain.

The load file is a CSV (comma, semicolon or tab separated; a header row of column names; rows that are
not numbers, such as a units row, are skipped) with a force column (N), a time column (seconds, or ISO
8601 date-times) and/or an image index column, and optionally a crosshead displacement column (mm).
Columns are named by the caller or found by their names (`read_load`).

Joining (`join_load`): by index, state k takes the load at image index k + offset; by time, state k takes
the load at its time, the machine's force interpolated linearly between its samples (NaN outside
them). The states' times (`state_times`) come from the images' own timestamps (what the video and
high-speed readers give, recorded with the result), a timestamps file, or a start time and frame rate,
in the machine's clock (a start time of the first image in that clock; date-times on both sides need
no start).

Stress (`stress`): engineering sigma = F / A0 (MPa for N and mm^2); true stress sigma (1 + e) with the
engineering strain e along the load (constant volume). The modulus (`modulus`) is the least-squares
slope of stress against strain over a strain range.
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass
from datetime import datetime, timezone

import numpy as np

from calib.errors import InputError

_GUESS = {"force": ("force", "load", "kraft", "fn"), "time": ("time", "zeit", "timestamp", "t"),
          "index": ("image", "frame", "index", "state", "img"),
          "crosshead": ("crosshead", "extension", "position", "stroke", "displacement")}


@dataclass
class LoadData:
    """A load file's samples: `force_n` (N,), `time_s` (N,) seconds (date-times as seconds since the
    epoch) or None, `index` (N,) image indices or None, `crosshead_mm` (N,) or None; `columns` the
    names used."""

    path: str
    force_n: np.ndarray
    time_s: np.ndarray | None
    index: np.ndarray | None
    crosshead_mm: np.ndarray | None
    columns: dict[str, str]


def parse_time(text: str) -> float:
    """Seconds of a time value: a number, or an ISO 8601 date-time (seconds since the epoch, UTC when
    it names no zone); ValueError otherwise."""
    try:
        return float(text)
    except ValueError:
        t = datetime.fromisoformat(text.strip())
        if t.tzinfo is None:
            t = t.replace(tzinfo=timezone.utc)
        return t.timestamp()


def _find(header: list[str], name: str | None, kind: str, path, required: bool) -> str | None:
    low = [h.strip().lower() for h in header]
    if name is not None:
        if name.strip().lower() not in low:
            raise InputError(path, f"has no column {name!r} (its columns: {', '.join(header)})")
        return header[low.index(name.strip().lower())]
    for guess in _GUESS[kind]:
        for h, lo in zip(header, low):
            word = lo.split("[")[0].split("(")[0].strip()
            if word == guess or (len(guess) > 2 and guess in word):
                return h
    if required:
        what = "image index" if kind == "index" else kind
        raise InputError(path, f"has no {what} column (its columns: {', '.join(header)}; name it with "
                               f"--load-{kind})")
    return None


def read_load(path: str | os.PathLike, *, force_column: str | None = None, time_column: str | None = None,
              index_column: str | None = None, crosshead_column: str | None = None,
              need: str = "any") -> LoadData:
    """A testing machine's CSV (module docstring).

    Parameters
    ----------
    path : path
        The CSV file.
    force_column, time_column, index_column, crosshead_column : str, optional
        The columns' names (case-insensitive); None: found by their names (force/load, time,
        image/frame/index, crosshead/extension/position); crosshead is optional.
    need : {"any", "time", "index"}
        Which of time and index the join needs ("any": one of them).

    Returns
    -------
    load : LoadData
        Force N, time s, index, crosshead mm. InputError naming the file when a named or needed column
        is missing, or it holds fewer than 2 numeric rows.
    """
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            text = f.read()
    except UnicodeDecodeError:
        raise InputError(path, "is not a text (CSV) file") from None
    if not text.strip():
        raise InputError(path, "is empty")
    try:
        dialect = csv.Sniffer().sniff(text[:4096], delimiters=",;\t")
    except csv.Error:
        dialect = csv.excel
    rows = list(csv.reader(text.splitlines(), dialect))
    header = [h.strip() for h in rows[0]]
    cols = {"force": _find(header, force_column, "force", path, True),
            "time": _find(header, time_column, "time", path, need == "time"),
            "index": _find(header, index_column, "index", path, need == "index"),
            "crosshead": _find(header, crosshead_column, "crosshead", path, False)}
    cols = {k: v for k, v in cols.items() if v is not None}
    if need == "any" and "time" not in cols and "index" not in cols:
        raise InputError(path, f"has neither a time nor an image index column (its columns: {', '.join(header)})")
    at = {k: header.index(v) for k, v in cols.items()}
    values: dict[str, list[float]] = {k: [] for k in cols}
    for row in rows[1:]:
        try:
            parsed = {k: (parse_time(row[i]) if k == "time" else float(row[i])) for k, i in at.items()}
        except (ValueError, IndexError):
            continue                                  # a units row, a comment, a short line
        for k, v in parsed.items():
            values[k].append(v)
    if len(values["force"]) < 2:
        raise InputError(path, f"holds {len(values['force'])} numeric rows of {', '.join(cols.values())}: "
                               f"too few for a load")
    arr = {k: np.asarray(v, float) for k, v in values.items()}
    return LoadData(str(path), arr["force"], arr.get("time"), arr.get("index"), arr.get("crosshead"), cols)


def state_times(count: int, *, start_s: float | None = None, rate_hz: float | None = None,
                times_file: str | os.PathLike | None = None, recorded: list[float] | None = None) -> np.ndarray:
    """Each state's time, seconds, in the testing machine's clock.

    Parameters
    ----------
    count : int
        The states.
    start_s : float, optional
        The first state's time; with `rate_hz`, state k at start_s + k / rate_hz; alone, an offset
        added to the recorded or file times.
    rate_hz : float, optional
        The frame rate.
    times_file : path, optional
        A CSV or text file of one time per state (a column named time/timestamp, else the last
        column), seconds or date-times.
    recorded : list of float, optional
        The images' own timestamps (seconds), recorded with the result.

    Returns
    -------
    times : (count,) float
        Seconds. InputError naming the option or file when none is given or they do not fit.
    """
    offset = start_s or 0.0
    if times_file is not None and rate_hz is not None:
        raise InputError("--state-times", "give either the states' times or --frame-rate, not both")
    if rate_hz is not None:
        if not rate_hz > 0:
            raise InputError("--frame-rate", f"must be > 0 Hz, got {rate_hz}")
        return offset + np.arange(count) / rate_hz
    if times_file is not None:
        try:
            with open(times_file, newline="", encoding="utf-8-sig") as f:
                rows = [r for r in csv.reader(f) if r]
        except (UnicodeDecodeError, csv.Error):
            raise InputError(times_file, "is not a text (CSV) file of times") from None
        col = -1
        low = [c.strip().lower() for c in rows[0]] if rows else []
        for name in ("time", "timestamp", "time_s", "t"):
            if name in low:
                col = low.index(name)
        times = []
        for r in rows:
            try:
                times.append(parse_time(r[col]))
            except (ValueError, IndexError):
                continue
        if len(times) != count:
            raise InputError(times_file, f"holds {len(times)} times, the result {count} states")
        return offset + np.asarray(times)
    if recorded is not None and len(recorded) == count:
        return offset + np.asarray(recorded, float)
    raise InputError("--join time", "needs the states' times: --frame-rate (and --start-time), --state-times "
                                    "FILE, or a result whose images recorded their timestamps")


@dataclass
class LoadAtStates:
    """The load at each state: `force_n` (S,), `crosshead_mm` (S,) or None; NaN where the load file
    does not reach."""

    force_n: np.ndarray
    crosshead_mm: np.ndarray | None


def join_load(load: LoadData, count: int, *, by: str = "index", times_s: np.ndarray | None = None,
              index_offset: int = 0) -> LoadAtStates:
    """The load at every state of a result (module docstring).

    Parameters
    ----------
    load : LoadData
        The machine's samples.
    count : int
        The result's states.
    by : {"index", "time"}
        Join by image index (state k at index k + `index_offset`) or by time (`times_s`).
    times_s : (count,) float, optional
        With "time": each state's time in the machine's clock, seconds (`state_times`).
    index_offset : int
        With "index": the load file's index of state 0.

    Returns
    -------
    at : LoadAtStates
        Force N and crosshead mm per state, interpolated linearly; NaN outside the file's samples.
    """
    if by == "time":
        if load.time_s is None:
            raise InputError(load.path, "has no time column: join by index, or name it with --load-time")
        x, at = load.time_s, np.asarray(times_s, float)
    elif by == "index":
        if load.index is None:
            raise InputError(load.path, "has no image index column: join by time, or name it with --load-index")
        x, at = load.index, np.arange(count) + index_offset
    else:
        raise InputError("--join", f"must be index or time, got {by!r}")
    order = np.argsort(x, kind="stable")
    x = x[order]
    if np.any(np.diff(x) <= 0):
        x, first = np.unique(x, return_index=True)
        order = order[first]

    def interp(y):
        return np.interp(at, x, y[order], left=np.nan, right=np.nan)

    return LoadAtStates(interp(load.force_n), None if load.crosshead_mm is None else interp(load.crosshead_mm))


def stress(force_n: np.ndarray, *, area_mm2: float, strain: np.ndarray | None = None
           ) -> tuple[np.ndarray, np.ndarray | None]:
    """Engineering and true stress (module docstring).

    Parameters
    ----------
    force_n : (S,) float
        Force, N.
    area_mm2 : float
        The initial cross-section, mm^2 (> 0).
    strain : (S,) float, optional
        Engineering strain along the load, dimensionless, for the true stress.

    Returns
    -------
    engineering : (S,) float
        MPa.
    true : (S,) float or None
        MPa (None without `strain`).
    """
    if not area_mm2 > 0:
        raise InputError("--section", f"must be > 0 mm^2, got {area_mm2}")
    eng = np.asarray(force_n, float) / area_mm2
    return eng, None if strain is None else eng * (1.0 + np.asarray(strain, float))


def modulus(strain: np.ndarray, stress_mpa: np.ndarray, *, strain_range: tuple[float, float] | None = None
            ) -> tuple[float, float, int]:
    """The least-squares slope of stress against strain.

    Parameters
    ----------
    strain : (S,) float
        Dimensionless.
    stress_mpa : (S,) float
        MPa.
    strain_range : (lo, hi), optional
        The strains fitted (default: 10 % to 50 % of the largest strain, the elastic part of a test
        that goes on to yield).

    Returns
    -------
    modulus_mpa : float
        MPa (NaN with fewer than 2 points in the range).
    intercept_mpa : float
        MPa.
    points : int
        The states fitted.
    """
    e, s = np.asarray(strain, float), np.asarray(stress_mpa, float)
    ok = np.isfinite(e) & np.isfinite(s)
    if strain_range is None:
        top = np.max(e[ok]) if ok.any() else 0.0
        strain_range = (0.1 * top, 0.5 * top)
    ok &= (e >= strain_range[0]) & (e <= strain_range[1])
    if ok.sum() < 2:
        return float("nan"), float("nan"), int(ok.sum())
    slope, icpt = np.polyfit(e[ok], s[ok], 1)
    return float(slope), float(icpt), int(ok.sum())
