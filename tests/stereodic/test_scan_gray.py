"""Gray-code scans: the simulated scanner's sphere with Gray code alone and Gray code plus phase shifting
against its exact surface, bad Gray-code input, and the real statue scans (OpenCV's GrayCodePattern,
JPEG images) against OpenCV's own decoding of the same images."""

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from calib.capture import load_capture
from scanners.sim.scan import default_scan_rig, load_truth, simulate_scan, standard_scenes
from scanners.sim.scan_scene import surface_from_dict
from stereodic.cli import main
from stereodic.scan.fit import fit_sphere, trimmed_range
from stereodic.stereo.rig import load_rig, rig_from_files, save_rig
from stereodic.scan.pipeline import scan_state

STATUE = Path(__file__).resolve().parents[3] / "shared" / "data" / "gsoc-statue-graycode"


def _simulate(folder, **kw):
    simulate_scan(folder, scenes=standard_scenes(objects=("sphere",))[:1], rig=default_scan_rig(width=320, height=256),
                  **kw)
    save_rig(folder / "rig.npz", rig_from_files(folder / "truth_cam0.npz", folder / "truth_cam1.npz"))
    return folder


@pytest.fixture(scope="module")
def gray_only(tmp_path_factory):
    return _simulate(tmp_path_factory.mktemp("gray"), periods=(), gray=True)


@pytest.fixture(scope="module")
def gray_phase(tmp_path_factory):
    return _simulate(tmp_path_factory.mktemp("grayps"), periods=(32,), steps=16, gray=True)


def _sphere_fit(folder):
    result, _ = scan_state(load_rig(folder / "rig.npz"), load_capture(folder), 0)
    sphere = surface_from_dict(load_truth(folder)["states"][0]["surfaces"][0])
    on = result.points[np.abs(sphere.distance(result.points)) < 0.5]
    return sphere, on, fit_sphere(on)


def test_gray_code_and_phase_shifting_measure_the_sphere(gray_phase):
    # 320-px cameras, 32-px fringes (7 camera pixels a period), 16 steps, Gray code down to 16-px stripes:
    # the multi-period fringe scan of the same sphere gives PF ~16 um, radius within 20 um
    sphere, on, fit = _sphere_fit(gray_phase)
    assert len(on) > 1200
    assert fit.radius_mm == pytest.approx(sphere.radius_mm, abs=0.03)
    assert np.linalg.norm(fit.centre - sphere.centre) < 0.05
    assert trimmed_range(fit.residuals) < 0.03


def test_gray_code_alone_measures_the_sphere_coarsely(gray_only):
    # one projector column is ~1.4 camera pixels: the stairs, smoothed by the phase filter, leave ~0.1 mm
    sphere, on, fit = _sphere_fit(gray_only)
    assert len(on) > 600
    assert fit.radius_mm == pytest.approx(sphere.radius_mm, abs=0.05)
    assert trimmed_range(fit.residuals) < 0.25


def _edited(folder, tmp_path, keep):
    copy = tmp_path / "edited"
    shutil.copytree(folder, copy)
    m = json.loads((copy / "capture.json").read_text())
    m["frames"] = [f for f in m["frames"] if keep(f)]
    (copy / "capture.json").write_text(json.dumps(m))
    return copy


@pytest.mark.parametrize("drop, message", [
    (lambda p: p["type"] == "gray" and p["bit"] == 6, "bit(s) 6 missing"),
    (lambda p: p["type"] == "gray" and p["bit"] == 4 and p["inverse"], "bit(s) 4 lack their inverse"),
])
def test_a_gray_code_missing_a_bit_or_an_inverse_is_named(gray_phase, tmp_path, capsys, drop, message):
    copy = _edited(gray_phase, tmp_path, lambda f: not (f["camera"] == "cam1" and drop(f["pattern"])))
    assert main(["scan", str(gray_phase / "rig.npz"), str(copy), "-o", str(tmp_path / "c.ply")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "capture.json" in err[0] and "'cam1'" in err[0] and message in err[0]
    assert not (tmp_path / "c.ply").exists()


def test_an_opencv_folder_missing_an_image_is_named(tmp_path, capsys):
    folder = tmp_path / "opencv"
    folder.mkdir()
    for cam in (1, 2):
        for i in range(1, 45):
            if (cam, i) != (2, 17):
                cv2.imwrite(str(folder / f"pattern_cam{cam}_im{i}.png"), np.zeros((24, 32), np.uint8))
    rig = tmp_path / "rig.npz"
    save_rig(rig, _statue_like_rig(tmp_path))
    assert main(["scan", str(rig), str(folder), "--projector", "1280x800", "-o", str(tmp_path / "c.ply")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "lacks image 17 of the series pattern_cam2_im*" in err[0] and "(x bit 2:" in err[0]


def _statue_like_rig(tmp_path):
    """A 32 x 24 rig of two pinhole cameras, for input checks that stop before the images are read."""
    fs = cv2.FileStorage(str(tmp_path / "pair.yml"), cv2.FILE_STORAGE_WRITE)
    k = np.array([[40.0, 0, 15.5], [0, 40.0, 11.5], [0, 0, 1]])
    for key, value in (("M1", k), ("D1", np.zeros(5)), ("M2", k), ("D2", np.zeros(5)), ("R", np.eye(3)),
                       ("T", np.array([-100.0, 0, 0])), ("image_size", np.array([32.0, 24.0]))):
        fs.write(key, value)
    fs.release()
    assert main(["import", str(tmp_path / "pair.yml"), "-o", str(tmp_path / "pair.npz")]) == 0
    return load_rig(tmp_path / "pair.npz")


def test_patterns_command_writes_opencvs_sequence(tmp_path):
    assert main(["patterns", "--display", "1280x800", "--gray", "-o", str(tmp_path)]) == 0
    manifest = json.loads((tmp_path / "patterns.json").read_text())
    ok, reference = cv2.structured_light.GrayCodePattern.create(1280, 800).generate()
    files = [e["file"] for e in manifest["patterns"]]
    assert len(files) == 44
    for name, ref in zip(files, reference):
        assert np.array_equal(cv2.imread(str(tmp_path / name), cv2.IMREAD_GRAYSCALE), ref), name


# ------------------------------------------------------------------------------------- the real statue

def _opencv_cloud(side: str) -> np.ndarray:
    """OpenCV's structured-light pipeline on the same images (its pointcloud sample): rectify with the
    file's R1 P1 R2 P2, GrayCodePattern.decode, reprojectImageTo3D with Q; (N, 3) points in camera 1's frame."""
    fs = cv2.FileStorage(str(STATUE / "calibrationParameters.yml"), cv2.FILE_STORAGE_READ)
    node = lambda k: fs.getNode(k).mat()  # noqa: E731
    size = (1920, 1280)
    maps = [cv2.initUndistortRectifyMap(node(f"cam{c}_intrinsics"), node(f"cam{c}_distorsion"), node(f"R{c}"),
                                        node(f"P{c}"), size, cv2.CV_32FC1) for c in (1, 2)]

    def image(cam, i):
        img = cv2.imread(str(STATUE / side / f"pattern_cam{cam}_im{i}.jpg"), cv2.IMREAD_GRAYSCALE)
        return cv2.remap(img, *maps[cam - 1], cv2.INTER_NEAREST)

    patterns = [[image(c, i) for i in range(1, 43)] for c in (1, 2)]
    white, black = [image(c, 43) for c in (1, 2)], [image(c, 44) for c in (1, 2)]
    code = cv2.structured_light.GrayCodePattern.create(1280, 800)
    code.setWhiteThreshold(5)                                   # the sample's thresholds
    code.setBlackThreshold(40)
    ok, disparity = code.decode(patterns, blackImages=black, whiteImages=white,
                                flags=cv2.structured_light.DECODE_3D_UNDERWORLD)
    assert ok
    xyz = cv2.reprojectImageTo3D(disparity.astype(np.float32), node("Q"), handleMissingValues=True)
    good = (disparity > 0) & np.isfinite(xyz).all(axis=-1) & (np.abs(xyz[..., 2]) < 1e4)
    return xyz[good].astype(np.float64) @ node("R1")         # rectified -> camera 1: x1 = R1^T x_rect


def _patch_noise(points: np.ndarray, k: np.ndarray, box, tile_px: int = 16) -> dict:
    """RMS residual (mm) of the plane fitted to the points of each tile_px x tile_px tile of camera 1's
    image inside `box` (x0, y0, x1, y1 pixels), tiles with 30 points or more."""
    uv = points @ k.T
    uv = uv[:, :2] / uv[:, 2:]
    x0, y0, x1, y1 = box
    inside = (uv[:, 0] >= x0) & (uv[:, 0] < x1) & (uv[:, 1] >= y0) & (uv[:, 1] < y1)
    key = ((uv[inside, 1] - y0) // tile_px).astype(int) * 10_000 + ((uv[inside, 0] - x0) // tile_px).astype(int)
    order = np.argsort(key)
    key, pts = key[order], points[inside][order]
    cuts = np.flatnonzero(np.diff(key)) + 1
    out = {}
    for name, group in zip(key[np.r_[0, cuts]], np.split(pts, cuts)):
        if len(group) >= 30:
            out[name] = np.linalg.svd(group - group.mean(axis=0), compute_uv=False)[-1] / np.sqrt(len(group))
    return out


@pytest.mark.slow
@pytest.mark.skipif(not STATUE.is_dir(), reason="the statue dataset is not on this machine")
def test_statue_scan_covers_more_and_is_smoother_than_opencvs_decoding(tmp_path):
    """JPEG-compressed real scans: a robustness test, not an accuracy one (no ground truth). Coverage and
    local noise (planes fitted in ~11 mm patches of the smooth torso and of the flat wall) against
    OpenCV's decoding of the same images."""
    import open3d as o3d
    rig = tmp_path / "rig.npz"
    assert main(["import", str(STATUE / "calibrationParameters.yml"), "-o", str(rig)]) == 0
    assert main(["scan", str(rig), str(STATUE / "statue_front_side"), "--projector", "1280x800",
                 "-o", str(tmp_path / "front.ply")]) == 0
    ours = np.asarray(o3d.io.read_point_cloud(str(tmp_path / "front.ply")).points)
    reference = _opencv_cloud("statue_front_side")
    assert len(ours) >= len(reference)                                 # 946 k against 714 k
    fs = cv2.FileStorage(str(STATUE / "calibrationParameters.yml"), cv2.FILE_STORAGE_READ)
    k1 = fs.getNode("cam1_intrinsics").mat()
    for box in ((260, 300, 640, 900), (1000, 100, 1350, 700)):       # torso, wall (camera 1 pixels)
        a, b = _patch_noise(ours, k1, box), _patch_noise(reference, k1, box)
        common = sorted(set(a) & set(b))
        assert len(common) > 0.9 * len(b)
        assert np.median([a[t] for t in common]) <= np.median([b[t] for t in common])   # 0.11 vs 0.35 mm
    # the torso stands before the wall (the calibration's R, T read as camera 2's pose in camera 1's frame)
    uv = ours @ k1.T
    uv = uv[:, :2] / uv[:, 2:]
    depth = lambda x0, y0, x1, y1: np.median(ours[(uv[:, 0] >= x0) & (uv[:, 0] < x1) & (uv[:, 1] >= y0)  # noqa: E731
                                                 & (uv[:, 1] < y1), 2])
    assert depth(260, 300, 640, 900) < depth(1000, 100, 1350, 700) - 200


# ------------------------------------------------------------------------------ clipped highlights

@pytest.fixture(scope="module")
def glossy(tmp_path_factory):
    """A sphere with a specular lobe whose highlight clips in the brightest frames (~0.4 % of the
    pixels), 8 steps on every period (so that clipped pixels keep 3 or more unclipped samples)."""
    from scanners.sim.scan import TARGET, _background
    from scanners.sim.scan_scene import Scene, Sphere
    sphere = Sphere(centre=TARGET + [10.0, 5.0, 0], radius_mm=25.0, albedo=0.5, texture=0.1, specular=2.0,
                    shininess=30.0)
    out = tmp_path_factory.mktemp("glossy")
    simulate_scan(out, scenes=[Scene([sphere, _background()], "glossy sphere")],
                  rig=default_scan_rig(width=320, height=256), steps=8)
    save_rig(out / "rig.npz", rig_from_files(out / "truth_cam0.npz", out / "truth_cam1.npz"))
    return out


def test_a_clipped_highlight_does_not_bend_the_sphere(glossy):
    # pixels with clipped samples solved from the unclipped ones (and their neighbours, which the blur
    # mixes with the highlight) put points 12-18 um off the true sphere (range 30 um); dropped, 7 um
    cap = load_capture(glossy)
    assert max((cap.read(f) == 255).mean() for f in cap.frames) > 0.002
    result, _ = scan_state(load_rig(glossy / "rig.npz"), cap, 0)
    sphere = surface_from_dict(load_truth(glossy)["states"][0]["surfaces"][0])
    d = sphere.distance(result.points)
    on = d[np.abs(d) < 0.5]
    assert len(on) > 100
    assert trimmed_range(on) < 0.012


# ------------------------------------------------------------------------- several exposures (HDR)

def _sphere_scan(folder, surface_kw, exposures=(1.0,)):
    from scanners.sim.scan import TARGET, _background
    from scanners.sim.scan_scene import Scene, Sphere
    sphere = Sphere(centre=TARGET + [10.0, 5.0, 0], radius_mm=25.0, **surface_kw)
    simulate_scan(folder, scenes=[Scene([sphere, _background()], "sphere")],
                  rig=default_scan_rig(width=320, height=256), exposures=exposures)
    save_rig(folder / "rig.npz", rig_from_files(folder / "truth_cam0.npz", folder / "truth_cam1.npz"))
    result, _ = scan_state(load_rig(folder / "rig.npz"), load_capture(folder), 0)
    on = result.points[np.abs(sphere.distance(result.points)) < 0.5]
    return on, fit_sphere(on) if len(on) > 10 else None


EXPOSURES = (4.0, 1.0, 0.25)


@pytest.mark.slow
def test_several_exposures_recover_a_metal_part_and_a_dark_one(tmp_path):
    matte, matte_fit = _sphere_scan(tmp_path / "matte", dict(albedo=0.3, texture=0.1))
    metal = dict(albedo=0.3, texture=0.1, specular=2.0, shininess=30.0)      # the same, with a specular lobe
    glint, _ = _sphere_scan(tmp_path / "metal1", metal)
    hdr, hdr_fit = _sphere_scan(tmp_path / "metal3", metal, EXPOSURES)
    # one exposure loses the highlight (clipped) and the 8-px filter band around it: 8 % of the sphere
    assert len(glint) < 0.3 * len(matte)
    assert len(hdr) >= 0.98 * len(matte)                                     # 1358 of 1358
    matte_pf = trimmed_range(matte_fit.residuals)
    assert trimmed_range(hdr_fit.residuals) <= 1.5 * matte_pf               # 26.9 against 23.2 um
    dark, dark_fit = _sphere_scan(tmp_path / "dark3", dict(albedo=0.1), EXPOSURES)
    # 3.5 x darker than the plate behind it, but lit: its fringes are weak and sharp, not a shadow's
    assert len(dark) >= 0.97 * len(matte)                                    # 1375 of 1358
    assert trimmed_range(dark_fit.residuals) <= 1.5 * matte_pf              # 22.7 um
    assert abs(dark_fit.radius_mm - 25.0) <= 0.03                           # +11 um
    # and the sphere's shadow on the plate stays empty: no plate point whose way to the projector passes
    # through the sphere more than 1 mm inside its rim
    from scanners.sim.scan import TARGET
    cloud, _ = scan_state(load_rig(tmp_path / "dark3" / "rig.npz"), load_capture(tmp_path / "dark3"), 0)
    plate = cloud.points[np.abs(cloud.points[:, 2] - (TARGET[2] + 60.0)) < 0.5]
    to = default_scan_rig(width=320, height=256).projector.centre_mm - plate
    centre = TARGET + [10.0, 5.0, 0]
    along = np.clip(np.einsum("ij,ij->i", centre - plate, to) / np.einsum("ij,ij->i", to, to), 0, 1)
    miss = np.linalg.norm(plate + along[:, None] * to - centre, axis=1)       # the segment's nearest approach
    assert len(plate) > 10000 and (miss < 25.0 - 1.0).sum() == 0


def test_exposures_that_do_not_match_are_an_error(tmp_path, capsys):
    from scanners.sim.scan import TARGET
    from scanners.sim.scan_scene import Plane, Scene
    out = tmp_path / "hdr"
    simulate_scan(out, scenes=[Scene([Plane(centre=TARGET, normal=(0, 0, -1), size_mm=(100, 80))], "plate")],
                  rig=default_scan_rig(width=32, height=24, supersample=1), periods=(1280, 160), steps=3,
                  exposures=(1.0, 0.5))
    save_rig(out / "rig.npz", rig_from_files(out / "truth_cam0.npz", out / "truth_cam1.npz"))
    m = json.loads((out / "capture.json").read_text())
    m["frames"] = [f for f in m["frames"] if not (f["camera"] == "cam0" and f.get("exposure_ms") == 5.0
                                                   and f["pattern"]["period_px"] == 160
                                                   and f["pattern"]["shift_rad"] == 0)]
    (out / "capture.json").write_text(json.dumps(m))
    assert main(["scan", str(out / "rig.npz"), str(out), "-o", str(tmp_path / "c.ply")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exposures of period 160 px do not match" in err[0] and "2 at 5 ms" in err[0]


@pytest.mark.skipif(not STATUE.is_dir(), reason="the statue dataset is not on this machine")
def test_statue_calibration_reads_as_it_is():
    from stereodic.formats import read_calibration
    fmt, (one, two) = read_calibration([STATUE / "calibrationParameters.yml"])
    fs = cv2.FileStorage(str(STATUE / "calibrationParameters.yml"), cv2.FILE_STORAGE_READ)
    assert fmt == "opencv" and (one.width, one.height) == (two.width, two.height) == (1920, 1280)
    assert one.fx == fs.getNode("cam1_intrinsics").mat()[0, 0] and two.cx == fs.getNode("cam2_intrinsics").mat()[0, 2]
    assert np.allclose(one.R, np.eye(3)) and np.allclose(one.t, 0)
    # R, T: camera 2's pose in camera 1's frame (x1 = R x2 + T), so camera 2's centre is T
    assert np.allclose(-two.R.T @ two.t, fs.getNode("T").mat().ravel())
    assert np.allclose(two.R, fs.getNode("R").mat().T)
