"""Shared test cameras for the virtual-camera tests: an OpenCV camera with known intrinsics and pose,
and its PRVM built by OpenCV's own model (independent of the calibration)."""

import cv2
import numpy as np

from calib.pinhole import prvm_from_opencv

W, H = 320, 240
K = np.array([[300.0, 0, 165.3], [0, 302.0, 118.7], [0, 0, 1]])
DIST = np.array([-0.28, 0.09, 0.001, -0.0007, -0.01])
RVEC = np.array([0.05, -0.03, 0.02])
CENTRE = np.array([10.0, -5.0, -500.0])  # optical centre, WCS mm (the camera looks along +z)


def opencv_camera():
    """(K, dist, rvec, tvec, prvm) of the test camera."""
    R = cv2.Rodrigues(RVEC)[0]
    tvec = -R @ CENTRE
    return K, DIST, RVEC, tvec, prvm_from_opencv(K, DIST, RVEC, tvec, W, H, reference_z_mm=0.0)


def smooth_texture(seed=1, blur=3.0, h=H, w=W):
    """An 8-bit random texture blurred to a few grey levels per pixel of gradient."""
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), blur)
    return cv2.normalize(img, None, 10, 245, cv2.NORM_MINMAX).astype(np.uint8)
