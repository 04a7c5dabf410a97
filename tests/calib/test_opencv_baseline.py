import numpy as np

from calib.opencv_baseline import calibrate_opencv, chessboard_display_corners


def test_opencv_recovers_an_exact_brown_camera():
    """Dense correspondences on two planes of a pinhole + radial camera: OpenCV's rays are exact."""
    k = np.array([[800.0, 0, 319.5], [0, 800.0, 239.5], [0, 0, 1]])
    rng = np.random.default_rng(0)
    centre = np.array([100.0, 80.0, -400.0])
    pts, img = [], []
    for z in (0.0, 50.0):
        xy = rng.uniform([-100, -80], [300, 240], (3000, 2))
        p = np.column_stack([xy, np.full(len(xy), z)])
        rel = (p - centre) / (p - centre)[:, 2:3]
        r2 = (rel[:, :2] ** 2).sum(1, keepdims=True)
        dist = rel[:, :2] * (1 - 0.1 * r2)
        uv = dist * k[0, 0] + k[:2, 2]
        keep = (uv >= 0).all(1) & (uv[:, 0] < 640) & (uv[:, 1] < 480)
        pts.append(p[keep])
        img.append(uv[keep])
    cam = calibrate_opencv(np.concatenate(pts), np.concatenate(img), 640, 480)
    assert cam.rms_px < 1e-3
    o, d = cam.rays(640, 480)
    # the true ray of a pixel passes through the centre: check at two pixels
    for u, v in ((10, 10), (320, 240), (600, 450)):
        t = (centre[2] - o[v, u, 2]) / d[v, u, 2]
        assert np.linalg.norm(o[v, u] + t * d[v, u] - centre) < 0.05


def test_chessboard_corner_positions():
    c = chessboard_display_corners((3, 2), 10, (5, 7))
    np.testing.assert_allclose(c, [[14.5, 16.5], [24.5, 16.5]])
