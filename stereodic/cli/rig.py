"""`stereodic rig`: the rectified virtual stereo pair of two calibrated cameras.

LEFT.npz and RIGHT.npz are PRVM files in one WCS (calibrated from one dataset, or registered). The rig
puts one virtual sensor on the Rectified Common FOV Plane: parallel to the baseline between the two fitted
optical centres, through the point the cameras look at, rows along the baseline, the largest grid of
--virtual-size inside both fields. Per camera it keeps the IMM, the model-less rays (pinhole Virtual PRVM + EVM)
and the intensity matrix. See docs/stereo-rig.md for the RIG.npz format.

Separately calibrated cameras: --register LEFT_REG.npz RIGHT_REG.npz are the same two cameras calibrated
from a registration dataset seen by both (the common WCS); each camera's rays are moved into that WCS by
the rigid transform fitted to all its pixels (stereodic.stereo.register).
"""

from __future__ import annotations


from stereodic.cli.common import add_input, add_output, deprecated, parse_size, wrote


def register(sub):
    p = sub.add_parser("rig", help="rectified virtual stereo pair from two PRVMs",
                       description=__doc__)
    add_input(p, "left", what="PRVM", metavar="LEFT.npz", help="left camera's PRVM file")
    add_input(p, "right", what="PRVM", metavar="RIGHT.npz", help="right camera's PRVM file")
    p.add_argument("--model", choices=["pinhole", "modelless"], default="pinhole",
                   help="rays of the Virtual PRVMs: pinhole (default; EVM = real - pinhole) or modelless "
                        "(EVM zero); the rectified images are the same (a pair of telecentric cameras has no "
                        "common pinhole geometry to rectify to)")
    p.add_argument("--virtual-size", type=parse_size, metavar="WxH", help="virtual image size (default: the left camera's)")
    p.add_argument("--virtual-pitch-mm", type=float, metavar="MM",
                   help="virtual pixel pitch on the common plane (default: the largest common field)")
    p.add_argument("--plane-z-mm", type=float, metavar="MM",
                   help="the plane passes where the central rays cross z = MM (default: the left PRVM's "
                        "reference plane)")
    deprecated(p, "--size", "--virtual-size")
    deprecated(p, "--pitch", "--virtual-pitch-mm")
    deprecated(p, "--plane-z", "--plane-z-mm")
    add_input(p, "--register", what="PRVM", nargs=2, metavar=("LEFT_REG.npz", "RIGHT_REG.npz"),
                   help="register separately calibrated cameras into the WCS of these calibrations")
    add_output(p, metavar="RIG.npz", help="output rig file")
    p.set_defaults(func=run)


def run(args) -> int:
    from calib.errors import InputError
    from calib.prvm_file import load_prvm
    from stereodic.stereo.register import apply_registration, estimate_registration
    from stereodic.stereo.rig import build_rig, save_rig, wcs_name

    prvms = [load_prvm(args.left), load_prvm(args.right)]
    names = [args.left, args.right]
    if args.register:
        common = [load_prvm(f) for f in args.register]
        wcs = wcs_name(common[0])
        if wcs != wcs_name(common[1]):
            raise InputError(args.register[1], f"is not in the WCS of {args.register[0]}: the registration "
                                               f"calibrations must come from one dataset")
        for k in range(2):
            reg = estimate_registration(prvms[k], common[k], where=args.register[k])
            prvms[k] = apply_registration(prvms[k], reg, wcs or args.register[0])
            print(f"{names[k]}: registered with {reg.pixels} rays, RMS {reg.rms_mm * 1e3:.2f} um")
    width, height = args.virtual_size if args.virtual_size else (None, None)
    rig = build_rig(prvms[0], prvms[1], model=args.model, width=width, height=height, pitch_mm=args.virtual_pitch_mm,
                    plane_z_mm=args.plane_z_mm, where=tuple(names))
    save_rig(args.output, rig)
    s = rig.sensor
    wrote(args.output, f"{s.width}x{s.height} virtual pixels of {s.pitch_mm[0] * 1e3:.1f} um, baseline "
                       f"{(rig.baseline ** 2).sum() ** 0.5:.2f} mm, working distance {rig.working_distance_mm:.1f} mm")
    for side in ("left", "right"):
        blank = rig.camera(side).info["blank_pixels"]
        if blank:
            print(f"{args.output}: note: {blank} virtual pixels are blank in the {side} camera (holes in its field)")
    return 0
