"""The display's poses estimated together with a generic (possibly non-central) ray per pixel.

The data: at each of M display poses, each camera pixel n sees a known point q_kn of the display's
plane (decoded display coordinates times the pitch, `calib.decode`). The model: pose k maps the display
frame into a working frame, X_kn = R_k q_kn + t_k, and every pixel's points lie on one line, its ray.
The unknowns are the poses (6 numbers each) and a line per pixel (4 numbers): millions of them, but
given the poses each line is the closed-form weighted least-squares fit through its points
(`calib.prvm.fit_lines`: x, y as linear functions of z, the working frame's z roughly along the rays).
So the poses are found by variable projection (Golub and Pereyra 1973): the residual of the line fits
is minimised as a function of the poses alone, on a subsample of pixels, with Kaufman's (1975)
Jacobian: per pixel, the derivative of its points' offsets from its (fixed) line, projected onto the
complement of the line fit's design. Levenberg-Marquardt steps solve the 6M x 6M normal equations,
which are summed over the pixels from that structure (each point moves with its own pose; the
projection is the identity less a rank-2 term per pixel), so the Jacobian of 2M rows per pixel is
never formed. Then every pixel's ray is fitted once (`calib.prvm.fit_posed_lines`).

The subsample (`pose_sample`) uses every pixel: the image is cut into square blocks (a few thousand),
and each block's points at a pose are averaged with equal weights: that mean lies on the ray of the
block's centre but for a second-order term (the curvature of the image of a tilted plane: ~1 um for
blocks of ~1/80 of the image width, a different amount at each pose), which is taken from a smooth fit
of the means and removed (`_centre_blocks`); the noise is that of one point divided by the block's
width. (Weighting by each pixel's modulation would move the mean off the centre by a different amount
at each pose.)
Blocks with a pixel that did not see a pose, or that lies within `EDGE_MARGIN_PX` of one, are left out
at that pose.

The gauge: one pose's six numbers are fixed (the result's WCS is that display's frame). With display
planes in general poses (hand-held, tilted by tens of degrees) nothing else is free: three planes at
unknown poses fix a generic ray field (Sturm and Ramalingam 2004). With (nearly) parallel planes (a
stage) the affine maps x + a z, y + b z, c z carry parallel planes isometrically onto parallel planes
and lines onto lines, so the data cannot tell those three numbers: `staged_basis` keeps the
stage's nominal travel for them (the linear trend of the positions along and across the axis), and
leaves the rest free (each position's tilt, and its z and lateral errors off that trend), of which
`calib.stage_poses` estimates what the data fix.

Each pose is moved about the centroid of its own points (so rotation and translation decorrelate):
X = Exp(w) (X0 - c) + c + d, with X0 = R0 q + t0 its starting pose. Uncertainty: the covariance of
the free parameters sigma^2 (J^T J)^-1 from the Jacobian at the solution and the residual's variance
per degree of freedom (2 per point less 4 per line and the pose parameters).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

# a pose whose points deviate from a rigid display by a smooth pattern (`_Problem.held_out`: its F
# statistic, over the median pose's or 1, whichever is larger) by more than this is out of family:
# its display moved while its fringes were shown (or bent, or its fringes were decoded wrongly)
OUT_OF_FAMILY = 5.0
# about this many blocks in the subsample (`pose_sample`), each at least MIN_BLOCK pixels wide
SAMPLE_BLOCKS = 6000
MIN_BLOCK = 4
# pixels this close to one that did not see the display are left out of the subsample (the defocus
# blur mixes the display's edge into their fringes)
EDGE_MARGIN_PX = 4
# the degree of the global polynomial whose curvature moves the block means to the blocks' centres
CENTRE_DEGREE = 4


@dataclass
class PoseSample:
    """The subsample of `pose_sample`: points (M, N, 2) display-frame mm (block means), weights (M, N)
    their inverse variances (0: not seen), pixels (N, 2) the (u, v) of each block's centre, block: its
    width (pixels)."""

    points: np.ndarray
    weights: np.ndarray
    pixels: np.ndarray
    block: int

    def subset(self, poses) -> PoseSample:
        """The sample of some of its poses (indices)."""
        return PoseSample(self.points[poses], self.weights[poses], self.pixels, self.block)


def pose_sample(coords: list[np.ndarray], weights: list[np.ndarray], pitch_mm, *, block: int | None = None,
                margin: int = EDGE_MARGIN_PX) -> PoseSample:
    """Block means of decoded display points (module docstring).

    coords: per pose (2, H, W) display coordinates (c, r) (display pixels); weights: per pose (H, W)
    inverse variances of a coordinate in display pixels^2 (0 where not decoded); pitch_mm: (x, y);
    block: the block width (default: `SAMPLE_BLOCKS` blocks over the image, at least `MIN_BLOCK`).
    """
    h, w = weights[0].shape
    if block is None:
        block = max(MIN_BLOCK, int(round(np.sqrt(h * w / SAMPLE_BLOCKS))))
    hb, wb = h // block, w // block
    pitch = np.asarray(pitch_mm, float)
    m = len(coords)
    points = np.zeros((m, hb * wb, 2))
    out_w = np.zeros((m, hb * wb))
    kernel = np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)
    for k, (c, wt) in enumerate(zip(coords, weights)):
        ok = cv2.erode((wt > 0).astype(np.uint8), kernel, borderType=cv2.BORDER_REPLICATE) > 0 if margin else wt > 0
        ok = ok[:hb * block, :wb * block].reshape(hb, block, wb, block)
        full = ok.all(axis=(1, 3)).ravel()
        for i in range(2):
            blocks = c[i, :hb * block, :wb * block].reshape(hb, block, wb, block)
            points[k, :, i] = np.where(full, np.where(ok, blocks, 0.0).mean(axis=(1, 3)).ravel(), 0.0) * pitch[i]
        var = 1.0 / np.maximum(wt[:hb * block, :wb * block].astype(np.float64), 1e-300)
        inv = np.where(ok, var.reshape(hb, block, wb, block), 0.0).sum(axis=(1, 3)).ravel()
        # variance of the mean: sum of the variances / n^2, in mm^2 (the mean pitch; the axes' pitches differ
        # by a fraction of a percent on real displays)
        out_w[k] = np.where(full, block ** 4 / np.maximum(inv, 1e-300), 0.0) / float(np.prod(pitch))
    vb, ub = np.mgrid[0:hb, 0:wb]
    pixels = np.column_stack([ub.ravel() * block + (block - 1) / 2, vb.ravel() * block + (block - 1) / 2])
    _centre_blocks(points, out_w, pixels, (w, h), block)
    return PoseSample(points, out_w, pixels.astype(float), block)


def _centre_blocks(points: np.ndarray, weights: np.ndarray, pixels: np.ndarray, size: tuple[int, int],
                   block: int) -> None:
    """Move each block mean (in place) to its centre pixel's point: the mean of a smooth field over a
    block of b x b pixels exceeds its centre value by (b^2 - 1) / 24 times the field's Laplacian (in
    pixels^-2), taken here from a global polynomial of degree `CENTRE_DEGREE` fitted to the block means
    of each pose and coordinate."""
    scale = np.array([2.0 / size[0], 2.0 / size[1]])
    uv = pixels * scale - 1
    deg = CENTRE_DEGREE
    design = np.polynomial.legendre.legvander2d(uv[:, 0], uv[:, 1], [deg, deg])
    total = np.add.outer(np.arange(deg + 1), np.arange(deg + 1)).ravel() <= deg
    design = design[:, total]
    for k in range(len(points)):
        ok = weights[k] > 0
        if ok.sum() < 4 * total.sum():
            continue
        coef = np.zeros((deg + 1) * (deg + 1))
        for i in range(2):
            coef[total] = np.linalg.lstsq(design[ok], points[k, ok, i], rcond=None)[0]
            c = coef.reshape(deg + 1, deg + 1)
            lap = (np.polynomial.legendre.legval2d(uv[:, 0], uv[:, 1], np.polynomial.legendre.legder(c, 2, axis=0))
                   * scale[0] ** 2 +
                   np.polynomial.legendre.legval2d(uv[:, 0], uv[:, 1], np.polynomial.legendre.legder(c, 2, axis=1))
                   * scale[1] ** 2)
            points[k, ok, i] -= (block ** 2 - 1) / 24 * lap[ok]


@dataclass
class PoseFit:
    """Result of `refine_poses`, in the working frame (mm).

    rotation: (M, 3, 3), translation: (M, 3): X = R q + t for display-frame points q of each pose.
    centre: (M, 3) the centroid of each pose's points (the point its rotation turns about);
    covariance: (M, 6, 6) of each pose's (rotation vector (rad), translation of its centre (mm));
    joint_covariance: (M, 6, M, 6) of all poses' parameters together (`covariance` is its diagonal blocks);
    rms_mm: (M,) RMS distance of its points from the fitted lines (across the working z); chi: (M,) how
    far its points are from one rigid display (`_Problem.held_out`, over the median pose's, or over 1
    if the median is below); sigma: the weighted residual's RMS per
    degree of freedom; pixels: how many pixels the fit used; cost_start, cost: the weighted residual
    sum of squares at the start and the end; dof: the residual's degrees of freedom.
    """

    rotation: np.ndarray
    translation: np.ndarray
    centre: np.ndarray
    covariance: np.ndarray
    rms_mm: np.ndarray
    chi: np.ndarray
    sigma: float
    pixels: int
    cost_start: float
    cost: float
    dof: int
    joint_covariance: np.ndarray | None = None

    @property
    def out_of_family(self) -> np.ndarray:
        """(M,) bool: poses whose residual is out of family (`OUT_OF_FAMILY`)."""
        return self.chi > OUT_OF_FAMILY


def exp_so3(w: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices of rotation vectors w (..., 3) (radians; Rodrigues)."""
    w = np.asarray(w, float)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    k = _skew(w)
    small = theta < 1e-8
    a = np.where(small, 1.0, np.sin(theta) / np.where(small, 1.0, theta))
    b = np.where(small, 0.5, (1 - np.cos(theta)) / np.where(small, 1.0, theta) ** 2)
    return np.eye(3) + a * k + b * (k @ k)


def log_so3(r: np.ndarray) -> np.ndarray:
    """(3,) the rotation vector (radians) of a rotation matrix r."""
    c = np.clip((np.trace(r) - 1) / 2, -1.0, 1.0)
    theta = np.arccos(c)
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if theta < 1e-8:
        return v / 2
    if np.pi - theta < 1e-6:            # near a half turn: from the symmetric part
        m = (r + np.eye(3)) / 2
        axis = m[np.argmax(np.diag(m))]
        return theta * axis / np.linalg.norm(axis)
    return theta * v / (2 * np.sin(theta))


def _skew(w: np.ndarray) -> np.ndarray:
    k = np.zeros(np.shape(w)[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    k[..., 1, 0], k[..., 2, 0], k[..., 2, 1] = w[..., 2], -w[..., 1], w[..., 0]
    return k


def _right_jacobian(w: np.ndarray) -> np.ndarray:
    """(3, 3) right Jacobian of SO(3) at w: Exp(w + dw) = Exp(w) Exp(J_r(w) dw) to first order."""
    theta = float(np.linalg.norm(w))
    k = _skew(w)
    if theta < 1e-6:
        return np.eye(3) - k / 2 + k @ k / 6
    return (np.eye(3) - (1 - np.cos(theta)) / theta ** 2 * k
            + (theta - np.sin(theta)) / theta ** 3 * (k @ k))


class _Problem:
    """The variable-projection residual and Jacobian of a subsample of pixels (module docstring).

    points: (M, N, 2) display-frame points (mm); weights: (M, N) inverse variances (0: missing);
    rotation, translation: the starting poses; basis: (6M, P) the free parameters' directions in the
    poses' parameters (pose k's rotation vector then its centre's translation), x = basis @ p.
    """

    def __init__(self, points, weights, rotation, translation, basis):
        self.w = np.asarray(weights, float)
        self.sw = np.sqrt(self.w)
        q = np.concatenate([points, np.zeros(points.shape[:2] + (1,))], axis=-1)
        x0 = np.einsum("kij,knj->kni", rotation, q) + translation[:, None, :]
        wsum = self.w.sum(axis=1)
        self.centre = (self.w[..., None] * x0).sum(axis=1) / np.maximum(wsum, 1e-300)[:, None]
        self.y = x0 - self.centre[:, None, :]                    # (M, N, 3) about each pose's centre
        self.rotation0, self.translation0 = rotation, translation
        self.basis = basis
        self.m, self.n = self.w.shape

    def unpack(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = (self.basis @ p).reshape(self.m, 6)
        return x[:, :3], x[:, 3:]

    def points(self, p: np.ndarray) -> np.ndarray:
        w, d = self.unpack(p)
        rot = exp_so3(w)
        return np.einsum("kij,knj->kni", rot, self.y) + (self.centre + d)[:, None, :]

    def poses(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rotation (M, 3, 3), translation (M, 3)) of parameters p: X = R q + t."""
        w, d = self.unpack(p)
        rot = exp_so3(w)
        r = rot @ self.rotation0
        t = np.einsum("kij,kj->ki", rot, self.translation0 - self.centre) + self.centre + d
        return r, t

    def _lines(self, x: np.ndarray):
        """Per pixel, the weighted fit of x, y on z over the poses: (mean z, mean xy, slope, residual
        (M, N, 2) weighted, leverage parts (sum w, Szz))."""
        w = self.w
        sw = np.maximum(w.sum(axis=0), 1e-300)
        zm = (w * x[..., 2]).sum(axis=0) / sw
        xm = (w[..., None] * x[..., :2]).sum(axis=0) / sw[:, None]
        dz = x[..., 2] - zm
        szz = np.maximum((w * dz * dz).sum(axis=0), 1e-300)
        b = (w[..., None] * dz[..., None] * (x[..., :2] - xm)).sum(axis=0) / szz[:, None]
        r = self.sw[..., None] * (x[..., :2] - xm - b * dz[..., None])
        return dz, b, r, sw, szz

    def residual(self, p: np.ndarray) -> np.ndarray:
        return self._lines(self.points(p))[2].ravel()

    def normal_equations(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """(J^T J (P, P), J^T r (P,), r^T r) of Kaufman's Jacobian J at p, without forming J: J = Pperp G
        per pixel, G block-diagonal over the poses (each point moves with its own pose only), and
        Pperp = I - u u^T - v v^T the complement of the line fit (u_k = sw_k / sqrt(sum w),
        v_k = sw_k dz_k / sqrt(Szz)), so J^T J = G^T G - (G^T u)(u^T G) - (G^T v)(v^T G) and, as r is
        already projected, J^T r = G^T r. J^T r is the exact gradient of the variable-projection cost."""
        x = self.points(p)
        dz, b, r, sw, szz = self._lines(x)
        w, _ = self.unpack(p)
        rot = exp_so3(w)
        jr = np.stack([_right_jacobian(wk) for wk in w])                          # (M, 3, 3)
        rotated = np.einsum("kij,knj->kni", rot, self.y)                          # Exp(w) y
        # dX/dw = -Exp(w) [y]_x J_r(w) = -[Exp(w) y]_x Exp(w) J_r(w); dX/dd = I
        dxdw = -np.einsum("knij,kjl->knil", _skew(rotated), rot @ jr)             # (M, N, 3, 3)
        g = np.concatenate([dxdw, np.broadcast_to(np.eye(3), dxdw.shape)], axis=-1)  # (M, N, 3, 6)
        gl = self.sw[..., None, None] * (g[..., :2, :] - b[None, :, :, None] * g[..., 2:3, :])  # (M, N, 2, 6)
        u = self.sw / np.sqrt(sw)
        v = self.sw * dz / np.sqrt(szz)
        m, n = self.m, self.n
        jtj = np.zeros((6 * m, 6 * m))
        for k in range(m):
            blk = gl[k].reshape(-1, 6)
            jtj[6 * k:6 * k + 6, 6 * k:6 * k + 6] = blk.T @ blk
        for c in (u, v):
            proj = (c[:, :, None, None] * gl).transpose(1, 2, 0, 3).reshape(2 * n, 6 * m)
            jtj -= proj.T @ proj
        jtr = np.einsum("knid,kni->kd", gl, r).ravel()
        return self.basis.T @ jtj @ self.basis, self.basis.T @ jtr, float(np.sum(r * r))


    def held_out(self, p: np.ndarray, pixels: np.ndarray, iterations: int = 5) -> np.ndarray:
        """(M,) for each pose, how far its points are from one rigid display: its own pose refitted
        alone (6 parameters) against the lines of the other poses' points (which, unlike the joint fit's,
        cannot bend towards it), then the F statistic of the part of that residual a quadratic in the
        image position (`pixels` (N, 2)) explains, against the rest. A display that moved while its
        fringes were shown gives points of two poses, which no rigid pose fits: a smooth residual."""
        x0 = self.points(p)
        span = np.ptp(pixels, axis=0)
        uv = (pixels - pixels.min(axis=0)) / np.where(span > 0, span, 1.0) * 2 - 1
        design = np.column_stack([np.ones(len(uv)), uv[:, 0], uv[:, 1], uv[:, 0] ** 2, uv[:, 0] * uv[:, 1],
                                  uv[:, 1] ** 2])
        out = np.zeros(self.m)
        for k in range(self.m):
            w = self.w.copy()
            w[k] = 0.0
            ok = (self.w[k] > 0) & ((w > 0).sum(axis=0) >= 2)
            sw = np.maximum(w.sum(axis=0), 1e-300)
            zm = (w * x0[..., 2]).sum(axis=0) / sw
            xm = (w[..., None] * x0[..., :2]).sum(axis=0) / sw[:, None]
            dz = x0[..., 2] - zm
            b = (w[..., None] * dz[..., None] * (x0[..., :2] - xm)).sum(axis=0) / \
                np.maximum((w * dz * dz).sum(axis=0), 1e-300)[:, None]
            y = x0[k, ok] - self.centre[k]                            # (n, 3) about the pose's centre
            sq, xm, zm, b = np.sqrt(self.w[k, ok]), xm[ok], zm[ok], b[ok]
            rot, shift = np.eye(3), np.zeros(3)
            for _ in range(iterations):
                x = y @ rot.T + self.centre[k] + shift
                r = sq[:, None] * (x[:, :2] - xm - b * (x[:, 2:] - zm[:, None]))
                g = np.concatenate([-_skew(y @ rot.T), np.broadcast_to(np.eye(3), (len(y), 3, 3))], axis=-1)
                jac = (sq[:, None, None] * (g[:, :2, :] - b[:, :, None] * g[:, 2:3, :])).reshape(-1, 6)
                step = np.linalg.lstsq(jac, -r.ravel(), rcond=None)[0]
                rot, shift = exp_so3(step[:3]) @ rot, shift + step[3:]
            x = y @ rot.T + self.centre[k] + shift
            r = sq[:, None] * (x[:, :2] - xm - b * (x[:, 2:] - zm[:, None]))
            a = sq[:, None] * design[ok]
            smooth = a @ np.linalg.lstsq(a, r, rcond=None)[0]
            ss_smooth, ss = float(np.sum(smooth ** 2)), float(np.sum(r ** 2))
            dof = max(2 * len(r) - 2 * design.shape[1] - 6, 1)
            out[k] = (ss_smooth / (2 * design.shape[1])) / max((ss - ss_smooth) / dof, 1e-300)
        return out


def free_basis(m: int, fixed: int = 0) -> np.ndarray:
    """(6M, 6(M-1)) basis of every pose's six parameters but pose `fixed`'s (the gauge)."""
    keep = [i for i in range(6 * m) if i // 6 != fixed]
    return np.eye(6 * m)[:, keep]


def staged_basis(z_mm: np.ndarray) -> np.ndarray:
    """Basis of the observable pose errors of a stage (module docstring): pose 0 fixed; each other
    pose's rotation free; its translation along x, y and z free off the linear trend in the nominal
    position z_mm (M,) (a nominal travel error, a stage axis not along z: the gauge of parallel
    planes). M >= 3; (6M, 3(M-1) + 3(M-2))."""
    z = np.asarray(z_mm, float)
    m = len(z)
    # translations per axis: vectors v (M,) with v_0 = 0 and sum v (z - z_0) = 0
    a = np.stack([np.eye(m)[0], z - z[0]])
    _, _, vt = np.linalg.svd(a)
    trend_free = vt[2:].T                                         # (M, M-2), orthonormal
    cols = []
    for k in range(1, m):
        for i in range(3):
            c = np.zeros(6 * m)
            c[6 * k + i] = 1.0
            cols.append(c)
    for i in range(3):
        for j in range(trend_free.shape[1]):
            c = np.zeros(6 * m)
            c[6 * np.arange(m) + 3 + i] = trend_free[:, j]
            cols.append(c)
    return np.stack(cols, axis=1)


def information(sample: PoseSample, rotation: np.ndarray, translation: np.ndarray, *,
                basis: np.ndarray) -> np.ndarray:
    """(P, P) J^T J of the free parameters (`basis`) at the given poses: the information the data hold
    on them, per unit residual variance (arguments as `refine_poses`)."""
    points, weights = sample.points, sample.weights
    keep = (weights > 0).sum(axis=0) >= 3
    wts = np.where(weights[:, keep] > 0, weights[:, keep], 0.0)
    pts = np.where(wts[..., None] > 0, points[:, keep], 0.0)
    prob = _Problem(pts, wts, np.asarray(rotation, float), np.asarray(translation, float), basis)
    return prob.normal_equations(np.zeros(basis.shape[1]))[0]


def refine_poses(sample: PoseSample, rotation: np.ndarray, translation: np.ndarray, *,
                 basis: np.ndarray | None = None, max_iterations: int = 50) -> PoseFit:
    """Refine display poses by variable projection (module docstring).

    sample: the display-frame points (mm, x along columns, y along rows) of N pixels (blocks) at M
    poses, with their inverse variances (0 where a pixel did not see that pose) and image positions
    (`pose_sample`); rotation (M, 3, 3), translation (M, 3): the starting poses in the working frame
    (X = R q + t, mm); basis: the free parameters (`free_basis`, the default with pose 0 fixed, or
    `staged_basis`). Pixels need points at 3 or more poses (others are left out).
    """
    points, weights = sample.points, sample.weights
    m = len(rotation)
    keep = (weights > 0).sum(axis=0) >= 3
    pts, wts = points[:, keep], np.where(weights[:, keep] > 0, weights[:, keep], 0.0)
    pts = np.where(wts[..., None] > 0, pts, 0.0)
    basis = free_basis(m) if basis is None else basis
    prob = _Problem(pts, wts, np.asarray(rotation, float), np.asarray(translation, float), basis)
    p = np.zeros(basis.shape[1])
    jtj, jtr, cost = prob.normal_equations(p)
    cost_start, damping = cost, 1e-6
    for _ in range(max_iterations):
        scale = np.maximum(np.diag(jtj), 1e-300)
        step = -np.linalg.solve(jtj + damping * np.diag(scale), jtr)
        trial = float(np.sum(prob.residual(p + step) ** 2))
        if trial < cost:
            p = p + step
            done = cost - trial <= 1e-12 * cost
            jtj, jtr, cost = prob.normal_equations(p)
            damping = max(damping / 10, 1e-12)
            if done:
                break
        else:
            damping *= 10
            if damping > 1e8:
                break
    r = prob.residual(p).reshape(m, -1, 2)
    npts = int((wts > 0).sum())
    dof = max(2 * npts - 4 * int(keep.sum()) - basis.shape[1], 1)
    sigma2 = cost / dof
    cov_p = sigma2 * np.linalg.pinv(jtj)
    joint = (basis @ cov_p @ basis.T).reshape(m, 6, m, 6)
    cov = joint[np.arange(m), :, np.arange(m), :]
    chi_k = prob.held_out(p, sample.pixels[keep])
    rot, t = prob.poses(p)
    # unweighted distances from the lines (mm): the weighted residual over sqrt(w)
    dist = np.where(wts > 0, np.linalg.norm(r, axis=-1) / np.sqrt(np.maximum(wts, 1e-300)), np.nan)
    rms = np.sqrt(np.nanmean(dist ** 2, axis=1))
    w, d = prob.unpack(p)
    centre = prob.centre + d
    return PoseFit(rot, t, centre, cov, rms, chi_k / max(float(np.median(chi_k)), 1.0), float(np.sqrt(sigma2)),
                   int(keep.sum()), cost_start, cost, dof, joint)
