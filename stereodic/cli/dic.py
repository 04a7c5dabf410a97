"""`stereodic dic RIG.npz (DATASET | --left PATTERN --right PATTERN | --images DIR) -o DIR`: stereo 3D
digital image correlation (stereodic.dic3d).

Writes DIR/run.json and DIR/states/ (the run folder: one result file per state, so that an interrupted
run resumes where it stopped when the same command is given again), then DIR/dic.csv (one row per point
and state, columns in docs/dic.md and stereodic/dic3d/output.py; or DICe's files with --columns dice),
DIR/dic.npz (the arrays), DIR/vtk/states.pvd + state{k:03d}.vtp (ParaView) and DIR/maps/ (PNG maps of
Z, displacements and strains per state).
"""

from __future__ import annotations

from stereodic.cli.common import (add_grid_options, add_input, add_output, add_prefilter_option, add_scheduler_option,
                                  add_search_option, check_prefilter, dic_grid, parse_ints, search_settings)


def register(sub):
    from stereodic.cli.common import STRAIN_MEASURES as MEASURES, SWITCH_ZNCC
    p = sub.add_parser("dic", help="stereo 3D digital image correlation",
                       description="Stereo 3D-DIC on the rectified virtual pair: 3D shape, 3D displacement and "
                                   "surface strain of every state of an experiment: a `kind: dic` dataset, two "
                                   "patterns (one per camera) or a folder of image pairs. State 0 is the "
                                   "reference.")
    add_input(p, "rig", what="rig", metavar="RIG.npz", help="the rectified stereo rig (stereodic rig, stereodic import)")
    add_input(p, "dataset", kind="dataset", metavar="DATASET", nargs="?",
              help="folder (or capture.json) of a kind 'dic' dataset")
    add_input(p, "--left", kind="pattern", what="image", metavar="PATTERN",
              help="the left camera's images: a shell-style pattern (quote it), natural order")
    add_input(p, "--right", kind="pattern", what="image", metavar="PATTERN", help="the right camera's images, likewise")
    add_input(p, "--images", kind="dir", what="image", metavar="DIR",
              help="a folder of image pairs NAME<left suffix>.tif / NAME<right suffix>.tif (DICe's and VIC-3D's "
                   "naming)")
    p.add_argument("--left-suffix", default="_0", help="with --images: the left images' suffix (default _0)")
    p.add_argument("--right-suffix", default="_1", help="with --images: the right images' suffix (default _1)")
    add_output(p, kind="dir", metavar="DIR", help="output folder (also the run folder)")
    add_grid_options(p, "left rectified image")
    p.add_argument("--shape", choices=["affine", "quadratic"], default="affine",
                   help="subset shape function (default affine)")
    p.add_argument("--disparity", metavar="DMIN,DMAX",
                   help="row search range of the seeds, x_right - x_left in pixels (default +-half the width)")
    p.add_argument("--vertical-search", type=int, default=0, metavar="ROWS",
                   help="rows above and below the row that the seeds' stereo search also covers (default 0: the "
                        "row only; more for a rig whose calibration no longer fits its images, whose matches sit "
                        "off the rectified rows)")
    p.add_argument("--max-gap", type=float, default=1.0, metavar="PITCHES",
                   help="largest distance between the two rays of a trusted point, in virtual pixel pitches "
                        "(default 1; points beyond are flagged ray_gap)")
    add_search_option(p, "temporal seeds")
    add_prefilter_option(p)
    p.add_argument("--min-zncc", type=float, default=0.8, help="points below are flagged (default 0.8)")
    p.add_argument("--strain-window", type=int, default=5, metavar="N",
                   help="strains fitted over N x N grid points, odd; 0 = none (default 5)")
    p.add_argument("--measure", choices=MEASURES, default="green-lagrange",
                   help="strain measure (default green-lagrange)")
    p.add_argument("--switch-zncc", type=float, default=SWITCH_ZNCC, metavar="ZNCC",
                   help=f"a point whose ZNCC against the reference falls below this switches to incremental "
                        f"correlation, displacements still from the reference (default {SWITCH_ZNCC}; 0 = never)")
    p.add_argument("--incremental", action="store_true",
                   help="every point incremental from state 1: track the left camera state to state and match "
                        "stereo at every state (large deformations)")
    p.add_argument("--columns", choices=["stereodic", "dice"], default="stereodic",
                   help="dice: write DICe's solution files (DIR/DICe_solution_<k>.txt, left camera with 3D, and "
                        "DIR/DICe_solution_stereo_<k>.txt, right camera) instead of dic.csv")
    p.add_argument("--restart", action="store_true",
                   help="discard a run already in the output folder (default: resume it)")
    p.add_argument("--no-vtk", action="store_true", help="skip the VTK files")
    p.add_argument("--no-plot", action="store_true", help="skip the PNG maps")
    p.add_argument("--plot-every", type=int, default=1, metavar="N",
                   help="PNG maps of every N-th state only (default 1: all)")
    add_scheduler_option(p, "states (a chain: one state after the other) and their maps")
    p.set_defaults(func=run)


def _settings(args):
    from calib.errors import InputError
    from stereodic.dic import DicSettings
    from stereodic.dic3d.stereo import StereoSettings
    if args.strain_window and (args.strain_window < 3 or args.strain_window % 2 == 0):
        raise InputError("--strain-window", f"must be 0 or an odd number >= 3, got {args.strain_window}")
    if not 0 <= args.min_zncc <= 1:
        raise InputError("--min-zncc", f"must be between 0 and 1, got {args.min_zncc}")
    if not 0 <= args.switch_zncc <= 1:
        raise InputError("--switch-zncc", f"must be between 0 and 1, got {args.switch_zncc}")
    if args.plot_every < 1:
        raise InputError("--plot-every", f"must be >= 1, got {args.plot_every}")
    if args.vertical_search < 0:
        raise InputError("--vertical-search", f"must be >= 0 rows, got {args.vertical_search}")
    if not args.max_gap > 0:
        raise InputError("--max-gap", f"must be > 0 pixel pitches, got {args.max_gap}")
    check_prefilter(args)
    disparity = None
    if args.disparity:
        disparity = tuple(parse_ints(args.disparity, 2, "--disparity"))
        if disparity[0] > disparity[1]:
            raise InputError("--disparity", f"DMIN must not exceed DMAX, got {args.disparity}")
    dic = DicSettings(subset=args.subset, shape=args.shape, min_zncc=args.min_zncc, **search_settings(args),
                      prefilter_sigma=args.prefilter)
    return StereoSettings(dic, disparity, args.strain_window or None, args.incremental, max_gap_px=args.max_gap,
                          switch_zncc=args.switch_zncc, strain_measure=args.measure,
                          vertical_search=args.vertical_search)


def _states(args, rig):
    """The experiment's states from whichever of the three forms was given (exactly one)."""
    from calib.errors import InputError
    from stereodic.dic3d.dataset import load_states, states_from_folder, states_from_patterns
    forms = [args.dataset is not None, bool(args.left or args.right), args.images is not None]
    if sum(forms) != 1:
        raise InputError("DATASET/--left/--right/--images", "give exactly one of a dataset, --left and --right "
                                                            "patterns, or --images DIR")
    if args.dataset is not None:
        return load_states(args.dataset, rig)
    if forms[1]:
        if not (args.left and args.right):
            raise InputError("--left" if not args.left else "--right", "is needed with the other camera's pattern")
        return states_from_patterns(args.left, args.right, rig)
    return states_from_folder(args.images, args.left_suffix, args.right_suffix, rig)


def _run_record(args, rig_path, data, settings):
    """(settings, inputs) of the run manifest: everything that decides the results."""
    import dataclasses
    import json
    import os

    from calib import __version__
    from calib.batch import file_sha256, fingerprint
    grid_args = {"subset": args.subset, "step": args.step, "roi": args.roi,
                 "mask": file_sha256(args.mask) if args.mask else None, "seeds": args.seed}
    record = {"software": __version__, "stereo": dataclasses.asdict(settings), "grid": grid_args}
    paths = [str(p) for p in data.left + data.right]
    root = os.path.commonpath([os.path.abspath(p) for p in paths])
    root = root if os.path.isdir(root) else os.path.dirname(root)
    images = [[os.path.relpath(os.path.abspath(lp), root), fingerprint(lp),
               os.path.relpath(os.path.abspath(rp), root), fingerprint(rp)] for lp, rp in zip(data.left, data.right)]
    inputs = {"rig": file_sha256(rig_path), "images": images}
    return json.loads(json.dumps(record)), inputs


def _summary(st, n) -> str:
    import numpy as np

    from calib.numbers import fixed
    c = st.converged
    mean = st.displacement[c].mean(0) if c.any() else np.full(3, np.nan)
    text = (f"state {st.state}: {int(c.sum())}/{n} points converged, mean dX {fixed(mean[0], 4)} dY "
            f"{fixed(mean[1], 4)} dZ {fixed(mean[2], 4)} mm")
    if st.measure is not None and st.measure.valid.any():
        text += (f", mean exx {fixed(np.nanmean(st.measure.exx) * 1e6, 0)} eyy "
                 f"{fixed(np.nanmean(st.measure.eyy) * 1e6, 0)} microstrain")
    if st.incremental.any():
        text += f", {int((st.incremental & c).sum())} incremental"
    return text


def run(args) -> int:
    import sys
    from pathlib import Path

    from calib.progress import note
    from stereodic.cli.common import wrote
    from stereodic.dic3d import epipolar
    from stereodic.dic3d.run import run_states, write_outputs
    from stereodic.dic3d.store import RunStore
    from stereodic.rig import load_rig

    rig = load_rig(args.rig)
    width, height = rig.sensor.width, rig.sensor.height
    data = _states(args, rig)                   # every state and file checked before the work
    grid, seeds = dic_grid(args, width, height, "rectified image", args.rig)
    settings = _settings(args)
    record, inputs = _run_record(args, args.rig, data, settings)
    out = Path(args.output)
    store = RunStore(out)
    n = len(data)
    done = store.open(record, inputs, n, restart=args.restart)
    outputs = {"columns": args.columns, "vtk": not args.no_vtk, "plot_every": 0 if args.no_plot else args.plot_every}
    if done == n and store.outputs_written(outputs):
        print(f"{out}: all {n} states are done and written; nothing to do (--restart to run again)")
        return 0
    if done:
        print(f"{out}: resuming a run with {done} of {n} states done")
    active = int(grid.active.sum())
    plot_every = outputs["plot_every"]
    labels = [data.label(k) for k in range(n)]
    if args.scheduler:
        import functools

        from stereodic.cluster import connect
        from stereodic.dic3d.cluster import RunSpec, run_states_on
        spec = RunSpec.make(args.rig, inputs["rig"], out, data, grid, seeds, settings,
                            functools.partial(_summary, n=active))
        with connect(args.scheduler) as client:
            state0 = run_states_on(client, store, data, spec, csv=args.columns != "dice", vtk=not args.no_vtk,
                                   plot_every=plot_every, labels=labels)
    else:
        state0 = run_states(store, data, rig, grid, seeds, settings, report=lambda st: note(_summary(st, active)))
    c0 = state0.left.ok & state0.right.ok         # matched, whether or not the rays meet
    X, Y = (a.reshape(grid.shape) for a in grid.points())
    report = epipolar.check(rig, X[c0], Y[c0], (X + state0.right.u)[c0], (Y + state0.right.v)[c0],
                            state0.right.noise_px[c0])
    if report is not None:
        print(report.line())
        if report.bumped:
            print(f"stereodic dic: warning: the rig's epipolar error (median {report.median:+.3f} px, p95 "
                  f"{report.p95:.3f} px) is larger than its calibration allows (p95 {report.expected_p95:.3f} px): "
                  f"has a camera moved since the calibration?", file=sys.stderr)
    info = {"rig": str(args.rig), "dataset": data.source, "world_from_rig": rig.world_from_rig.tolist(),
            "state_labels": labels}
    dice = None
    if args.columns == "dice":
        from stereodic.dice_columns import StereoDiceWriter
        dice = StereoDiceWriter(out, grid, data, settings, args.step)
    write_outputs(store, grid, out, settings, info, vtk=not args.no_vtk, plot_every=plot_every,
                  dice=dice, csv=args.columns != "dice", state_files=not args.scheduler, labels=labels)
    store.record_outputs(outputs)
    states = f"{active} points x {n} states"
    if args.columns == "dice":
        wrote(out, f"DICe's solution files DICe_solution_<k>.txt and DICe_solution_stereo_<k>.txt ({states})")
    else:
        wrote(out / "dic.csv", f"one row per point and state ({states})")
    wrote(out / "dic.npz", "the same as arrays")
    if not args.no_vtk:
        wrote(out / "vtk" / "states.pvd", f"ParaView collection of {n} states (state*.vtp)")
    if not args.no_plot:
        wrote(out / "maps", "PNG maps of Z, displacements and strains per state")
    return 0

