"""`stereodic calibrate` of several cameras (`--camera` repeated), several datasets (or a quoted pattern
naming them), or on a Dask cluster (`--scheduler`): each camera of each dataset is a task
(`stereodic.cluster.batch`) that reads its dataset where it runs and writes its PRVM file (and its report), by
`calib.calibration.calibrate_camera` as a single calibration does.

Outputs: one camera, -o OUT.npz as a single calibration; several, the folder -o DIR: DIR/<camera>.npz,
or DIR/<dataset folder name>_<camera>.npz when there are several datasets; with --report DIR each
camera's pictures go to DIR/<the same name without .npz>/. A batch of several cameras records each one
done in DIR/calibrate.batch.json (`calib.batch`): the same command after a stop calibrates only the rest.
"""

from __future__ import annotations

RECORD = "calibrate.batch.json"


def is_batch(args) -> bool:
    """Whether the command line asks for more than one camera, or for a cluster."""
    import glob
    return bool(args.scheduler) or len(args.dataset) > 1 or len(args.camera or []) > 1 or any(
        glob.has_magic(str(d)) for d in args.dataset)


def calibrate_task(dataset: str, camera: str, smoother, output: str, report_dir: str | None, refine: bool):
    """One camera where it runs (this process, or a worker reading the dataset from shared storage);
    `refine`: the stage pose refinement (`calibrate_camera`'s)."""
    from calib.calibration import calibrate_camera
    from calib.capture import load_capture
    from stereodic.cluster.batch import Done
    from stereodic.cli.calibrate_report import report, summary
    capture = load_capture(dataset)
    cal = calibrate_camera(capture, camera=camera, smoother=smoother, refine=refine and not capture.posed)
    cal.prvm.save(output)
    outputs = [(output, summary(cal))]
    if report_dir is not None:
        outputs += report(report_dir, cal)
    return Done(outputs, [f"{dataset}, {camera}: {note}" for note in cal.notes])


def _plan(args) -> list[tuple[str, str, str, str | None]]:
    """(dataset, camera, output file, report folder) per camera to calibrate, all absolute paths."""
    import os
    from pathlib import Path

    from calib.calibration import default_camera
    from calib.capture import load_capture
    from calib.errors import InputError
    from calib.image_files import expand_datasets
    from stereodic.cli.common import check_file_output
    datasets = [d for v in args.dataset for d in expand_datasets(v)]
    items = []
    for ds in datasets:
        cap = load_capture(ds)
        cams = [default_camera(cap, c) for c in (args.camera or [None])]
        name = (ds.parent if ds.name == "capture.json" else ds).resolve().name
        items += [(os.path.abspath(ds), cam, f"{name}_{cam}" if len(datasets) > 1 else cam) for cam in cams]
    stems = [stem for _, _, stem in items]
    for stem in stems:
        if stems.count(stem) > 1:
            raise InputError(stem, "two cameras to calibrate would get this output name (datasets of the same "
                                   "folder name?)")
    if len(items) == 1:
        (ds, cam, _), = items
        check_file_output(args.output, "-o/--output")
        return [(ds, cam, os.path.abspath(args.output), args.report and os.path.abspath(args.report))]
    out = Path(args.output)
    if out.is_file() or out.suffix.lower() == ".npz":
        raise InputError(out, "several cameras make several PRVM files: -o/--output must name a folder")
    out.mkdir(parents=True, exist_ok=True)       # writable: checked before the work (check_paths)
    out = out.resolve()
    report = None if args.report is None else Path(args.report).resolve()
    return [(ds, cam, str(out / f"{stem}.npz"), None if report is None else str(report / stem))
            for ds, cam, stem in items]


def _inputs(dataset: str, camera: str) -> dict:
    from calib.batch import file_sha256, fingerprint
    from calib.capture import load_capture
    cap = load_capture(dataset)
    return {"capture": file_sha256(cap.manifest_path), "frames": [fingerprint(cap.path(f)) for f in cap.select(camera)]}


def run(args, smoother) -> int:
    """The batch (module docstring); `smoother` as `stereodic.cli.calibrate` chose it."""
    import sys
    from pathlib import Path

    from calib import __version__
    from calib.batch import BatchRecord
    from calib.errors import InputError
    from stereodic.cluster.batch import Task, run_batch
    from stereodic.cli.common import wrote
    if args.reduced:
        raise InputError("--reduced", "calibrates one camera at a time, in this process (no --scheduler, one "
                                      "--camera, one dataset)")
    plan = _plan(args)
    record = None
    if len(plan) > 1:
        record = BatchRecord(Path(plan[0][2]).parent / RECORD,
                             {"software": __version__, "regularise": not args.no_regularise, "window": args.regularise_window,
                              "report": args.report is not None, "refine_poses": not args.no_refine_poses})
    tasks = [Task(f"{ds}#{cam}", _inputs(ds, cam) if record else {}, (ds, cam, smoother, out, rep, not args.no_refine_poses))
             for ds, cam, out, rep in plan]
    count = 0
    for _, done in run_batch(calibrate_task, tasks, record, scheduler=args.scheduler, desc="calibrating",
                             unit="camera"):
        count += 1
        for note in done.warnings:
            print(f"stereodic calibrate: warning: {note}", file=sys.stderr)
        for path, text in done.outputs:
            wrote(path, text)
    if count < len(tasks):
        print(f"{record.path}: {len(tasks) - count} of {len(tasks)} cameras were done already with these settings "
              f"and inputs (their files are kept)")
    return 0
