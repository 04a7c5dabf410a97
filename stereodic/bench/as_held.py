"""Benchmark rows of `stereodic bench calib` for issue 29: a stage-free calibration with the display held
as people hold a monitor (`scanners.sim.handheld.as_held`: 7 poses about 420 mm away, 45 mm nearer to
25 mm farther, tipped 4-15 degrees about its x or y axis; the lens focused at 420 mm; a 0.5 mm cover
glass; 90 % pixel fill; gamma 2.2), against a staged calibration of the same lens, display and glass
with as many fringe frames (7 positions evenly over the same depth).

Ray errors are in camera pixels of the working plane, RMS over 8 planes across the poses' depth range
(where the central pixel's ray met the nearest and the farthest display), in the simulator's frame
(each estimate moved there by the true pose of its WCS display, `stereodic.bench.poses`). Two captures
of the same poses with other sensor noise are calibrated: the total is the RMS over both, the random
part the RMS difference between them over sqrt 2, the systematic part what is left, sqrt(total^2 -
random^2) (`error_parts`). The uncertainty ratios: the RMS
over the poses (and axes) of each pose's error over its reported 1-sigma, and over the pixels of each
ray's error on the first uncertainty plane over its reported 1-sigma there; each pooled (RMS) over the
two captures. A 1-sigma is a statement about the spread of the errors over noise draws, and one
capture's ray errors are mostly a few numbers: the poses' errors, carried into every ray (a pose's
error moves all its points together). One capture's ratio is therefore itself a random number (on
the non-central lens at 640 x 512, over six captures with other sensor noise: 2.47, 0.88, 1.17, 1.05,
1.58, 0.83; the first capture's pose errors are 7.1 for 6 x 6 numbers in Mahalanobis distance,
chi^2 50.6 for 36, p = 0.054; docs/calibration.md).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from stereodic.bench import Figure

HELD_LENSES = ("noncentral", "brown", "freeform")
PLANES = 8


def depth_range(truth, pitch_mm) -> tuple[float, float]:
    """(nearest, farthest) simulator-frame z (mm) where the central pixel's true ray meets the display at
    the hand-held truth's poses."""
    h, w = truth.valid.shape
    cr = truth.extra["display_cr"][:, h // 2, w // 2].astype(np.float64)
    q = np.column_stack([cr * np.asarray(pitch_mm), np.zeros(len(cr))])
    wcs = np.einsum("kij,kj->ki", truth.extra["display_rotation"], q) + truth.extra["display_translation_mm"]
    z = wcs @ truth.extra["sim_rotation"][2] + truth.extra["sim_translation_mm"][2]
    return float(z.min()), float(z.max())


def _volume(prvm, truth, planes, footprint: float) -> np.ndarray:
    """(planes, H, W) distances (camera px of `footprint` mm) between the rays of `prvm` and `truth` on
    each plane; NaN where `prvm` is not valid."""
    from calib.evaluate import ray_error_px
    return np.stack([ray_error_px(prvm, truth, z_mm=z, footprint=footprint) for z in planes])


def _sim_frame(cal, truth):
    """The calibration's rays and the hand-held truth, both in the simulator's frame."""
    r, t = truth.extra["sim_rotation"], truth.extra["sim_translation_mm"]
    return cal.prvm.transformed(r, t), truth.transformed(r, t)


def pose_sigma_ratio(cal, truth) -> float:
    """RMS over the poses used but pose 0 (the WCS) and the axes of each pose's error (the translation of
    the seen area's centre and the rotation vector) over its reported 1-sigma."""
    from calib.poses import log_so3
    rep = cal.poses
    rt, tt = truth.extra["display_rotation"], truth.extra["display_translation_mm"]
    z = []
    for k in np.flatnonzero(rep.used)[1:]:
        c = rep.centre_mm[k]
        q = rep.rotation[k].T @ (c - rep.translation[k])
        z.append(1000 * (c - (rt[k] @ q + tt[k])) / rep.sd_translation_um[k])
        z.append(np.degrees(log_so3(rep.rotation[k] @ rt[k].T)) / rep.sd_rotation_deg[k])
    return float(np.sqrt(np.mean(np.square(z))))


def ray_sigma_ratio(cal, truth) -> float:
    """RMS over the valid pixels of each ray's error on the first uncertainty plane (WCS) per axis (the
    distance over sqrt 2) over its reported 1-sigma there."""
    z = cal.prvm.meta["uncertainty_z_mm"][0]
    sigma = cal.prvm.extra["uncertainty_mm"][..., 0].astype(np.float64)
    d = np.linalg.norm(cal.prvm.at_z(z) - truth.at_z(z), axis=-1) / np.sqrt(2)
    ok = cal.prvm.valid & (sigma > 0)
    return float(np.sqrt(np.mean((d[ok] / sigma[ok]) ** 2)))


def held_accuracy(lens: str, width: int, height: int, root: Path, seed: int = 0) -> dict:
    """Simulate the as-held capture of `lens` (twice, the second with other sensor noise) and the staged
    one, calibrate them, and measure (module docstring): {"total", "random", "systematic", "staged" (px),
    "pose_ratio", "ray_ratio" (pooled over the two captures), "pose_ratios", "ray_ratios" (each
    capture's), "planes" (mm), "notes" (the first capture's)}."""
    from calib.calibration import calibrate_camera
    from calib.capture import load_capture
    from calib.evaluate import footprint_mm
    from calib.prvm_file import load_prvm
    from scanners.sim.calibration import simulate_calibration
    from scanners.sim.handheld import as_held
    from stereodic.bench.poses import _field
    field = _field(width)
    options = as_held(**field["lens_options"])
    common = dict(lens=lens, width=width, height=height, seed=seed, supersample=field["supersample"])
    cals = []
    for sensor in (seed, seed + 1):
        out = root / f"held_{lens}_{sensor}"
        simulate_calibration(out, sensor_seed=sensor, **common, **options)
        cals.append(calibrate_camera(load_capture(out)))
    truth = load_prvm(root / f"held_{lens}_{seed}" / "truth.npz")
    planes = np.linspace(*depth_range(truth, load_capture(root / f"held_{lens}_{seed}").display.pitch_mm), PLANES)
    est, sim_truth = _sim_frame(cals[0], truth)
    again, _ = _sim_frame(cals[1], truth)
    fp = footprint_mm(sim_truth, float(np.mean(planes)))
    total, random, systematic = error_parts(_volume(est, sim_truth, planes, fp), _volume(again, sim_truth, planes, fp),
                                            _volume(est, again, planes, fp))
    staged_out = root / f"held_staged_{lens}"
    staged = {k: v for k, v in options.items() if k != "handheld"}
    positions = list(np.linspace(planes[0], planes[-1], len(truth.extra["display_cr"])))
    simulate_calibration(staged_out, z_positions=positions, **common, **staged)
    st_truth = load_prvm(staged_out / "truth.npz")
    st_cal = calibrate_camera(load_capture(staged_out))
    # the staged WCS: the first position's display, at its nominal z (X_sim = R (X - z0 e_z) + t)
    r, t = st_truth.extra["display_rotation"][0], st_truth.extra["display_translation_mm"][0]
    z0 = st_truth.extra["stage_nominal_z_mm"][0]
    staged_total = float(np.sqrt(np.nanmean(_volume(st_cal.prvm.transformed(r, t - r[:, 2] * z0), st_truth,
                                                    planes, fp) ** 2)))
    pose, ray = ([pose_sigma_ratio(c, truth) for c in cals], [ray_sigma_ratio(c, truth) for c in cals])
    return {"total": total, "random": random, "systematic": systematic,
            "staged": staged_total, "pose_ratio": _pooled(pose), "ray_ratio": _pooled(ray),
            "pose_ratios": pose, "ray_ratios": ray, "planes": planes, "notes": cals[0].notes}


def error_parts(first: np.ndarray, second: np.ndarray, between: np.ndarray) -> tuple[float, float, float]:
    """(total, random, systematic) ray error (px) from two captures of the same poses with other sensor
    noise: `first` and `second` each capture's distances to the truth, `between` the distances between
    their rays (arrays of one shape, NaN where a ray is not valid). total: the RMS over both captures;
    random: the RMS of `between` over sqrt 2 (the part that differs from one noise draw to the next);
    systematic: sqrt(total^2 - random^2), the part common to both. Pooled over both captures, so that one
    unlucky draw of the poses' errors (module docstring) counts as much as the other."""
    total = float(np.sqrt(np.nanmean(np.concatenate([np.ravel(first), np.ravel(second)]) ** 2)))
    random = float(np.sqrt(np.nanmean(np.square(between)) / 2))
    return total, random, float(np.sqrt(max(total ** 2 - random ** 2, 0.0)))


def _pooled(ratios: list[float]) -> float:
    """The RMS of per-capture ratios (each an RMS of errors over 1-sigma): the ratio over the captures'
    errors together (as many terms in each)."""
    return float(np.sqrt(np.mean(np.square(ratios))))



def run(quick: bool = False) -> list[Figure]:
    """The rows (module docstring): the non-central lens at 320 x 256 (--quick), or the three lenses of
    `HELD_LENSES` at 640 x 512 (the size of the independently rendered as-held capture of issue 29)."""
    width, height = (320, 256) if quick else (640, 512)
    figs: list[Figure] = []
    with tempfile.TemporaryDirectory(prefix="bench_held_") as tmp:
        for lens in HELD_LENSES[:1] if quick else HELD_LENSES:
            r = held_accuracy(lens, width, height, Path(tmp))
            g = f"calib/as-held/{lens}"
            ratio = r["total"] / r["staged"]
            figs.append(Figure(g, f"ray error RMS over the poses' depth range, 7 poses as held, {ratio:.2f}x staged",
                               r["total"], "px", "staged, 7 positions over that depth, same glass and blur",
                               r["staged"], "<= 2x staged", ratio <= 2))
            figs.append(Figure(g, f"systematic part of that error (random part {r['random']:.4f} px, two captures)",
                               r["systematic"], "px", "the whole error", r["total"], "<= half",
                               r["systematic"] <= r["total"] / 2))
            for what in ("pose", "ray"):
                v, each = r[f"{what}_ratio"], r[f"{what}_ratios"]
                figs.append(Figure(g, f"{what} error over its reported 1-sigma (RMS over two captures; each "
                                      f"{', '.join(f'{x:.2f}' for x in each)})", v, "", goal="0.5-2",
                                   ok=0.5 <= v <= 2))
    return figs
