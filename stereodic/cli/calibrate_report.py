"""What a calibration reports beside its PRVM file, for `calibrate` and its batches (calibrate_batch): the
one-line summary and the report folder (pictures, estimated poses, the measured display response)."""

from __future__ import annotations


def summary(cal) -> str:
    """The `wrote` line's summary of a calibration."""
    import numpy as np
    v = cal.prvm.valid
    unc = cal.prvm.extra["uncertainty_mm"][..., 0][v]
    where = "display poses" if cal.prvm.meta.get("poses") is not None else "stage positions"
    return (f"{cal.prvm.meta['camera']}, {v.shape[1]}x{v.shape[0]}, {v.mean():.1%} of pixels calibrated from "
            f"{len(cal.positions)} {where}; median 1-sigma ray uncertainty {1000 * float(np.median(unc)):.2f} um")


def report(out_dir, cal) -> list:
    """The pictures and the measured display response in `out_dir`; each file written and what it is."""
    from pathlib import Path

    from calib.atomic import write_json
    from stereodic.cli.show import write_report
    paths = write_report(cal.prvm, out_dir)
    poses = {k: cal.prvm.meta[k] for k in ("poses", "stage_poses") if k in cal.prvm.meta}
    if poses:
        path = Path(out_dir) / "poses.json"
        write_json(path, poses)
        paths.append((path, "the display's estimated poses"))
    if cal.intensity is not None:
        path = Path(out_dir) / "display_response.json"
        write_json(path, cal.intensity.response.to_json())
        paths.append((path, "the measured display response (for `stereodic patterns --response`)"))
    return paths
