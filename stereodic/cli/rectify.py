"""`stereodic rectify`: a stereo image pair onto the rig's Rectified Common FOV Plane.

Each image goes through its camera's intensity matrix (if the rig has one) and IMM. Writes
DIR/left/<name of LEFT_IMG> and DIR/right/<name of RIGHT_IMG> (same format and bit depth) and
DIR/overlay.png, which shows whether the rows line up (a scene point must lie on the same row in both
images): the pair side by side with a line every --every rows, features matched from left to right and
magnified, and their vertical disparity (y_right - y_left, pixels; its RMS is printed too). The features
need texture in both directions (speckle, a chessboard): a pair of stripes cannot show it.
"""

from __future__ import annotations


from stereodic.cli.common import add_input, add_output, wrote


def register(sub):
    p = sub.add_parser("rectify", help="rectify a stereo image pair with a rig",
                       description=__doc__)
    add_input(p, "rig", what="rig", metavar="RIG.npz", help="rig file from `stereodic rig`")
    add_input(p, "left", what="image", metavar="LEFT_IMG", help="left camera's image (8/16-bit PNG or TIFF)")
    add_input(p, "right", what="image", metavar="RIGHT_IMG", help="right camera's image")
    add_output(p, kind="dir", metavar="DIR", help="output folder")
    p.add_argument("--no-intensity", action="store_true", help="do not apply the intensity matrices")
    kind = p.add_mutually_exclusive_group()
    kind.add_argument("--float", dest="fixed_point", action="store_false",
                      help="float32 maps: exact bilinear interpolation (default)")
    kind.add_argument("--fixed-point", dest="fixed_point", action="store_true",
                      help="OpenCV fixed-point maps (1/32 pixel positions)")
    p.add_argument("--every", type=int, default=32, metavar="ROWS", help="overlay line spacing (default 32)")
    p.set_defaults(func=run, fixed_point=False)


def run(args) -> int:
    from pathlib import Path

    from calib.atomic import atomic_output
    from calib.imageio import read_gray, write_gray
    from calib.numbers import fixed
    from stereodic.stereo.rectify import offset_text, plot_row_alignment, rectify_pair, row_alignment, row_band
    from stereodic.stereo.rig import load_rig

    rig = load_rig(args.rig)
    left, right = rectify_pair(rig, read_gray(args.left), read_gray(args.right), intensity=not args.no_intensity,
                               fixed_point=args.fixed_point, where=(args.left, args.right))
    out = Path(args.output)
    for side, image, source in (("left", left, args.left), ("right", right, args.right)):
        write_gray(out / side / Path(source).name, image)
        wrote(out / side / Path(source).name, f"{source} rectified, {image.shape[1]}x{image.shape[0]}")
    match = row_alignment(left, right)
    fig = plot_row_alignment(left, right, match, max(args.every, 2))
    with atomic_output(out / "overlay.png") as tmp:
        fig.savefig(tmp, dpi=100, bbox_inches="tight")
    offset = offset_text(match)
    wrote(out / "overlay.png", f"row alignment: vertical disparity RMS {fixed(match.rms, 3)} px over "
                               f"{match.dy.size} matched features{'; ' + offset if offset else ''}" if match.dy.size
                               else f"row alignment: no feature with texture in both directions matched within "
                                    f"{row_band(left.shape[0])} rows of its own to measure it")
    return 0
