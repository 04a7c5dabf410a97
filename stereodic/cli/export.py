"""`stereodic export`: a virtual camera's pinhole model, or a stereo rig, for other software.

FILE is a virtual camera file (`stereodic undistort ... --save-virtual VCAM.npz`), a calibrated camera's
PRVM file (its default virtual pinhole camera, as `stereodic undistort` builds it, is exported) or a
stereo rig (`stereodic rig`: the rectified pair's two virtual pinhole cameras). Formats:
  opencv  OpenCV FileStorage YAML: camera_matrix, distortion_coefficients (all zero: the virtual images
          are distortion free), image size, rotation_matrix, translation_vector (mm); for a rig the
          stereo_calib keys M1 D1 M2 D2 R T R1 R2 P1 P2 Q and the WCS pose of camera 1
  colmap  COLMAP text model: cameras.txt (PINHOLE); for a rig a folder with cameras.txt, images.txt
          (the two posed cameras) and points3D.txt
  dice    DICe's camera system XML (DICe_xml_camera_system_file: CAMERA 0 and 1 with CX CY FX FY, no
          lens distortion, rotation and TX TY TZ in the WCS, mm): a stereo rig only
  json    everything: model, sensor plane, centre and OpenCV intrinsics/pose (also the telecentric and
          model-less cameras that have no pinhole form)
  vic3d   VIC-3D calibration XML (cx cy fx fy skew kappa1..3, Cardan-Bryant orientation)
  mrcal   a .cameramodel (LENSMODEL_PINHOLE); for a rig a folder with left.cameramodel and
          right.cameramodel
Poses are in the world frame of the file (for one made by `stereodic import`: the calibration file's
own world frame).
"""

from __future__ import annotations


from stereodic.cli.common import add_input, add_output, wrote


def register(sub):
    p = sub.add_parser("export", help="a virtual camera's pinhole model for other software",
                       description=__doc__)
    add_input(p, "file", what="camera or rig", metavar="FILE",
              help="virtual camera file (VCAM.npz), camera PRVM file (CAM.npz) or stereo rig (RIG.npz)")
    p.add_argument("--format", required=True, choices=["opencv", "colmap", "dice", "json", "vic3d", "mrcal"],
                   help="opencv: FileStorage YAML; colmap: cameras.txt; dice: DICe's camera system XML (a rig "
                        "only); json: everything, also the non-pinhole models; vic3d: VIC-3D calibration XML; "
                        "mrcal: .cameramodel")
    p.add_argument("--model", choices=["pinhole", "telecentric", "modelless"], default="pinhole",
                   help="model of the default virtual camera of a PRVM file (json export only for the "
                        "non-pinhole ones)")
    add_output(p, kind="any", metavar="FILE", help="the file to write (a folder for a rig's colmap or mrcal "
                                                   "model)")
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from calib.atomic import write_text
    from calib.errors import InputError
    from calib.npzfile import read_npz
    from calib.prvm_file import FORMAT as PRVM_FORMAT
    from calib.prvm_file import load_prvm
    from stereodic.virtual.export import export_text
    from stereodic.stereo.export import export_rig
    from stereodic.stereo.rig import FORMAT as RIG_FORMAT
    from stereodic.stereo.rig import world_from_rig
    from stereodic.virtual.camera import VirtualCamera, default_camera
    from stereodic.virtual.prvm import is_virtual

    meta, _ = read_npz(args.file, (PRVM_FORMAT, RIG_FORMAT), "camera or rig", keys=())   # the meta alone
    rig = meta["format"] == RIG_FORMAT
    folder = rig and args.format in ("colmap", "mrcal")
    if Path(args.output).is_dir() != folder and Path(args.output).exists():
        raise InputError(args.output, f"is a file; the {args.format} export of a rig is a folder" if folder else
                         "is a directory; -o/--output expects a file name")
    if rig:  # a stereo rig (RIG.npz): stereodic.stereo.export, every format
        export_rig(args.file, args.output, fmt=args.format)
        wrote(args.output, f"{args.format} stereo rig of {args.file}")
        return 0
    if args.format == "dice":
        raise InputError("--format", "dice export needs a stereo rig (RIG.npz), not a single camera")
    prvm = load_prvm(args.file)
    camera = VirtualCamera.from_dict(prvm.meta["virtual"]) if is_virtual(prvm) else \
        default_camera(prvm, model=args.model)
    name = prvm.meta.get("camera", Path(args.file).stem)
    try:
        text = export_text({name: camera}, fmt=args.format, world_from_rig=world_from_rig(prvm.meta, args.file))
    except InputError as exc:
        raise InputError(args.file, exc.problem) from None
    write_text(args.output, text)
    wrote(args.output, f"{args.format} {camera.model} camera {name}, {camera.sensor.width}x{camera.sensor.height}")
    return 0
