"""`stereodic scan RIG.npz DATASET... -o CLOUD.ply|DIR`: structured-light scan to a point cloud (stereodic.scan.pipeline).

DATASET is a capture of kind "scan" (fringes projected along the projector's columns, several periods
and steps, or Gray code alone or with one fringe period; a top-level `projector` block with the panel's
width_px), or, with --projector WxH, a folder of images in OpenCV's GrayCodePattern order without a
capture.json (two numbered series, the left camera's first in natural order); RIG.npz is the rectified pair of
the two cameras (`stereodic rig`). Each state of the dataset is one scan: the absolute projector phase of
both cameras is mapped into the rectified virtual images, matched along rows, triangulated with the
EVM-corrected rays, cleaned of statistical outliers and written as a binary float32 PLY with normals and
the per-point scalars `quality` (fringe modulation, fraction of full scale) and `gap_mm` (ray gap).
A dataset with several states gives one file per state, CLOUD_s<state>.ply; with --merge its states are
views of one object taken round it in order (a turntable): registered view to view, the loop closed by a
pose graph (with --turntable, then as turns about one fitted axis), merged into the one cloud CLOUD.ply
(and --mesh MESH.ply, its Poisson surface), each view's rotation, residual and overlap printed (and the
fitted axis). Several datasets (or a
quoted pattern naming them) are a batch into the folder -o DIR: DIR/<dataset folder name>.ply (or
_s<state>.ply per state). A batch of several scans records each one done (CLOUD.batch.json, or
DIR/scan.batch.json: calib.batch), so that the same command after a stop does only the rest; with
--scheduler each scan is a task on a Dask cluster (stereodic.cluster.batch). See docs/scanner.md and
docs/cluster.md.
"""

from __future__ import annotations

import argparse

from stereodic.cli.common import (add_input, add_output, add_scheduler_option, deprecated, parse_floats,
                                  parse_size, wrote)

RECORD = "scan.batch.json"


def _pair(text: str) -> tuple[str, str]:
    names = [t.strip() for t in text.split(",")]
    if len(names) != 2 or not all(names):
        raise argparse.ArgumentTypeError(f"expected LEFT,RIGHT camera names, got {text!r}")
    return names[0], names[1]


def register(sub):
    p = sub.add_parser("scan", help="structured-light scan to a point cloud",
                       description=__doc__)
    add_input(p, "rig", what="rig", metavar="RIG.npz", help="the rectified stereo rig (stereodic rig)")
    add_input(p, "dataset", kind="dataset", metavar="DATASET", nargs="+",
              help="scan dataset folder or its capture.json; several, or a quoted shell-style pattern, for a batch")
    add_output(p, kind="any", metavar="CLOUD.ply|DIR",
               help="output point cloud (CLOUD_s<state>.ply per state if several); a folder for several datasets")
    p.add_argument("--state", type=int, action="append", metavar="N",
                   help="scan only this state (repeatable; default all)")
    p.add_argument("--camera", type=_pair, metavar="LEFT,RIGHT",
                   help="dataset camera names of the rig's left and right camera (default: the rig's names)")
    deprecated(p, "--cameras", "--camera")
    add_output(p, "--mesh", kind="any", metavar="MESH.ply|DIR",
               help="also write a Poisson surface mesh (named like the clouds; a folder for several datasets)")
    p.add_argument("--merge", action="store_true",
                   help="the dataset's states are views of one object taken round it in order (a turntable): "
                        "register them (loop closed), write one merged cloud and, with --mesh, its surface")
    p.add_argument("--turntable", type=parse_floats, metavar="X,Y,Z,DX,DY,DZ",
                   help="with --merge: the views are a whole turn of a turntable in equal steps (360/views "
                        "degrees, right-handed about the direction) about this axis (a point and a direction in "
                        "the rig's WCS, mm): the nominal turn starts the registration instead of a global search, and "
                        "the views are registered as turns about one fitted axis (printed)")
    p.add_argument("--projector", type=parse_size, metavar="WxH",
                   help="a DATASET folder without capture.json holds OpenCV's GrayCodePattern sequence for a "
                        "projector of this size, read as it is")
    p.add_argument("--no-evm", action="store_true",
                   help="triangulate with the pinhole rays (no EVM correction), for comparison")
    p.add_argument("--smooth", type=float, default=None, metavar="PX",
                   help="phase filter sigma in virtual pixels before matching (default 3; 0: none)")
    p.add_argument("--outlier-neighbours", type=int, default=20,
                   help="statistical outlier removal: neighbours (default 20; 0 disables)")
    p.add_argument("--outlier-std", type=float, default=3.0,
                   help="statistical outlier removal: std ratio (default 3)")
    add_scheduler_option(p, "scans (each one a task)")
    p.set_defaults(func=run)


def _batch_folder(path, option: str):
    """`path` as the folder of a batch's outputs, created; InputError naming `option` if it is a file."""
    from pathlib import Path

    from calib.errors import InputError
    if Path(path).is_file() or Path(path).suffix.lower() == ".ply":
        raise InputError(path, f"several datasets make several clouds: {option} must name a folder")
    Path(path).mkdir(parents=True, exist_ok=True)        # writable: checked before the work (check_paths)
    return Path(path)


def _jobs(args, rig, datasets):
    """The scans: per dataset its states (`plan_scans`), named as the module docstring says."""

    from calib.errors import InputError
    from stereodic.scan.pipeline import plan_scans
    if len(datasets) == 1:
        from stereodic.cli.common import check_file_output
        check_file_output(args.output, "-o/--output")
        if args.mesh is not None:
            check_file_output(args.mesh, "--mesh")
        return plan_scans(rig, datasets[0], args.output, args.state, args.camera, args.mesh, args.projector)
    out = _batch_folder(args.output, "-o/--output")
    mesh = None if args.mesh is None else _batch_folder(args.mesh, "--mesh")
    jobs, seen = [], {}
    for ds in datasets:
        name = (ds.parent if ds.name == "capture.json" else ds).resolve().name
        if name in seen:
            raise InputError(ds, f"has the folder name of {seen[name]}: their clouds would have the same name")
        seen[name] = ds
        jobs += plan_scans(rig, ds, out / f"{name}.ply", args.state, args.camera,
                           None if mesh is None else mesh / f"{name}.ply", args.projector)
    return jobs


def _inputs(job, cameras) -> dict:
    """The files a scan reads, fingerprinted (calib.batch)."""
    from calib.batch import file_sha256, fingerprint
    from stereodic.scan.pipeline import load_scan
    cap = load_scan(job.dataset, projector=job.projector, cameras=cameras)
    frames = [f for cam in cameras for f in cap.select(cam, state=job.state)]
    manifest = file_sha256(cap.manifest_path) if cap.manifest_path.is_file() else f"opencv {job.projector}"
    return {"capture": manifest, "frames": [fingerprint(cap.path(f)) for f in frames]}


def _merge(args, rig, datasets) -> int:
    """--merge: the states of one dataset registered and merged (stereodic.scan.pipeline.merge_to_files)."""
    import numpy as np

    from calib.errors import InputError
    from stereodic.cli.common import check_file_output
    from stereodic.scan.pipeline import SMOOTH_PX, merge_to_files
    if len(datasets) != 1:
        raise InputError("--merge", f"merges the states of one dataset, got {len(datasets)} datasets")
    if args.scheduler is not None:
        raise InputError("--merge", "runs in this process: drop --scheduler")
    axis = args.turntable
    if axis is not None and (len(axis) != 6 or not np.all(np.isfinite(axis)) or not np.any(axis[3:])):
        raise InputError("--turntable", f"need a point and a non-zero direction X,Y,Z,DX,DY,DZ (mm), got {axis}")
    check_file_output(args.output, "-o/--output")
    if args.mesh is not None:
        check_file_output(args.mesh, "--mesh")
    written, states, reg = merge_to_files(
        rig, datasets[0], args.output, states=args.state, cameras=args.camera, mesh=args.mesh,
        projector=args.projector, corrected=not args.no_evm, neighbours=args.outlier_neighbours,
        std_ratio=args.outlier_std, smooth_px=SMOOTH_PX if args.smooth is None else args.smooth,
        turntable=None if axis is None else (axis[:3], axis[3:]))
    if axis is None:
        from scipy.spatial.transform import Rotation
        turn = Rotation.from_matrix(reg.transforms[:, :3, :3]).inv().as_rotvec()      # view 0 -> view k
        ahead = turn[1] / max(np.linalg.norm(turn[1]), 1e-12)
        angles = np.degrees(np.linalg.norm(turn, axis=1)) * np.where(turn @ ahead >= 0, 1, -1) % 360
    else:
        table = reg.turntable
        nominal = np.asarray(axis[3:]) / np.linalg.norm(axis[3:])
        across = table.point_mm - axis[:3] - nominal * (nominal @ (table.point_mm - axis[:3]))
        print(f"turntable axis: through ({', '.join(f'{v:.3f}' for v in table.point_mm)}) mm, "
              f"direction ({', '.join(f'{v:.5f}' for v in table.direction)}); "
              f"{np.degrees(np.arccos(np.clip(table.direction @ nominal, -1, 1))):.3f} deg and "
              f"{np.linalg.norm(across):.3f} mm from the nominal")
        angles = table.angles_deg
    for k, state in enumerate(states):
        step = "" if k == 0 else f" (step {(angles[k] - angles[k - 1]) % 360:.3f} deg)"
        print(f"view {k} (state {state}): turned {angles[k]:.3f} deg from view 0{step}, residual "
              f"{1000 * reg.residual_mm[k]:.1f} um, {100 * reg.fitness[k]:.0f} % of its points overlap the others")
    for path, count, what in written:
        wrote(path, f"{count} {what}")
    return 0


def scan_task(rig_path: str, rig_sha256: str, job, options: dict):
    """One scan where it runs (in this process or on a worker: the rig loaded once per process)."""
    from stereodic.cluster.batch import Done
    from stereodic.cluster import per_worker
    from stereodic.stereo.rig import load_rig
    from stereodic.scan.pipeline import scan_job
    rig = per_worker(f"rig:{rig_path}:{rig_sha256}", lambda: load_rig(rig_path))
    return Done([(path, f"{count} {what}") for path, count, what in scan_job(rig, job, **options)])


def run(args) -> int:
    import dataclasses
    import os
    from pathlib import Path

    from calib import __version__
    from calib.batch import BatchRecord, file_sha256
    from calib.errors import InputError
    from calib.image_files import expand_datasets
    from stereodic.cluster.batch import Task, run_batch
    from stereodic.stereo.rig import load_rig
    from stereodic.scan.pipeline import SMOOTH_PX
    rig = load_rig(args.rig)
    datasets = [d for v in args.dataset for d in expand_datasets(v)]
    if args.merge:
        return _merge(args, rig, datasets)
    if args.turntable is not None:
        raise InputError("--turntable", "goes with --merge")
    jobs = _jobs(args, rig, datasets)
    cameras = args.camera or (rig.left.name, rig.right.name)
    options = {"cameras": cameras, "corrected": not args.no_evm, "neighbours": args.outlier_neighbours,
               "std_ratio": args.outlier_std, "smooth_px": SMOOTH_PX if args.smooth is None else args.smooth}
    rig_sha = file_sha256(args.rig)
    record = None
    if len(jobs) > 1:
        out = Path(args.output)
        path = out / RECORD if len(datasets) > 1 else out.with_name(f"{out.stem}.batch.json")
        record = BatchRecord(path, {"software": __version__, "rig": rig_sha, "mesh": args.mesh is not None,
                                    **options})
    given = {}                                  # absolute paths for the workers, the user's in the `wrote` lines
    for j in jobs:
        given.update({os.path.abspath(p): p for p in (j.cloud, j.mesh) if p is not None})
    absolute = lambda p: None if p is None else Path(os.path.abspath(p))  # noqa: E731
    tasks = [Task(f"{os.path.abspath(j.dataset)}#state{j.state}", _inputs(j, cameras) if record else {},
                  (os.path.abspath(args.rig), rig_sha,
                   dataclasses.replace(j, dataset=os.path.abspath(j.dataset), cloud=absolute(j.cloud),
                                       mesh=absolute(j.mesh)), options)) for j in jobs]
    count = 0
    for _, done in run_batch(scan_task, tasks, record, scheduler=args.scheduler, desc="scanning", unit="scan"):
        count += 1
        for path, summary in done.outputs:
            wrote(given.get(os.fspath(path), path), summary)
    if count < len(tasks):
        print(f"{record.path}: {len(tasks) - count} of {len(tasks)} scans were done already with these settings "
              f"and inputs (their files are kept)")
    return 0
