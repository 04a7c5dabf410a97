"""Simulated calibration datasets: the display on the stage, showing flats, phase-shifting fringes and
(optionally) chessboards, rendered by a simulated camera, written as a `stereodic.capture/1` dataset with
its ground truth (`truth.npz`, a PRVM file: the true ray of every pixel centre, reference z = 0).

Frame order per stage position (nominal positions in the manifest; the true ones in truth.npz, as
`stage_true_z_mm` and as the display's true poses `display_rotation` (M, 3, 3) and
`display_translation_mm` (M, 3), X_wcs = R @ X_display + t, `scanners.sim.pose`): flats at
`flat_levels` (intensity calibration), then fringes for axis x then y, each period, each shift
2*pi*k/N wrapped to (-pi, pi], then chessboards. Files: `z000/cam0_flat_128.png`,
`z000/cam0_x_P60_s0.png`, `z000/cam0_chess_0.png`, ... The manifest is written last, so an interrupted
run never leaves a folder that looks like a complete dataset.

With `handheld` (`scanners.sim.handheld`) the display is held by hand in random poses instead: frames
carry `pose` (files `pose00/cam0_x_P60_s0.png`, ...), the flats are at pose 0 only, and the truth is in
the display's frame at pose 0 (DESIGN.md's WCS of a stage-free capture).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

from calib.capture import MANIFEST, Capture, CoverGlass, Frame, Pattern, load_capture
from calib.errors import InputError
from calib.imageio import write_gray
from calib.progress import progress
from scanners.sim.bayer import BayerCamera, BayerSensor
from scanners.sim.camera import SimCamera
from scanners.sim.display import SimDisplay
from scanners.sim.handheld import HandHeld, disturbed_pose, handheld_poses, relative_poses, to_pose0_frame
from scanners.sim.lenses import DEFAULT_TARGET_MM, Lens, make_lens
from scanners.sim.pose import DisplayPose
from scanners.sim.screens import fringe_shifts, screen_image
from scanners.sim.sensor import Sensor
from scanners.sim.stage import SimStage

DEFAULT_FLATS = (0, 32, 64, 96, 128, 160, 192, 224, 255)
CHESS_SQUARES = (9, 7)          # columns, rows: 8 x 6 inner corners


def simulate_calibration(out_dir: str | os.PathLike, *, lens: str | Lens = "brown", width: int = 1280,
                         height: int = 1024, seed: int = 0, periods=(60, 360, 1920), steps=3,
                         z_positions=(0.0, 50.0), flat_levels=DEFAULT_FLATS, noise: bool = True,
                         bit_depth: int = 8, supersample: int = 3,
                         cover_glass: CoverGlass | tuple[float, float] | None = None, low: int = 20,
                         high: int = 240, chessboard: bool = False, stage_error_um: float = 3.0,
                         stage_tilt_deg: float = 0.0, stage_lateral_um: float = 0.0,
                         stage_axis=(0.0, 0.0, 1.0), exposure_fraction: float = 0.87,
                         display: SimDisplay | None = None, lens_options: dict | None = None,
                         camera: str = "cam0", sensor_seed: int | None = None, ambient: float = 0.0,
                         ambient_variation: float = 0.0, hot_pixels: float = 0.0, overexposure: float = 0.0,
                         unseen: float = 0.0, board_lenses: tuple[Lens, ...] = (), handheld: HandHeld | None = None,
                         bayer: BayerSensor | None = None) -> Capture:
    """Write a simulated calibration dataset (and its truth.npz) and return it.

    A real bench's flaws (`display`, `ambient`, `ambient_variation`, `hot_pixels`, `overexposure`,
    `unseen`) are all off by default (docs/simulator.md).

    Parameters
    ----------
    out_dir : path
        The dataset's folder (created).
    lens : str or Lens
        A family of `scanners.sim.lenses` (made with `lens_options`) or a Lens.
    width, height : int
        The image size, pixels (for a lens family).
    seed : int
        Seeds the lens, stage errors, poses and (unless `sensor_seed`) the sensor.
    periods : sequence of float
        Fringe periods, display pixels.
    steps : int or sequence of int
        Phase shifts per period (>= 3): one number, or one per period.
    z_positions : sequence of float
        Nominal stage positions, mm (one or more).
    flat_levels : sequence of int
        Grey levels of the flat frames.
    noise : bool
        Sensor noise (False: the expected images, rounded).
    bit_depth : int
        The sensor's bits per pixel.
    supersample : int
        Sub-samples per pixel side (1..16).
    cover_glass : CoverGlass or (thickness_mm, refractive_index), optional
        The display's cover glass.
    low, high : int
        The fringe (and chessboard) code values.
    chessboard : bool
        Add chessboards (squares CHESS_SQUARES) at 5 placements per position, inside the field there.
    stage_error_um, stage_tilt_deg, stage_lateral_um : float
        RMS stage errors per position: along the axis (um), tilt about each of the display's x and y
        axes about its centre (degrees), across the axis (um) (`scanners.sim.stage.SimStage`).
    stage_axis : (3,) float
        The stage's direction of travel, WCS.
    exposure_fraction : float
        The brightest fringe pixel as a fraction of full scale.
    display : SimDisplay, optional
        The display and its flaws (bow, pitch error, viewing-angle falloff and gamma, bezel); None: the
        default 24" 1080p display.
    lens_options : dict, optional
        Overrides passed to `make_lens`.
    camera : str
        The camera's name in the manifest.
    sensor_seed : int, optional
        Seed of the camera's gain map, hot pixels and noise; None: `seed` (cameras of one rig share the
        stage's seed but each has its own sensor).
    ambient, ambient_variation : float
        Room light on the sensor, relative to a white display, and its variation across the image
        (`SimCamera`).
    hot_pixels : float
        Their fraction (`Sensor`).
    overexposure : float
        The fraction of the pixels seeing the display that exceed full scale at a flat of level `high`
        (instead of `exposure_fraction`).
    unseen : float
        The fraction of the image rows beyond the display's lower edge at the last stage position (a lens
        family on a stage only: the camera and its aim are moved along the display's rows until they are).
    board_lenses : tuple of Lens
        Further lenses (a stereo rig's other cameras) that must see every chessboard whole too.
    handheld : HandHeld, optional
        Hold the display by hand in random poses (`scanners.sim.handheld`) instead of the stage
        (`z_positions` and the stage errors unused).
    bayer : BayerSensor, optional
        A colour camera with that raw Bayer mosaic (its lens gets the sensor's lateral chromatic
        aberration).

    Returns
    -------
    capture : Capture
        The dataset as `calib.capture.load_capture` reads it; ``truth.npz`` beside it holds the true rays
        (WCS mm) and poses. InputError naming the argument for bad arguments, or a camera that does not
        see the display.
    """
    periods = _check_list("--periods", periods, positive=True)
    z_nominal = _check_list("--positions-mm", z_positions)
    flats = [int(v) for v in _check_list("flat_levels", flat_levels, allow_empty=True)]
    if len(set(z_nominal)) != len(z_nominal):
        raise InputError("--positions-mm", f"stage positions must be distinct, got {z_nominal}")
    steps = _check_list("--steps", [steps] * len(periods) if np.isscalar(steps) else steps)
    if len(steps) != len(periods) or any(int(n) != n or n < 3 for n in steps):
        raise InputError("--steps", f"need a whole number >= 3 of phase steps (one, or one per period), "
                                    f"got {steps}")
    if not (0 <= overexposure < 1 and 0 <= unseen < 1 and 0 <= hot_pixels < 1):
        raise InputError("flaws", f"overexposure, unseen and hot_pixels are fractions in [0, 1), got "
                                  f"{overexposure}, {unseen}, {hot_pixels}")
    if not 0 <= low < high <= 255 or any(not 0 <= v <= 255 for v in flats):
        raise InputError("--low/--high", f"levels must satisfy 0 <= low < high <= 255 and flats within "
                                         f"0..255, got low={low}, high={high}, flats={flats}")
    if bit_depth not in (8, 10, 12, 14, 16):
        raise InputError("--bit-depth", f"must be 8, 10, 12, 14 or 16, got {bit_depth}")
    if not 0 < exposure_fraction <= 1:
        raise InputError("exposure_fraction", f"must be in (0, 1], got {exposure_fraction}")
    if cover_glass is not None and not isinstance(cover_glass, CoverGlass):
        if len(cover_glass) != 2 or cover_glass[0] < 0 or cover_glass[1] < 1:
            raise InputError("--cover-glass", f"need THICKNESS_MM,INDEX with thickness >= 0 and index >= 1, "
                                              f"got {cover_glass}")
        cover_glass = CoverGlass(float(cover_glass[0]), float(cover_glass[1]))
    display = display or SimDisplay()
    if cover_glass is not None:
        display = dataclasses.replace(display, cover_glass=cover_glass)
    if unseen > 0 and (handheld is not None or not isinstance(lens, str)):
        raise InputError("--unseen", "needs a lens family on a stage (the camera is moved), not a Lens or a "
                                     "hand-held display")
    if isinstance(lens, str):
        lens = make_lens(lens, width=width, height=height, seed=seed, **(lens_options or {}))
        if unseen > 0:
            lens = _shifted_for_unseen(lens, display, seed, unseen, z_nominal[-1], stage_axis, lens_options)
    if handheld is not None and chessboard:
        raise InputError("--chessboard", "chessboards are rendered at stage positions only")
    stage = None
    if handheld is None:
        try:
            stage = SimStage(tuple(z_nominal), stage_error_um, tuple(stage_axis), seed, stage_tilt_deg,
                             stage_lateral_um, pivot_mm=tuple(np.array(display.size_mm) / 2))
        except ValueError as exc:
            raise InputError("stage", str(exc)) from None
    sensor = Sensor(bit_depth=bit_depth, hot_pixels=hot_pixels)
    sensor_options = dict(seed=seed if sensor_seed is None else sensor_seed, ambient=ambient,
                          ambient_variation=ambient_variation)
    if bayer is not None:
        lens = dataclasses.replace(lens, colour=bayer.colour(lens.width, lens.height))
        cam = BayerCamera(lens, sensor=sensor, supersample=supersample, bayer=bayer, **sensor_options)
    else:
        cam = SimCamera(lens, sensor=sensor, supersample=supersample, **sensor_options)
    poses = list(stage.poses) if stage is not None else handheld_poses(lens, display, handheld, seed)
    cam.set_exposure(display, high, poses[0], fraction=exposure_fraction, clipped=overexposure)

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / MANIFEST).unlink(missing_ok=True)     # an old manifest must not describe half-new images
    others = [SimCamera(ln, sensor=Sensor(bit_depth=bit_depth),
                        supersample=cam.supersample) for ln in board_lenses]
    boards = [_chess_placements([cam, *others], display, pose) if chessboard else [] for pose in poses]
    places = ([{"z_mm": z} for z in z_nominal] if stage is not None else
              [{"pose": i} for i in range(len(poses))])
    frames = _frames(camera, places, flats, periods, steps, low, high, boards)
    shown = _shown_poses(frames, poses, stage, handheld, display, seed)
    for f, pose in progress(list(zip(frames, shown)), "simulating", total=len(frames)):
        image = screen_image(f.pattern, display.width_px, display.height_px)
        write_gray(out / f.file, cam.render(image, display, pose, noise=noise))

    truth = _truth(cam, display, poses, seed, noise, camera, stage, ambient, ambient_variation, overexposure)
    simulated = {"lens": lens.family, "seed": seed, "noise": noise, "supersample": cam.supersample,
                 "truth": "truth.npz"}
    if bayer is not None:
        simulated["bayer"] = dataclasses.asdict(bayer)
        truth.meta["bayer"] = simulated["bayer"]
    if handheld is not None:
        truth = _handheld_truth(truth, poses, handheld, shown, frames)
        simulated["handheld"] = truth.meta["handheld"]
    truth.save(out / "truth.npz")
    cap = Capture(out, "calibration", {camera: (lens.width, lens.height)}, frames, display.record(),
                  stage.axis if stage is not None else (0.0, 0.0, 1.0), {"simulated": simulated},
                  {camera: bit_depth}, {camera: bayer.pattern} if bayer is not None else {})
    cap.save()
    return load_capture(out, min_positions=1)


def _check_list(name: str, values, positive: bool = False, allow_empty: bool = False) -> list[float]:
    try:
        vals = [float(v) for v in values]
    except (TypeError, ValueError):
        raise InputError(name, f"expected a list of numbers, got {values!r}") from None
    if (not vals and not allow_empty) or not all(np.isfinite(vals)) or (positive and min(vals, default=1) <= 0):
        raise InputError(name, f"expected {'positive' if positive else 'finite'} numbers, got {values!r}")
    return [int(v) if v == int(v) else v for v in vals]


def _shifted_for_unseen(lens: Lens, display: SimDisplay, seed: int, unseen: float, z_last: float, axis,
                        lens_options: dict | None) -> Lens:
    """The same lens family and seed moved (camera and aim together, along the display's rows) so that
    the last `unseen` fraction of its image rows lies beyond the display's lower edge at stage position
    z_last (nominal, an ideal stage), judged along the middle column."""
    v = np.arange(lens.height, dtype=np.float64)
    o, d = lens.rays(np.full_like(v, (lens.width - 1) / 2), v)
    r = display.hit(o, d, DisplayPose.staged(z_last, axis=axis))[1]
    row = min(int(round((1 - unseen) * lens.height)), lens.height - 1)
    shift = (display.height_px - 0.5 - r[row]) * display.true_pitch_mm[1] * np.sign(r[-1] - r[0])
    options = dict(lens_options or {})
    target = np.asarray(options.get("target_mm", DEFAULT_TARGET_MM), float) + [0.0, shift, 0.0]
    return make_lens(lens.family, width=lens.width, height=lens.height, seed=seed,
                     **{**options, "target_mm": tuple(target)})


def _frames(camera, places, flats, periods, steps, low, high, boards) -> list[Frame]:
    """The frames at each place ({"z_mm": z}: flats at every stage position; {"pose": i}: at pose 0)."""
    frames = []
    for i, where in enumerate(places):
        folder = f"z{i:03d}" if "z_mm" in where else f"pose{i:02d}"
        for level in flats if "z_mm" in where or i == 0 else ():
            frames.append(Frame(camera, f"{folder}/{camera}_flat_{level}.png", Pattern("flat", {"level": level}),
                                **where))
        for axis in ("x", "y"):
            for p, n in zip(periods, steps):
                for k, shift in enumerate(fringe_shifts(int(n))):
                    frames.append(Frame(camera, f"{folder}/{camera}_{axis}_P{p:g}_s{k}.png",
                                        Pattern("fringe", {"axis": axis, "period_px": p, "shift_rad": shift,
                                                           "low": low, "high": high}), **where))
        for j, board in enumerate(boards[i]):
            frames.append(Frame(camera, f"{folder}/{camera}_chess_{j}.png",
                                Pattern("chessboard", {**board, "low": low, "high": high}), **where))
    return frames


def _shown_poses(frames, poses, stage, held, display, seed) -> list[DisplayPose]:
    """The display's true pose while each frame was captured: the stage's at its nominal position, or
    the hand's, moved halfway through the fringe frames of the disturbed pose."""
    if stage is not None:
        return [stage.true_pose(f.z_mm) for f in frames]
    shown = [poses[f.pose] for f in frames]
    if held.disturbed is not None:
        moved = disturbed_pose(poses[held.disturbed], display, held, seed)
        index = [i for i, f in enumerate(frames) if f.pose == held.disturbed and f.pattern.type == "fringe"]
        for i in index[len(index) // 2:]:
            shown[i] = moved
    return shown


def _chess_placements(cams: list[SimCamera], display: SimDisplay, pose: DisplayPose) -> list[dict]:
    """Five board placements (centre and four shifted ones) inside every camera's field at the display's
    true pose: sized from the common field's extent (2nd-98th percentile of the display coordinates
    each camera sees), then shrunk until every corner of every board lies inside each field's outline
    (an oblique view sees a trapezoid, not the box of its extent) by half a square or more (the light
    border a detector needs)."""
    lo, hi, outlines = np.full(2, -np.inf), np.full(2, np.inf), []
    for cam in cams:
        cr = cam.view(display, pose).display_cr
        a, b = np.percentile(cr.reshape(-1, 2), [2, 98], axis=0)
        lo, hi = np.maximum(lo, a), np.minimum(hi, b)
        outlines.append(np.concatenate([cr[0], cr[1:, -1], cr[-1, -2::-1], cr[-2:0:-1, 0]]).astype(np.float32))
    lo = np.maximum(lo, 0.0)                            # and on the display, if it does not fill the field
    hi = np.minimum(hi, [display.width_px - 1.0, display.height_px - 1.0])
    field = np.maximum(hi - lo, 0.0)
    size = int(0.65 * min(field[0] / CHESS_SQUARES[0], field[1] / CHESS_SQUARES[1]))
    while size >= 4:
        boards = _boards(size, lo, hi)
        if all(_inside(outline, b, size / 2) for b in boards for outline in outlines):
            return boards
        size -= 1
    raise InputError("chessboard", f"the camera(s) see in common only {field[0]:.0f}x{field[1]:.0f} display "
                                   f"pixels at z = {pose.translation[2]:g} mm: too few for a {CHESS_SQUARES[0]}x{CHESS_SQUARES[1]} "
                                   f"chessboard")


def _boards(size: int, lo: np.ndarray, hi: np.ndarray) -> list[dict]:
    """The five placements of a board of `size`-pixel squares in the display box [lo, hi]."""
    board = np.array(CHESS_SQUARES) * size
    centre = (lo + hi) / 2 - board / 2
    slack = (hi - lo - board) / 2 * 0.8
    return [{"squares": list(CHESS_SQUARES), "square_px": size,
             "origin_px": [int(round(centre[0] + dx * slack[0])), int(round(centre[1] + dy * slack[1]))]}
            for dx, dy in ((0, 0), (-1, -1), (1, -1), (-1, 1), (1, 1))]


def _inside(outline: np.ndarray, board: dict, margin: float) -> bool:
    """Whether the board's four corners lie inside the closed `outline` ((N, 2) display c, r) by
    `margin` display pixels or more."""
    import cv2
    c0, r0 = board["origin_px"]
    w, h = np.array(board["squares"]) * board["square_px"]
    return all(cv2.pointPolygonTest(outline, (float(c), float(r)), True) >= margin
               for c, r in ((c0, r0), (c0 + w, r0), (c0, r0 + h), (c0 + w, r0 + h)))


def _truth(cam: SimCamera, display: SimDisplay, poses: list[DisplayPose], seed: int, noise: bool, camera: str,
           stage: SimStage | None, ambient: float, ambient_variation: float, overexposure: float):
    """The true PRVM (simulator frame) with the rig's other truths: stage positions (with a stage), the
    display's true poses, gain and vignetting maps (and the hot pixels' and ambient light's, if any), and
    the display coordinates (c, r) each pixel centre's ray reaches at each true pose (outside
    0..width-1, 0..height-1 by more than half a pixel: the ray misses the display's pixel area)."""
    lens = cam.lens
    o, d = lens.rays(*lens.pixel_grid())
    display_cr = np.stack([np.stack(display.hit(o, d, pose), axis=-1) for pose in poses])
    first = cam.view(display, poses[0]).points_mm
    h, w = lens.height, lens.width
    centre = first[h // 2, w // 2]
    footprint = 0.5 * (np.linalg.norm(np.diff(first, axis=1), axis=-1).mean()
                       + np.linalg.norm(np.diff(first, axis=0), axis=-1).mean())
    rig = {} if stage is None else {"stage": {
        "nominal_mm": list(stage.nominal_mm), "true_mm": list(stage.true_mm), "axis": list(stage.axis),
        "error_um": stage.error_um, "tilt_deg": stage.tilt_deg, "lateral_um": stage.lateral_um,
        "true_tilt_deg": stage.tilts_deg.tolist(), "true_lateral_mm": stage.lateral_mm.tolist()}}
    prvm = lens.true_prvm(
        camera=camera, dataset="capture.json", seed=seed, noise=noise,
        working_distance_mm=float(lens.axis_depth(centre)), pixel_footprint_mm=float(footprint), **rig,
        display={"fill_factor": list(display.fill_factor), "stripes": display.stripes,
                 "black_level": display.black_level, "gamma": display.gamma, **display.flaws()},
        sensor={**cam.sensor.__dict__, "exposure_e": cam.exposure_e, "supersample": cam.supersample,
                "diffraction_sigma_px": cam.sigma_px, "ambient": ambient, "ambient_variation": ambient_variation,
                "overexposure": overexposure})
    prvm.extra = {"display_rotation": np.array([p.R for p in poses]),
                  "display_translation_mm": np.array([p.t for p in poses]), "gain": cam.gain,
                  "vignetting": cam.vignetting, "display_cr": display_cr.astype(np.float32)}
    if stage is not None:
        prvm.extra = {"stage_nominal_z_mm": np.array(stage.nominal_mm, float),
                      "stage_true_z_mm": np.array(stage.true_mm, float), **prvm.extra}
    if cam.hot_e is not None:
        prvm.extra["hot_pixels_e"] = cam.hot_e
    if cam.ambient is not None:
        prvm.extra["ambient"] = cam.ambient
    return prvm


def _handheld_truth(truth, poses: list[DisplayPose], held: HandHeld, shown: list[DisplayPose],
                    frames: list[Frame]):
    """The truth of a hand-held capture in the display's frame at pose 0 (the WCS its calibration
    reports): rays, and each pose relative to pose 0 (the disturbed pose: where its first frames saw it);
    `sim_rotation`, `sim_translation_mm`: pose 0 in the simulator's frame (X_sim = R X_wcs + t)."""
    out = to_pose0_frame(truth, poses[0])
    rot, t = relative_poses(poses)
    out.extra.update({"display_rotation": rot, "display_translation_mm": t, "sim_rotation": poses[0].R,
                      "sim_translation_mm": poses[0].t})
    meta = {"poses": held.poses, "distance_mm": list(held.distance_mm), "first_mm": held.first_mm,
            "min_tilt_deg": held.min_tilt_deg, "tilt_about": held.tilt_about, "max_tilt_deg": held.max_tilt_deg,
            "roll_deg": held.roll_deg, "min_cover": held.min_cover, "disturbed": held.disturbed}
    if held.disturbed is not None:
        moved = next(p for p, f in zip(reversed(shown), reversed(frames)) if f.pose == held.disturbed)
        mr, mt = relative_poses([poses[0], moved])
        out.extra.update({"disturbed_rotation": mr[1], "disturbed_translation_mm": mt[1]})
        meta.update(disturbance_mm=held.disturbance_mm, disturbance_deg=held.disturbance_deg)
    out.meta["handheld"] = meta
    return out
