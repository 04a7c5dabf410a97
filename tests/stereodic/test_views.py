"""Several views merged: a simulated turntable (known rotations) registered by Open3D (global registration
from FPFH features, then ICP) and merged; rotations and the merged sphere's form against the truth. A whole
turn of a free-form part (`register_turn`: view to view, the loop closed by a pose graph) merged and meshed:
rotations, the merged cloud and the Poisson mesh against the exact surface. The turntable's axis and angles
(`fit_turntable` on exact transforms; `register_turntable` on a whole turn) against the simulator's."""

import numpy as np
import pytest

from calib.capture import load_capture
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from scanners.sim.scan import (TARGET, TURNTABLE_BALL, _rot_x, default_scan_rig, simulate_scan, turntable_scenes,
                               turntable_transform)
from scanners.sim.scan_scene import HeightField, Scene, Sphere
from stereodic.scan.cloud import make_cloud, poisson_mesh
from stereodic.scan.fit import fit_sphere, trimmed_range
from stereodic.stereo.rig import load_rig, rig_from_files, save_rig
from stereodic.scan.pipeline import scan_state
from stereodic.scan.views import (fit_turntable, merged_cloud, register_turn, register_turntable, register_views,
                                  turntable_transforms)

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

    merged = merged_cloud(views, reg).point.positions.numpy()
    assert sphere_pf(merged) <= 1.5 * sphere_pf(views[0])   # 4.8 against 4.9 um


# ------------------------------------------------------------------------------------ a whole turn

def _rotation_errors(transforms: np.ndarray) -> np.ndarray:
    """Degrees between each registered rotation and the true one of the simulated turn (view k's points
    into view 0's frame: the part turned back by 360 k / K degrees)."""
    n = len(transforms)
    out = []
    for k, t in enumerate(transforms):
        delta = t[:3, :3] @ turntable_transform(-360.0 * k / n)[:3, :3].T
        out.append(np.degrees(np.arccos(np.clip((np.trace(delta) - 1) / 2, -1, 1))))
    return np.array(out)


def _exact_distance(points: np.ndarray, scene: Scene) -> np.ndarray:
    """(N,) signed distance (mm) of points to the union of the scene's surfaces (the nearest one)."""
    d = np.array([s.distance(points) for s in scene.surfaces])
    return d[np.argmin(np.abs(d), axis=0), np.arange(len(points))]


def _nominal_turn(n: int) -> np.ndarray:
    """A turntable known only nominally: the whole turn in equal steps about an axis 1.1 mm off and
    tilted 0.5 degree from the true one (vertical through the target)."""
    tilt = np.radians(0.5)
    return turntable_transforms(n, TARGET + [1.0, 0.0, 0.5], [np.sin(tilt), 1.0, 0.0])


def test_turntable_transforms_match_the_simulated_turntable():
    """The nominal turn about the simulator's axis is the simulator's own turn (two implementations)."""
    got = turntable_transforms(8, TARGET, [0, 1.0, 0])
    for k in range(8):
        np.testing.assert_allclose(got[k], turntable_transform(-45.0 * k), atol=1e-9)


def test_fit_turntable_recovers_a_known_axis_and_angles():
    """Transforms built as turns about y in a rigid frame tilted and moved anywhere (not by `Turntable`):
    the fitted axis, its point nearest to the one asked for and the angles (unequal, one past 180 degrees)
    are the truth to rounding."""
    frame = Rotation.from_euler("xyz", [25.0, -40.0, 70.0], degrees=True).as_matrix()
    origin = np.array([12.0, -30.0, 410.0])
    angles = np.array([0.0, 37.0, 95.0, 170.0, 181.0, 250.0, 330.0])
    place = np.eye(4)
    place[:3, :3], place[:3, 3] = frame, origin
    transforms = []
    for a in np.radians(-angles):                 # view k's points turned back about the frame's y axis
        turn = np.eye(4)
        turn[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
        transforms.append(place @ turn @ np.linalg.inv(place))
    near = origin + 7.0 * frame[:, 1] + [1.0, 2.0, 3.0]
    table = fit_turntable(np.array(transforms), near_mm=near)
    np.testing.assert_allclose(table.direction, frame[:, 1], atol=1e-12)
    np.testing.assert_allclose(table.angles_deg, angles, atol=1e-9)
    np.testing.assert_allclose(table.point_mm, origin + frame[:, 1] * (frame[:, 1] @ (near - origin)), atol=1e-9)
    np.testing.assert_allclose(table.transforms(), transforms, atol=1e-12)
    backwards = fit_turntable(np.array(transforms)[::-1] @ np.linalg.inv(transforms[-1]))   # the turn reversed
    np.testing.assert_allclose(backwards.direction, -frame[:, 1], atol=1e-12)


SIGMA_MM = 0.002      # the sampled views' noise along the line of sight


def _sampled_view(scene: Scene, rng, *, step_mm: float = 0.8, max_incidence_deg: float = 60.0):
    """What a scanner 400 mm in front of the target sees of `scene`, sampled without the scanner: the
    surface points hit by rays through a grid of `step_mm` at the target, those seen within
    `max_incidence_deg` of their normal, moved by Gaussian noise of SIGMA_MM along the ray; and their true
    normals (towards the scanner)."""
    origin = TARGET + [0, 0, -400.0]
    x, y = np.meshgrid(np.arange(-60, 60, step_mm), np.arange(-60, 60, step_mm))
    d = np.stack([x.ravel(), y.ravel(), np.full(x.size, 400.0)], axis=1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    hit = scene.intersect(np.tile(origin, (len(d), 1)), d)
    keep = np.isfinite(hit.t) & (np.einsum("ij,ij->i", hit.normal, -d) > np.cos(np.radians(max_incidence_deg)))
    points = hit.point[keep] + rng.normal(0, SIGMA_MM, keep.sum())[:, None] * d[keep]
    return points, hit.normal[keep]


def test_whole_turn_registers_closes_and_meshes():
    """6 views of the free-form part all the way round (sampled from its exact surface, 2 um noise),
    started from a nominal turntable 1 mm and 0.5 degree off: every rotation within the issue's 0.02
    degree (measured 0.010: the 0.8 mm sampling's curvature bias, far above the noise's ~0.001), the
    merged cloud within 2 x the noise of the surface (voxel averaging lowers it, registration adds to
    it) and its normals all outwards, as Poisson needs (the slow test meshes it)."""
    rng = np.random.default_rng(1)
    scenes = turntable_scenes(views=6)
    sampled = [_sampled_view(sc, rng) for sc in scenes]
    reg = register_turn([p for p, _ in sampled], initial=_nominal_turn(len(scenes)))
    errors = _rotation_errors(reg.transforms)
    print("rotation errors (degrees)", np.round(errors, 4), "residuals (um)", np.round(1000 * reg.residual_mm, 1))
    assert errors.max() < 0.02
    assert np.all(reg.residual_mm < 5 * SIGMA_MM) and np.all(reg.fitness > 0.5)

    merged = merged_cloud([p for p, _ in sampled], reg, normals=[n for _, n in sampled], voxel_mm=1.0)
    rms = np.sqrt(np.mean(_exact_distance(merged.point.positions.numpy(), scenes[0]) ** 2))
    print(f"merged RMS {1000 * rms:.1f} um")
    assert rms < 2 * SIGMA_MM
    points, h = merged.point.positions.numpy(), 1e-4      # outwards normals (the exact distance's gradient)
    exact = np.stack([_exact_distance(points + h * e, scenes[0]) - _exact_distance(points - h * e, scenes[0])
                      for e in np.eye(3)], axis=1)
    assert np.mean(np.einsum("ij,ij->i", merged.point.normals.numpy(), exact) > 0) > 0.999


def _axis_errors(table) -> tuple[float, float]:
    """(degrees, mm) a fitted turntable axis's tilt from the simulator's (the rotation axis of its quarter
    turn, `turntable_transform`) and its point's distance from it (half what a half turn moves it)."""
    quarter, half = turntable_transform(90.0), turntable_transform(180.0)
    true_axis = Rotation.from_matrix(quarter[:3, :3]).as_rotvec() / (np.pi / 2)
    tilt = np.degrees(np.arccos(np.clip(table.direction @ true_axis, -1, 1)))
    return tilt, np.linalg.norm(half[:3, :3] @ table.point_mm + half[:3, 3] - table.point_mm) / 2


def test_turntable_registration_finds_the_axis_and_angles():
    """The 6 sampled views (2 um noise, their exact normals) from the turntable 1.1 mm and 0.5 degree off:
    the fitted axis is the simulator's (`turntable_transform`: its direction, and its point on the true axis,
    which a half turn leaves in place) and so are the angles (360 k / 6 degrees) and the rotations, with
    one axis for all views ~10 x nearer than `register_turn`'s 6 unknowns per view (0.0096 degree)."""
    rng = np.random.default_rng(1)
    scenes = turntable_scenes(views=6)
    sampled = [_sampled_view(sc, rng) for sc in scenes]
    reg = register_turntable([p for p, _ in sampled], initial=_nominal_turn(len(scenes)),
                             normals=[n for _, n in sampled])
    tilt, across = _axis_errors(reg.turntable)
    angle_errors = reg.turntable.angles_deg - 360.0 * np.arange(6) / 6
    errors = _rotation_errors(reg.transforms)
    print(f"axis {tilt:.5f} deg and {1000 * across:.2f} um off; angle errors (degrees)", np.round(angle_errors, 5),
          "rotation errors", np.round(errors, 5), "residuals (um)", np.round(1000 * reg.residual_mm, 1))
    assert tilt < 0.002 and across < 0.005
    assert np.abs(angle_errors).max() < 0.003
    assert errors.max() < 0.003
    np.testing.assert_allclose(reg.transforms, reg.turntable.transforms())
    assert np.all(reg.residual_mm < 5 * SIGMA_MM) and np.all(reg.fitness > 0.5)


@pytest.mark.slow
def test_whole_turn_of_rendered_scans_merges_within_0p02_degrees(tmp_path):
    """6 rendered scans (640 x 512) of the free-form part with its ball, all the way round, registered as a
    turntable (`register_turntable`) from a nominal one 1.1 mm and 0.5 degree off: the fitted axis and
    rotations against the simulator's (within the issue's 0.02 degree), the object's centre within 20 um,
    the merged ball's form within the issue's 1.5 x one view's (measured 1.38 x; each view's ball is 9-20
    um large in radius, differently from each side: with the TRUE poses it is 1.45 x), and the Poisson mesh
    against the exact surface, covering the data and trimmed where no view looked."""
    scenes = turntable_scenes(views=6)
    simulate_scan(tmp_path, scenes=scenes, rig=default_scan_rig(width=640, height=512))
    save_rig(tmp_path / "rig.npz", rig_from_files(tmp_path / "truth_cam0.npz", tmp_path / "truth_cam1.npz"))
    rig, cap = load_rig(tmp_path / "rig.npz"), load_capture(tmp_path)
    viewpoint = (rig.left.centre + rig.right.centre) / 2
    points, normals = [], []
    for k in range(len(scenes)):
        result, _ = scan_state(rig, cap, k)
        cloud, _ = make_cloud(result.points, {}, viewpoint)
        points.append(cloud.point.positions.numpy().astype(np.float64))
        normals.append(cloud.point.normals.numpy().astype(np.float64))
    reg = register_turntable(points, initial=_nominal_turn(len(scenes)))
    errors = _rotation_errors(reg.transforms)
    shifts = [np.linalg.norm(t[:3, :3] @ TARGET + t[:3, 3] - TARGET) for t in reg.transforms]
    tilt, across = _axis_errors(reg.turntable)
    print(f"axis {tilt:.4f} deg and {1000 * across:.1f} um off; rotation errors (degrees)", np.round(errors, 4),
          "centre shifts (um)", np.round(1000 * np.array(shifts), 1),
          "residuals (um)", np.round(1000 * reg.residual_mm, 1))
    assert errors.max() < 0.02
    assert max(shifts) < 0.02
    assert tilt < 0.01 and across < 0.02

    ball = TARGET + TURNTABLE_BALL[0]

    def ball_pf(p, scene):         # the ball's points 4 mm or more from the blob (not the crease's)
        d = np.array([s.distance(p) for s in scene.surfaces])
        return trimmed_range(fit_sphere(p[(np.abs(d[0]) > 4) & (np.abs(d[1]) < 0.5)]).residuals)

    single = np.median([ball_pf(p, sc) for p, sc in zip(points, scenes)])
    merged = merged_cloud(points, reg, normals=normals)
    pf = ball_pf(merged.point.positions.numpy(), scenes[0])
    print(f"ball PF: merged {1000 * pf:.1f} um, one view (median) {1000 * single:.1f} um; ball {ball}")
    assert pf <= 1.5 * single
    mesh = poisson_mesh(merged, max_gap_mm=1.0)
    vertices = np.asarray(mesh.vertices)
    d = np.abs([s.distance(vertices) for s in scenes[0].surfaces])
    off, crease = d.min(axis=0), d.max(axis=0) < 2.0      # within 2 mm of both the part and the ball
    covered, _ = cKDTree(vertices).query(merged.point.positions.numpy())
    print(f"mesh: median {1000 * np.median(off):.1f} um, 99 % {1000 * np.quantile(off, 0.99):.0f} um "
          f"({1000 * np.quantile(off[~crease], 0.99):.0f} um beyond 2 mm of the ball's crease, "
          f"{100 * crease.mean():.1f} % of the vertices within), "
          f"99 % of the points within {1000 * np.quantile(covered, 0.99):.0f} um of a vertex")
    assert np.median(off) < 0.01                           # the scans' own ~5-10 um view-dependent bias
    assert np.quantile(off[~crease], 0.99) < 0.05          # no balloon (the crease is rounded off: 6 views
                                                           # see less into it, 99 % of all 54 um)
    assert np.quantile(covered, 0.99) < 0.5                # no hole where the data is
