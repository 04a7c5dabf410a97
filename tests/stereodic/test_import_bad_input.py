"""Bad input to `stereodic import`: one line naming the file (or option) and the problem, exit status 2,
no output written."""

import cv2
import numpy as np
from stereodic.cli import main

K = np.array([[400.0, 0, 160], [0, 400.0, 120], [0, 0, 1]])


def _run(argv, capsys):
    status = main(argv)
    return status, capsys.readouterr().err.strip()


def _stereo_yaml(path, skip=(), size=True, R=np.eye(3), T=(-100.0, 0, 0)):
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in (("M1", K), ("D1", np.zeros((1, 5))), ("M2", K), ("D2", np.zeros((1, 5))), ("R", R),
                       ("T", np.array(T, np.float64).reshape(3, 1))):
        if key not in skip:
            fs.write(key, value)
    if size:
        fs.write("image_width", 320)
        fs.write("image_height", 240)
    fs.release()
    return str(path)


def _one_line(status, err, *words):
    assert status == 2 and len(err.splitlines()) == 1, err
    for w in words:
        assert w in err, err


def test_a_file_of_no_known_format(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("left camera: the good one\nright camera: bumped\n")
    _one_line(*_run(["import", str(tmp_path / "notes.txt"), "-o", str(tmp_path / "o.npz")], capsys),
              "notes.txt", "not a calibration file")
    assert not (tmp_path / "o.npz").exists()


def test_a_binary_file_is_not_a_calibration(tmp_path, capsys):
    cv2.imwrite(str(tmp_path / "img.png"), np.zeros((8, 8), np.uint8))
    _one_line(*_run(["import", str(tmp_path / "img.png"), "-o", str(tmp_path / "o.npz")], capsys), "img.png",
              "not a calibration")


def test_the_wrong_format_forced(tmp_path, capsys):
    path = _stereo_yaml(tmp_path / "stereo.yml")
    _one_line(*_run(["import", path, "--format", "vic3d", "-o", str(tmp_path / "o.npz")], capsys), "stereo.yml")


def test_no_image_size_needs_size(tmp_path, capsys):
    path = _stereo_yaml(tmp_path / "stereo.yml", size=False)
    _one_line(*_run(["import", path, "-o", str(tmp_path / "rig.npz")], capsys), "stereo.yml", "--size")
    assert not (tmp_path / "rig.npz").exists()
    assert main(["import", path, "--size", "320x240", "-o", str(tmp_path / "rig.npz")]) == 0
    assert (tmp_path / "rig.npz").exists()


def test_a_stereo_file_missing_a_key(tmp_path, capsys):
    path = _stereo_yaml(tmp_path / "stereo.yml", skip=("T",))
    _one_line(*_run(["import", path, "-o", str(tmp_path / "rig.npz")], capsys), "stereo.yml", "missing T")


def test_cameras_facing_each_other_have_no_display_side(tmp_path, capsys):
    """Two pinholes looking at each other: no frame has all their rays travel towards +z."""
    R = cv2.Rodrigues(np.array([0.0, np.pi, 0.0]))[0]
    path = _stereo_yaml(tmp_path / "facing.yml", R=R, T=(0.0, 0.0, 800.0))
    _one_line(*_run(["import", path, "-o", str(tmp_path / "rig.npz")], capsys), "facing.yml", "display side")


def test_unknown_models_and_cameras(tmp_path, capsys):
    (tmp_path / "m.cameramodel").write_text("{'lensmodel': 'LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=30_Ny=20"
                                            "_fov_x_deg=170', 'intrinsics': [1, 2, 3, 4], 'imagersize': [320, 240]}")
    _one_line(*_run(["import", str(tmp_path / "m.cameramodel"), "-o", str(tmp_path / "o.npz")], capsys),
              "m.cameramodel", "not supported")
    (tmp_path / "c.yaml").write_text("cam0:\n  camera_model: omni\n  intrinsics: [1, 2, 3, 4]\n"
                                     "  distortion_model: radtan\n  distortion_coeffs: [0, 0, 0, 0]\n"
                                     "  resolution: [320, 240]\n")
    _one_line(*_run(["import", str(tmp_path / "c.yaml"), "-o", str(tmp_path / "o.npz")], capsys), "c.yaml", "omni")
    path = _stereo_yaml(tmp_path / "stereo.yml")
    _one_line(*_run(["import", path, "--camera", "7", "-o", str(tmp_path / "o.npz")], capsys), "stereo.yml",
              "no camera named '7'")


def test_output_checked_before_the_work(tmp_path, capsys):
    """-o naming a folder is refused before the calibration is read (the file given is not one)."""
    (tmp_path / "out").mkdir()
    (tmp_path / "notes.txt").write_text("nothing")
    _one_line(*_run(["import", str(tmp_path / "notes.txt"), "-o", str(tmp_path / "out")], capsys), "out", "is a directory")


def test_unread_model_flags_and_chains_are_refused(tmp_path, capsys):
    """A ROS distortion model we do not read, an OpenCV fisheye_model other than 0/1, a Kalibr chain whose
    cam1 has neither T_cn_cnm1 nor (with every camera) T_cam_imu: one line each, exit 2."""
    (tmp_path / "ros.yaml").write_text("image_width: 320\nimage_height: 240\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
                                       "  data: [300, 0, 160, 0, 300, 120, 0, 0, 1]\ndistortion_model: fov\n"
                                       "distortion_coefficients:\n  rows: 1\n  cols: 1\n  data: [0.9]\n")
    _one_line(*_run(["import", str(tmp_path / "ros.yaml"), "-o", str(tmp_path / "o.npz")], capsys), "ros.yaml",
              "'fov' is not supported")
    fs = cv2.FileStorage(str(tmp_path / "cam.yml"), cv2.FILE_STORAGE_WRITE)
    for k, v in (("image_width", 320), ("image_height", 240), ("fisheye_model", 2), ("camera_matrix", np.eye(3)),
                 ("distortion_coefficients", np.zeros((4, 1)))):
        fs.write(k, v)
    fs.release()
    _one_line(*_run(["import", str(tmp_path / "cam.yml"), "-o", str(tmp_path / "o.npz")], capsys), "cam.yml",
              "fisheye_model")
    cam = ("  camera_model: pinhole\n  intrinsics: [300, 300, 160, 120]\n  distortion_model: radtan\n"
           "  distortion_coeffs: [0, 0, 0, 0]\n  resolution: [320, 240]\n")
    (tmp_path / "chain.yaml").write_text("%YAML:1.0\ncam0:\n  T_cam_imu:\n  - [1, 0, 0, 0]\n  - [0, 1, 0, 0]\n"
                                         "  - [0, 0, 1, 0]\n  - [0, 0, 0, 1]\n" + cam + "cam1:\n" + cam)
    _one_line(*_run(["import", str(tmp_path / "chain.yaml"), "-o", str(tmp_path / "o.npz")], capsys), "chain.yaml",
              "T_cam_imu")
