"""What users have today: OpenCV's `calibrateCamera` with its richest model (rational + thin prism +
tilted sensor, 14 distortion coefficients), fed the same captures, turned into per-pixel rays so that it
can be compared with the PRVM by the same metric.

Correspondences are WCS points (mm) and image points (pixels): either dense (the decoded display point of
every `step`-th pixel at every stage position, every 2nd by default) or the inner corners of displayed
chessboards. The display
moves only along the stage axis, so all stage positions share one camera pose; they are given to OpenCV as
one non-planar "view" (parallel planes as separate planar views are degenerate for its initialisation),
with the intrinsics initialised from a linear (DLT) projection matrix.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

FLAGS = cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL | cv2.CALIB_TILTED_MODEL


@dataclass
class OpenCVCamera:
    """camera_matrix (3, 3), dist (14,), rvec/tvec (WCS -> camera), rms reprojection error (px)."""

    camera_matrix: np.ndarray
    dist: np.ndarray
    rvec: np.ndarray
    tvec: np.ndarray
    rms_px: float

    def project(self, norm: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) of normalised camera coordinates (N, 2) through the distortion model."""
        obj = np.column_stack([norm, np.ones(len(norm))])
        px, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), self.camera_matrix, self.dist)
        return px.reshape(-1, 2)

    def normalised(self, pixels: np.ndarray, iterations: int = 5) -> np.ndarray:
        """Normalised camera coordinates (N, 2) of pixels (N, 2): OpenCV's undistortion refined by
        Gauss-Newton steps on the forward model, so the inverse is exact to ~1e-6 px."""
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
        x = cv2.undistortPoints(pixels[:, None, :], self.camera_matrix, self.dist, criteria=crit).reshape(-1, 2)
        h = 1e-7
        for _ in range(iterations):
            r = self.project(x) - pixels
            jx = (self.project(x + [h, 0]) - self.project(x)) / h
            jy = (self.project(x + [0, h]) - self.project(x)) / h
            det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
            x = x - np.column_stack([(jy[:, 1] * r[:, 0] - jy[:, 0] * r[:, 1]) / det,
                                     (-jx[:, 1] * r[:, 0] + jx[:, 0] * r[:, 1]) / det])
        return x

    def rays(self, width: int, height: int, z_ref: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """(origin on z = z_ref, unit direction), each (H, W, 3) float64 WCS, of every pixel centre."""
        v, u = np.mgrid[0:height, 0:width].astype(np.float64)
        pts = np.stack([u.ravel(), v.ravel()], axis=1)[:, None, :]
        norm = self.normalised(pts.reshape(-1, 2))
        rot, _ = cv2.Rodrigues(self.rvec)
        d = np.column_stack([norm, np.ones(len(norm))]) @ rot          # rot.T @ [x, y, 1]
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        centre = -rot.T @ self.tvec.ravel()
        t = (z_ref - centre[2]) / d[:, 2]
        o = centre + t[:, None] * d
        return o.reshape(height, width, 3), d.reshape(height, width, 3)


def _dlt(obj: np.ndarray, img: np.ndarray) -> np.ndarray:
    """Intrinsic matrix from a linear 3x4 projection matrix fitted to non-coplanar points."""
    mean, scale = obj.mean(0), obj.std()
    o = (obj - mean) / scale
    rows = []
    for (x, y, z), (u, v) in zip(o, img):
        rows.append([x, y, z, 1, 0, 0, 0, 0, -u * x, -u * y, -u * z, -u])
        rows.append([0, 0, 0, 0, x, y, z, 1, -v * x, -v * y, -v * z, -v])
    _, _, vt = np.linalg.svd(np.asarray(rows))
    p = vt[-1].reshape(3, 4)
    # p[:, :3] = K R, so its inverse R^T K^-1 = Q R' (QR) gives K = inv(R') up to scale and signs
    k = np.linalg.inv(np.linalg.qr(np.linalg.inv(p[:, :3]))[1])
    k = k / k[2, 2]
    s = np.diag(np.sign(np.diag(k)))
    k = k @ s
    k[0, 1] = 0.0
    return k


def calibrate_opencv(object_points: np.ndarray, image_points: np.ndarray, width: int, height: int,
                     flags: int = FLAGS) -> OpenCVCamera:
    """Calibrate from (N, 3) WCS points (mm, on 2 or more planes) and their (N, 2) image points (px)."""
    obj = np.ascontiguousarray(object_points, np.float32)
    img = np.ascontiguousarray(image_points, np.float32)
    sub = np.linspace(0, len(obj) - 1, min(len(obj), 2000)).astype(int)
    k0 = _dlt(obj[sub].astype(np.float64), img[sub].astype(np.float64))
    if not (0 < k0[0, 2] < width and 0 < k0[1, 2] < height and k0[0, 0] > 0 and k0[1, 1] > 0):
        f = float(np.abs(np.diag(k0)[:2]).mean())       # a poor linear fit: start from the centre
        k0 = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    rms, k, dist, rvecs, tvecs = cv2.calibrateCamera([obj], [img], (width, height), k0, np.zeros(14),
                                                     flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS, criteria=crit)
    return OpenCVCamera(k, dist.ravel(), rvecs[0], tvecs[0], float(rms))


def dense_correspondences(points_wcs: list[np.ndarray], valid: list[np.ndarray], step: int = 2):
    """(N, 3) WCS points and (N, 2) pixels from decoded positions: points_wcs[i] (H, W, 3) and valid[i]
    (H, W) per stage position, every `step`-th pixel in both directions. OpenCV's own noise falls with
    the number of points: at 1.3 MP every 8th pixel left it at 2x the rig's stage-error floor, every 2nd
    (650k points, ~4 s) within 25 % of it."""
    obj, img = [], []
    for p, ok in zip(points_wcs, valid):
        h, w = ok.shape
        v, u = np.mgrid[0:h:step, 0:w:step]
        sel = ok[::step, ::step]
        obj.append(p[::step, ::step][sel])
        img.append(np.stack([u[sel], v[sel]], axis=1).astype(np.float64))
    return np.concatenate(obj), np.concatenate(img)


def chessboard_corners(image: np.ndarray, squares: tuple[int, int]) -> np.ndarray | None:
    """(K, 2) inner corners (px), row by row, of a chessboard with squares = (columns, rows), or None."""
    img8 = image if image.dtype == np.uint8 else cv2.convertScaleAbs(image, alpha=255.0 / image.max())
    pattern = (squares[0] - 1, squares[1] - 1)
    ok, corners = cv2.findChessboardCornersSB(img8, pattern, flags=cv2.CALIB_CB_ACCURACY)
    if not ok:
        return None
    corners = corners.reshape(-1, 2).astype(np.float64)
    # OpenCV may return the grid in reverse order; put the first corner nearest the image's top-left
    if corners[0].sum() > corners[-1].sum():
        corners = corners[::-1]
    return corners


def chessboard_display_corners(squares: tuple[int, int], square_px: float, origin_px) -> np.ndarray:
    """(K, 2) display coordinates (c, r) of the inner corners, row by row: square k spans display pixels
    origin + k*size .. origin + (k+1)*size - 1, so its edge lies half a pixel before origin + k*size."""
    cols, rows = squares
    j, i = np.mgrid[1:rows, 1:cols]
    return np.stack([origin_px[0] + i.ravel() * square_px - 0.5, origin_px[1] + j.ravel() * square_px - 0.5], 1)
