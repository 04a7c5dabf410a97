"""`stereodic dic RIG.npz DATASET -o DIR`: stereo 3D digital image correlation (stereodic.dic3d).

Writes DIR/dic.csv (one row per point and state, columns in docs/dic.md and stereodic/dic3d/output.py),
DIR/dic.npz (the arrays), DIR/vtk/states.pvd + state{k:03d}.vtp (ParaView) and DIR/maps/ (PNG maps of
Z, displacements and strains per state).
"""

from __future__ import annotations

from stereodic.cli.common import add_grid_options, add_input, add_output, dic_grid, parse_ints


def register(sub):
    p = sub.add_parser("dic", help="stereo 3D digital image correlation",
                       description="Stereo 3D-DIC on the rectified virtual pair: 3D shape, 3D displacement and "
                                   "surface strain of every state of a `kind: dic` dataset.")
    add_input(p, "rig", what="rig", metavar="RIG.npz", help="the rectified stereo rig (stereodic rig)")
    add_input(p, "dataset", kind="dataset", metavar="DATASET", help="folder (or capture.json) of a kind 'dic' dataset")
    add_output(p, kind="dir", metavar="DIR", help="output folder")
    add_grid_options(p, "left rectified image")
    p.add_argument("--shape", choices=["affine", "quadratic"], default="affine",
                   help="subset shape function (default affine)")
    p.add_argument("--disparity", metavar="DMIN,DMAX",
                   help="row search range of the seeds, x_right - x_left in pixels (default +-half the width)")
    p.add_argument("--search", type=int, default=40, metavar="PIXELS",
                   help="search range of the temporal seeds (default 40)")
    p.add_argument("--min-zncc", type=float, default=0.8, help="points below are flagged (default 0.8)")
    p.add_argument("--strain-window", type=int, default=5, metavar="N",
                   help="strains fitted over N x N grid points, odd; 0 = none (default 5)")
    p.add_argument("--incremental", action="store_true",
                   help="track the left camera state to state and match stereo at every state (large "
                        "deformations)")
    p.add_argument("--no-vtk", action="store_true", help="skip the VTK files")
    p.add_argument("--no-plot", action="store_true", help="skip the PNG maps")
    p.set_defaults(func=run)


def _settings(args):
    from calib.errors import InputError
    from stereodic.dic import DicSettings
    from stereodic.dic3d.stereo import StereoSettings
    if args.strain_window and (args.strain_window < 3 or args.strain_window % 2 == 0):
        raise InputError("--strain-window", f"must be 0 or an odd number >= 3, got {args.strain_window}")
    if not 0 <= args.min_zncc <= 1:
        raise InputError("--min-zncc", f"must be between 0 and 1, got {args.min_zncc}")
    disparity = None
    if args.disparity:
        disparity = tuple(parse_ints(args.disparity, 2, "--disparity"))
        if disparity[0] > disparity[1]:
            raise InputError("--disparity", f"DMIN must not exceed DMAX, got {args.disparity}")
    dic = DicSettings(subset=args.subset, shape=args.shape, min_zncc=args.min_zncc, search_radius=args.search)
    return StereoSettings(dic, disparity, args.strain_window or None, args.incremental)


def run(args) -> int:
    from pathlib import Path

    import numpy as np

    from calib.numbers import fixed
    from calib.progress import progress
    from stereodic.cli.common import wrote
    from stereodic.dic3d.dataset import load_states
    from stereodic.dic3d.output import plot_states, write_csv, write_npz
    from stereodic.dic3d.stereo import StereoDic
    from stereodic.dic3d.vtk import write_states
    from stereodic.rig import load_rig

    rig = load_rig(args.rig)
    width, height = rig.sensor.width, rig.sensor.height
    data = load_states(args.dataset, rig)       # every state and file checked before the work
    grid, seeds = dic_grid(args, width, height, "rectified image", args.rig)
    settings = _settings(args)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    pairs = list(progress(data.rectified(rig), "rectifying", total=len(data)))
    states = []
    n = int(grid.active.sum())
    for st in progress(StereoDic(rig, grid, settings, seeds).run(pairs), "dic", total=len(pairs)):
        states.append(st)
        c = st.converged & grid.active
        mean = st.displacement[c].mean(0) if c.any() else np.full(3, np.nan)
        strain = (f", mean exx {fixed(np.nanmean(st.strain.exx) * 1e6, 0)} eyy "
                  f"{fixed(np.nanmean(st.strain.eyy) * 1e6, 0)} microstrain"
                  if st.strain is not None and st.strain.valid.any() else "")
        print(f"state {st.state}: {int(c.sum())}/{n} points converged, mean dX {fixed(mean[0], 4)} dY "
              f"{fixed(mean[1], 4)} dZ {fixed(mean[2], 4)} mm{strain}")
    write_csv(out / "dic.csv", grid, states)
    wrote(out / "dic.csv", f"one row per point and state ({n} points x {len(states)} states)")
    write_npz(out / "dic.npz", grid, states, settings, {"rig": str(args.rig), "dataset": str(args.dataset)})
    wrote(out / "dic.npz", "the same as arrays")
    if not args.no_vtk:
        wrote(write_states(out / "vtk", states), f"ParaView collection of {len(states)} states (state*.vtp)")
    if not args.no_plot:
        plot_states(out / "maps", grid, states)
        wrote(out / "maps", "PNG maps of Z, displacements and strains per state")
    return 0
