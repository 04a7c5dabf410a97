"""The structured-light scan: phase in the virtual images, 1-D matching, triangulation, the cloud, the
command line and bad input; checked against the simulated scanner's exact surfaces."""

import json
import shutil

import numpy as np
import pytest

from calib.capture import load_capture
from calib.errors import InputError
from stereodic.scan.pipeline import scan_state
from scanners.sim.scan import TARGET, default_scan_rig, load_truth, simulate_scan, standard_scenes
from scanners.sim.scan_scene import Plane, Scene, Sphere, surface_from_dict
from stereodic.cli import main
from stereodic.scan.fit import fit_plane, fit_sphere, trimmed_range
from stereodic.scan.matching import match_rows
from stereodic.stereo.rig import load_rig, rig_from_files, save_rig

PERIODS = (1280, 160, 32)       # a 320-pixel camera sees ~7 pixels per 32-px fringe


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Noisy 320 x 256 scans: the sphere before its plate, a plate, a sphere outside the field."""
    out = tmp_path_factory.mktemp("scan")
    scenes = standard_scenes(objects=("sphere",))[:1] + standard_scenes(objects=("plane",))[:1]
    scenes.append(Scene([Sphere(centre=TARGET + [500.0, 0, 0], radius_mm=25.0)], "outside"))
    simulate_scan(out, scenes=scenes, rig=default_scan_rig(width=320, height=256), periods=PERIODS)
    save_rig(out / "rig.npz", rig_from_files(out / "truth_cam0.npz", out / "truth_cam1.npz"))
    return out


@pytest.fixture(scope="module")
def noise_free(tmp_path_factory):
    out = tmp_path_factory.mktemp("clean")
    simulate_scan(out, scenes=[Scene([Plane(centre=TARGET, normal=(0.2, 0.1, -1), size_mm=(180, 120))], "plate")],
                  rig=default_scan_rig(width=320, height=256), periods=PERIODS, noise=False)
    save_rig(out / "rig.npz", rig_from_files(out / "truth_cam0.npz", out / "truth_cam1.npz"))
    return out


def _objects(folder, state):
    return [surface_from_dict(s) for s in load_truth(folder)["states"][state]["surfaces"]]


def test_plane_scan_lies_on_the_true_plane(dataset):
    result, _ = scan_state(load_rig(dataset / "rig.npz"), load_capture(dataset), 1)
    assert np.isfinite(result.points).all() and len(result.points) > 5000
    plane = _objects(dataset, 1)[0]
    d = plane.distance(result.points)
    assert abs(np.median(d)) < 0.01                           # no bias beyond 10 um
    assert np.sqrt(np.mean(d ** 2)) < 0.1                     # 0.7 mm pixels, 8 mm fringes, 8-bit noise
    assert trimmed_range(fit_plane(result.points).residuals) < 0.6
    assert np.all((result.quality > 0) & (result.quality <= 1))


def test_sphere_scan_gives_the_true_radius(dataset):
    result, _ = scan_state(load_rig(dataset / "rig.npz"), load_capture(dataset), 0)
    sphere, plate = _objects(dataset, 0)
    on_sphere = result.points[np.abs(sphere.distance(result.points)) < 0.5]
    on_plate = np.abs(plate.distance(result.points)) < 0.5
    assert len(on_sphere) > 1200 and on_plate.sum() > 5000       # an 80-px disc less the filter's 8-px rim
    fit = fit_sphere(on_sphere)
    assert fit.radius_mm == pytest.approx(sphere.radius_mm, abs=0.05)
    assert np.linalg.norm(fit.centre - sphere.centre) < 0.05
    # few points far from both true surfaces: the checks reject most of the occlusion edges (what is left
    # are pixels mixing sphere and plate on the silhouette, for the cloud's outlier removal)
    far = np.minimum(np.abs(sphere.distance(result.points)), np.abs(plate.distance(result.points))) > 2.0
    assert far.mean() < 0.01


def test_matches_are_sub_pixel_against_the_true_correspondence(noise_free):
    rig = load_rig(noise_free / "rig.npz")
    result, _ = scan_state(rig, load_capture(noise_free), 0)
    plane = _objects(noise_free, 0)[0]
    # the true point: the left virtual pixel's ray (model-less) meets the true plane; the true right match
    # is where the right camera's centre -> point line crosses the common plane (central lenses)
    from stereodic.stereo.triangulate import rays_at
    o, d = rays_at(rig, "left", result.x_left, result.row.astype(float))
    t = ((plane.centre - o) @ plane.normal) / (d @ plane.normal)
    x = o + t[:, None] * d
    uv = rig.sensor.intersect(np.broadcast_to(rig.right.centre, x.shape), x - rig.right.centre)
    err = result.x_right - uv[:, 0]
    assert np.abs(np.median(err)) < 0.01
    assert np.sqrt(np.mean(err ** 2)) < 0.03
    assert np.abs(uv[:, 1] - result.row).max() < 1e-3          # the true match lies on the same row


def test_match_rows_interpolates_and_checks():
    x = np.arange(200, dtype=np.float64)
    left = np.tile(0.8 * x, (4, 1)).astype(np.float32)
    right = np.tile(0.8 * (x + 12.25), (4, 1)).astype(np.float32)
    right[1, 100:110] = right[1, 100:110][::-1]              # a non-monotonic segment
    right[2, 50:60] = np.nan                                   # a hole
    xr = match_rows(left, right)
    assert np.allclose(xr[0, 20:180], x[20:180] - 12.25, atol=1e-4)
    assert np.isnan(xr[0, :12]).all()                          # phases the right row never reaches
    bad = (left[1] >= right[1, 99]) & (left[1] <= right[1, 110])
    assert np.isnan(xr[1][bad]).all() and np.isfinite(xr[1][~bad & (x > 15) & (x < 198)]).all()
    assert np.isnan(xr[2][(left[2] > right[2, 49]) & (left[2] < right[2, 60])]).all()
    # decreasing phase along the rows is matched the same way
    assert np.allclose(match_rows(-left, -right)[0, 20:180], x[20:180] - 12.25, atol=1e-4)


def test_fits_recover_known_shapes():
    rng = np.random.default_rng(0)
    v = rng.normal(size=(500, 3))
    v[:, 2] = -np.abs(v[:, 2])
    pts = [1.0, 2.0, 3.0] + 12.5 * v / np.linalg.norm(v, axis=1, keepdims=True)
    fit = fit_sphere(pts)
    assert fit.radius_mm == pytest.approx(12.5, abs=1e-9) and np.allclose(fit.centre, [1, 2, 3], atol=1e-9)
    plane = fit_plane(np.column_stack([rng.random((100, 2)), np.zeros(100)]) + [0, 0, 5])
    assert abs(plane.normal[2]) == pytest.approx(1.0) and trimmed_range(plane.residuals, keep=1.0) < 1e-12


def test_cli_writes_float32_ply_with_normals_and_quality(dataset, tmp_path):
    import open3d as o3d
    out = tmp_path / "plate.ply"
    assert main(["scan", str(dataset / "rig.npz"), str(dataset), "--state", "1", "-o", str(out)]) == 0
    header = out.read_bytes()[:600].split(b"end_header")[0].decode()
    assert "binary_little_endian" in header
    for prop in ("x", "y", "z", "nx", "ny", "nz", "quality", "gap_mm"):
        assert f"property float {prop}\n" in header
    cloud = o3d.t.io.read_point_cloud(str(out))
    pts = cloud.point.positions.numpy()
    assert len(pts) > 5000 and np.isfinite(pts).all()
    plane = _objects(dataset, 1)[0]
    assert np.abs(plane.distance(pts.astype(np.float64))).max() < 1.0       # outliers removed
    n = cloud.point.normals.numpy()
    assert np.median(n @ plane.normal) > 0.99 or np.median(n @ plane.normal) < -0.99


def test_object_outside_the_common_field_is_a_clear_error(dataset, capsys, tmp_path):
    assert main(["scan", str(dataset / "rig.npz"), str(dataset), "--state", "2", "-o", str(tmp_path / "x.ply")]) == 2
    err = capsys.readouterr().err
    assert str(dataset) in err and "common field of view" in err and err.count("\n") == 1
    assert not (tmp_path / "x.ply").exists()


def _edited(dataset, tmp_path, edit):
    copy = tmp_path / "ds"
    shutil.copytree(dataset, copy)
    manifest = json.loads((copy / "capture.json").read_text())
    edit(manifest)
    (copy / "capture.json").write_text(json.dumps(manifest))
    return copy


def test_missing_patterns_are_named(dataset, tmp_path, capsys):
    def drop(m):   # two of the three shifts of the 32-px fringe of cam1 in state 1
        keep = [f for f in m["frames"] if not (f["camera"] == "cam1" and f["state"] == 1
                                               and f["pattern"]["period_px"] == 32 and f["pattern"]["shift_rad"] != 0)]
        m["frames"] = keep
    copy = _edited(dataset, tmp_path, drop)
    assert main(["scan", str(dataset / "rig.npz"), str(copy), "--state", "1", "-o", str(tmp_path / "c.ply")]) == 2
    err = capsys.readouterr().err
    assert "capture.json" in err and "period 32" in err and "fewer than 3" in err
    assert not (tmp_path / "c.ply").exists()


def test_periods_that_differ_from_the_projector_block_are_an_error(dataset, tmp_path, capsys):
    def change(m):
        m["projector"]["periods_px"] = [1280, 128, 32]
    copy = _edited(dataset, tmp_path, change)
    assert main(["scan", str(dataset / "rig.npz"), str(copy), "-o", str(tmp_path / "c.ply")]) == 2
    err = capsys.readouterr().err
    assert "capture.json" in err and "periods_px" in err and "[32, 160, 1280]" in err


def test_wrong_inputs_exit_2(dataset, tmp_path, capsys):
    assert main(["scan", str(dataset / "truth_cam0.npz"), str(dataset), "-o", str(tmp_path / "c.ply")]) == 2
    assert "truth_cam0.npz" in capsys.readouterr().err
    with pytest.raises(InputError, match="no state 7"):
        from stereodic.scan.pipeline import scan_to_files
        scan_to_files(load_rig(dataset / "rig.npz"), dataset, tmp_path / "c.ply", states=[7])


@pytest.mark.parametrize("options, message", [
    (["DATASET", "--merge"], "--merge: merges the states of one dataset, got 2"),
    (["--turntable", "1,2,3,0,1,0"], "--turntable: goes with --merge"),
    (["--merge", "--turntable", "1,2,3"], "--turntable: need a point and a non-zero direction"),
    (["--merge", "--turntable", "1,2,3,0,0,0"], "--turntable: need a point and a non-zero direction"),
    (["--merge", "--state", "1"], "merging needs two views or more")])
def test_bad_merge_options_exit_2_with_one_line(dataset, tmp_path, capsys, options, message):
    options = [str(dataset) if o == "DATASET" else o for o in options]
    out = tmp_path / "merged.ply"
    assert main(["scan", str(dataset / "rig.npz"), str(dataset), *options, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1 and not out.exists()


def test_steps_per_period_are_checked_against_the_projector_block(dataset, tmp_path, capsys):
    manifest = json.loads((dataset / "capture.json").read_text())
    assert manifest["projector"]["steps"] == [3, 3, 16]          # the default: 16 steps on the finest period
    def change(m):
        m["projector"]["steps"] = [3, 3, 12]
    copy = _edited(dataset, tmp_path, change)
    assert main(["scan", str(dataset / "rig.npz"), str(copy), "--state", "1", "-o", str(tmp_path / "c.ply")]) == 2
    err = capsys.readouterr().err
    assert "period 32 px has 16 frames" in err and "[3, 3, 12]" in err


def test_phase_filter_removes_the_silhouettes_mixed_pixels(dataset):
    """Unfiltered, pixels mixing sphere and plate on the silhouette give points between them; the filter's
    continuity mask drops them, and the filtered points lie closer to the truth."""
    rig, cap = load_rig(dataset / "rig.npz"), load_capture(dataset)
    sphere, plate = _objects(dataset, 0)
    spread = {}
    for smooth in (0.0, 1.0):
        result, _ = scan_state(rig, cap, 0, smooth_px=smooth)
        d = np.minimum(np.abs(sphere.distance(result.points)), np.abs(plate.distance(result.points)))
        spread[smooth] = ((d > 2.0).mean(), np.sqrt(np.mean(d[d < 0.5] ** 2)))
    assert spread[1.0][0] < spread[0.0][0] / 3
    assert spread[1.0][1] < 0.75 * spread[0.0][1]      # sigma 1: white noise / 2.2, less on interpolated phase
