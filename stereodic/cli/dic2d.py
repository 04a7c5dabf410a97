"""`stereodic dic2d`: 2D subset digital image correlation of one or more deformed images.

Deformed images are files or shell-style patterns (quoted, expanded by the program in natural order).
Writes one CSV row per point and deformed image: image (0-based index among the deformed images), x, y
(the point in the reference image, pixels), u, v (displacement, pixels, u along x), zncc, converged
(1/0), status (ok, no_texture, outside, diverged, low_zncc, unreached, inconsistent, low_texture),
iterations, noise_px and, with --strain-window, the strain measure's exx, eyy, exy, principal strains,
von Mises equivalent and strain_valid (stereodic.dic.output); or, with --columns dice, DICe's solution
files OUT_<k>.csv. u, v are NaN exactly where converged is 0; strains are NaN exactly where
strain_valid is 0. Results are written image by image: memory holds one image's results at a time.
"""

from __future__ import annotations

from stereodic.cli.common import (add_grid_options, add_input, add_output, add_prefilter_option, add_scheduler_option,
                                  add_search_option, check_prefilter, search_settings)


def register(sub):
    from stereodic.cli.common import STRAIN_MEASURES as MEASURES, SWITCH_ZNCC
    p = sub.add_parser("dic2d", help="2D subset digital image correlation",
                       description="2D subset DIC: displacements (and strains) of deformed images against a "
                                   "reference, on a grid of points.")
    add_input(p, "ref", what="image", metavar="REF_IMG", help="reference image (8/16-bit PNG or TIFF)")
    add_input(p, "defs", kind="pattern", what="image", metavar="DEF_IMG_OR_PATTERN", nargs="+",
              help="deformed images in order, or shell-style patterns (quote them; natural order), or a video, "
                   "TIFF stack, .cine or .mraw (every frame; FILE::K is frame K, also as REF_IMG)")
    add_output(p, metavar="OUT.csv", help="CSV of the results")
    add_grid_options(p, "reference image")
    p.add_argument("--shape", choices=["affine", "quadratic"], default="affine",
                   help="subset shape function (default affine)")
    p.add_argument("--interp", choices=["cubic", "quintic"], default="cubic",
                   help="B-spline interpolation (default cubic)")
    add_prefilter_option(p)
    add_search_option(p, "seeds' integer displacement")
    p.add_argument("--min-zncc", type=float, default=0.8, help="points below are flagged (default 0.8)")
    p.add_argument("--switch-zncc", type=float, default=SWITCH_ZNCC, metavar="ZNCC",
                   help=f"a point whose ZNCC against the reference falls below this switches to incremental "
                        f"correlation, displacements still from the reference (default {SWITCH_ZNCC}; 0 = never)")
    p.add_argument("--incremental", action="store_true",
                   help="register each image against the previous one for every point (large deformations)")
    p.add_argument("--strain-window", type=int, metavar="N",
                   help="add strains fitted over N x N grid points, odd; 0 = none (default: none)")
    p.add_argument("--measure", choices=MEASURES, default="green-lagrange", metavar="MEASURE",
                   help=f"strain measure: {', '.join(MEASURES)} (default green-lagrange)")
    p.add_argument("--columns", choices=["stereodic", "dice"], default="stereodic",
                   help="dice: DICe's solution files OUT_<k>.csv (its column names and layout) instead of OUT.csv")
    add_output(p, "--npz", metavar="OUT.npz", help="also write the fields as arrays (n_images, ny, nx)")
    add_output(p, "--mat", metavar="OUT.mat", help="also write the NPZ's arrays as a MATLAB file")
    add_output(p, "--plot", kind="dir", metavar="DIR", help="write PNG maps of u, v, zncc (and strains) per image")
    add_scheduler_option(p, "deformed images (a chain: one image after the other)")
    p.set_defaults(func=run)


def _check_args(args) -> None:
    """The options beyond the grid's (stereodic.cli.common.dic_grid checks those)."""
    from calib.errors import InputError
    if args.strain_window and (args.strain_window < 3 or args.strain_window % 2 == 0):
        raise InputError("--strain-window", f"must be 0 or an odd number >= 3, got {args.strain_window}")
    for name, value in (("--min-zncc", args.min_zncc), ("--switch-zncc", args.switch_zncc)):
        if not 0 <= value <= 1:
            raise InputError(name, f"must be between 0 and 1, got {value}")
    search_settings(args)
    check_prefilter(args)


PRELOAD_BYTES = 64 * 2 ** 20  # deformed images read before the work, at most this much memory


def read_checked(path, shape: tuple[int, int], reference: str, image=None):
    """A deformed image (`image`, if it was read already); InputError naming it unless it has the
    reference's `shape` (rows, columns)."""
    from calib.errors import InputError
    from calib.imageio import read_gray
    img = read_gray(path) if image is None else image
    if img.shape != shape:
        raise InputError(path, f"image is {img.shape[1]}x{img.shape[0]} but the reference {reference} is "
                               f"{shape[1]}x{shape[0]}")
    return img


def run(args) -> int:
    import contextlib
    import functools
    import itertools
    import tempfile
    from concurrent.futures import ThreadPoolExecutor
    from pathlib import Path

    import numpy as np

    from calib.atomic import write_npz as save_npz
    from calib.image_files import expand
    from calib.imageio import check_size, read_gray
    from calib.numbers import fixed
    from calib.progress import note, progress
    from calib.sequences import frame_times
    from stereodic.cli.common import dic_grid, memory_reuse, wrote
    memory_reuse()
    from stereodic.dic import STATUS_NAMES, BSplineImage, DicSettings, ImageRef, correlate_sequence
    from stereodic.dic.background import side_by_side
    from stereodic.dic.output import CsvWriter, image_arrays, image_maps, plot_image, write_npz
    from stereodic.dic3d.diagnose import diagnosis
    if args.strain_window:  # strain (and its scipy) only when asked for
        from stereodic.strain.fit import strain_2d
        from stereodic.strain.measures import measure_strain
    if args.plot:  # the maps' module only when they are asked for
        from stereodic.dic.maps import MapPainter, RunScales, pixel_axes
    if args.columns == "dice":
        from stereodic.formats.dice_columns import gauge_px, header, numbered, sigma_gamma, strain_columns, write_solution

    _check_args(args)
    with ThreadPoolExecutor(1) as pool:   # the first deformed image read while the reference is
        first = None if args.scheduler else pool.submit(lambda: read_gray(expand(args.defs[0])[0]))
        ref = read_gray(args.ref)
        height, width = ref.shape
        defs = [p for pattern in args.defs for p in expand(pattern)]
        read = functools.partial(read_checked, shape=ref.shape, reference=str(args.ref))
        # every file checked before the (long) work starts: in-process, the first images are read whole
        # while they fit in PRELOAD_BYTES (reading is their check: a single pair needs no header reader),
        # the others by their headers
        preloaded = [] if args.scheduler else [read(p, image=first.result() if k == 0 else None)
                                               for k, p in enumerate(defs[:PRELOAD_BYTES // ref.nbytes])]
    for path in defs[len(preloaded):]:
        check_size(path, (width, height), f"the reference {args.ref}")
    settings = DicSettings(subset=args.subset, shape=args.shape, order=3 if args.interp == "cubic" else 5,
                           prefilter_sigma=args.prefilter, min_zncc=args.min_zncc, **search_settings(args))
    # in-process, the reference prepared once: its noise estimate also places the points (specimen_mask)
    reference = None if args.scheduler else ImageRef.prepare(ref, settings, keep_subsets=True)

    def place_points():
        return dic_grid(args, width, height, "reference", args.ref, reference=lambda: ref,
                        noise=None if reference is None else reference.sigma)

    if preloaded:
        # the first image's B-spline and, for the automatic initial guess, its feature matches with the
        # reference (no motion before it: its registration starts from them) made beside the points'
        # placement, and kept for its registration (`stereodic.dic.kept`: the images are read-only from here)
        ref.flags.writeable = preloaded[0].flags.writeable = False
        first = [lambda: BSplineImage.from_image(preloaded[0], order=settings.order,
                                                 prefilter_sigma=settings.prefilter_sigma)]
        if settings.feature_guess:
            first.append(lambda: reference.matches(preloaded[0]))
        (grid, seeds), *_ = side_by_side(place_points, *first)
    else:
        grid, seeds = place_points()
    out = Path(args.output)

    has_strain = bool(args.strain_window)
    act = grid.active.ravel()
    scales = RunScales(floor={c: 100.0 for c in ("exx", "eyy", "exy")}) if args.plot else None
    cluster = contextlib.nullcontext()
    if args.scheduler:
        from stereodic.cluster import connect
        from stereodic.dic.cluster import correlate_sequence_on
        cluster = connect(args.scheduler)
    writer = CsvWriter(out, has_strain) if args.columns == "stereodic" else contextlib.nullcontext()
    with cluster as client, tempfile.TemporaryDirectory(prefix=".dic2d-", dir=out.parent) as tmp, writer as csv:
        if client is None:
            images = itertools.chain(preloaded, (read(p) for p in defs[len(preloaded):]))
            fields = correlate_sequence(ref, images, grid, settings=settings, seeds=seeds,
                                        incremental=args.incremental, switch_zncc=args.switch_zncc,
                                        reference=reference)
        else:
            fields = correlate_sequence_on(client, args.ref, [str(p) for p in defs], read, grid, settings, seeds,
                                           args.incremental, args.switch_zncc)
        for k, f in enumerate(progress(fields, "dic2d", total=len(defs), unit="image")):
            m = None
            if has_strain:
                m = measure_strain(strain_2d(grid.xs, grid.ys, f.u, f.v, window=args.strain_window),
                                   measure=args.measure)
            if csv is not None:
                csv.write(k, f, m)
            else:
                X, Y = grid.points()
                cols = [("SUBSET_ID", np.arange(int(act.sum()))), ("COORDINATE_X", X[act]), ("COORDINATE_Y", Y[act]),
                        ("DISPLACEMENT_X", f.u.ravel()[act]), ("DISPLACEMENT_Y", f.v.ravel()[act])]
                cols += sigma_gamma(f.noise_px.ravel()[act], f.zncc.ravel()[act], f.ok.ravel()[act])
                cols += [(name, a.ravel()[act]) for name, a in strain_columns(m)]
                write_solution(numbered(out.with_suffix(""), k, len(defs), out.suffix or ".txt"),
                               header(args.ref, str(defs[k]), args.subset, args.step, args.shape,
                                      "true" if args.incremental else "false",
                                      gauge_px(args.strain_window, args.step, args.subset)), cols)
            if args.npz or args.mat or args.plot:
                arrays = image_arrays(f, m)
                save_npz(Path(tmp) / f"{k}.npz", **arrays)
                if args.plot:
                    for q, (values, _, _) in image_maps(arrays).items():
                        scales.add(q, values, signed=q != "zncc", active=grid.active)
            n_ok = int(f.ok.sum())
            note(f"image {k} ({defs[k]}): {n_ok}/{int(grid.active.sum())} points converged, "
                 f"mean u {fixed(np.nanmean(f.u) if n_ok else np.nan, 4)} px, "
                 f"mean v {fixed(np.nanmean(f.v) if n_ok else np.nan, 4)} px")
            why = diagnosis(f.ok, np.array(STATUS_NAMES, dtype=object)[f.status], grid.active, label=f"image {k}",
                            reference=False, search_px=args.search)
            if why is not None:
                note(why)
        if args.plot:      # after every image: the maps share the run's colour scale per quantity
            axes, painter = pixel_axes(grid.xs, grid.ys, grid.active), MapPainter()   # for every image's maps
            for k in progress(range(len(defs)), "maps", total=len(defs), unit="image"):
                with np.load(Path(tmp) / f"{k}.npz") as z:
                    if (z["status"] == 0).any():     # none for an image that measured nothing (its diagnosis says why)
                        plot_image(args.plot, k, dict(z), grid, Path(defs[k]).name,
                                   args.measure if has_strain else None, scales=scales, image=read(defs[k]),
                                   axes=axes, painter=painter)
        if args.npz or args.mat:
            def values(key):
                for k in range(len(defs)):
                    with np.load(Path(tmp) / f"{k}.npz") as z:
                        yield z[key]

            npz = args.npz or Path(tmp) / "result.npz"
            write_npz(npz, grid, values, len(defs), has_strain, settings, [str(p) for p in defs],
                      args.measure if has_strain else None, frame_times([args.ref, *defs]),
                      reference=str(args.ref))
            if args.mat:
                from stereodic.dic.matfile import write_mat
                write_mat(npz, args.mat)
    n_points = int(act.sum())
    if args.columns == "dice":
        wrote(out.parent, f"DICe's solution files {out.stem}_<k>{out.suffix or '.txt'} ({n_points} points x "
                          f"{len(defs)} deformed images)")
    else:
        wrote(out, f"{n_points * len(defs)} rows ({n_points} points x {len(defs)} deformed images)")
    if args.npz:
        wrote(args.npz, "the fields as arrays (n_images, ny, nx)")
    if args.mat:
        wrote(args.mat, "the same arrays as a MATLAB file")
    if args.plot:
        wrote(args.plot, f"PNG maps of u, v, zncc{' and strains' if has_strain else ''} per deformed image, one "
                         f"colour scale per quantity, beside their copy over the image")
    return 0
