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
                                  add_frame_options, add_search_option, check_prefilter, dic_grid, frame_options,
                                  parse_ints, search_settings)


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
              help="the left camera's images: a shell-style pattern (quote it), natural order; or a video, TIFF "
                   "stack, .cine or .mraw (every frame a state; VIDEO:left for the left half of a side-by-side "
                   "stream)")
    add_input(p, "--right", kind="pattern", what="image", metavar="PATTERN", help="the right camera's images, likewise")
    add_input(p, "--images", kind="dir", what="image", metavar="DIR",
              help="a folder of image pairs NAME<left suffix>.tif / NAME<right suffix>.tif (DICe's and VIC-3D's "
                   "naming)")
    p.add_argument("--left-suffix", default="_0", help="with --images: the left images' suffix (default _0)")
    p.add_argument("--right-suffix", default="_1", help="with --images: the right images' suffix (default _1)")
    add_output(p, kind="dir", metavar="DIR", help="output folder (also the run folder)")
    # 29: VIC-3D's default; a stereo match's random error reaches the shape amplified by the triangulation
    # (Z^2 / (baseline f)), so stereo wants larger subsets than 2-D DIC's 21 (docs/dic.md: on the
    # dice-stereo-list case 21 gives 18 % more out-of-plane noise than DICe's 27, 29 6 % less)
    add_grid_options(p, "left rectified image", subset=29)
    p.add_argument("--roi-frame", choices=["rectified", "original"], default="rectified",
                   help="the image that --roi, --mask, --roi-polygon and --start-point are given in: the left "
                        "rectified image (default) or the left camera's original image (the frame a user draws "
                        "in; its region and points are moved onto the rectified image through the rig)")
    p.add_argument("--shape", choices=["affine", "quadratic"], default="affine",
                   help="subset shape function (default affine)")
    p.add_argument("--disparity", metavar="DMIN,DMAX",
                   help="row search range of the seeds, x_right - x_left in pixels (default +-half the width)")
    p.add_argument("--vertical-search", type=int, metavar="ROWS",
                   help="rows above and below the row that the seeds' stereo search also covers (default: 0 for a "
                        "rig that fits its images; for one whose rows are off, a band about the offsets measured "
                        "in the reference pair, as wide as they scatter)")
    p.add_argument("--max-gap", type=float, default=1.0, metavar="ROWS",
                   help="largest epipolar error of a trusted match, in virtual pixels, beyond the rows' offset "
                        "measured in the reference pair (default 1; points beyond are flagged ray_gap; the rays' "
                        "distance of every point is reported as gap_mm)")
    p.add_argument("--keep-rig", action="store_true",
                   help="keep the rig's calibration as it is (default: when the reference pair's rows are off by "
                        "more than it allows, its right camera is re-oriented from the speckle and the corrected "
                        "rig written to DIR/rig_refit.npz); refused for a rig whose rows are off by more than "
                        "--max-gap")
    add_search_option(p, "temporal seeds")
    add_prefilter_option(p)
    p.add_argument("--min-zncc", type=float, default=0.8, help="points below are flagged (default 0.8)")
    p.add_argument("--strain-window", type=int, default=5, metavar="N",
                   help="strains fitted over N x N grid points, odd; 0 = none (default 5)")
    p.add_argument("--measure", choices=MEASURES, default="green-lagrange", metavar="MEASURE",
                   help=f"strain measure: {', '.join(MEASURES)} (default green-lagrange)")
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
    add_frame_options(p, "the frame of X, Y, Z, displacements and strains is the rig's world frame")
    p.add_argument("--remove-rigid", action="store_true",
                   help="also write each state's displacement less its rigid motion (dX_def, dY_def, dZ_def; "
                        "dic.npz's deformation), in the reporting frame")
    p.add_argument("--mat", action="store_true", help="also write DIR/dic.mat: dic.npz's arrays as a MATLAB file")
    p.add_argument("--no-vtk", action="store_true", help="skip the VTK files")
    p.add_argument("--no-plot", action="store_true", help="skip the PNG maps")
    p.add_argument("--no-overlay", action="store_true",
                   help="maps without their copy over the state's left image")
    p.add_argument("--animate", metavar="Q[,Q...]", default="",
                   help="also write DIR/maps/<Q>.mp4, the maps of these quantities over the test (Z, dX, dY, dZ, "
                        "exx, eyy, exy)")
    p.add_argument("--limits", action="append", default=[], metavar="Q=LO,HI",
                   help="fix a map's colour limits (e.g. exx=-5000,5000 in microstrain, dZ=-0.1,0.1 in mm) instead "
                        "of the run's 1st-99th percentiles; repeat for more quantities")
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
    if args.vertical_search is not None and args.vertical_search < 0:
        raise InputError("--vertical-search", f"must be >= 0 rows, got {args.vertical_search}")
    if not args.max_gap > 0:
        raise InputError("--max-gap", f"must be > 0 rows, got {args.max_gap}")
    check_prefilter(args)
    maps = {"Z", "dX", "dY", "dZ", "exx", "eyy", "exy"} | ({"dX_def", "dY_def", "dZ_def"} if args.remove_rigid else set())
    unknown = set(filter(None, args.animate.split(","))) - maps
    if unknown:
        raise InputError("--animate", f"no map of {', '.join(sorted(unknown))} ({', '.join(sorted(maps))})")
    frame_options(args)
    _limits(args, maps)
    disparity = None
    if args.disparity:
        disparity = tuple(parse_ints(args.disparity, 2, "--disparity"))
        if disparity[0] > disparity[1]:
            raise InputError("--disparity", f"DMIN must not exceed DMAX, got {args.disparity}")
    dic = DicSettings(subset=args.subset, shape=args.shape, min_zncc=args.min_zncc, **search_settings(args),
                      prefilter_sigma=args.prefilter)
    return StereoSettings(dic, disparity, args.strain_window or None, args.incremental, max_gap_px=args.max_gap,
                          switch_zncc=args.switch_zncc, strain_measure=args.measure)


def _limits(args, maps: set[str]) -> dict[str, tuple[float, float]]:
    """--limits Q=LO,HI as {quantity: (lo, hi)}; InputError naming the option when one does not fit."""
    from calib.errors import InputError
    out = {}
    for text in args.limits:
        name, _, values = text.partition("=")
        try:
            lo, hi = (float(v) for v in values.split(","))
        except ValueError:
            raise InputError("--limits", f"{text!r}: needs Q=LO,HI (two numbers)") from None
        if name not in maps or not lo < hi:
            raise InputError("--limits", f"{text!r}: needs a map's quantity ({', '.join(sorted(maps))}) and LO < HI")
        out[name] = (lo, hi)
    return out


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


def _run_record(args, rig_sha, data, settings, grid):
    """(settings, inputs) of the run manifest: everything that decides the results (rig_sha: the rig
    file's SHA-256)."""
    import dataclasses
    import hashlib
    import json
    import os

    from calib import __version__
    from calib.batch import file_sha256, fingerprint
    grid_args = {"subset": args.subset, "step": args.step, "roi": args.roi,
                 "mask": file_sha256(args.mask) if args.mask else None, "seeds": args.start_point, "keep_rig": args.keep_rig,
                 "roi_polygon": file_sha256(args.roi_polygon) if args.roi_polygon else None,
                 "roi_frame": args.roi_frame,
                 "active": hashlib.sha256(grid.active.tobytes()).hexdigest()}
    record = {"software": __version__, "stereo": dataclasses.asdict(settings), "grid": grid_args}
    paths = [str(p) for p in data.left + data.right]
    root = os.path.commonpath([os.path.abspath(p) for p in paths])
    root = root if os.path.isdir(root) else os.path.dirname(root)
    images = [[os.path.relpath(os.path.abspath(lp), root), fingerprint(lp),
               os.path.relpath(os.path.abspath(rp), root), fingerprint(rp)] for lp, rp in zip(data.left, data.right)]
    inputs = {"rig": rig_sha, "images": images}
    return json.loads(json.dumps(record)), inputs


def _summary(st, n, active, search_px) -> str:
    """The state's line (points, mean displacement and strain), and the diagnosis when it measured under
    half of its points (`stereodic.dic3d.diagnose`)."""
    import numpy as np

    from calib.numbers import fixed
    from stereodic.dic3d.diagnose import diagnosis
    c = st.converged
    mean = st.displacement[c].mean(0) if c.any() else np.full(3, np.nan)
    text = (f"state {st.state}: {int(c.sum())}/{n} points converged, mean dX {fixed(mean[0], 4)} dY "
            f"{fixed(mean[1], 4)} dZ {fixed(mean[2], 4)} mm")
    if st.measure is not None and st.measure.valid.any():
        text += (f", mean exx {fixed(np.nanmean(st.measure.exx) * 1e6, 0)} eyy "
                 f"{fixed(np.nanmean(st.measure.eyy) * 1e6, 0)} microstrain")
    if st.incremental.any():
        text += f", {int((st.incremental & c).sum())} incremental"
    why = diagnosis(st.converged, st.status, active, label=f"state {st.state}", reference=st.state == 0,
                    search_px=search_px)
    return text if why is None else f"{text}\n{why}"


def run(args) -> int:
    import gc
    try:
        return _run(args)
    finally:
        gc.unfreeze()         # what `_run` froze, collectable again for a caller in the same process


def _run(args) -> int:
    import gc

    from stereodic.cli.common import memory_reuse
    memory_reuse()
    import stereodic.dic3d.run  # noqa: F401  (the run and its output tasks: imported before the workers fork)
    from stereodic.dic.background import Background, threads
    from stereodic.dic.maps import load_matplotlib

    # the objects alive now (the modules imported) frozen for the run: the collector's full passes need
    # not walk them again (0.13-0.15 -> 0.05 s of collection a run), nor touch the workers' copies of them
    gc.freeze()
    # the processes that write the outputs (`stereodic.dic.background`), forked now, while this process is
    # small and runs one thread; they import matplotlib for the maps beside the checks (`--animate` draws
    # the maps here, a movie's frames in order)
    workers = threads() if threads() > 1 else 0
    with Background(workers, prepare=None if args.no_plot or args.animate else load_matplotlib) as background:
        return _measure(args, background)


def _measure(args, background) -> int:
    """The run (module docstring), its outputs written by `background`'s workers."""
    import functools
    import os
    import sys
    from concurrent.futures import ThreadPoolExecutor
    from pathlib import Path

    import numpy as np

    from calib.batch import file_sha256
    from calib.progress import note
    from calib.sequences import frame_times
    from stereodic.cli.common import wrote
    from stereodic.dic.background import threads
    from stereodic.dic3d import epipolar
    from stereodic.dic3d.refit import reference_geometry
    from stereodic.dic3d.run import run_states, write_outputs
    from stereodic.dic3d.store import RunStore
    from stereodic.stereo.rig import load_rig

    rig = load_rig(args.rig)
    # on more than one thread, beside the checks and the correlation: the rig file's hash for the run's
    # record (hashlib releases the GIL), and with --animate, once the correlation runs, whose kernels leave
    # the interpreter's lock free (beside the checks an import would hold it from their Python),
    # matplotlib for the maps; on one thread, each when it is needed (the output workers import
    # matplotlib themselves: `_run`)
    rig_hash = beside = None
    if threads() > 1:
        beside = ThreadPoolExecutor(2)
        rig_hash = beside.submit(file_sha256, args.rig)
    width, height = rig.sensor.width, rig.sensor.height
    data = _states(args, rig)                   # every state and file checked before the work
    settings = _settings(args)
    grid, seeds = dic_grid(args, width, height, "rectified image", args.rig, original=rig.left.imm)
    automatic = not (args.roi or args.mask or args.roi_polygon)    # the options were checked above
    placed = None
    if automatic and beside is not None:
        # the specimen's points placed beside the rig check, on the reference as the rig rectifies it (placed
        # again below if the check re-orients the rig)
        left0 = data.rectified_pair(rig, 0)[0]
        placed = beside.submit(dic_grid, args, width, height, "rectified image", str(data.left[0]),
                               reference=lambda: left0)
    geometry = reference_geometry(rig, lambda r: data.rectified_pair(r, 0), keep_rig=args.keep_rig,
                                  max_gap_px=args.max_gap, rig_name=args.rig)
    for line in geometry.notes:
        if line.startswith("warning"):
            print(f"stereodic dic: {line}", file=sys.stderr)
        else:
            print(line)
    rig, settings = geometry.rig, geometry.settings(settings, band=args.vertical_search)
    if placed is not None and geometry.correction is None:
        grid, seeds = placed.result()
    elif automatic:
        grid, seeds = dic_grid(args, width, height, "rectified image", str(data.left[0]),
                               reference=lambda: data.rectified_pair(rig, 0)[0])
    record, inputs = _run_record(args, file_sha256(args.rig) if rig_hash is None else rig_hash.result(), data,
                                 settings, grid)
    out = Path(args.output)
    store = RunStore(out)
    n = len(data)
    done = store.open(record, inputs, n, restart=args.restart)
    rig_path, rig_sha = args.rig, inputs["rig"]
    if geometry.correction is not None:
        from stereodic.stereo.rig import save_rig
        rig_path = out / "rig_refit.npz"
        save_rig(rig_path, rig)
        rig_sha = file_sha256(rig_path)
        wrote(rig_path, "the rig with its right camera re-oriented from the reference pair")
    outputs = {"columns": args.columns, "vtk": not args.no_vtk, "plot_every": 0 if args.no_plot else args.plot_every,
               "mat": args.mat, "frame": [args.frame, args.origin, args.x_axis, args.remove_rigid],
               "overlay": not args.no_overlay,
               "animate": args.animate, "limits": args.limits}
    if done == n and store.outputs_written(outputs):
        print(f"{out}: all {n} states are done and written; nothing to do (--restart to run again)")
        return 0
    if done:
        print(f"{out}: resuming a run with {done} of {n} states done")
    if beside is not None:
        if args.animate and not args.no_plot:     # the maps drawn in this process (`_run`)
            from stereodic.dic.maps import load_matplotlib
            beside.submit(load_matplotlib)
        beside.shutdown(wait=False)
    active = int(grid.active.sum())
    summary = functools.partial(_summary, n=active, active=grid.active, search_px=args.search)

    def nothing_measured(st):
        """InputError (exit status 2) with the diagnosis when the reference measured no point."""
        if not st.converged.any():
            from calib.errors import InputError
            from stereodic.dic3d.diagnose import diagnosis
            why = diagnosis(st.converged, st.status, grid.active, label="state 0", reference=True,
                            search_px=args.search)
            raise InputError(data.source, f"no point measured in the reference pair: {why}")
    plot_every = outputs["plot_every"]
    labels = [data.label(k) for k in range(n)]
    if args.scheduler:
        from stereodic.cluster import connect
        from stereodic.dic3d.cluster import RunSpec, run_states_on
        spec = RunSpec.make(str(rig_path), rig_sha, out, data, grid, seeds, settings, summary)
        with connect(args.scheduler) as client:
            state0 = run_states_on(client, store, data, spec, csv=args.columns != "dice", vtk=not args.no_vtk,
                                   plot_every=0, labels=labels)    # the maps need the run's scales: drawn after
        nothing_measured(state0)
    else:
        def report(st):
            note(summary(st))
            if st.state == 0:
                nothing_measured(st)
        # dic.csv's rows, the VTK files and the maps' value ranges made as the states are solved, where they
        # show the states as solved
        as_solved = args.frame != "specimen" and not args.remove_rigid
        state0 = run_states(store, data, rig, grid, seeds, settings, report=report,
                            rows=args.columns != "dice" and as_solved, vtk=not args.no_vtk and as_solved,
                            ranges=not args.no_plot and as_solved, background=background)
    c0 = state0.left.ok & state0.right.ok         # matched, whether or not the rays meet
    X, Y = (a.reshape(grid.shape) for a in grid.points())
    report = epipolar.check(rig, X[c0], Y[c0], (X + state0.right.u)[c0], (Y + state0.right.v)[c0],
                            state0.right.noise_px[c0])
    if report is not None:
        print(report.line())
        if report.bumped and geometry.correction is not None:
            print(f"what a turn of the right camera does not explain (a lens, its focus or the scale changed since "
                  f"the calibration?) is left: the stereo matches follow the rows measured in the reference pair, "
                  f"the rays' distance is reported as gap_mm (median {np.nanmedian(state0.gap_mm):.3f} mm)")
        elif report.bumped and not (geometry.before is not None and geometry.before.bumped):
            print(f"stereodic dic: warning: the rig's epipolar error (median {report.median:+.3f} px, p95 "
                  f"{report.p95:.3f} px) is larger than its calibration allows (p95 {report.expected_p95:.3f} px): "
                  f"has a camera moved since the calibration?", file=sys.stderr)
    info = {"rig": str(rig_path), "dataset": data.source, "world_from_rig": rig.world_from_rig.tolist(),
            "state_labels": labels, "rig_notes": geometry.notes,
            "left_images": [os.path.abspath(p) for p in data.left]}
    frame = None
    info["frame"] = {"frame": "rig", "rigid_motion_removed": False}
    if args.frame == "specimen" or args.remove_rigid:
        from stereodic.dic3d.frame import ReportingFrame
        origin, x_dir = frame_options(args)
        frame = ReportingFrame(state0, settings, specimen=args.frame == "specimen", remove_rigid=args.remove_rigid,
                               origin_px=origin, x_direction_px=x_dir)
        info["frame"] = frame.record()
    times = frame_times(data.left)            # the frames' own timestamps (a video, .cine, .mraw): for loads
    if times is not None:
        info["state_times_s"] = times
    dice = None
    if args.columns == "dice":
        from stereodic.formats.dice_columns import StereoDiceWriter
        dice = StereoDiceWriter(out, grid, data, settings, args.step)
    write_outputs(store, grid, out, settings, info, vtk=not args.no_vtk, plot_every=plot_every,
                  dice=dice, csv=args.columns != "dice", state_files=not args.scheduler, labels=labels, frame=frame,
                  left_images=None if args.no_overlay else [str(p) for p in data.left],
                  frame_name=f"{args.frame}'s frame", animate=tuple(filter(None, args.animate.split(","))),
                  limits=_limits(args, {*"Z dX dY dZ exx eyy exy dX_def dY_def dZ_def".split()}), background=background)
    store.record_outputs(outputs)
    states = f"{active} points x {n} states"
    if args.columns == "dice":
        wrote(out, f"DICe's solution files DICe_solution_<k>.txt and DICe_solution_stereo_<k>.txt ({states})")
    else:
        wrote(out / "dic.csv", f"one row per point and state ({states})")
    wrote(out / "dic.npz", "the same as arrays")
    if args.mat:
        from stereodic.dic.matfile import write_mat
        write_mat(out / "dic.npz", out / "dic.mat")
        wrote(out / "dic.mat", "dic.npz's arrays as a MATLAB file")
    if not args.no_vtk:
        wrote(out / "vtk" / "states.pvd", f"ParaView collection of {n} states (state*.vtp)")
    if not args.no_plot:
        wrote(out / "maps", f"PNG maps of Z, displacements and strains per state, in the {args.frame}'s frame, "
                            f"one colour scale per quantity over the run"
                            + ("" if args.no_overlay else ", beside their copy over the left image"))
        for q in filter(None, args.animate.split(",")):
            wrote(out / "maps" / f"{q}.mp4", f"{q} over the test")
    return 0

