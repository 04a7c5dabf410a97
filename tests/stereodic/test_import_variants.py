"""`stereodic import` on the layouts real calibration files have, each written here in its program's own
layout (OpenCV's FileStorage with the key names of OpenCV's tutorial, samples and cv2.fisheye scripts; ROS
camera_info as camera_calibration_parsers writes it; Kalibr's camchain-imucam with OpenCV's %YAML line),
each camera's rays held against an independent implementation of its model (cv2.projectPoints,
cv2.fisheye.projectPoints, the model's equations written here), and the models that fold (no ray may lie
beyond the first fold) and the flags that must be read or refused."""

import cv2
import numpy as np
import pytest

from calib.camera_models import pixel_grid, transform
from stereodic.cli import main
from stereodic.formats import import_calibration

W, H = 160, 120
K = np.array([[150.0, 0.0, 79.3], [0.0, 151.0, 60.2], [0.0, 0.0, 1.0]])


def _fs(path, items):
    """A FileStorage file written by OpenCV itself, with the given key names."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for k, v in items:
        fs.write(k, v)
    fs.release()
    return path


def _world_points(prvm, z):
    """(N, 3) file-frame points of every valid pixel's ray at internal depth z, and those pixels (N, 2)."""
    v, u = np.nonzero(prvm.valid)
    return transform(np.asarray(prvm.meta["world_from_rig"]), prvm.at_z(z)[v, u]), np.stack([u, v], -1)


def _worst_px(prvm, project, depths=(200.0, 700.0)):
    """Largest distance (px) between the pixels and `project` (file-frame points -> pixels) of their rays."""
    err = 0.0
    for z in depths:
        p, uv = _world_points(prvm, z)
        err = max(err, np.abs(project(p) - uv).max())
    return err


def _pinhole(dist, rvec=np.zeros(3), tvec=np.zeros(3), k=K):
    return lambda p: cv2.projectPoints(p, rvec, tvec, k, np.asarray(dist, float))[0].reshape(-1, 2)


def _fisheye(dist, rvec=np.zeros(3), tvec=np.zeros(3), k=K):
    """cv2.fisheye's projection; its skew alpha is K[0, 1] / fx (as cv2.fisheye.calibrate writes K)."""
    return lambda p: cv2.fisheye.projectPoints(p.reshape(-1, 1, 3), rvec.reshape(3, 1), tvec.reshape(3, 1), k,
                                               np.asarray(dist, float), alpha=k[0, 1] / k[0, 0])[0].reshape(-1, 2)


def test_strong_k1_has_no_ray_beyond_the_fold(tmp_path):
    """A 5-coefficient OpenCV camera whose k1 folds the radial model inside the image: the pixels with a ray
    are exactly those inside the fold (r_d < r_f (1 + k1 r_f^2), r_f^2 = -1 / (3 k1), computed here), and
    each of their rays projects onto its pixel by cv2.projectPoints (1e-6 px) on the pixel's side of the
    centre; the corners, which the model reaches only mirrored, get none."""
    k1 = -0.9
    dist = np.array([k1, 0.0, 0.0, 0.0, 0.0])
    path = _fs(tmp_path / "cam.yml", [("image_width", W), ("image_height", H), ("camera_matrix", K),
                                      ("distortion_coefficients", dist.reshape(1, -1))])
    prvm = import_calibration([path]).result
    uv = pixel_grid(W, H)
    xd = np.stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1]], -1)
    rf = np.sqrt(-1 / (3 * k1))
    inside = np.linalg.norm(xd, axis=1) < rf * (1 + k1 * rf * rf)
    assert 0.3 < inside.mean() < 0.95                              # the fold lies inside the image
    assert np.array_equal(prvm.valid.ravel(), inside)
    assert _worst_px(prvm, _pinhole(dist)) < 1e-6
    d = prvm.direction.reshape(-1, 3)[inside]
    assert (np.sign(d[:, 0]) == np.sign(xd[inside, 0])).all() and (np.sign(d[:, 1]) == np.sign(xd[inside, 1])).all()


def test_tutorial_fisheye_file_is_the_fisheye_model(tmp_path, capsys):
    """OpenCV's calibration tutorial writing a fisheye camera (fisheye_model: 1, its flags, 4 coefficients
    as a 4x1 column): read as cv2.fisheye's model, every ray on its pixel by cv2.fisheye.projectPoints
    (1e-6 px) - not as k1 k2 p1 p2 (tens of pixels away)."""
    dist = np.array([0.08, -0.02, 0.01, -0.003])
    path = _fs(tmp_path / "out_camera_data.yml", [
        ("calibration_time", "Fri Dec  4 17:00:00 2026"), ("nr_of_frames", 25), ("image_width", W),
        ("image_height", H), ("board_width", 9), ("board_height", 6), ("square_size", 50.0),
        ("flags", 1 << 1 | 1 << 3), ("fisheye_model", 1), ("camera_matrix", K),
        ("distortion_coefficients", dist.reshape(4, 1)), ("avg_reprojection_error", 0.3)])
    assert main(["import", str(path), "-o", str(tmp_path / "cam.npz")]) == 0
    from calib.prvm_file import load_prvm
    prvm = load_prvm(tmp_path / "cam.npz")
    assert prvm.valid.all()
    assert _worst_px(prvm, _fisheye(dist)) < 1e-6
    assert _worst_px(prvm, _pinhole(dist)) > 1.0


def test_fisheye_k_d_file(tmp_path):
    """A cv2.fisheye script's output: K and D (4x1) in FileStorage with image_width/height, a skew in K
    (K[0, 1] = alpha fx, as cv2.fisheye.calibrate returns K): cv2.fisheye.projectPoints within 1e-6 px."""
    k = K.copy()
    k[0, 1] = 0.3
    dist = np.array([-0.01, 0.03, -0.02, 0.004])
    path = _fs(tmp_path / "fisheye.yaml", [("K", k), ("D", dist.reshape(4, 1)), ("image_width", W),
                                           ("image_height", H)])
    prvm = import_calibration([path]).result
    assert prvm.valid.all() and _worst_px(prvm, _fisheye(dist, k=k)) < 1e-6


def test_old_tutorial_layout_and_rational_flags(tmp_path, capsys):
    """OpenCV 2.4's tutorial keys (Camera_Matrix, Distortion_Coefficients, image_Width, image_Height,
    flagValue) with CALIB_RATIONAL_MODEL and 8 coefficients: cv2.projectPoints within 1e-6 px; the same
    flags over 5 coefficients are refused in one line (exit 2)."""
    dist = np.array([-0.2, 0.05, 0.001, -0.0005, 0.01, 0.02, -0.01, 0.003])
    items = [("calibration_Time", "x"), ("nrOfFrames", 12), ("image_Width", W), ("image_Height", H),
             ("board_Width", 9), ("board_Height", 6), ("square_Size", 50.0), ("FixAspectRatio", 1.0),
             ("flagValue", cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_FIX_ASPECT_RATIO), ("Camera_Matrix", K),
             ("Distortion_Coefficients", dist.reshape(8, 1)), ("Avg_Reprojection_Error", 0.2)]
    prvm = import_calibration([_fs(tmp_path / "old.xml", items)]).result
    assert prvm.valid.all() and _worst_px(prvm, _pinhole(dist)) < 1e-6
    bad = _fs(tmp_path / "bad.xml", items[:-2] + [("Distortion_Coefficients", dist[:5].reshape(5, 1))])
    assert main(["import", str(bad), "-o", str(tmp_path / "o.npz")]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "CALIB_RATIONAL_MODEL" in err and "bad.xml" in err


def _stereo_pose():
    rvec, T = np.array([0.02, -0.35, 0.01]), np.array([-120.0, 2.0, 15.0])
    return rvec, cv2.Rodrigues(rvec)[0], T


@pytest.mark.parametrize("names", [("K1", "D1", "K2", "D2"), ("cam1_intrinsics", "cam1_distorsion",
                                                                 "cam2_intrinsics", "cam2_distorsion")])
def test_stereo_files_k1_d1_and_cam1_intrinsics(tmp_path, names):
    """Stereo files naming the cameras K1 D1 K2 D2 (cv2.stereoCalibrate's names, R T with x2 = R x1 + T)
    or cam1_intrinsics cam1_distorsion (OpenCV's structured-light sample, whose R T are camera 2's pose in
    camera 1's frame, x1 = R x2 + T: its statue's scans say so, tests/stereodic/test_scan_gray.py): both
    cameras' rays on their pixels by cv2.projectPoints (1e-6 px), camera 2 with the pose each layout
    means."""
    rvec, R, T = _stereo_pose()
    d1, d2 = np.array([-0.1, 0.02, 0.001, 0.0, 0.0]), np.array([-0.12, 0.03, 0.0, 0.001, -0.01])
    k2 = K + np.array([[2.0, 0, 1.5], [0, 2.0, -1.0], [0, 0, 0]])
    size = ([("cam1_size", np.array([W, H])), ("cam2_size", np.array([W, H]))] if names[0].startswith("cam")
            else [("image_width", W), ("image_height", H)])
    path = _fs(tmp_path / "stereo.yml", [(names[0], K), (names[1], d1.reshape(1, -1)), *size[:1], (names[2], k2),
                                         (names[3], d2.reshape(1, -1)), *size[1:], ("R", R), ("T", T.reshape(3, 1))])
    imp = import_calibration([path])
    assert imp.format == "opencv" and [c.name for c in imp.cameras] == ["1", "2"]
    assert _worst_px(imp.prvms[0], _pinhole(d1), depths=(300.0, 800.0)) < 1e-6
    if names[0].startswith("cam"):
        rvec, T = cv2.Rodrigues(R.T)[0].ravel(), -R.T @ T
    assert _worst_px(imp.prvms[1], _pinhole(d2, rvec, T, k2), depths=(300.0, 800.0)) < 1e-6


@pytest.mark.slow
def test_gsoc_structured_light_calibration():
    """The real stereo calibration of ../shared/data/gsoc-statue-graycode (cam1_intrinsics, cam1_distorsion,
    cam1_size, R, T; k3 = 9.5): camera 2 (#1) imported alone, every ray on its pixel by cv2.projectPoints
    with the pose R, T give camera 2 in camera 1's frame, x_1 = R x_2 + T (the statue's scans say which
    way: tests/stereodic/test_scan_gray.py), 1e-6 px, over the whole image but the pixels beyond the
    model's fold."""
    import os
    path = "/work/shared/data/gsoc-statue-graycode/calibrationParameters.yml"
    if not os.path.exists(path):
        pytest.skip("the shared data is not here")
    fs = cv2.FileStorage(path, cv2.FILE_STORAGE_READ)
    k2, d2, R, T = (fs.getNode(n).mat() for n in ("cam2_intrinsics", "cam2_distorsion", "R", "T"))
    imp = import_calibration([path], cameras=["#1"])
    prvm = imp.result
    assert (prvm.width, prvm.height) == (1920, 1280) and prvm.valid.mean() > 0.99
    assert _worst_px(prvm, _pinhole(d2.ravel(), cv2.Rodrigues(R.T)[0], -R.T @ T.ravel(), k2),
                     depths=(2000.0, 4000.0)) < 1e-6


def test_kalibr_imucam_chain_with_yaml_header(tmp_path):
    """Kalibr's camchain-imucam.yaml with OpenCV's %YAML:1.0 first line and only each camera's T_cam_imu:
    recognised as Kalibr, camera 1 placed by T_cam1_imu T_cam0_imu^-1; its rays on their pixels by
    cv2.projectPoints with that pose (metres -> mm), 1e-6 px."""
    def t_cam_imu(rvec, t):
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = cv2.Rodrigues(np.asarray(rvec, float))[0], t
        return m

    T0, T1 = t_cam_imu([0.01, 1.2, -0.02], [0.05, -0.01, 0.02]), t_cam_imu([0.03, 1.1, 0.0], [-0.07, 0.0, 0.03])

    def rows(m):
        return "".join(f"  - [{', '.join(repr(float(v)) for v in r)}]\n" for r in m)

    def cam(i, m):
        return (f"cam{i}:\n  T_cam_imu:\n{rows(m)}  cam_overlaps: [{1 - i}]\n  camera_model: pinhole\n"
                f"  distortion_coeffs: [-0.1, 0.02, 0.001, -0.001]\n  distortion_model: radtan\n"
                f"  intrinsics: [150.0, 151.0, 79.3, 60.2]\n  resolution: [{W}, {H}]\n  rostopic: /cam{i}/image_raw\n"
                f"  timeshift_cam_imu: 0.001\n")
    path = tmp_path / "camchain-imucam.yaml"
    path.write_text("%YAML:1.0\n" + cam(0, T0) + cam(1, T1))
    imp = import_calibration([path])
    assert imp.format == "kalibr"
    rel = T1 @ np.linalg.inv(T0)
    dist = [-0.1, 0.02, 0.001, -0.001]
    assert _worst_px(imp.prvms[0], _pinhole(dist), depths=(100.0, 300.0)) < 1e-6
    assert _worst_px(imp.prvms[1], _pinhole(dist, cv2.Rodrigues(rel[:3, :3])[0], rel[:3, 3] * 1000),
                     depths=(100.0, 300.0)) < 1e-6


def _ros(name, model, d, R=np.eye(3), P=None):
    P = np.hstack([K, np.zeros((3, 1))]) if P is None else P

    def mat(key, m):
        return f"{key}:\n  rows: {m.shape[0]}\n  cols: {m.shape[1]}\n  data: [{', '.join(repr(float(v)) for v in m.ravel())}]\n"
    return (f"image_width: {W}\nimage_height: {H}\ncamera_name: {name}\n" + mat("camera_matrix", K)
            + f"distortion_model: {model}\n" + mat("distortion_coefficients", np.asarray(d, float).reshape(1, -1))
            + mat("rectification_matrix", R) + mat("projection_matrix", P))


def test_ros_camera_info_single_and_pair(tmp_path):
    """ROS camera_info YAML (camera_calibration_parsers' layout): plumb_bob against cv2.projectPoints,
    equidistant against cv2.fisheye.projectPoints (1e-6 px); a left/right pair placed by the rectification
    matrices and the right projection's Tx = -f' B (metres): x_right = R_r^T (R_l x_left + (Tx / f', 0, 0))."""
    d = [-0.1, 0.02, 0.001, -0.001, 0.003]
    (tmp_path / "ost.yaml").write_text(_ros("narrow_stereo", "plumb_bob", d))
    imp = import_calibration([tmp_path / "ost.yaml"])
    assert imp.format == "ros" and imp.cameras[0].name == "narrow_stereo"
    assert _worst_px(imp.result, _pinhole(d)) < 1e-6
    e = [0.05, -0.01, 0.004, -0.001]
    (tmp_path / "fish.yaml").write_text(_ros("fish", "equidistant", e))
    assert _worst_px(import_calibration([tmp_path / "fish.yaml"]).result, _fisheye(e)) < 1e-6

    rl, rr = cv2.Rodrigues(np.array([0.0, 0.1, 0.0]))[0], cv2.Rodrigues(np.array([0.0, -0.1, 0.0]))[0]
    f, tx = 140.0, -140.0 * 0.12
    P = np.array([[f, 0, 80.0, 0], [0, f, 60.0, 0], [0, 0, 1, 0]])
    (tmp_path / "left.yaml").write_text(_ros("left", "plumb_bob", d, rl, P))
    P[0, 3] = tx
    (tmp_path / "right.yaml").write_text(_ros("right", "plumb_bob", d, rr, P))
    imp = import_calibration([tmp_path / "left.yaml", tmp_path / "right.yaml"])
    R = rr.T @ rl
    t = rr.T @ np.array([tx / f, 0, 0]) * 1000
    assert _worst_px(imp.prvms[1], _pinhole(d, cv2.Rodrigues(R)[0], t), depths=(400.0, 900.0)) < 1e-6


def test_camera_by_exact_name_or_position(tmp_path, capsys):
    """--camera 1 is the camera NAMED "1" (OpenCV's first), #1 the one at position 1 (the second);
    a name two cameras share is refused, and #N picks an unnamed (DICe CAMERA_ID "") camera."""
    rvec, R, T = _stereo_pose()
    path = _fs(tmp_path / "stereo.yml", [("M1", K), ("D1", np.zeros((1, 5))), ("M2", K), ("D2", np.zeros((1, 5))),
                                         ("R", R), ("T", T.reshape(3, 1)), ("image_width", W), ("image_height", H)])
    assert import_calibration([path], cameras=["1"]).cameras[0].name == "1"
    assert import_calibration([path], cameras=["#1"]).cameras[0].name == "2"
    cams = "".join(f'<ParameterList name="CAMERA {i}"><Parameter name="CAMERA_ID" type="string" value=""/>'
                   f'<Parameter name="CX" type="double" value="79.5"/><Parameter name="CY" type="double" value="59.5"/>'
                   f'<Parameter name="FX" type="double" value="150"/><Parameter name="FY" type="double" value="150"/>'
                   f'<Parameter name="TX" type="double" value="{-60 * i}"/>'
                   f'<Parameter name="IMAGE_HEIGHT_WIDTH" type="string" value="{{ {H}, {W} }}"/></ParameterList>'
                   for i in range(2))
    (tmp_path / "dice.xml").write_text('<ParameterList><Parameter name="xml_file_format" type="string" '
                                       f'value="DICe_xml_camera_system_file"/>{cams}</ParameterList>')
    assert main(["import", str(tmp_path / "dice.xml"), "--camera", "", "-o", str(tmp_path / "o.npz")]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "2 cameras named ''" in err
    imp = import_calibration([tmp_path / "dice.xml"], cameras=["#1"])
    assert np.allclose(imp.cameras[0].t, [-60.0, 0, 0])


def test_camera_at_its_origin_exports_and_comes_back(tmp_path):
    """A pose-less OpenCV camera (at its file's origin): its export (the default virtual pinhole camera)
    imports back to that virtual camera's rays: every exported pixel's ray passes through the virtual
    camera's sensor point of that pixel and its centre, within 1e-6 virtual pixel."""
    from calib.prvm_file import load_prvm
    from stereodic.virtual.camera import default_camera
    dist = np.array([-0.2, 0.05, 0.001, 0.0, 0.0])
    path = _fs(tmp_path / "cam.yml", [("image_width", W), ("image_height", H), ("camera_matrix", K),
                                      ("distortion_coefficients", dist.reshape(1, -1))])
    assert main(["import", str(path), "-o", str(tmp_path / "cam.npz")]) == 0
    assert main(["export", str(tmp_path / "cam.npz"), "--format", "opencv", "-o", str(tmp_path / "out.yml")]) == 0
    vcam = default_camera(load_prvm(tmp_path / "cam.npz"))
    back = import_calibration([tmp_path / "out.yml"]).result
    wfr = np.asarray(back.meta["world_from_rig"])
    o, d = transform(wfr, back.origin), back.direction @ wfr[:3, :3].T
    v, u = np.mgrid[0:vcam.sensor.height, 0:vcam.sensor.width].astype(float)
    assert back.valid.all() and back.valid.shape == u.shape
    for p in (vcam.sensor.points(u, v), np.broadcast_to(vcam.centre, o.shape)):
        w = p - o
        miss = np.linalg.norm(w - np.sum(w * d, -1)[..., None] * d, axis=-1)
        assert miss.max() / min(vcam.sensor.pitch_mm) < 1e-6


def _dice_convergent(path, angle_deg=35.0):
    """A DICe camera system of two cameras converging by `angle_deg` on a point 500 mm away, K1R2_K2R4_K3R6
    lenses, rotations printed to 6 digits (as DICe's examples are): returns the cameras as written."""
    from scipy.spatial.transform import Rotation
    cams, xml = [], ""
    for i, a in enumerate((angle_deg / 2, -angle_deg / 2)):
        R = np.round(Rotation.from_euler("y", a, degrees=True).as_matrix(), 6)
        t = -R @ (np.array([0.0, 0.0, 500.0]) - 500.0 * R[2])
        cams.append((R, t))
        rows = "".join(f'<Parameter name="ROW {j}" type="string" value="{{ {R[j, 0]:.6f}, {R[j, 1]:.6f}, '
                       f'{R[j, 2]:.6f} }}"/>' for j in range(3))
        xml += (f'<ParameterList name="CAMERA {i}"><Parameter name="CAMERA_ID" type="string" value="cam{i}"/>'
                f'<Parameter name="CX" type="double" value="79.5"/><Parameter name="CY" type="double" value="59.5"/>'
                f'<Parameter name="FX" type="double" value="300"/><Parameter name="FY" type="double" value="300.5"/>'
                + "".join(f'<Parameter name="T{c}" type="double" value="{float(v)!r}"/>' for c, v in zip("XYZ", t))
                + '<Parameter name="LENS_DISTORTION_MODEL" type="string" value="K1R2_K2R4_K3R6"/>'
                '<Parameter name="K1" type="double" value="-0.1"/><Parameter name="K2" type="double" value="0.02"/>'
                f'<Parameter name="IMAGE_HEIGHT_WIDTH" type="string" value="{{ {H}, {W} }}"/>'
                f'<ParameterList name="rotation_3x3_matrix">{rows}</ParameterList></ParameterList>')
    path.write_text('<ParameterList><Parameter name="xml_file_format" type="string" '
                    f'value="DICe_xml_camera_system_file"/>{xml}</ParameterList>')
    return cams


@pytest.mark.parametrize("fmt", ["opencv", "dice", "vic3d", "mrcal"])
def test_convergent_dice_rig_projects_with_r_as_written_and_round_trips(tmp_path, fmt):
    """A 35-degree convergent DICe rig whose rotations are orthonormal to 6 digits only: each imported
    ray projects onto its pixel by DICe's model with R as written (x_cam = R X + t, then DICe's
    K1R2_K2R4_K3R6: r_d = r + K1 r^2 + K2 r^4, written here) within 1e-6 px; its export imports back to the exported virtual cameras' rays
    (1e-6 virtual px), on the plane the export carries."""
    from stereodic.stereo.rig import load_rig, save_rig
    from tests.stereodic.test_import import _ray_error_px
    cams = _dice_convergent(tmp_path / "dice.xml")
    assert np.abs(cams[0][0] @ cams[0][0].T - np.eye(3)).max() > 1e-7     # R as written is not orthonormal
    imp = import_calibration([tmp_path / "dice.xml"])

    def dice(R, t):
        def project(p):
            q = p @ R.T + t
            x, y = q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]
            r = np.hypot(x, y)
            s = (r - 0.1 * r ** 2 + 0.02 * r ** 4) / r
            return np.stack([300.0 * x * s + 79.5, 300.5 * y * s + 59.5], -1)
        return project
    for prvm, (R, t) in zip(imp.prvms, cams):
        assert prvm.valid.all() and _worst_px(prvm, dice(R, t), depths=(400.0, 700.0)) < 1e-6
    save_rig(tmp_path / "rig.npz", imp.result)
    rig = load_rig(tmp_path / "rig.npz")
    out = tmp_path / ("out" if fmt == "mrcal" else f"out.{'yml' if fmt == 'opencv' else 'xml'}")
    assert main(["export", str(tmp_path / "rig.npz"), "--format", fmt, "-o", str(out)]) == 0
    files = [out / "left.cameramodel", out / "right.cameramodel"] if fmt == "mrcal" else [out]
    back = import_calibration(files, fmt=fmt)
    for side, prvm in zip(("left", "right"), back.prvms):
        assert prvm.valid.all() and _ray_error_px(rig, side, prvm, back.result.world_from_rig) < 1e-6


def test_vic3d_kappa_reading_fits_vic3d_own_matches_best():
    """VIC-3D's own automatic stereo matches stored in the shared cal.xml (dice-stereo-list), triangulated
    and reprojected through each reading of the kappas (the models written here through CameraModel's
    lenses): kappa1..3 on r^2, r^4, r^6 (ours) reprojects them within 0.06 px; DICe's reading
    (k1 r + k2 r^2 + k3 r^3 added to r) at least twice as far (docs/import.md, "VIC-3D's distortion")."""
    import os

    from calib.camera_models import CameraModel, project, unproject
    from stereodic.formats import read_calibration
    from tests.stereodic.test_import_real import VIC_AUTO
    path = "/work/shared/data/dice-stereo-list/cal.xml"
    if not os.path.exists(path):
        pytest.skip("the shared data is not here")
    _, cams = read_calibration([path])
    dice = [CameraModel(c.fx, c.fy, c.cx, c.cy, c.skew, "radial", c.coefficients[[0, 1, 4]], c.R, c.t, c.width,
                        c.height, c.name, (0, 1, 2)) for c in cams]

    def worst(cs):
        uv = (VIC_AUTO[:, :2], VIC_AUTO[:, 2:])
        rays = [(c.centre, c.to_world(unproject(c, p)[0])) for c, p in zip(cs, uv)]
        (c0, d0), (c1, d1) = rays
        w, b = c0 - c1, np.sum(d0 * d1, 1)
        s = (b * (d1 @ w) - d0 @ w) / (1 - b * b)
        t = ((d1 @ w) - b * (d0 @ w)) / (1 - b * b)
        mid = (c0 + s[:, None] * d0 + c1 + t[:, None] * d1) / 2
        return max(np.linalg.norm(project(c, mid) - p, axis=1).max() for c, p in zip(cs, uv))
    ours, theirs = worst(cams), worst(dice)
    assert ours < 0.06 and theirs > 2 * ours


def test_rig_maps_are_the_model_at_every_virtual_pixel(tmp_path):
    """A strongly distorted OpenCV pair (k1 = -0.3): every virtual pixel's map position in the real image
    is cv2.projectPoints of the point its rig ray passes through (the sensor point, taken to the file's
    frame) within the maps' float32 rounding (1e-5 px here): the maps come from the model at their own
    sub-pixel positions, not from rays interpolated between real pixels (1e-3 px off in the corners). The
    rig file keeps the models (a few kB) and gives the same maps and rays when read."""
    rvec, R, T = _stereo_pose()
    rvec, T = rvec * 0.3, T * np.array([1.0, 0, 0])
    R = cv2.Rodrigues(rvec)[0]
    d = np.array([-0.3, 0.08, 0.001, -0.0005, 0.0])
    path = _fs(tmp_path / "stereo.yml", [("M1", K), ("D1", d.reshape(1, -1)), ("M2", K), ("D2", d.reshape(1, -1)),
                                         ("R", R), ("T", T.reshape(3, 1)), ("image_width", W), ("image_height", H)])
    rig = import_calibration([path]).result
    for side, (rv, tv) in (("left", (np.zeros(3), np.zeros(3))), ("right", (rvec, T))):
        cam = rig.camera(side)
        v, u = np.nonzero(cam.imm.valid)
        assert len(v) > 0.9 * cam.imm.valid.size
        p = rig.to_world(cam.centre + 300.0 * cam.direction[v, u])
        px = _pinhole(d, rv, tv)(p)
        assert np.abs(px[:, 0] - cam.imm.map_x[v, u]).max() < 1e-5
        assert np.abs(px[:, 1] - cam.imm.map_y[v, u]).max() < 1e-5
    # the file keeps the two models, not the maps: a few kB, and the same maps and rays when read
    from stereodic.stereo.rig import load_rig, save_rig
    save_rig(tmp_path / "rig.npz", rig)
    assert (tmp_path / "rig.npz").stat().st_size < 20_000
    back = load_rig(tmp_path / "rig.npz")
    for side in ("left", "right"):
        a, b = rig.camera(side), back.camera(side)
        assert np.array_equal(a.imm.map_x, b.imm.map_x) and np.array_equal(a.imm.valid, b.imm.valid)
        assert np.array_equal(a.direction, b.direction, equal_nan=True)
