"""`stereodic speckle IMAGE [--subset N] [--target PX] -o DIR`: how good a speckle is for DIC, before the test.

Prints and writes DIR/speckle.json (image noise, mean intensity gradient, the predicted random error of
a subset's displacement for each subset size, the smallest subset reaching the target), DIR/speckle.png
(the map of the predicted error at --subset, and the error against the subset size) and
DIR/noise_map.npz (the maps: predicted error and SSSIG at --subset) (stereodic.dic.speckle_quality).
"""

from __future__ import annotations


def register(sub):
    p = sub.add_parser("speckle", help="speckle quality: noise, MIG, SSSIG, predicted displacement noise",
                       description="Before the test: the image noise, mean intensity gradient, SSSIG per subset "
                                   "and the predicted displacement noise for each subset size of a speckle image.")
    p.add_argument("image", metavar="IMAGE", help="an image of the speckled specimen (8/16-bit PNG or TIFF)")
    p.add_argument("--subset", type=int, default=21, help="subset size of the maps, odd (default 21)")
    p.add_argument("--target", type=float, default=0.01, metavar="PX",
                   help="target random error: the smallest subset whose median prediction reaches it (default "
                        "0.01 px)")
    p.add_argument("--static", metavar="IMAGE2", help="a second image of the same static scene: the noise is "
                                                      "measured from the two (default: estimated from IMAGE)")
    p.add_argument("--roi", metavar="X0,Y0,X1,Y1", help="subset centres inside this region only")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output folder")
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from calib.atomic import write_json, write_npz
    from calib.errors import InputError
    from calib.imageio import read_gray
    from stereodic.cli.common import output_folder, parse_roi
    from stereodic.dic.speckle_quality import plot, speckle_quality

    img = read_gray(args.image)
    h, w = img.shape
    if args.subset < 5 or args.subset % 2 == 0 or args.subset > min(w, h):
        raise InputError("--subset", f"must be an odd number >= 5 that fits the {w}x{h} image, got {args.subset}")
    if not args.target > 0:
        raise InputError("--target", f"must be > 0 px, got {args.target}")
    second = None
    if args.static:
        second = read_gray(args.static)
        if second.shape != img.shape:
            raise InputError(args.static, f"image is {second.shape[1]}x{second.shape[0]} but {args.image} is {w}x{h}")
    roi = parse_roi(args.roi, w, h, "image")
    out = output_folder(args.output)
    q = speckle_quality(img, subset=args.subset, target_px=args.target, roi=roi, second=second)
    at = int(np.flatnonzero(q.sizes == args.subset)[0]) if args.subset in q.sizes else None
    record = {"image": str(args.image), "noise_grey": q.sigma, "noise_from": q.sigma_source, "mig_grey_per_px": q.mig,
              "subset_px": [int(s) for s in q.sizes], "predicted_noise_median_px": q.median_px.tolist(),
              "predicted_noise_p95_px": q.p95_px.tolist(), "target_px": q.target_px,
              "smallest_subset_px": q.smallest, "roi": list(roi) if roi else None}
    write_json(out / "speckle.json", record)
    write_npz(out / "noise_map.npz", noise_px=q.noise_map.astype(np.float32), sssig=q.sssig_map.astype(np.float32),
              subset=np.array(args.subset))
    plot(q, out / "speckle.png")
    print(f"{args.image}: noise {q.sigma:.2f} grey levels ({q.sigma_source}), mean intensity gradient {q.mig:.2f} "
          f"grey/px")
    median_here = float(np.nanmedian(q.noise_map))
    print(f"subset {args.subset} px: median SSSIG {np.nanmedian(q.sssig_map):.4g} grey^2, predicted random error "
          f"median {median_here:.4f} px" + (f", p95 {q.p95_px[at]:.4f} px" if at is not None else ""))
    if q.smallest is None:
        print(f"no subset up to {int(q.sizes[-1])} px reaches {q.target_px:g} px (median {q.median_px[-1]:.4f} px)")
    else:
        print(f"smallest subset reaching {q.target_px:g} px (median): {q.smallest} px")
    return 0
