"""`stereodic undistort`: distortion-free virtual images of one camera's images.

CAM.npz is a calibrated camera (PRVM file) - its default virtual camera is built (the largest field
inside the real one, the real pixel count unless --size/--pitch say otherwise) - or a virtual camera file
written by --save-virtual, whose IMM is applied as it is. Each IMAGE gives DIR/<its name>, same format
and bit depth.
"""

from __future__ import annotations


from stereodic.cli.common import add_input, add_output, deprecated, parse_size, wrote


def register(sub):
    p = sub.add_parser("undistort", help="distortion-free virtual images of one camera's images",
                       description=__doc__)
    add_input(p, "camera", what="camera", metavar="CAM.npz", help="camera PRVM file, or a virtual camera file")
    add_input(p, "images", what="image", metavar="IMAGE", nargs="+", help="8- or 16-bit grayscale PNG/TIFF")
    add_output(p, kind="dir", metavar="DIR", help="output folder")
    p.add_argument("--model", choices=["pinhole", "telecentric", "modelless"], default="pinhole",
                   help="ray model of the virtual camera (default pinhole; telecentric for telecentric "
                        "lenses); the images are the same, the saved Virtual PRVM and EVM differ")
    p.add_argument("--virtual-size", type=parse_size, metavar="WxH", help="virtual image size (default: the real one)")
    p.add_argument("--virtual-pitch-mm", type=float, metavar="MM",
                   help="virtual pixel pitch on the sensor plane, mm (default: the largest field that fits)")
    p.add_argument("--plane-z-mm", type=float, metavar="MM",
                   help="the virtual sensor plane passes where the central ray crosses z = MM "
                        "(default: the PRVM's reference plane)")
    deprecated(p, "--size", "--virtual-size")
    deprecated(p, "--pitch", "--virtual-pitch-mm")
    deprecated(p, "--plane-z", "--plane-z-mm")
    kind = p.add_mutually_exclusive_group()
    kind.add_argument("--float", dest="fixed_point", action="store_false",
                      help="float32 maps: exact bilinear interpolation (default)")
    kind.add_argument("--fixed-point", dest="fixed_point", action="store_true",
                      help="OpenCV fixed-point maps (1/32 pixel positions)")
    p.add_argument("--no-intensity", action="store_true", help="do not apply the camera's intensity matrix")
    add_output(p, "--save-virtual", metavar="VCAM.npz",
                   help="also write the virtual camera (Virtual PRVM + IMM + EVM) for `undistort`/`export`")
    p.set_defaults(func=run, fixed_point=False)


def run(args) -> int:
    from pathlib import Path

    from calib.errors import InputError
    from calib.imageio import check_size, read_gray, write_gray
    from calib.prvm_file import load_prvm
    from calib.progress import progress
    from stereodic.virtual.undistort import intensity_matrix, undistort_image
    from stereodic.virtual.prvm import as_virtual, is_virtual, save_virtual

    prvm = load_prvm(args.camera)
    im = None if args.no_intensity else intensity_matrix(prvm)
    setup = None
    if is_virtual(prvm):
        if args.virtual_size or args.virtual_pitch_mm or args.plane_z_mm is not None:
            raise InputError(args.camera, "is a virtual camera file: --virtual-size, --virtual-pitch-mm and --plane-z-mm do not apply")
        setup = as_virtual(prvm)
    out = Path(args.output)
    names = [Path(f).name for f in args.images]
    if len(set(names)) != len(names):
        raise InputError(args.output, "two input images have the same name; outputs are named after the inputs")
    real = setup.imm.real_size if setup is not None else (prvm.width, prvm.height)
    for path in args.images:  # every image checked before the work
        check_size(path, real, "the camera")
    if setup is None:
        setup = virtual_setup(prvm, args)
    if args.save_virtual:
        if im is not None:
            setup.prvm.extra.update(im.to_arrays())
        save_virtual(args.save_virtual, setup)
        wrote(args.save_virtual, f"virtual camera ({args.model}), {setup.imm.valid.shape[1]}x"
                                 f"{setup.imm.valid.shape[0]}")
    for path, name in progress(list(zip(args.images, names)), "undistort"):
        virtual = undistort_image(read_gray(path), setup.imm, im=im, fixed_point=args.fixed_point, where=path)
        write_gray(out / name, virtual)
        wrote(out / name, f"{path} without distortion, {virtual.shape[1]}x{virtual.shape[0]}")
    return 0


def virtual_setup(prvm, args):
    """The default virtual camera of `prvm` with the command's options, checked to have no blank pixel."""
    from calib.errors import InputError
    from stereodic.virtual.camera import default_camera
    from stereodic.virtual.prvm import make_virtual

    width, height = args.virtual_size if args.virtual_size else (None, None)
    try:
        camera = default_camera(prvm, model=args.model, width=width, height=height, pitch_mm=args.virtual_pitch_mm,
                                plane_z_mm=args.plane_z_mm)
    except InputError as exc:
        raise InputError(args.camera, exc.problem) from None
    setup = make_virtual(prvm, camera)
    blank = int((~setup.imm.valid).sum())
    if blank:
        raise InputError(args.camera, f"the virtual camera is larger than the real field: {blank} of "
                                      f"{setup.imm.valid.size} virtual pixels would be blank")
    return setup
