"""`stereodic gauge DIC_RESULT [--extensometer X0,Y0,X1,Y1]... [--point X,Y]... [--area X,Y;X,Y;...]...
[--line X0,Y0,X1,Y1]... [--gauges FILE] [--frame rig|specimen] [--load LOADS.csv ...] -o DIR`: virtual
extensometers, points, areas and lines over a test (stereodic.gauge), positions in the ORIGINAL left
reference image (pixels), in the rig's or the specimen's frame, joined to a testing machine's load.

Writes DIR/extensometers.csv, points.csv, areas.csv, lines.csv (the kinds given; columns in
stereodic/gauge/files.py and docs/gauges.md), a PNG of each, DIR/gauge.json (the frame, the units and the
gauges, reusable with --gauges) and, with --load, DIR/load.csv, and with --section, stress_strain.csv
and stress_strain.png.
"""

from __future__ import annotations

from stereodic.cli.common import add_frame_options, add_input, add_output, parse_floats


def register(sub):
    from stereodic.cli.common import STRAIN_MEASURES as MEASURES
    p = sub.add_parser("gauge", help="extensometers, points, areas and lines over a test; load and stress-strain",
                       description="Gauges on a saved DIC result (a `dic` output folder or dic.npz, or a `dic2d` "
                                   "NPZ), placed in the ORIGINAL left reference image (pixels), any number of "
                                   "each, each optionally named NAME=...: a virtual extensometer (its length and "
                                   "engineering strain dL/L0 in every state), a point (every quantity's history), "
                                   "an area (mean and spread over a polygon), a line (profiles along it). State 0 "
                                   "is the reference (for dic2d: the reference image).")
    add_input(p, "result", kind="any", what="DIC result", metavar="DIC_RESULT",
              help="a `stereodic dic` output folder or dic.npz, or a dic2d NPZ")
    p.add_argument("--extensometer", action="append", default=[], metavar="[NAME=]X0,Y0,X1,Y1",
                   help="a virtual extensometer between two pixels of the left reference image")
    p.add_argument("--point", action="append", default=[], metavar="[NAME=]X,Y", help="a point gauge")
    p.add_argument("--area", action="append", default=[], metavar="[NAME=]X,Y;X,Y;...",
                   help="a polygon (3 corners or more; quote it)")
    p.add_argument("--line", action="append", default=[], metavar="[NAME=]X0,Y0,X1,Y1", help="a line profile")
    add_input(p, "--gauges", what="gauge file", metavar="FILE",
              help="gauges from a JSON file (format stereodic.gauges/1, as DIR/gauge.json's `gauges`)")
    p.add_argument("--line-states", type=parse_floats, metavar="K,K,...",
                   help="the states the lines are profiled at (default: all, or 11 spread over a longer test)")
    add_frame_options(p, "the frame the result was saved in (the rig's world frame, or the specimen's)")
    p.add_argument("--remove-rigid", action="store_true",
                   help="also give each state's deformation-only displacement dX_def, dY_def, dZ_def (stereo)")
    p.add_argument("--scale", type=float, metavar="MM_PER_PX",
                   help="a dic2d result's scale: lengths and displacements in mm (default: pixels)")
    p.add_argument("--window", type=int, metavar="N",
                   help="strain window, grid points, odd (default: the run's own, else 5)")
    p.add_argument("--measure", choices=MEASURES, help="strain measure (default: the run's own, else green-lagrange)")
    add_input(p, "--load", what="load file", metavar="LOADS.csv",
              help="the testing machine's CSV: force, time and/or image index, optionally crosshead")
    p.add_argument("--join", choices=["index", "time"], default="index",
                   help="join the load to the states by image index (default) or by time")
    p.add_argument("--load-force", metavar="COLUMN", help="the force column, N (default: found by name)")
    p.add_argument("--load-time", metavar="COLUMN", help="the time column, s or date-times (default: by name)")
    p.add_argument("--load-index", metavar="COLUMN", help="the image index column (default: by name)")
    p.add_argument("--load-crosshead", metavar="COLUMN", help="the crosshead column, mm (default: by name)")
    p.add_argument("--index-offset", type=int, default=0, metavar="N",
                   help="--join index: the load file's image index of state 0 (default 0)")
    p.add_argument("--frame-rate", type=float, metavar="HZ", help="--join time: the cameras' frame rate")
    p.add_argument("--start-time", type=float, metavar="S",
                   help="--join time: state 0's time in the machine's clock, s (default 0)")
    add_input(p, "--state-times", what="timestamps file", metavar="FILE",
              help="--join time: one time per state (s or date-times), in the machine's clock")
    p.add_argument("--section", type=float, metavar="MM2",
                   help="the specimen's initial cross-section, mm^2: stress and the stress-strain curve")
    p.add_argument("--stress-strain", metavar="NAME[:QUANTITY]",
                   help="the gauge whose strain the curve uses: an extensometer, or a point or area with a "
                        "quantity (default exx) (default: the first extensometer)")
    p.add_argument("--modulus-range", type=parse_floats, metavar="LO,HI",
                   help="the strains the modulus is fitted over (default: 10 %% to 50 %% of the largest)")
    add_output(p, kind="dir", metavar="DIR", help="output folder")
    p.add_argument("--no-plot", action="store_true", help="skip the PNG plots")
    p.set_defaults(func=run)


def _named(text: str, prefix: str, k: int, option: str) -> tuple[str, list[float]]:
    from calib.errors import InputError
    name, _, coords = text.rpartition("=")
    name = name.strip() or f"{prefix}{k}"
    try:
        values = [float(v) for v in coords.replace(";", ",").split(",") if v.strip()]
    except ValueError:
        raise InputError(option, f"{text!r}: coordinates must be numbers in pixels") from None
    return name, values


def _gauges(args):
    from calib.errors import InputError
    from stereodic.gauge.gauges import AreaGauge, Extensometer, Gauges, LineGauge, PointGauge, read_gauge_file
    g = read_gauge_file(args.gauges) if args.gauges else Gauges()
    for k, text in enumerate(args.extensometer, len(g.extensometers) + 1):
        name, v = _named(text, "E", k, "--extensometer")
        if len(v) != 4:
            raise InputError("--extensometer", f"{text!r}: needs X0,Y0,X1,Y1 (pixels)")
        g.extensometers.append(Extensometer(name, (v[0], v[1]), (v[2], v[3])))
    for k, text in enumerate(args.point, len(g.points) + 1):
        name, v = _named(text, "P", k, "--point")
        if len(v) != 2:
            raise InputError("--point", f"{text!r}: needs X,Y (pixels)")
        g.points.append(PointGauge(name, (v[0], v[1])))
    for k, text in enumerate(args.area, len(g.areas) + 1):
        name, v = _named(text, "A", k, "--area")
        if len(v) < 6 or len(v) % 2:
            raise InputError("--area", f"{text!r}: needs 3 corners or more, X,Y;X,Y;X,Y (pixels)")
        g.areas.append(AreaGauge(name, tuple(zip(v[0::2], v[1::2]))))
    for k, text in enumerate(args.line, len(g.lines) + 1):
        name, v = _named(text, "L", k, "--line")
        if len(v) != 4:
            raise InputError("--line", f"{text!r}: needs X0,Y0,X1,Y1 (pixels)")
        g.lines.append(LineGauge(name, (v[0], v[1]), (v[2], v[3])))
    if not len(g):
        raise InputError("--extensometer/--point/--area/--line/--gauges", "give at least one gauge")
    names = [x.name for kind in (g.extensometers, g.points, g.areas, g.lines) for x in kind]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise InputError("--gauges", f"gauge names must differ, {', '.join(twice)} given twice")
    return g


def _strain_source(args, tables):
    """(strain (S,), its words) of the stress-strain gauge."""
    from calib.errors import InputError
    if not args.stress_strain:
        if not tables.extensometers:
            raise InputError("--stress-strain", "name the gauge whose strain the curve uses (no extensometer given)")
        e = tables.extensometers[0]
        return e.strain, f"extensometer {e.gauge.name}"
    name, _, quantity = args.stress_strain.partition(":")
    for e in tables.extensometers:
        if e.gauge.name == name:
            return e.strain, f"extensometer {name}"
    quantity = quantity or "exx"
    for s in tables.points:
        if s.gauge.name == name and quantity in s.values:
            return s.values[quantity], f"point {name} {quantity}"
    for a in tables.areas:
        if a.gauge.name == name and quantity in a.mean:
            return a.mean[quantity], f"area {name} mean {quantity}"
    raise InputError("--stress-strain", f"{args.stress_strain!r} is no extensometer, point or area with that quantity")


def _join(args, result):
    """(the load at each state, the states' times or None, gauge.json's load record), read and checked
    before any work."""
    import numpy as np

    from calib.errors import InputError
    from stereodic.gauge import load as ld
    data = ld.read_load(args.load, force_column=args.load_force, time_column=args.load_time,
                        index_column=args.load_index, crosshead_column=args.load_crosshead, need=args.join)
    S = result.count
    times = None
    if args.join == "time":
        times = ld.state_times(S, start_s=args.start_time, rate_hz=args.frame_rate, times_file=args.state_times,
                               recorded=result.meta.get("state_times_s"))
    at = ld.join_load(data, S, by=args.join, times_s=times, index_offset=args.index_offset)
    missing = int(np.isnan(at.force_n).sum())
    if missing == S:
        raise InputError(args.load, f"covers none of the {S} states (joined by {args.join}): check the clocks "
                                    f"or --index-offset")
    if missing:
        print(f"{missing} of {S} states lie outside {args.load}: their load is NaN")
    return at, times, {"load": {"file": str(args.load), "join": args.join, "columns": data.columns,
                                "states_without_load": missing}}


def _load_files(args, out, at, times, record, tables):
    """load.csv and, with a cross-section, the stress-strain curve; returns [(path, summary)]."""
    import numpy as np

    from calib.errors import InputError
    from calib.numbers import fixed
    from stereodic.gauge import files, load as ld, plots
    S = len(at.force_n)
    written = []
    strain = true = None
    eng = np.full(S, np.nan)
    if args.section:
        strain, source = _strain_source(args, tables)
        eng, true = ld.stress(at.force_n, area_mm2=args.section, strain=strain)
        rng = tuple(args.modulus_range) if args.modulus_range else None
        E, icpt, n = ld.modulus(strain, eng, strain_range=rng)
        record["load"].update(section_mm2=args.section, strain_of=source, modulus_mpa=E, modulus_points=n)
        if not args.no_plot:
            plots.plot_stress_strain(out / "stress_strain.png", strain, eng, true_mpa=true, modulus_mpa=E,
                                     intercept_mpa=icpt, source=source)
            written.append((out / "stress_strain.png", "the stress-strain curve"))
        print(f"modulus {fixed(E / 1000, 3)} GPa from {n} states ({source})" if np.isfinite(E) else
              f"modulus: too few states in the strain range ({n})")
    for p in files.write_load_tables(out, times, at.force_n, at.crosshead_mm, eng, strain, true):
        written.append((p, f"{S} states"))
    return written


def run(args) -> int:
    from pathlib import Path

    from calib.errors import InputError
    from stereodic.cli.common import frame_options, wrote
    from stereodic.gauge import files, load as ld, plots
    from stereodic.gauge.gauges import measure_gauges
    from stereodic.gauge.result import open_gauge_result

    origin, x_dir = frame_options(args)
    if args.section is not None and not args.load:
        raise InputError("--section", "needs --load (the force)")
    line_states = None
    if args.line_states:
        line_states = [int(v) for v in args.line_states]
    result = open_gauge_result(args.result, frame=args.frame, origin_px=origin, x_direction_px=x_dir,
                               remove_rigid=args.remove_rigid, scale_mm_per_px=args.scale, window=args.window,
                               measure=args.measure)
    gauges = _gauges(args)
    if args.section is not None:
        name = (args.stress_strain or "").partition(":")[0]
        names = {x.name for kind in (gauges.extensometers, gauges.points, gauges.areas) for x in kind}
        if not name and not gauges.extensometers:
            raise InputError("--stress-strain", "name the gauge whose strain the curve uses (no extensometer given)")
        if name and name not in names:
            raise InputError("--stress-strain", f"no extensometer, point or area is named {name!r}")
    if args.modulus_range is not None and len(args.modulus_range) != 2:
        raise InputError("--modulus-range", f"needs LO,HI strains, got {args.modulus_range}")
    at = times = None
    record = {}
    if args.load:
        at, times, record = _join(args, result)
        if args.section is not None:
            ld.stress(at.force_n, area_mm2=args.section)                   # the section checked before the work
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    tables = measure_gauges(result, gauges, line_states=line_states)
    written = [(p, f"{result.count} states") for p in files.write_gauge_tables(out, tables)]
    if args.load:
        written += _load_files(args, out, at, times, record, tables)
    if not args.no_plot:
        for kind, plot in (("extensometers", plots.plot_extensometers), ("points", plots.plot_points),
                           ("areas", plots.plot_areas)):
            if getattr(tables, kind):
                plot(out / f"{kind}.png", tables, times)
                written.append((out / f"{kind}.png", f"{kind} over the test"))
        if tables.lines:
            plots.plot_lines(out / "lines.png", tables)
            written.append((out / "lines.png", "the line profiles"))
    written.append((files.write_run_record(out, result.path, tables, gauges, record),
                    f"the frame ({tables.frame['frame']}), units and gauges"))
    for e in tables.extensometers:
        print(f"extensometer {e.gauge.name}: L0 {e.length[0]:.4f} {tables.unit}, strain at the last state "
              f"{e.strain[-1] * 1e6:.0f} microstrain")
    for p, what in written:
        wrote(p, what)
    return 0
