"""OpenCV calibrations in and out: the imported PRVM's rays, the intrinsics round trip, and undistortion
against cv2.undistort."""

import cv2
import numpy as np
import pytest

from calib.errors import InputError
from calib.pinhole import PinholeCamera, opencv_yaml, prvm_from_opencv, read_opencv_yaml
from stereodic.virtual.export import pinhole_of
from stereodic.virtual.imm import apply_imm, build_imm
from stereodic.virtual.camera import VirtualCamera, VirtualSensor, fit_optical_centre

from virtual_cases import CENTRE, H, W, opencv_camera, smooth_texture


def test_imported_rays_project_back_onto_their_pixels():
    K, dist, rvec, tvec, prvm = opencv_camera()
    v, u = np.mgrid[0:H:7, 0:W:7]
    far = prvm.at_z(250.0)[v, u].reshape(-1, 1, 3)
    px = cv2.projectPoints(far, rvec, tvec, K, dist)[0].reshape(v.shape + (2,))
    assert np.abs(px[..., 0] - u).max() < 1e-6 and np.abs(px[..., 1] - v).max() < 1e-6
    assert np.allclose(prvm.origin[..., 2], 0.0) and (prvm.direction[..., 2] > 0).all()


def test_fitted_centre_is_the_opencv_centre():
    prvm = opencv_camera()[-1]
    centre, miss = fit_optical_centre(prvm)
    assert np.linalg.norm(centre - CENTRE) < 1e-6
    assert np.nanmax(miss) < 1e-6


def _virtual_of(K, rvec, prvm):
    """The virtual pinhole camera whose sensor is OpenCV's camera (K, R), through the fitted centre."""
    R = cv2.Rodrigues(rvec)[0]
    centre, _ = fit_optical_centre(prvm)
    return VirtualCamera(VirtualSensor.from_pinhole(K, R, centre, W, H, 480.0), "pinhole", centre)


def test_import_then_export_gives_back_the_intrinsics():
    K, dist, rvec, tvec, prvm = opencv_camera()
    back = pinhole_of(_virtual_of(K, rvec, prvm))
    assert np.allclose(back.K, K, rtol=0, atol=1e-8)
    assert np.array_equal(back.dist, np.zeros(5))
    assert np.allclose(back.R, cv2.Rodrigues(rvec)[0], atol=1e-12)
    assert np.allclose(back.t, tvec, atol=1e-6)
    assert (back.width, back.height) == (W, H)


def test_undistortion_matches_cv2_undistort():
    K, dist, rvec, tvec, prvm = opencv_camera()
    imm = build_imm(prvm, _virtual_of(K, rvec, prvm).sensor)
    img = smooth_texture()
    ref = cv2.undistort(img, K, dist)  # OpenCV undistorts with its fixed-point maps
    ours = apply_imm(img, imm, fixed_point=True)
    inner = np.zeros((H, W), bool)
    inner[20:-20, 20:-20] = True
    assert imm.valid[inner].all()
    rms = np.sqrt(np.mean((ours.astype(float) - ref)[inner] ** 2))
    assert rms <= 0.05
    # the maps themselves agree with OpenCV's to well below a 1/32 pixel step
    mx, my = cv2.initUndistortRectifyMap(K, dist, None, K, (W, H), cv2.CV_32FC1)
    assert np.abs(mx - imm.map_x)[inner].max() < 2e-3 and np.abs(my - imm.map_y)[inner].max() < 2e-3


def test_opencv_yaml_round_trip(tmp_path):
    K, dist, rvec, tvec, _ = opencv_camera()
    cam = PinholeCamera(K, dist, rvec, tvec, W, H)
    path = tmp_path / "cam.yaml"
    path.write_text(opencv_yaml(cam))
    back = read_opencv_yaml(path)
    assert np.allclose(back.K, K) and np.allclose(back.dist, dist) and np.allclose(back.R, cam.R)
    assert np.allclose(back.t, tvec) and (back.width, back.height) == (W, H)
    assert np.allclose(back.centre, CENTRE)


def test_camera_looking_away_is_refused():
    K, dist, _, _, _ = opencv_camera()
    with pytest.raises(InputError):
        prvm_from_opencv(K, dist, np.array([0.0, np.pi, 0.0]), np.zeros(3), W, H)
