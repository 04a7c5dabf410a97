"""`stereodic dic RIG.npz DATASET -o DIR`: stereo 3D digital image correlation (stereodic.dic3d).

Writes DIR/dic.csv (one row per point and state, columns in docs/dic.md and stereodic/dic3d/output.py),
DIR/dic.npz (the arrays), DIR/vtk/states.pvd + state{k:03d}.vtp (ParaView) and DIR/maps/ (PNG maps of
Z, displacements and strains per state).
"""

from __future__ import annotations

from stereodic.cli.common import dic_grid, parse_ints


def register(sub):
    p = sub.add_parser("dic", help="stereo 3D digital image correlation",
                       description="Stereo 3D-DIC on the rectified virtual pair: 3D shape, 3D displacement and "
                                   "surface strain of every state of a `kind: dic` dataset.")
    p.add_argument("rig", metavar="RIG.npz", help="the rectified stereo rig (stereodic rig)")
    p.add_argument("dataset", metavar="DATASET", help="folder (or capture.json) of a kind 'dic' dataset")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output folder")
    p.add_argument("--subset", type=int, default=21, help="subset side in pixels, odd (default 21)")
    p.add_argument("--step", type=int, default=5, help="grid step in pixels (default 5)")
    p.add_argument("--shape", choices=["affine", "quadratic"], default="affine",
                   help="subset shape function (default affine)")
    p.add_argument("--roi", metavar="X0,Y0,X1,Y1", help="region of interest in the left rectified image")
    p.add_argument("--mask", metavar="PNG", help="image of the rectified size: points where it is non-zero")
    p.add_argument("--seed", action="append", default=[], metavar="X,Y",
                   help="start point in the left rectified image (repeatable; default automatic)")
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

    from calib.progress import progress
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
        print(f"state {st.state}: {int(c.sum())}/{n} points converged, mean dX {mean[0]:.4f} dY {mean[1]:.4f} "
              f"dZ {mean[2]:.4f} mm" + (f", mean exx {np.nanmean(st.strain.exx) * 1e6:.0f} eyy "
                                         f"{np.nanmean(st.strain.eyy) * 1e6:.0f} microstrain"
                                         if st.strain is not None and st.strain.valid.any() else ""))
    write_csv(out / "dic.csv", grid, states)
    write_npz(out / "dic.npz", grid, states, settings, {"rig": str(args.rig), "dataset": str(args.dataset)})
    if not args.no_vtk:
        write_states(out / "vtk", states)
    if not args.no_plot:
        plot_states(out / "maps", grid, states)
    return 0
