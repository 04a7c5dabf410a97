import cv2
import numpy as np

from calib.reduced import load_undistort_map
from stereodic.cli import main
from synth_capture import DISPLAY, make_capture


def _homography_residual(display_pts, image_pts):
    hom, _ = cv2.findHomography(display_pts, image_pts, 0)
    proj = cv2.perspectiveTransform(display_pts[:, None, :], hom)[:, 0]
    return np.sqrt(np.mean(np.sum((proj - image_pts) ** 2, axis=1)))


def test_reduced_prvm_undistorts_one_plane(tmp_path):
    """Six photos at one stage position: after the map, the display plane is an exact homography."""
    manifest, truth = make_capture(tmp_path / "d", zs=(0.0,), periods=(480,), flat_levels=[0, 64, 128, 192, 255],
                                   gamma=2.2)
    assert main(["calibrate", str(tmp_path / "d"), "--reduced", "-o", str(tmp_path / "map.npz")]) == 0
    umap = load_undistort_map(tmp_path / "map.npz")
    pts = truth.at_z(0.0)[..., :2] / np.array(DISPLAY.pitch_mm)           # true display px per camera px
    h, w = umap.valid.shape
    v, u = np.mgrid[0:h, 0:w]
    ok = umap.valid
    seen = np.stack([cv2.remap(pts[..., i].astype(np.float32), umap.map_x, umap.map_y, cv2.INTER_LINEAR)
                     for i in range(2)], axis=-1)
    ok &= np.isfinite(seen).all(-1)
    assert ok.mean() > 0.7
    before = _homography_residual(pts.reshape(-1, 2), np.stack([u, v], -1).reshape(-1, 2).astype(float))
    after = _homography_residual(seen[ok].astype(float), np.stack([u[ok], v[ok]], -1).astype(float))
    assert before > 0.1 and after < 0.15 * before
    img = (np.random.default_rng(0).random((h, w)) * 255).astype(np.uint8)
    assert umap.apply(img).shape == img.shape
