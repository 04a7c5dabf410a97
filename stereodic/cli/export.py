"""`stereodic export`: a virtual camera's pinhole model for other software.

FILE is a virtual camera file (`stereodic undistort ... --save-virtual VCAM.npz`) or a calibrated
camera's PRVM file (its default virtual pinhole camera, as `stereodic undistort` builds it, is
exported). opencv: FileStorage YAML (camera_matrix, distortion_coefficients all zero, image size,
rotation_matrix, translation_vector in mm); colmap: cameras.txt (PINHOLE); json: model, sensor plane
and OpenCV intrinsics/pose; vic3d: VIC-3D project XML; mrcal: a .cameramodel (LENSMODEL_PINHOLE). Rig
files come with the rectified stereo pair (dice too; mrcal and colmap write a folder). Poses are in the
world frame of the file (for one made by `stereodic import`: the calibration file's world frame).
"""

from __future__ import annotations

import argparse


def register(sub):
    p = sub.add_parser("export", help="a virtual camera's pinhole model for other software",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file", metavar="FILE", help="virtual camera file (VCAM.npz) or camera PRVM file (CAM.npz)")
    p.add_argument("--format", required=True, choices=["opencv", "colmap", "dice", "json", "vic3d", "mrcal"])
    p.add_argument("--model", choices=["pinhole", "telecentric", "modelless"], default="pinhole",
                   help="model of the default virtual camera of a PRVM file (json export only for the "
                        "non-pinhole ones)")
    p.add_argument("-o", "--out", metavar="FILE", required=True)
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from calib.atomic import write_text
    from calib.errors import InputError
    from calib.prvm_file import load_prvm
    from stereodic.export import export_text
    from stereodic.rig import world_from_rig
    from stereodic.virtual import VirtualCamera, default_camera
    from stereodic.virtual_prvm import is_virtual

    from stereodic.export_rig import export_rig, is_rig_file
    if is_rig_file(args.file):  # a stereo rig (RIG.npz): stereodic.export_rig, all four formats
        export_rig(args.file, args.format, args.out)
        return 0
    if args.format == "dice":
        raise InputError("--format", "dice export needs a stereo rig (RIG.npz), not a single camera")
    prvm = load_prvm(args.file)
    camera = VirtualCamera.from_dict(prvm.meta["virtual"]) if is_virtual(prvm) else \
        default_camera(prvm, args.model)
    name = prvm.meta.get("camera", Path(args.file).stem)
    try:
        text = export_text({name: camera}, args.format, world_from_rig(prvm.meta, args.file))
    except InputError as exc:
        raise InputError(args.file, exc.problem) from None
    write_text(args.out, text)
    return 0
