"""Calibration without a stage: the display held still in several unknown poses (the seed's tip 2.3,
DESIGN.md's stage-free captures, frames with `pose`).

1. Every pose decoded as on a stage (`calib.sensor.decode_all`: the intensity matrix from the
   flats, which may be at one pose only, then display coordinates per pixel).
2. Starting poses from a central camera fitted to block means of the correspondences
   (`calib.pose_init`), in that camera's frame (its z along the optical axis: the working frame).
3. The poses refined together with a generic ray per pixel (`calib.poses`, variable projection with
   pose 0 fixed). A pose whose residual is out of family (its display moved while its fringes were
   shown) is reported and left out, and the others refined again, as long as `MIN_POSES` remain.
4. Every pixel's ray fitted through its points at the refined poses (`calib.prvm.fit_posed_lines`, in
   the working frame), then regularised and given its uncertainty as on a stage
   (`calib.sensor.regularise_lines`) on two planes z = const of the working frame (across the
   optical axis) spanning where the displays were, and expressed in the WCS: the display's frame at pose
   0 (x along its columns, y along its rows, z away from the camera). Planes across the axis, not
   along pose 0's display (tilted by up to tens of degrees): a tilted plane's points are a perspective
   (rational) function of the pixel, which the regularisation's polynomials follow less well (on the
   bench: the plane error 10-45 % higher). The uncertainty is then given on two planes z = const of
   the WCS (`_wcs_sigma`).

The per-pose report (`PoseReport`, the PRVM's `meta.poses`): each pose in the WCS, its 1-sigma
uncertainty (from the Jacobian and the residual), the RMS distance of its points from the rays, its
out-of-family statistic, and whether it was out of family (and left out).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.capture import MIN_POSES, Capture, CoverGlass
from calib.errors import InputError
from calib.pose_init import central_start
from calib.poses import OUT_OF_FAMILY, PoseFit, PoseSample, log_so3, pose_sample, refine_poses
from calib.positions import dropped_quality, point_weights
from calib.prvm import GLASS_ITERATIONS, Lines, fit_posed_lines, posed_glass_offset
from calib.ray_field import Calibration, coverage_notes, ray_meta, ray_prvm
from calib.sensor import decode_all, regularise_lines

# a calibration whose rays' directions (1-sigma), over this fraction of the distance from the camera,
# move a ray by more than DIRECTION_NOTE_PX camera pixels says so (`_direction_note`)
EXTRAPOLATION = 0.1
DIRECTION_NOTE_PX = 0.002
# the poses' part of the rays' uncertainty is computed on at most this many pixels (`_pose_sigma`)
POSE_SIGMA_PIXELS = 400_000
# the planes of the regularisation (working frame) and of the uncertainty (WCS): these quantiles of the
# z of the displays' points in that frame
PLANE_QUANTILES = (0.05, 0.95)


@dataclass
class PoseReport:
    """The estimated display poses of a stage-free calibration, in the WCS (the display at pose 0).

    poses: the pose numbers; rotation (M, 3, 3), translation (M, 3): X_wcs = R q + t for display-frame
    points q; sd_rotation_deg, sd_translation_um (M, 3): 1-sigma of the rotation vector and of the
    translation of `centre_mm` (M, 3), the centroid of the display area the camera saw; rms_um (M,): RMS
    distance of the pose's points from the rays; chi (M,): how far its points are from one rigid display
    (`calib.poses.PoseFit.chi`); out_of_family (M,) bool: chi above `calib.poses.OUT_OF_FAMILY`; used
    (M,) bool: its points went into the rays (an out-of-family pose is left out, but for pose 0, the
    WCS); start_rms_px: the central starting model's reprojection error.
    """

    poses: list[int]
    rotation: np.ndarray
    translation: np.ndarray
    centre_mm: np.ndarray
    sd_rotation_deg: np.ndarray
    sd_translation_um: np.ndarray
    rms_um: np.ndarray
    chi: np.ndarray
    out_of_family: np.ndarray
    used: np.ndarray
    start_rms_px: float

    def to_json(self) -> list[dict]:
        return [{"pose": int(n), "rotation_deg": np.degrees(log_so3(self.rotation[k])).tolist(),
                 "translation_mm": self.translation[k].tolist(), "centre_mm": self.centre_mm[k].tolist(),
                 "sd_rotation_deg": self.sd_rotation_deg[k].tolist(),
                 "sd_translation_um": self.sd_translation_um[k].tolist(), "rms_um": float(self.rms_um[k]),
                 "chi": float(self.chi[k]), "out_of_family": bool(self.out_of_family[k]),
                 "used": bool(self.used[k])} for k, n in enumerate(self.poses)]


def _refine(sample, start, active: np.ndarray, glass: CoverGlass | None) -> PoseFit:
    """Refine the poses of the `active` ones (pose 0 among them) from the central start; with a cover
    glass, again `GLASS_ITERATIONS` times with each block's points moved to where its ray, refracted by
    the glass of each pose's display, meets the pixel plane (`calib.prvm.posed_glass_offset`, the rays
    those of the previous poses)."""
    idx = np.flatnonzero(active)
    part = sample.subset(idx)
    fit = refine_poses(part, start.rotation[idx], start.translation[idx])
    if glass is None or glass.thickness_mm <= 0:
        return fit
    coords = [p.T[:, None, :] for p in part.points]             # (2, 1, N) display mm
    weights = [w[None, :].astype(np.float32) for w in part.weights]
    for _ in range(GLASS_ITERATIONS):
        lines = fit_posed_lines(coords, weights, fit.rotation, fit.translation, (1.0, 1.0), glass=glass).lines
        shift = posed_glass_offset(lines.slope[0], fit.rotation, glass)
        moved = PoseSample(part.points + shift, part.weights, part.pixels, part.block)
        fit = refine_poses(moved, fit.rotation, fit.translation)
    return fit


def estimate_poses(capture: Capture, camera: str, coords: list[np.ndarray],
                   weights: list[np.ndarray]) -> tuple[PoseFit, np.ndarray, np.ndarray, object]:
    """The refined poses (working frame) of the poses kept, which poses those are ((M,) bool), the
    out-of-family statistic of every pose when it was last refined ((M,)), and the central start.
    InputError naming the manifest when the central model cannot be fitted."""
    w, h = capture.cameras[camera]
    sample = pose_sample(coords, weights, capture.display.pitch_mm)
    try:
        start = central_start(sample.points, sample.weights, sample.pixels, w, h)
    except ValueError as exc:
        raise InputError(capture.manifest_path, f"camera {camera!r}: no starting poses: {exc}") from None
    m = len(coords)
    active = np.ones(m, bool)
    chi = np.zeros(m)
    while True:
        fit = _refine(sample, start, active, capture.display.cover_glass)
        idx = np.flatnonzero(active)
        chi[idx] = fit.chi
        bad = [k for j, k in enumerate(idx) if k != 0 and fit.out_of_family[j]]
        if not bad or active.sum() - 1 < MIN_POSES:
            return fit, active, chi, start
        active[max(bad, key=lambda k: chi[k])] = False


def _frame_z(coord: np.ndarray, pitch: np.ndarray, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """z, in a frame, of display coordinates (2, ...) of a display whose pose there is (rotation,
    translation)."""
    return coord[0] * pitch[0] * rotation[2, 0] + coord[1] * pitch[1] * rotation[2, 1] + translation[2]


def _planes(coords: list[np.ndarray], weights: list[np.ndarray], pitch: np.ndarray, rotation: np.ndarray,
            translation: np.ndarray) -> tuple[float, float]:
    """The planes z = const (`PLANE_QUANTILES` of the displays' points' z, every 16th pixel) of a frame
    in which the displays' poses are (rotation (M, 3, 3), translation (M, 3))."""
    z = np.concatenate([_frame_z(c[:, ::16, ::16], pitch, r, t)[w[::16, ::16] > 0]
                        for c, w, r, t in zip(coords, weights, rotation, translation)])
    z_a, z_b = np.quantile(z, PLANE_QUANTILES)
    return float(z_a), float(z_b)


def _wcs_sigma(lines: Lines, sigma: np.ndarray, to_wcs: tuple[np.ndarray, np.ndarray], working: tuple[float, float],
               wcs: tuple[float, float]) -> np.ndarray:
    """(H, W, 2) float32 1-sigma (mm) on the WCS planes z = wcs[0], wcs[1] of `lines` (in the WCS),
    whose 1-sigma `sigma` (H, W, 2) was estimated on the working frame's planes z = working[0],
    working[1] (`to_wcs`: (A, b), X_wcs = A X_working + b): interpolated along each line between its
    crossings with those planes, the two planes' errors taken as independent."""
    a, b = to_wcs
    normal = a[:, 2]                             # the working planes: normal . X_wcs = z_w + normal . b
    d = np.concatenate([lines.slope, np.ones(lines.slope.shape[:-1] + (1,))], axis=-1)
    p = lines.origin()
    along = d @ normal
    with np.errstate(invalid="ignore", divide="ignore"):
        z_w = [p[..., 2] + (z + normal @ b - p @ normal) / along for z in working]      # WCS z of the crossings
        out = []
        for z in wcs:
            lam = (z - z_w[0]) / (z_w[1] - z_w[0])
            out.append(np.sqrt(((1 - lam) * sigma[..., 0]) ** 2 + (lam * sigma[..., 1]) ** 2))
    return np.stack(out, axis=-1).astype(np.float32)


def _pose_sigma(coords: list[np.ndarray], weights: list[np.ndarray], pitch: np.ndarray, fit: PoseFit, lines: Lines,
                planes: tuple[float, float]) -> np.ndarray:
    """`_pose_sigma_grid` on every s-th pixel each way (s such that at most `POSE_SIGMA_PIXELS` are
    computed; the field is smooth but where a pose stops being seen), repeated over each s x s block."""
    h, w = weights[0].shape
    s = max(1, int(np.ceil(np.sqrt(h * w / POSE_SIGMA_PIXELS))))
    if s == 1:
        return _pose_sigma_grid(coords, weights, pitch, fit, lines, planes)
    sub = Lines(lines.start[::s, ::s], lines.slope[::s, ::s], lines.valid[::s, ::s], lines.residual_mm[::s, ::s],
                lines.used[::s, ::s], lines.z_ref)
    small = _pose_sigma_grid([c[:, ::s, ::s] for c in coords], [wk[::s, ::s] for wk in weights], pitch, fit, sub,
                             planes)
    return np.repeat(np.repeat(small, s, axis=0), s, axis=1)[:h, :w]


def _pose_sigma_grid(coords: list[np.ndarray], weights: list[np.ndarray], pitch: np.ndarray, fit: PoseFit,
                     lines: Lines, planes: tuple[float, float], rows: int = 32) -> np.ndarray:
    """(H, W, 2) float32 1-sigma (mm, RMS over x and y) that the poses' uncertainty (all of them together,
    `PoseFit.joint_covariance`) gives each line's point on the working frame's planes z = planes[0],
    planes[1]: a pose's error (dw, dd) moves its point X by -[X - centre]_x dw + dd, across the line by
    (dx - s_x dz, dy - s_y dz) (s the line's slope), and the line's point on the plane z by that
    times the point's least-squares weight there, w_k / sum w + w_k (z_k - z_mean)(z - z_mean) / Szz."""
    h, w = weights[0].shape
    out = np.zeros((h, w, 2), np.float32)
    rot, trans = fit.rotation, fit.translation
    cov = fit.joint_covariance.reshape(6 * len(rot), 6 * len(rot))
    for r0 in range(0, h, rows):
        sl = slice(r0, min(h, r0 + rows))
        q = np.stack([np.stack([c[0, sl] * pitch[0], c[1, sl] * pitch[1], np.zeros_like(c[0, sl])], axis=-1)
                      for c in coords])                                            # (M, r, W, 3)
        x = np.einsum("kij,k...j->k...i", rot, q) + trans[:, None, None, :]
        wt = np.where(np.isfinite(x).all(axis=-1), np.stack([wk[sl] for wk in weights]), 0.0).astype(np.float64)
        x = np.nan_to_num(x)
        s_w = np.maximum(wt.sum(axis=0), 1e-300)
        z_mean = (wt * x[..., 2]).sum(axis=0) / s_w
        szz = np.maximum((wt * (x[..., 2] - z_mean) ** 2).sum(axis=0), 1e-300)
        slope = np.nan_to_num(lines.slope[sl])
        lever = x - fit.centre[:, None, None, :]
        # across the line per unit pose change: (M, r, W, 2, 6)
        jac = np.zeros(x.shape[:-1] + (2, 6))
        for i in range(2):
            along = np.zeros(slope.shape[:-1] + (3,))                                  # e_i - s_i e_z
            along[..., i], along[..., 2] = 1.0, -slope[..., i]
            jac[..., i, :3] = np.cross(lever, along)                  # d(along . X)/dw = (X - c) x along
            jac[..., i, 3:] = along
        for j, z in enumerate(planes):
            a = wt / s_w + wt * (x[..., 2] - z_mean) * (z - z_mean) / szz
            g = np.moveaxis(a[..., None, None] * jac, 0, -2).reshape(-1, 6 * len(rot))        # (r W 2, 6M)
            var = ((g @ cov) * g).sum(axis=-1).reshape(-1, 2).mean(axis=-1)
            out[sl, :, j] = np.sqrt(np.maximum(var, 0)).reshape(a.shape[1:])
    return out


def _direction_note(camera: str, lines: Lines, sigma: np.ndarray, working: tuple[float, float],
                    fit: PoseFit) -> list[str]:
    """A note when the poses' depth spread and tilts leave the rays' directions uncertain: their median
    1-sigma (from the two working planes' 1-sigma `sigma`, the planes z = working[0], working[1] of the
    working frame, where z is roughly the distance from the camera), times `EXTRAPOLATION` of the
    distance, is more than `DIRECTION_NOTE_PX` camera pixels (the pixel's angle: the median difference
    of neighbouring lines' slopes)."""
    span = working[1] - working[0]
    direction = np.sqrt(sigma[..., 0].astype(np.float64) ** 2 + sigma[..., 1] ** 2) / max(span, 1e-9)
    pairs = lines.valid[:, 1:] & lines.valid[:, :-1]
    angle = np.nanmedian(np.linalg.norm(np.diff(lines.slope, axis=1), axis=-1)[pairs])
    px = EXTRAPOLATION * float(np.nanmedian(direction[lines.valid])) / angle
    if not px > DIRECTION_NOTE_PX:
        return []
    normals = fit.rotation[:, :, 2]
    tilt = np.degrees(np.arccos(np.clip(normals @ normals.mean(axis=0) / np.linalg.norm(normals.mean(axis=0)), -1, 1)))
    depth = np.ptp(fit.centre[:, 2])
    mid = float(np.mean(working))
    return [f"camera {camera!r}: the poses span only {depth:.0f} mm in depth and are tilted at most {tilt.max():.1f} "
            f"degrees from their mean: the rays' directions are uncertain by {px:.3f} camera px at "
            f"{EXTRAPOLATION:.0%} of the distance beyond them (1-sigma); add poses about {0.15 * mid:.0f} mm "
            f"nearer and farther than {mid:.0f} mm, and tilted 15-30 degrees about the display's x and y axes"]


def _report(poses: list[int], fit: PoseFit, active: np.ndarray, chi: np.ndarray, start_rms_px: float,
            rms_mm: np.ndarray) -> PoseReport:
    """The poses kept, in the WCS (the working frame's pose 0 undone; their covariance rotated alike);
    NaN for those left out."""
    m = len(poses)
    r0, t0 = fit.rotation[0], fit.translation[0]
    rot, trans, centre = np.full((m, 3, 3), np.nan), np.full((m, 3), np.nan), np.full((m, 3), np.nan)
    sd_rot, sd_t, rms = np.full((m, 3), np.nan), np.full((m, 3), np.nan), np.full(m, np.nan)
    turn = np.kron(np.eye(2), r0.T)
    for j, k in enumerate(np.flatnonzero(active)):
        rot[k] = r0.T @ fit.rotation[j]
        trans[k] = r0.T @ (fit.translation[j] - t0)
        centre[k] = r0.T @ (fit.centre[j] - t0)
        sd = np.sqrt(np.maximum(np.diag(turn @ fit.covariance[j] @ turn.T), 0))
        sd_rot[k], sd_t[k] = np.degrees(sd[:3]), 1000 * sd[3:]
        rms[k] = 1000 * rms_mm[j]
    return PoseReport(poses, rot, trans, centre, sd_rot, sd_t, rms, chi, chi > OUT_OF_FAMILY, active.copy(),
                      start_rms_px)


def calibrate_handheld(capture: Capture, camera: str, smoother, z_ref: float = 0.0):
    """Calibrate one camera of a stage-free capture (module docstring); a `calib.ray_field.Calibration`
    whose `poses` is the `PoseReport`."""
    poses = capture.poses(camera)
    if len(poses) < MIN_POSES:
        raise InputError(capture.manifest_path, f"camera {camera!r} has frames at {len(poses)} display pose(s); "
                                                f"a stage-free calibration needs at least {MIN_POSES}")
    positions, im, notes = decode_all(capture, camera)
    coords = [p.coord for p in positions]
    weights = [point_weights(p) for p in positions]
    fit, active, chi, start = estimate_poses(capture, camera, coords, weights)
    out = [k for k in range(len(poses)) if not active[k]]
    if out:
        notes.append(f"camera {camera!r}: pose(s) {', '.join(str(poses[k]) for k in out)} left out: their points "
                     f"do not lie on one rigid display seen along the others' rays (smooth residual "
                     f"{', '.join(f'{chi[k]:.0f}' for k in out)}x the median pose's; did the display move "
                     f"while their fringes were shown?)")
    if chi[0] > OUT_OF_FAMILY:
        notes.append(f"camera {camera!r}: pose {poses[0]} (the WCS) does not lie on one rigid display seen along "
                     f"the others' rays (smooth residual {chi[0]:.0f}x the median pose's); hold the display "
                     f"still and capture it again")
    idx = np.flatnonzero(active)
    r0, t0 = fit.rotation[0], fit.translation[0]                 # pose 0 in the working frame
    to_wcs = (r0.T, -r0.T @ t0)
    pitch = np.asarray(capture.display.pitch_mm)
    used_coords, used_weights = [coords[k] for k in idx], [weights[k] for k in idx]
    posed = fit_posed_lines(used_coords, used_weights, fit.rotation, fit.translation, pitch,
                            glass=capture.display.cover_glass)
    quality = dropped_quality([positions[k] for k in idx])
    if not posed.lines.valid.any():
        raise InputError(capture.manifest_path, f"camera {camera!r}: no pixel was decoded at 2 or more poses")
    notes += coverage_notes(camera, quality, posed.lines.valid)

    report = _report(poses, fit, active, chi, start.rms_px, posed.rms_mm)
    used_positions = [positions[k] for k in idx]
    working = _planes(used_coords, used_weights, pitch, fit.rotation, fit.translation)
    lines, sigma, regularisation = regularise_lines(capture, camera, posed.lines, used_positions, smoother, *working,
                                                    working[0])
    sigma = np.hypot(sigma, _pose_sigma(used_coords, used_weights, pitch, fit, posed.lines, working))
    notes += _direction_note(camera, lines, sigma, working, fit)
    raw, lines = posed.lines.moved(*to_wcs, z_ref), lines.moved(*to_wcs, z_ref)
    z_a, z_b = _planes(used_coords, used_weights, pitch, report.rotation[idx], report.translation[idx])
    sigma = _wcs_sigma(lines, sigma, to_wcs, working, (z_a, z_b))
    meta = ray_meta(capture, camera, used_positions, im, regularisation, z_a, z_b, z_ref, notes)
    meta.update({"poses": report.to_json(), "wcs_definition": "the display's frame at pose "
                 f"{poses[0]}: x along its columns, y along its rows, z away from the camera (mm)"})
    prvm = ray_prvm(raw, lines, sigma, quality, im, meta)
    return Calibration(prvm, raw, lines, positions, quality, im, notes, report)
