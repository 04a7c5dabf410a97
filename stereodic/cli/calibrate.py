"""`stereodic calibrate`: one camera's per-pixel rays (PRVM) from a calibration dataset
(calib.calibration), or with --reduced the undistortion map of one stage position (calib.reduced)."""

from __future__ import annotations

import sys


def register(sub):
    p = sub.add_parser("calibrate", help="calibrate one camera's per-pixel rays (PRVM)",
                       description="Decode the fringe images of one camera at 2 or more stage positions into "
                                   "its Pixel Ray Vector Matrix (.npz, stereodic.prvm/1).")
    p.add_argument("dataset", metavar="DATASET", help="folder holding capture.json (or the manifest itself)")
    p.add_argument("--camera", help="camera to calibrate (default: the dataset's only camera)")
    p.add_argument("--no-regularise", action="store_true",
                   help="keep each pixel's own ray (no spatial regularisation)")
    p.add_argument("--window", type=int, default=None, metavar="PX",
                   help="one fixed regularisation window (odd, camera pixels; default: a window chosen per "
                        "pixel, from the smallest the data need up to the image's size): larger lowers noise, "
                        "smaller follows finer distortion")
    p.add_argument("--report", metavar="DIR", help="also write PNG pictures (distortion, residual, uncertainty, "
                                                   "mask) and the measured display response there")
    p.add_argument("--reduced", action="store_true",
                   help="reduced-dimensional PRVM: from one stage position, write the undistortion map "
                        "(stereodic.undistort/1) instead of rays")
    p.add_argument("--position", type=float, default=None, metavar="Z_MM",
                   help="with --reduced: the stage position to use (default the first)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.npz")
    p.set_defaults(func=run)


def _smoother(args):
    from calib.errors import InputError
    from calib.regularise import Smoother
    if args.no_regularise:
        return None
    if args.window is None:
        from calib.calibration import AUTO
        return AUTO
    if args.window < 5 or args.window % 2 == 0:
        raise InputError("--window", f"expected an odd number of pixels >= 5, got {args.window}")
    return Smoother(half_window=args.window // 2)


def run(args) -> int:
    import numpy as np

    from calib.capture import load_capture
    smoother = _smoother(args)
    if args.reduced:
        return _reduced(args, load_capture(args.dataset, min_positions=1), smoother)
    from calib.calibration import calibrate_camera
    capture = load_capture(args.dataset)
    cal = calibrate_camera(capture, args.camera, smoother)
    for note in cal.notes:
        print(f"stereodic calibrate: warning: {note}", file=sys.stderr)
    cal.prvm.save(args.output)
    v = cal.prvm.valid
    unc = cal.prvm.extra["uncertainty_mm"][..., 0][v]
    print(f"{args.output}: {cal.prvm.meta['camera']}, {v.shape[1]}x{v.shape[0]}, {v.mean():.1%} of pixels "
          f"calibrated from {len(cal.positions)} stage positions; median 1-sigma ray uncertainty "
          f"{1000 * float(np.median(unc)):.2f} um")
    if args.report:
        _report(args.report, cal)
    return 0


def _report(out_dir, cal) -> None:
    from pathlib import Path

    from calib.atomic import write_json
    from stereodic.cli.show import write_report
    paths = write_report(cal.prvm, out_dir)
    if cal.intensity is not None:
        path = Path(out_dir) / "display_response.json"
        write_json(path, cal.intensity.response.to_json())
        paths.append(path)
    for p in paths:
        print(p)


def _reduced(args, capture, smoother) -> int:
    from calib.calibration import default_camera
    from calib.decode import decode_position, intensity_matrix
    from calib.errors import InputError
    from calib.reduced import undistort_map
    camera = default_camera(capture, args.camera)
    zs = capture.z_positions(camera)
    z = zs[0] if args.position is None else args.position
    if z not in zs:
        raise InputError("--position", f"camera {camera!r} has no frames at z={z} mm (have {zs})")
    from calib.calibration import AUTO, auto_smoother
    decoded = decode_position(capture, camera, z, intensity_matrix(capture, camera, z))
    umap = undistort_map(decoded.coord, decoded.valid, auto_smoother([decoded]) if smoother is AUTO else smoother)
    umap.meta.update({"camera": camera, "dataset": str(capture.root), "z_mm": z})
    umap.save(args.output)
    print(f"{args.output}: undistortion map of {camera} at z={z} mm, {umap.valid.mean():.1%} of the output "
          "image covered")
    return 0

