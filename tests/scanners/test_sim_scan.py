"""The simulated scanner: exact ray tracing of the scenes, the projector, shadows, the dataset."""

import json

import numpy as np
import pytest

from calib.capture import Pattern, load_capture
from scanners.sim.projector import make_projector
from scanners.sim.scan import (TARGET, TURNTABLE_LOBES, default_scan_rig, lit_view, load_truth, simulate_scan,
                               standard_scenes)
from scanners.sim.scan_scene import Blob, HeightField, Plane, Scene, Sphere, ball_bar, surface_from_dict


def _rays(n=2000, seed=0):
    rng = np.random.default_rng(seed)
    o = np.tile(TARGET - [0, 0, 400.0], (n, 1))
    d = np.column_stack([rng.uniform(-0.15, 0.15, (n, 2)), np.ones(n)])
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize("surface", [Sphere(centre=TARGET, radius_mm=30.0),
                                     Plane(centre=TARGET, normal=(0.2, 0.1, -1), size_mm=(150, 100)),
                                     HeightField(centre=TARGET, rotation=np.diag([1.0, -1, -1]), half_mm=45.0),
                                     Blob(centre=TARGET, radius_mm=35.0, lobes=TURNTABLE_LOBES)])
def test_hits_lie_on_the_exact_surface(surface):
    o, d = _rays()
    hit = Scene([surface]).intersect(o, d)
    seen = np.isfinite(hit.t)
    assert seen.mean() > 0.1
    assert np.abs(surface.distance(hit.point[seen])).max() < 1e-7
    assert np.all(np.einsum("ij,ij->i", hit.normal[seen], d[seen]) < 0)     # normals face the camera
    again = surface_from_dict(json.loads(json.dumps(surface.describe())))
    assert np.allclose(again.distance(hit.point[seen]), surface.distance(hit.point[seen]))


def test_blob_normals_are_the_gradient_of_its_radius_function():
    """The blob's normals against central differences of r(u) = R (1 + sum a exp(-(1 - u.c) / s^2)),
    written here again, on the surface points r(u) u."""
    lobes = np.array(TURNTABLE_LOBES)
    c = lobes[:, :3] / np.linalg.norm(lobes[:, :3], axis=1, keepdims=True)

    def surface(theta, phi):
        u = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)
        r = 35.0 * (1 + (lobes[:, 4] * np.exp(-(1 - u @ c.T) / lobes[:, 3] ** 2)).sum(axis=-1))
        return TARGET + r[:, None] * u

    rng = np.random.default_rng(2)
    theta, phi, h = rng.uniform(0.3, 2.8, 200), rng.uniform(0, 2 * np.pi, 200), 1e-6
    p = surface(theta, phi)
    n = np.cross(surface(theta + h, phi) - surface(theta - h, phi), surface(theta, phi + h) - surface(theta, phi - h))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    blob = Blob(centre=TARGET, radius_mm=35.0, lobes=lobes)
    assert np.abs(blob.distance(p)).max() < 1e-9
    out = p + 100 * np.sign(np.einsum("ij,ij->i", n, p - TARGET))[:, None] * n        # outside, along the normal
    hit = Scene([blob]).intersect(out, -n * np.sign(np.einsum("ij,ij->i", n, p - TARGET))[:, None])
    near = np.linalg.norm(hit.point - p, axis=1) < 1e-5     # rays whose first hit is that point
    assert near.mean() > 0.8
    assert np.abs(np.abs(np.einsum("ij,ij->i", hit.normal[near], n[near])) - 1).max() < 1e-8


def test_nearest_surface_occludes_and_ball_bar_length():
    spheres = ball_bar(TARGET, (1, 0.5, 0.2), length_mm=150.0, radius_mm=12.5)
    assert np.linalg.norm(spheres[0].centre - spheres[1].centre) == pytest.approx(150.0)
    front = Sphere(centre=TARGET - [0, 0, 50.0], radius_mm=20.0)
    back = Plane(centre=TARGET, normal=(0, 0, -1), size_mm=(400, 400))
    o = np.array([TARGET - [0, 0, 400.0]])
    d = np.array([[0.0, 0.0, 1.0]])
    hit = Scene([back, front]).intersect(o, d)
    assert hit.surface[0] == 1 and hit.point[0, 2] == pytest.approx(TARGET[2] - 70.0)


def test_projector_projects_its_axis_to_the_panel_centre_and_emits_the_8bit_fringe():
    p = make_projector(TARGET, width_px=1280, height_px=800)
    c, r, cos_field = p.project(TARGET[None])
    assert c[0] == pytest.approx(639.5, abs=1e-9) and r[0] == pytest.approx(399.5, abs=1e-9)
    assert cos_field[0] == pytest.approx(1.0)
    pat = Pattern("fringe", {"axis": "x", "period_px": 16, "shift_rad": 0.0, "low": 10, "high": 250})
    cols = np.array([0.0, 4.0, 8.0])
    code = np.rint(10 + 120 * (1 + np.cos(2 * np.pi * cols / 16)))
    assert np.allclose(p.emission(pat, cols), p.luminance(code), rtol=1e-6)
    assert p.emission(pat, np.array([np.nan]))[0] == 0


def test_sphere_shadows_the_plate_behind_it():
    rig = default_scan_rig(width=96, height=80, supersample=1)
    cam = rig.cameras(0)[0]
    scene = standard_scenes(objects=("sphere",))[0]
    view = lit_view(cam, scene, rig.projector)
    sphere, plate = scene.surfaces
    plate_pts = np.isclose(view.points[..., 2], plate.centre[2])
    # a plate point whose segment to the projector passes through the sphere is not lit
    p = view.points[plate_pts]
    blocked = scene.blocked(p - [0, 0, 1e-4], rig.projector.centre_mm)
    unlit = np.isnan(view.c[plate_pts])             # supersample 1: one sub-sample per pixel
    assert blocked.sum() > 20
    assert np.array_equal(blocked & ~unlit, np.zeros_like(blocked))


def test_simulated_scan_dataset_is_complete(tmp_path):
    rig = default_scan_rig(width=64, height=48, supersample=1)
    cap = simulate_scan(tmp_path, scenes=standard_scenes(objects=("plane",))[:2], rig=rig,
                        periods=(1280, 160, 32), steps=4)
    cap = load_capture(tmp_path)
    assert cap.kind == "scan" and cap.states("cam0") == [0, 1]
    assert len(cap.frames) == 2 * 2 * 3 * 4
    assert cap.extra["projector"]["periods_px"] == [1280, 160, 32] and cap.extra["projector"]["steps"] == 4
    truth = load_truth(tmp_path)
    assert truth["states"][1]["surfaces"][0]["type"] == "plane"
    assert (tmp_path / "truth_cam0.npz").is_file() and not (tmp_path / "rig.npz").exists()


def test_steps_may_differ_per_period(tmp_path):
    from calib.errors import InputError
    from scanners.sim.scan import steps_per_period
    rig = default_scan_rig(width=48, height=32, supersample=1)
    cap = simulate_scan(tmp_path, scenes=standard_scenes(objects=("plane",))[:1], rig=rig,
                        periods=(1280, 160, 32), steps=[3, 4, 6])
    per = {p: sum(1 for f in cap.frames if f.camera == "cam0" and f.pattern.period_px == p) for p in (1280, 160, 32)}
    assert per == {1280: 3, 160: 4, 32: 6} and cap.extra["projector"]["steps"] == [3, 4, 6]
    assert steps_per_period((1280, 120, 8), None) == [3, 3, 16]
    for bad in ([3, 4], [3, 2, 5], 2.5):
        with pytest.raises(InputError, match="steps"):
            steps_per_period((1280, 160, 32), bad)
