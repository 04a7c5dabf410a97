"""`stereodic rectify`: a stereo image pair onto the rig's Rectified Common FOV Plane.

Each image goes through its camera's intensity matrix (if the rig has one) and IMM. Writes
DIR/left/<name of LEFT_IMG> and DIR/right/<name of RIGHT_IMG> (same format and bit depth) and
DIR/overlay.png: both rectified images side by side with coloured epipolar rows (a feature must lie on
the same row in both).
"""

from __future__ import annotations

import argparse


def register(sub):
    p = sub.add_parser("rectify", help="rectify a stereo image pair with a rig",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("rig", metavar="RIG.npz", help="rig file from `stereodic rig`")
    p.add_argument("left", metavar="LEFT_IMG", help="left camera's image (8/16-bit PNG or TIFF)")
    p.add_argument("right", metavar="RIGHT_IMG", help="right camera's image")
    p.add_argument("-o", "--out", metavar="DIR", required=True, help="output folder")
    p.add_argument("--no-intensity", action="store_true", help="do not apply the intensity matrices")
    p.add_argument("--fixed-point", action="store_true", help="OpenCV fixed-point maps (1/32 pixel)")
    p.add_argument("--every", type=int, default=32, metavar="ROWS", help="overlay line spacing (default 32)")
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    import cv2

    from calib.atomic import atomic_output
    from calib.imageio import read_gray, write_gray
    from stereodic.rectify import epipolar_overlay, rectify_pair
    from stereodic.rig import load_rig

    rig = load_rig(args.rig)
    left, right = rectify_pair(rig, read_gray(args.left), read_gray(args.right), not args.no_intensity,
                               args.fixed_point, (args.left, args.right))
    out = Path(args.out)
    write_gray(out / "left" / Path(args.left).name, left)
    write_gray(out / "right" / Path(args.right).name, right)
    with atomic_output(out / "overlay.png") as tmp:
        if not cv2.imwrite(str(tmp), epipolar_overlay(left, right, max(args.every, 2))):
            raise OSError(f"{out / 'overlay.png'}: could not write image")
    return 0
