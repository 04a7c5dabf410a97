"""Several views merged: a simulated turntable (known rotations) registered by Open3D (global registration
from FPFH features, then ICP) and merged; rotations and the merged sphere's form against the truth."""

import numpy as np
import pytest

from calib.capture import load_capture
from scanners.sim.scan import TARGET, _rot_x, default_scan_rig, simulate_scan
from scanners.sim.scan_scene import HeightField, Scene, Sphere
from stereodic.scan.cloud import make_cloud
from stereodic.scan.fit import fit_sphere, trimmed_range
from stereodic.stereo.rig import load_rig, rig_from_files, save_rig
from stereodic.scan.pipeline import scan_state
from stereodic.scan.views import merge_views, register_views

STEP_DEG = 12.0                      # the turntable's step between views
SPHERE = np.array([0, -30.0, -25.0])  # the 25 mm sphere before the free-form part, about the axis point


def _turn(deg: float) -> np.ndarray:
    """Rotation by `deg` about the turntable's vertical (y) axis."""
    a = np.radians(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def _truth(k: int) -> np.ndarray:
    """(4, 4) view k's points into view 0's frame: the object turned back by k steps about the axis
    through TARGET."""
    r = _turn(-STEP_DEG * k)
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = r, TARGET - r @ TARGET
    return t


@pytest.mark.slow
def test_turntable_views_register_within_0p02_degrees_and_merge(tmp_path):
    scenes = []
    for k in range(6):                  # the free-form part and a sphere, turned by 12 degrees a view
        r = _turn(STEP_DEG * k)
        scenes.append(Scene([HeightField(centre=TARGET + r @ np.array([0, 0, 10.0]),
                                         rotation=r @ np.diag([1.0, -1, -1]) @ _rot_x(10), half_mm=45.0),
                             Sphere(centre=TARGET + r @ SPHERE, radius_mm=12.5, seed=3)], f"view {k}"))
    simulate_scan(tmp_path, scenes=scenes, rig=default_scan_rig(width=640, height=512))
    save_rig(tmp_path / "rig.npz", rig_from_files(tmp_path / "truth_cam0.npz", tmp_path / "truth_cam1.npz"))
    rig, cap = load_rig(tmp_path / "rig.npz"), load_capture(tmp_path)
    viewpoint = (rig.left.centre + rig.right.centre) / 2
    views = []
    for k in range(6):
        result, _ = scan_state(rig, cap, k)
        views.append(result.points[make_cloud(result.points, {}, viewpoint)[1]])
    reg = register_views(views)                     # no initial guess: FPFH + RANSAC, then ICP
    angles, shifts = [], []
    for k in range(6):
        delta = reg.transforms[k][:3, :3] @ _truth(k)[:3, :3].T
        angles.append(np.degrees(np.arccos(np.clip((np.trace(delta) - 1) / 2, -1, 1))))
        moved = reg.transforms[k][:3, :3] @ TARGET + reg.transforms[k][:3, 3]      # the object's centre
        shifts.append(np.linalg.norm(moved - TARGET))
    print("rotation errors (degrees)", np.round(angles, 4), "centre shifts (mm)", np.round(shifts, 4))
    assert max(angles) < 0.02
    assert max(shifts) < 0.02
    assert np.all(reg.residual_mm[1:] < 0.15) and np.all(reg.fitness > 0.9)

    def sphere_pf(points):
        on = points[np.abs(np.linalg.norm(points - (TARGET + SPHERE), axis=1) - 12.5) < 0.5]
        return trimmed_range(fit_sphere(on).residuals)

    merged = merge_views(views, reg)
    assert sphere_pf(merged) <= 1.5 * sphere_pf(views[0])   # 4.8 against 4.9 um
