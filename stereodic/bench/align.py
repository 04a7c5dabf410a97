"""Benchmark of the alignment aid (`stereodic align`, scanners.align): its readings against the simulated
bench's truth, and the processing time of one update.

Accuracy: a 640x512 camera with the field of the default 1280x1024 one (10.6 um pixels, 12 mm lens,
400 mm from the default 24-inch display), aimed at tilts of 0 to 5 degrees (`TILTS`), with the brown
and the free-form lens (sensor noise on, gamma 2.2 display). Each figure is the largest error over the
tilts: of the tilts about x and y, of the roll, read through the lens's true PRVM (taken in another
pose: its seeded one) and from the pattern alone (principal point at the image centre, no distortion,
the focal length from the most oblique view, `calib.alignment.PatternIntrinsics`). With an emulated
stage whose travel leans 0.4 deg to the right and 0.3 deg up: the error of the stage axis through the
PRVM, and from the pattern alone, whose focal length the known travel then fixes.
Speed: the processing of one update of a 1280x1024 camera (decoding its 12 frames, or the 6 of a
tracked update, the homography, the pose through a PRVM's rays, the reading, the fused picture),
without the time the camera and the display take; the goal leaves room for a few updates a second.
"""

from __future__ import annotations

import numpy as np

from stereodic.bench import Figure, best_time

TILTS = [(0.1, -0.15, 0.1), (2.5, -1.5, 0.8), (-5.0, 3.5, -2.0), (4.5, 5.0, 1.5)]
STAGE_DEG = (0.4, -0.3)
GOAL_DEG = 0.05


def _bench(family: str, size, tilt, stage=None, model=None):
    from scanners.align import AlignSession, AlignSettings, default_periods
    from scanners.camera import SimulatedCamera
    from scanners.display import SimScreen
    screen = SimScreen()
    true_z = stage.emulator.true_position_mm if stage is not None else (lambda: 0.0)
    axis = stage.emulator.travel_axis if stage is not None else (0.0, 0.0, 1.0)
    cam = SimulatedCamera("cam0", screen, true_z, family, size, 0, pixel_um=5.3 * 1280 / size[0], aim=tilt,
                          stage_axis=axis)
    cam.set_exposure(240, 0.0)
    session = AlignSession(screen, cam, screen.pitch_mm, model,
                           settings=AlignSettings(default_periods(screen.size), hold_s=0.0))
    if stage is not None:
        stage.move_to(0.0)
    session.calibrate_response()
    return session, cam


def _error(m, cam) -> tuple[float, float]:
    """(largest tilt error, roll error) in degrees against the simulator's truth."""
    from scanners.sim.aim import true_alignment
    t = true_alignment(cam.sim.lens, cam.screen.sim, cam.true_pose())
    r = m.reading
    return (max(abs(r.tilt_x_deg - t["tilt_x_deg"]), abs(r.tilt_y_deg - t["tilt_y_deg"])),
            abs(r.roll_deg - t["roll_deg"]))


def _prvm_rays(family: str, size):
    from calib.alignment import PrvmRays
    from scanners.sim.lenses import make_lens
    from stereodic.virtual.camera import fit_optical_centre
    prvm = make_lens(family, width=size[0], height=size[1], seed=0, pixel_mm=0.0053 * 1280 / size[0]).true_prvm()
    return PrvmRays(prvm, fit_optical_centre(prvm)[0])


def _accuracy(family: str, size, tilts) -> list[Figure]:
    from calib.alignment import PatternIntrinsics
    model = _prvm_rays(family, size)
    prvm, pattern = [], []
    for tilt in tilts:
        session, cam = _bench(family, size, tilt, model=model)
        m = session.measure()
        prvm.append(_error(m, cam))
        alone = PatternIntrinsics(*size).update(m.homography, session.pitch_mm)
        pattern.append(_error(session.refit(m, alone), cam))
    prvm, pattern = np.array(prvm), np.array(pattern)
    name = f"{family}, tilts 0-5 deg, {size[0]}x{size[1]}"
    return [
        Figure("align", f"camera tilt error, PRVM rays, {name}, max", prvm[:, 0].max(), "deg", "", None,
               f"<= {GOAL_DEG} deg", prvm[:, 0].max() <= GOAL_DEG),
        Figure("align", f"camera roll error, PRVM rays, {name}, max", prvm[:, 1].max(), "deg", "", None,
               f"<= {GOAL_DEG} deg", prvm[:, 1].max() <= GOAL_DEG),
        Figure("align", f"camera tilt error, pattern alone, {name}, max", pattern[:, 0].max(), "deg"),
        Figure("align", f"camera roll error, pattern alone, {name}, max", pattern[:, 1].max(), "deg"),
    ]


def _stage(family: str, size) -> list[Figure]:
    from scanners.stage_url import open_stage
    url = f"emulated:zaber?speed=5000&axis_deg={STAGE_DEG[0]},{STAGE_DEG[1]}"
    out = []
    for label, model in (("PRVM rays", _prvm_rays(family, size)), ("pattern alone", None)):
        with open_stage(url) as stage:
            session, cam = _bench(family, size, TILTS[1], stage, model)
            axis, _ = session.measure_stage(stage, (0.0, 50.0))
            stage.move_to(0.0)
            tilt_err, _ = _error(session.measure(0.0), cam)
        err = max(abs(axis.angle_x_deg - STAGE_DEG[0]), abs(axis.angle_y_deg - STAGE_DEG[1]))
        name = f"{family}, {size[0]}x{size[1]}"
        out.append(Figure("align", f"stage axis error, {label}, {name}", err, "deg", "", None,
                          f"<= {GOAL_DEG} deg" if model is not None else "",
                          err <= GOAL_DEG if model is not None else None))
        if model is None:
            out.append(Figure("align", f"camera tilt error, pattern alone with the stage's travel, {name}", tilt_err,
                              "deg"))
    return out


def _speed(size) -> list[Figure]:
    from scanners.align_picture import fused_picture
    session, _ = _bench("brown", size, TILTS[1], model=_prvm_rays("brown", size))
    frames = {key: [session._grab(img) for img in images] for key, images in session.patterns.items()}
    last = session.process(frames).display_map
    short = {key: frames[key] for key in session.shortest}
    out = []
    for label, shown, previous in (("full", frames, None), ("tracked", short, last)):

        def update():
            m = session.process(shown, previous=previous)
            fused_picture(session.screen.size, m, session.pitch_mm, 0.2, [("readout", (255, 255, 255))])

        seconds = best_time(update, repeat=3)
        full = size == (1280, 1024)
        out.append(Figure("align", f"processing of one {label} update ({sum(len(f) for f in shown.values())} "
                                   f"frames, {size[0]}x{size[1]}): decode, pose, reading, picture", seconds, "s",
                          "", None, "<= 0.25 s at 1280x1024", seconds <= 0.25 if full else None))
    return out


def run(quick: bool = False) -> list[Figure]:
    size = (320, 256) if quick else (640, 512)
    tilts = TILTS[::3] if quick else TILTS
    figures = []
    for family in ("brown", "freeform"):
        figures += _accuracy(family, size, tilts)
    for family in ("brown", "freeform"):
        figures += _stage(family, size)
    figures += _speed(size if quick else (1280, 1024))
    return figures
