"""`stereodic calibrate`: one camera's per-pixel rays (PRVM) from a calibration dataset
(calib.calibration), or with --reduced the undistortion map of one stage position (calib.reduced)."""

from __future__ import annotations

import sys

from stereodic.cli.common import add_input, add_output, add_scheduler_option, check_file_output, deprecated, wrote


def register(sub):
    p = sub.add_parser("calibrate", help="calibrate one camera's per-pixel rays (PRVM)",
                       description="Decode the fringe images of one camera at 2 or more stage positions (or "
                                   "3 or more poses of a hand-held display) into its Pixel Ray Vector Matrix "
                                   "(.npz, stereodic.prvm/1). With a hand-held display the poses are estimated "
                                   "together with the rays and the WCS is the display's frame at pose 0.")
    add_input(p, "dataset", kind="dataset", metavar="DATASET", nargs="+",
              help="folder holding capture.json (or the manifest itself); several, or a quoted shell-style "
                   "pattern, for a batch (stereodic.cli.calibrate_batch)")
    p.add_argument("--camera", action="append",
                   help="camera to calibrate (default: the dataset's only camera); repeat it for several")
    p.add_argument("--no-regularise", action="store_true",
                   help="keep each pixel's own ray (no spatial regularisation)")
    p.add_argument("--regularise-window", type=int, default=None, metavar="PX",
                   help="one fixed regularisation window (odd, camera pixels; default: a window chosen per "
                        "pixel, from the smallest the data need up to the image's size): larger lowers noise, "
                        "smaller follows finer distortion")
    deprecated(p, "--window", "--regularise-window")
    p.add_argument("--no-refine-poses", action="store_true",
                   help="with 3 or more stage positions: use the nominal positions as they are (default: "
                        "estimate the display's tilt and z and lateral errors at each position from the data and "
                        "use them where they lower the residual significantly)")
    add_output(p, "--report", kind="dir", metavar="DIR", help="also write PNG pictures (distortion, uncertainty, mask; "
                                                   "residual with 3+ stage positions) and the measured display "
                                                   "response there")
    p.add_argument("--reduced", action="store_true",
                   help="reduced-dimensional PRVM: from one stage position, write the undistortion map "
                        "(stereodic.undistort/1) instead of rays")
    p.add_argument("--position", type=float, default=None, metavar="Z_MM",
                   help="with --reduced: the stage position to use, or the pose of a hand-held capture "
                        "(default the first)")
    add_output(p, kind="any", metavar="OUT.npz|DIR",
               help="the PRVM file (stereodic.prvm/1), or with --reduced the undistortion map; a folder for "
                    "several cameras: DIR/<camera>.npz, or DIR/<dataset folder>_<camera>.npz for several datasets")
    add_scheduler_option(p, "cameras (each one a task)")
    p.set_defaults(func=run)


def _smoother(args):
    from calib.errors import InputError
    from calib.regularise import Smoother
    if args.no_regularise:
        return None
    if args.regularise_window is None:
        from calib.ray_field import AUTO
        return AUTO
    if args.regularise_window < 5 or args.regularise_window % 2 == 0:
        raise InputError("--regularise-window", f"expected an odd number of pixels >= 5, got "
                                                f"{args.regularise_window}")
    return Smoother(half_window=args.regularise_window // 2)


def run(args) -> int:
    from calib.capture import load_capture
    from stereodic.cli import calibrate_batch
    if calibrate_batch.is_batch(args):
        return calibrate_batch.run(args, _smoother(args))
    args.dataset, args.camera = args.dataset[0], args.camera[0] if args.camera else None
    check_file_output(args.output, "-o/--output")
    smoother = _smoother(args)
    if args.reduced:
        return _reduced(args, load_capture(args.dataset, min_positions=1), smoother)
    from calib.calibration import calibrate_camera
    from calib.errors import InputError
    from stereodic.cli.calibrate_report import report, summary
    capture = load_capture(args.dataset)
    if args.no_refine_poses and capture.posed:
        raise InputError("--no-refine-poses", "a hand-held (stage-free) capture has no nominal poses to keep: "
                                              "its poses are always estimated")
    cal = calibrate_camera(capture, camera=args.camera, smoother=smoother, refine=not args.no_refine_poses)
    for note in cal.notes:
        print(f"stereodic calibrate: warning: {note}", file=sys.stderr)
    cal.prvm.save(args.output)
    wrote(args.output, summary(cal))
    for line in pose_lines(cal.prvm.meta):
        print(line)
    if args.report:
        for p, what in report(args.report, cal):
            wrote(p, what)
    return 0


def pose_lines(meta: dict) -> list[str]:
    """The estimated display poses (a hand-held capture) or stage errors (a staged one with 3 or more
    positions) of a PRVM's meta, one line each."""
    out = []
    for p in meta.get("poses", []):
        if not p["used"]:
            out.append(f"  pose {p['pose']}: left out, out of family: its points do not lie on one rigid display "
                       f"(statistic {p['chi']:.1f}; did the display move during its fringes?)")
            continue
        r, t = p["rotation_deg"], p["translation_mm"]
        out.append(f"  pose {p['pose']}: rotation ({r[0]:+.4f}, {r[1]:+.4f}, {r[2]:+.4f}) deg "
                   f"+- {max(p['sd_rotation_deg']):.5f}, translation ({t[0]:+.4f}, {t[1]:+.4f}, {t[2]:+.4f}) mm "
                   f"+- {max(p['sd_translation_um']):.2f} um, RMS residual {p['rms_um']:.1f} um, "
                   f"out-of-family statistic {p['chi']:.2f}" + (" OUT OF FAMILY" if p["out_of_family"] else ""))
    stage = meta.get("stage_poses")
    if stage:
        state = ("refined poses used" if stage["used"] else
                 "refinement not significant: nominal positions used")
        out.append(f"  stage poses: {state} (residual {stage['cost_nominal']:.4g} -> {stage['cost_refined']:.4g}, "
                   f"{stage['free_parameters']} parameters)")
        for e in stage["positions"][1:]:
            out.append(f"  z = {e['z_mm']:g} mm: z error {e['z_error_um']:+.2f} +- {e['sd_z_um']:.2f} um, lateral "
                       f"({e['lateral_um'][0]:+.2f}, {e['lateral_um'][1]:+.2f}) um, tilt ({e['tilt_deg'][0]:+.5f}, "
                       f"{e['tilt_deg'][1]:+.5f}, {e['tilt_deg'][2]:+.5f}) deg +- {max(e['sd_tilt_deg']):.5f}")
    return out


def _reduced(args, capture, smoother) -> int:
    from calib.calibration import default_camera
    from calib.decode import decode_position, intensity_matrix
    from calib.errors import InputError
    from calib.reduced import undistort_map
    camera = default_camera(capture, args.camera)
    zs = capture.positions(camera)
    z = zs[0] if args.position is None else (int(args.position) if capture.posed else args.position)
    if z not in zs:
        raise InputError("--position", f"camera {camera!r} has no frames at {capture.label(z)} (have {zs})")
    from calib.ray_field import AUTO, auto_smoother
    decoded = decode_position(capture, camera, z, intensity_matrix(capture, camera, z))
    umap = undistort_map(decoded.coord, decoded.valid, auto_smoother([decoded]) if smoother is AUTO else smoother)
    umap.meta.update({"camera": camera, "dataset": str(capture.root), **capture.at(z)})
    umap.save(args.output)
    wrote(args.output, f"undistortion map of {camera} at {capture.label(z)}, {umap.valid.mean():.1%} of the "
                       "output image covered")
    return 0

