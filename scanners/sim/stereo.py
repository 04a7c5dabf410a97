"""The simulated stereo rig: two cameras in one WCS (same display, same stage), any mix of lens families;
the true image position of world points; and the stereo calibration datasets.

Poses: both cameras `distance_mm` in front of the default display's centre, `baseline_mm` apart along
the WCS x axis (left camera at -x), each looking at the display centre (converging).

Datasets (`simulate_stereo`):
- joint (default): one `stereodic.capture/1` dataset with cameras cam0 (left) and cam1 (right), both
  rendering the same display at the same (true) stage positions; truth_cam0.npz / truth_cam1.npz hold
  the true rays in that WCS.
  With `handheld` (`scanners.sim.handheld.HandHeld`) the display is held by hand instead of staged:
  both cameras see the same poses (drawn so that the display covers both fields), and both truths are
  in the display's frame at pose 0.
- separate: each camera calibrated on its own, facing the display straight (its axis along +z, centred
  on the display) in its own display WCS: left/ and right/ (each a dataset of one camera with its
  truth.npz); then register/, a joint dataset of both cameras in the stereo pose (the common WCS)
  used only for the registration (`stereodic.stereo.register`): each camera's own rays are mapped into the
  common WCS by the rigid transform that best aligns them with the same pixels' rays decoded in
  register/. registration_truth.json holds the true transforms (X_common = R X_own + t).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

from calib.atomic import write_json
from calib.capture import MANIFEST, Capture, load_capture
from calib.errors import InputError
from calib.prvm_file import load_prvm
from scanners.sim.calibration import simulate_calibration
from scanners.sim.display import SimDisplay
from scanners.sim.handheld import handheld_poses
from scanners.sim.lenses import DEFAULT_TARGET_MM, Lens, look_at, make_lens

CAMERAS = ("cam0", "cam1")


def stereo_lenses(left: str = "brown", right: str = "brown", width: int = 1280, height: int = 1024,
                  seed: int = 0, baseline_mm: float = 200.0, distance_mm: float = 400.0,
                  **overrides) -> tuple[Lens, Lens]:
    """Two lenses (families `left`, `right`) posed as a converging stereo pair (module docstring);
    `overrides` go to both make_lens calls (e.g. pixel_mm)."""
    if not baseline_mm > 0:
        raise InputError("--baseline-mm", f"must be positive, got {baseline_mm}")
    lenses = []
    for k, (family, sign) in enumerate(((left, -1.0), (right, 1.0))):
        lenses.append(make_lens(family, width=width, height=height, seed=seed + 1000 * k, distance_mm=distance_mm,
                                offset_mm=(sign * baseline_mm / 2, 0.0), **overrides))
    return lenses[0], lenses[1]


def facing_straight(lens: Lens, distance_mm: float = 400.0) -> Lens:
    """The same lens (same intrinsics, distortion, window, roll) posed for a calibration of its own:
    centred on the default display, its axis along +z, `distance_mm` in front of it."""
    target = np.asarray(DEFAULT_TARGET_MM, float)
    centre = target - np.array([0.0, 0.0, distance_mm])
    roll = np.degrees(np.arctan2(lens.rotation[1, 0], lens.rotation[0, 0]))  # keep the image's roll
    return dataclasses.replace(lens, rotation=look_at(centre, target, roll), centre_mm=centre)


def own_to_common(own: Lens, common: Lens) -> tuple[np.ndarray, np.ndarray]:
    """The true rigid transform (R, t) with X_common = R X_own + t, for one physical camera posed as
    `own` (its calibration) and as `common` (the stereo rig)."""
    rot = common.rotation @ own.rotation.T
    return rot, common.centre_mm - rot @ own.centre_mm


def project_true(lens: Lens, points: np.ndarray, iterations: int = 12, coarse: int = 24) -> np.ndarray:
    """(N, 2) real pixel positions (u, v) whose TRUE ray passes through each WCS point (N, 3) (mm).

    A coarse search over every `coarse`-th pixel's ray gives the start; Newton steps on the two
    components of the point's offset from the ray (perpendicular to it) finish. NaN where the point is
    not seen (outside the sensor by more than a pixel) or Newton did not converge to 1e-9 mm.
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    gu, gv = np.meshgrid(np.arange(0, lens.width, coarse, dtype=np.float64),
                         np.arange(0, lens.height, coarse, dtype=np.float64))
    go, gd = lens.rays(gu.ravel(), gv.ravel())
    uv = np.empty((len(points), 2))
    for s in range(0, len(points), 2048):
        p = points[s:s + 2048, None, :] - go[None]
        off = p - np.einsum("nki,ki->nk", p, gd)[..., None] * gd
        k = np.argmin(np.einsum("nki,nki->nk", off, off), axis=1)
        uv[s:s + 2048] = np.stack([gu.ravel()[k], gv.ravel()[k]], axis=-1)
    _, d0 = lens.rays(uv[:, 0], uv[:, 1])
    e1 = np.cross(d0, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(d0, e1)

    def residual(q):
        o, d = lens.rays(q[:, 0], q[:, 1])
        p = points - o
        off = p - np.einsum("ni,ni->n", p, d)[:, None] * d
        return np.stack([np.einsum("ni,ni->n", off, e1), np.einsum("ni,ni->n", off, e2)], axis=-1)

    h = 1e-4
    for _ in range(iterations):
        r = residual(uv)
        ju = (residual(uv + [h, 0]) - r) / h
        jv = (residual(uv + [0, h]) - r) / h
        det = ju[:, 0] * jv[:, 1] - ju[:, 1] * jv[:, 0]
        step = np.stack([jv[:, 1] * r[:, 0] - jv[:, 0] * r[:, 1], ju[:, 0] * r[:, 1] - ju[:, 1] * r[:, 0]],
                        axis=-1) / det[:, None]
        uv = uv - step
        uv = np.clip(uv, [-2, -2], [lens.width + 1, lens.height + 1])
    bad = (np.hypot(*residual(uv).T) > 1e-9) | (uv[:, 0] < -1) | (uv[:, 1] < -1) \
        | (uv[:, 0] > lens.width) | (uv[:, 1] > lens.height)
    uv[bad] = np.nan
    return uv


def simulate_stereo(out_dir: str | os.PathLike, *, left: str = "brown", right: str = "brown", width: int = 1280,
                    height: int = 1024, seed: int = 0, separate: bool = False, baseline_mm: float = 200.0,
                    distance_mm: float = 400.0, lens_options: dict | None = None, **calibration) -> Path:
    """Write a simulated stereo calibration (module docstring).

    Parameters
    ----------
    out_dir : path
        The folder (created).
    left, right : str
        The two cameras' lens families (`scanners.sim.lenses`).
    width, height : int
        The image size of both, pixels.
    seed : int
        Seeds the lenses, stage and sensors.
    separate : bool
        Each camera calibrated on its own (left/, right/) plus a registration dataset (register/);
        False: one joint dataset.
    baseline_mm : float
        The cameras' distance along the WCS x axis, mm.
    distance_mm : float
        Their distance in front of the display's centre, mm.
    lens_options : dict, optional
        Overrides passed to both `make_lens` calls (e.g. pixel_mm).
    **calibration
        Passed to every `simulate_calibration` call (periods, steps, z_positions, noise, supersample,
        handheld, ...).

    Returns
    -------
    folder : Path
        `out_dir`: the joint dataset with truth_cam0.npz and truth_cam1.npz (true rays, WCS mm), or the
        separate datasets and registration_truth.json.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    lenses = stereo_lenses(left, right, width, height, seed, baseline_mm, distance_mm, **(lens_options or {}))
    held = calibration.get("handheld")
    if held is not None:
        if separate:
            raise InputError("--separate", "a hand-held stereo calibration is one joint dataset")
        poses = handheld_poses(list(lenses), calibration.get("display") or SimDisplay(), held, seed)
        calibration = {**calibration, "handheld": dataclasses.replace(held, given=tuple(poses))}
    if not separate:
        _joint(out, lenses, seed, calibration, f"simulated stereo rig, seed {seed}")
        return out
    truth = {}
    for side, name, lens in zip(("left", "right"), CAMERAS, lenses):
        own = facing_straight(lens, distance_mm)
        simulate_calibration(out / side, lens=own, seed=seed, camera=name, **calibration)
        _set_truth_wcs(out / side / "truth.npz", f"simulated {side} camera's own display, seed {seed}")
        rot, t = own_to_common(own, lens)
        truth[name] = {"rotation": rot.tolist(), "translation_mm": t.tolist()}
    _joint(out / "register", lenses, seed + 1, calibration,
           f"simulated stereo registration, seed {seed}")
    write_json(out / "registration_truth.json",
               {"convention": "X_common = rotation @ X_own + translation_mm (WCS mm)", "cameras": truth})
    return out


def _joint(out: Path, lenses: tuple[Lens, Lens], seed: int, calibration: dict, wcs: str) -> None:
    """One dataset of both cameras at the same stage positions: each camera is rendered into its own
    subfolder (same seed, hence the same true stage positions; each its own sensor gain map and noise;
    chessboards placed where both cameras see them), then one manifest lists both."""
    (out / MANIFEST).unlink(missing_ok=True)
    frames, cameras, bits, caps = [], {}, {}, []
    for k, (name, lens) in enumerate(zip(CAMERAS, lenses)):
        cap = simulate_calibration(out / name, lens=lens, seed=seed, camera=name,
                                   sensor_seed=seed + 7919 * (k + 1),
                                   board_lenses=tuple(ln for ln in lenses if ln is not lens), **calibration)
        caps.append(cap)
        frames += [dataclasses.replace(f, file=f"{name}/{f.file}") for f in cap.frames]
        cameras[name] = (lens.width, lens.height)
        bits.update(cap.bit_depth)
        os.replace(out / name / "truth.npz", out / f"truth_{name}.npz")
        _set_truth_wcs(out / f"truth_{name}.npz", wcs)
        (out / name / MANIFEST).unlink()
    first = caps[0]
    extra = {**first.extra, "simulated": {**first.extra.get("simulated", {}), "stereo": True,
                                          "lenses": [ln.family for ln in lenses],
                                          "truth": [f"truth_{n}.npz" for n in CAMERAS]}}
    Capture(out, "calibration", cameras, frames, first.display, first.stage_axis, extra, bits).save()
    load_capture(out, min_positions=1)


def _set_truth_wcs(path: Path, wcs: str) -> None:
    """Name the truth's WCS in its meta (so that truths of different frames are told apart)."""
    prvm = load_prvm(path)
    prvm.meta["wcs"] = wcs
    prvm.save(path)

