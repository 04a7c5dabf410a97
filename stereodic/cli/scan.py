"""`stereodic scan RIG.npz DATASET -o CLOUD.ply`: structured-light scan to a point cloud (stereodic.scan).

DATASET is a capture of kind "scan" (fringes projected along the projector's columns, several periods
and steps, a top-level `projector` block with the panel's width_px); RIG.npz is the rectified pair of
the two cameras (`stereodic rig`). Each state of the dataset is one scan: the absolute projector phase of
both cameras is mapped into the rectified virtual images, matched along rows, triangulated with the
EVM-corrected rays, cleaned of statistical outliers and written as a binary float32 PLY with normals and
the per-point scalars `quality` (fringe modulation, fraction of full scale) and `gap_mm` (ray gap).
A dataset with several states gives one file per state, CLOUD_s<state>.ply. See docs/scanner.md.
"""

from __future__ import annotations

import argparse

from stereodic.cli.common import add_input, add_output, wrote


def _pair(text: str) -> tuple[str, str]:
    names = [t.strip() for t in text.split(",")]
    if len(names) != 2 or not all(names):
        raise argparse.ArgumentTypeError(f"expected LEFT,RIGHT camera names, got {text!r}")
    return names[0], names[1]


def register(sub):
    p = sub.add_parser("scan", help="structured-light scan to a point cloud",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_input(p, "rig", what="rig", metavar="RIG.npz", help="the rectified stereo rig (stereodic rig)")
    add_input(p, "dataset", kind="dataset", metavar="DATASET", help="scan dataset folder or its capture.json")
    add_output(p, metavar="CLOUD.ply", help="output point cloud (CLOUD_s<state>.ply per state if several)")
    p.add_argument("--state", type=int, action="append", metavar="N",
                   help="scan only this state (repeatable; default all)")
    p.add_argument("--cameras", type=_pair, metavar="LEFT,RIGHT",
                   help="dataset camera names of the rig's left and right camera (default: the rig's names)")
    add_output(p, "--mesh", metavar="MESH.ply", help="also write a Poisson surface mesh")
    p.add_argument("--no-evm", action="store_true",
                   help="triangulate with the pinhole rays (no EVM correction), for comparison")
    p.add_argument("--smooth", type=float, default=None, metavar="PX",
                   help="phase filter sigma in virtual pixels before matching (default 3; 0: none)")
    p.add_argument("--outlier-neighbours", type=int, default=20,
                   help="statistical outlier removal: neighbours (default 20; 0 disables)")
    p.add_argument("--outlier-std", type=float, default=3.0,
                   help="statistical outlier removal: std ratio (default 3)")
    p.set_defaults(func=run)


def run(args) -> int:
    from stereodic.scan import SMOOTH_PX, scan_to_files
    from stereodic.rig import load_rig
    rig = load_rig(args.rig)
    written = scan_to_files(rig, args.dataset, args.output, args.state, args.cameras, args.mesh,
                            corrected=not args.no_evm, neighbours=args.outlier_neighbours,
                            std_ratio=args.outlier_std, smooth_px=SMOOTH_PX if args.smooth is None else args.smooth)
    for path, count, what in written:
        wrote(path, f"{count} {what}")
    return 0
