"""`stereodic strain DIC_RESULT [--window N] [--measure M] -o DIR`: strain recomputed from saved DIC results.

DIC_RESULT is a `stereodic dic` output folder (or its dic.npz) or a `stereodic dic2d --npz` file. Writes
DIR/strain.csv (state - or image for 2-D results -, x, y, exx, eyy, exy, e_major, e_minor, e_angle,
e_vm, strain_valid: one row per active point and state), DIR/strain.npz (x, y, active and per state
(S, ny, nx) the same arrays) and DIR/maps/ (PNG maps of exx, eyy, exy, e_vm per state), one state in
memory at a time (stereodic.strain.results).
"""

from __future__ import annotations


from stereodic.cli.common import add_frame_options, add_input, add_output, deprecated


def register(sub):
    from stereodic.cli.common import STRAIN_MEASURES as MEASURES
    p = sub.add_parser("strain", help="strain recomputed from saved DIC results",
                       description="Strain of saved DIC results (a `dic` output folder or a `dic2d` NPZ) with "
                                   "another window or measure, without correlating again.")
    add_input(p, "result", kind="any", what="DIC result", metavar="DIC_RESULT",
              help="a `stereodic dic` output folder or dic.npz, or a dic2d NPZ")
    p.add_argument("--strain-window", type=int, metavar="N",
                   help="strain fitted over N x N grid points, odd (default: the run's own, else 5)")
    deprecated(p, "--window", "--strain-window")
    p.add_argument("--measure", choices=MEASURES, default="green-lagrange", metavar="MEASURE",
                   help=f"strain measure: {', '.join(MEASURES)} (default green-lagrange)")
    add_frame_options(p, "a stereo result's strains in the axes it was saved in")
    add_output(p, kind="dir", metavar="DIR", help="output folder")
    p.add_argument("--no-plot", action="store_true", help="skip the PNG maps")
    p.set_defaults(func=run)


def run(args) -> int:
    import json
    from pathlib import Path

    import numpy as np

    from calib.atomic import atomic_output
    from calib.csv_text import format_rows
    from calib.errors import InputError
    from calib.npz_stream import write_stacked_npz
    from calib.progress import progress
    from stereodic.cli.common import frame_options, wrote
    from stereodic.dic.maps import MapPainter, RunScales, save_map
    from stereodic.dic.output import STRAIN_COLUMNS
    from stereodic.strain.results import map_axes, open_result, specimen_frame_of, state_labels, strains

    result = open_result(args.result)
    origin, x_dir = frame_options(args)
    frame = specimen_frame_of(result, origin_px=origin, x_direction_px=x_dir) if args.frame == "specimen" else None
    own = (result.meta.get("settings", {}).get("strain_window") if result.kind == "dic" else None)
    window = args.strain_window or own or 5
    if window < 3 or window % 2 == 0:
        raise InputError("--strain-window", f"must be an odd number >= 3, got {window}")
    out = Path(args.output)
    g = result.grid
    act = g.active.ravel()
    X, Y = g.points()
    label = "state" if result.kind == "dic" else "image"
    axes, titles = (map_axes(result, frame=frame), state_labels(result)) if not args.no_plot else (None, None)
    keys = [c for c, _, _ in STRAIN_COLUMNS] + ["strain_valid"]
    fields = {c: f for c, f, _ in STRAIN_COLUMNS} | {"strain_valid": "valid"}
    MAPS = ("exx", "eyy", "exy", "e_vm")
    scales = RunScales(floor={name: 100.0 for name in MAPS})
    tmp_dir = out / ".strain-states"
    tmp_dir.mkdir(parents=True, exist_ok=True)
    try:
        with atomic_output(out / "strain.csv") as tmp, open(tmp, "w") as csv:
            csv.write(",".join([label, "x", "y"] + keys) + "\n")
            for k, m in enumerate(progress(strains(result, window, args.measure, frame=frame), "strain", total=result.states,
                                           unit="state")):
                cols = [np.full(int(act.sum()), k), X[act], Y[act]]
                cols += [getattr(m, field).ravel()[act] for _, field, _ in STRAIN_COLUMNS] + [m.valid.ravel()[act]]
                csv.write(format_rows(cols, ["%d", "%g", "%g"] + [f for _, _, f in STRAIN_COLUMNS] + ["%d"]))
                np.savez(tmp_dir / f"{k}.npz", **{key: getattr(m, fields[key]) for key in keys})
                for name in MAPS:
                    scales.add(name, getattr(m, fields[name]) * 1e6, signed=name != "e_vm", active=g.active)
        if not args.no_plot:   # after every state: the maps share the run's colour scale per quantity
            painter = MapPainter()
            for k in progress(range(result.states), "maps", total=result.states, unit="state"):
                with np.load(tmp_dir / f"{k}.npz") as z:
                    for name in MAPS:
                        save_map(out / "maps" / f"{label}{k}_{name}.png", z[name] * 1e6, axes,
                                 title=f"{titles[k]} - {name}, {args.measure} strain ({args.frame}'s frame)",
                                 quantity=name, unit="microstrain", decimals=0, signed=name != "e_vm",
                                 scale=scales.scale(name), painter=painter)

        def values(key):
            for k in range(result.states):
                with np.load(tmp_dir / f"{k}.npz") as z:
                    yield z[key]

        meta = {"format": "stereodic.strain/1", "source": str(result.path), "window": window,
                "measure": args.measure,
                "frame": frame.record() if frame is not None else result.meta.get("frame", {"frame": "rig"})}
        write_stacked_npz(out / "strain.npz", dict(meta=np.array(json.dumps(meta)), x=g.xs, y=g.ys, active=g.active),
                          {key: (lambda key=key: values(key)) for key in keys}, result.states)
    finally:
        for p in tmp_dir.glob("*.npz"):
            p.unlink()
        tmp_dir.rmdir()
    what = f"{args.measure} strain of {result.states} {label}s of {result.path}, window {window} points"
    wrote(out / "strain.csv", f"{what}: one row per point and {label}")
    wrote(out / "strain.npz", "the same as arrays")
    if not args.no_plot:
        wrote(out / "maps", f"PNG maps of exx, eyy, exy and e_vm per {label}, one colour scale per quantity")
    return 0
