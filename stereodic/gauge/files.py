"""The files of `stereodic gauge`: one CSV per kind of gauge, the stress-strain curve, the frame and the
gauges used (all atomic).

- extensometers.csv: state, name, length_<unit>, delta_<unit>, strain (engineering, dL / L0), one row
  per state and extensometer (<unit> mm, or px for a 2-D result without scale);
- points.csv: state, name, then every quantity of the result (`stereodic.gauge.result`), one row per
  state and point;
- areas.csv: state, name, measured (grid points inside with a displacement), then <q>_mean, <q>_std of
  every quantity, one row per state and area;
- lines.csv: state, name, index, distance_<unit> (along the line on the reference shape), x_px, y_px
  (the sample in the original left reference image), then every quantity, one row per profiled state,
  line and sample;
- load.csv (with a load file): state, time_s, force_n, crosshead_mm, stress_mpa (engineering) and
  true_stress_mpa (with the stress-strain gauge's strain);
- stress_strain.csv: state, strain, stress_mpa, true_stress_mpa;
- gauge.json ("stereodic.gauge-run/1"): the result, the frame (`GaugeResult.frame_record`), units, the
  gauges (in the gauge-file format, for --gauges) and, with a load, the join and the modulus.
Numbers are written with 7 significant digits for lengths and 9 decimals for strains; NaN where not
measured.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from calib.atomic import atomic_output, write_json
from stereodic.gauge.gauges import GaugeTables, Gauges, gauges_document

RUN_FORMAT = "stereodic.gauge-run/1"


def _write(path: Path, header: list[str], rows) -> None:
    with atomic_output(path) as tmp, open(tmp, "w") as out:
        out.write(",".join(header) + "\n")
        for row in rows:
            out.write(",".join(row) + "\n")


def _g(v) -> str:
    return "nan" if not np.isfinite(v) else f"{v:.9g}"


def write_gauge_tables(folder: str | os.PathLike, tables: GaugeTables) -> list[Path]:
    """The CSV files of every kind of gauge measured (module docstring); returns the paths written."""
    folder = Path(folder)
    u = tables.unit
    S = len(tables.labels)
    written = []
    qs = list(tables.units)
    if tables.extensometers:
        p = folder / "extensometers.csv"
        _write(p, ["state", "name", f"length_{u}", f"delta_{u}", "strain"],
               ([str(k), e.gauge.name, _g(e.length[k]), _g(e.length[k] - e.length[0]), _g(e.strain[k])]
                for k in range(S) for e in tables.extensometers))
        written.append(p)
    if tables.points:
        p = folder / "points.csv"
        _write(p, ["state", "name"] + qs,
               ([str(k), s.gauge.name] + [_g(s.values[q][k]) for q in qs] for k in range(S) for s in tables.points))
        written.append(p)
    if tables.areas:
        p = folder / "areas.csv"
        disp = "dX" if "dX" in qs else "u"
        _write(p, ["state", "name", "measured"] + [f"{q}_{s}" for q in qs for s in ("mean", "std")],
               ([str(k), a.gauge.name, str(int(a.count[disp][k]))]
                + [_g(getattr(a, s)[q][k]) for q in qs for s in ("mean", "std")]
                for k in range(S) for a in tables.areas))
        written.append(p)
    if tables.lines:
        p = folder / "lines.csv"
        _write(p, ["state", "name", "index", f"distance_{u}", "x_px", "y_px"] + qs,
               ([str(k), ln.gauge.name, str(i), _g(ln.distance[i]), _g(ln.image_px[i, 0]), _g(ln.image_px[i, 1])]
                + [_g(ln.values[q][r, i]) for q in qs]
                for ln in tables.lines for r, k in enumerate(ln.states) for i in range(len(ln.distance))))
        written.append(p)
    return written


def write_load_tables(folder: str | os.PathLike, times_s, force_n, crosshead_mm, stress_mpa, strain,
                      true_mpa) -> list[Path]:
    """load.csv and stress_strain.csv (module docstring), per state arrays (S,) (times_s, crosshead_mm,
    strain and true_mpa may be None); returns the paths written."""
    folder = Path(folder)
    S = len(force_n)
    nan = np.full(S, np.nan)
    t = nan if times_s is None else times_s
    c = nan if crosshead_mm is None else crosshead_mm
    tr = nan if true_mpa is None else true_mpa
    _write(folder / "load.csv", ["state", "time_s", "force_n", "crosshead_mm", "stress_mpa", "true_stress_mpa"],
           ([str(k), _g(t[k]), _g(force_n[k]), _g(c[k]), _g(stress_mpa[k]), _g(tr[k])] for k in range(S)))
    out = [folder / "load.csv"]
    if strain is not None:
        _write(folder / "stress_strain.csv", ["state", "strain", "stress_mpa", "true_stress_mpa"],
               ([str(k), _g(strain[k]), _g(stress_mpa[k]), _g(tr[k])] for k in range(S)))
        out.append(folder / "stress_strain.csv")
    return out


def write_run_record(folder: str | os.PathLike, result_path, tables: GaugeTables, gauges: Gauges,
                     extra: dict | None = None) -> Path:
    """gauge.json (module docstring), with `extra` keys; returns its path."""
    record = {"format": RUN_FORMAT, "result": str(result_path), "frame": tables.frame, "unit": tables.unit,
              "units": tables.units, "states": len(tables.labels), "labels": tables.labels,
              "gauges": gauges_document(gauges), **(extra or {})}
    path = Path(folder) / "gauge.json"
    write_json(path, record)
    return path
