"""`stereodic import`: another program's calibration as a stereodic rig or camera.

CALIBRATION is a calibration file of OpenCV (FileStorage YAML/XML/JSON: one camera, or a stereo pair
M1 D1 M2 D2 R T; the stereo_calib sample's intrinsics.yml and extrinsics.yml may be given together),
VIC-3D (project/calibration XML), DICe (camera system XML or legacy cal.txt), mrcal (.cameramodel; two
files for a pair), Kalibr (camchain.yaml) or ROS (camera_info YAML; two files for a pair), recognised from its content (--format to insist). Each
camera's own model is kept exactly (skew included) and turned into its per-pixel rays; two cameras give
the rectified virtual stereo pair (RIG.npz) exactly as `stereodic rig` builds it from two PRVMs, one camera
its PRVM file (CAM.npz). Where the cameras look along -z of the file's world frame (VIC-3D's usual frame)
the rays are built in that frame rotated 180 degrees about x; the file records the transform back
(world_from_rig), so that 3D results are reported in the calibration file's own world frame.
See docs/import.md.
"""

from __future__ import annotations


from stereodic.cli.common import add_input, add_output, deprecated, parse_size, wrote


def register(sub):
    p = sub.add_parser("import", help="another program's calibration as a rig (RIG.npz) or camera (CAM.npz)",
                       description=__doc__)
    add_input(p, "calibration", what="calibration", nargs="+", metavar="CALIBRATION",
                   help="calibration file (two for a pair of mrcal models or ROS camera_info files, or OpenCV's "
                        "intrinsics + extrinsics)")
    p.add_argument("--format", default="auto", choices=["auto", "opencv", "vic3d", "dice", "mrcal", "kalibr", "ros"],
                   help="the file's format (default: recognised from its content)")
    p.add_argument("--size", type=parse_size, metavar="WxH",
                   help="image size, for a calibration file that does not give it")
    p.add_argument("--camera", metavar="NAME[,NAME]",
                   help="one camera (its PRVM) or two (a rig), by exact name or by 0-based position as #N "
                        "(default: all; one or two)")
    p.add_argument("--units", choices=["mm", "m"],
                   help="unit of the file's translations (default: mm; Kalibr, ROS: m)")
    p.add_argument("--model", choices=["pinhole", "modelless"], default="pinhole",
                   help="as `stereodic rig --model`: rays of the Virtual PRVMs (the images are the same)")
    p.add_argument("--virtual-size", type=parse_size, metavar="WxH",
                   help="as `stereodic rig --virtual-size`: virtual image size (default: the left camera's)")
    p.add_argument("--virtual-pitch-mm", type=float, metavar="MM", help="as `stereodic rig --virtual-pitch-mm`")
    p.add_argument("--plane-z-mm", type=float, metavar="MM",
                   help="as `stereodic rig --plane-z-mm`, in the rig's frame (default: the cameras' working "
                        "point)")
    deprecated(p, "--pitch", "--virtual-pitch-mm")
    deprecated(p, "--plane-z", "--plane-z-mm")
    add_output(p, metavar="OUT.npz", help="output rig or camera file")
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from calib.prvm_file import PRVM
    from stereodic.formats import import_calibration
    from stereodic.stereo.rig import save_rig

    names = [n.strip() for n in args.camera.split(",")] if args.camera is not None else None
    imp = import_calibration(args.calibration, fmt=args.format, size=args.size, units=args.units, cameras=names,
                             model=args.model, virtual_size=args.virtual_size, pitch_mm=args.virtual_pitch_mm,
                             plane_z_mm=args.plane_z_mm)
    fmt, cams, out = imp.format, imp.cameras, imp.result
    flipped = "" if np.allclose(out.meta["world_from_rig"] if isinstance(out, PRVM) else out.world_from_rig,
                                np.eye(4)) else " (rays in the file's frame turned to look along +z)"
    if isinstance(out, PRVM):
        out.save(args.output)
        c = cams[0]
        beyond = "" if out.valid.all() else " (the others lie beyond the lens model's first fold: no ray there)"
        wrote(args.output, f"{fmt} camera {c.name!r}, {c.width}x{c.height}, {out.valid.mean():.1%} of pixels "
                           f"with a ray{beyond}{flipped}")
        return 0
    save_rig(args.output, out)
    s = out.sensor
    wrote(args.output, f"{fmt} cameras {cams[0].name!r} (left) and {cams[1].name!r} (right); {s.width}x{s.height} "
                       f"virtual pixels of {s.pitch_mm[0] * 1e3:.1f} um, baseline {np.linalg.norm(out.baseline):.2f} "
                       f"mm, working distance {out.working_distance_mm:.1f} mm{flipped}")
    return 0
