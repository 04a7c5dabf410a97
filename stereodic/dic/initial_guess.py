"""Initial guesses: feature matches with a robust local affine fit, and zero-normalised cross-correlation
(ZNCC) search.

`image_features`, `consistent_matches` and `feature_guess` give every point of a grid a starting warp at once, whatever the
motion: ORB features (Rublee et al., ICCV 2011: oriented FAST corners with rotated BRIEF descriptors,
found over an 8-level scale pyramid, so they follow rotations of any angle and scale changes far beyond
20 %) matched with Lowe's ratio test (IJCV 60, 2004), outliers removed by RANSAC affine fits
(cv2.estimateAffine2D) over overlapping cells of the image, then an affine fitted per point to its
nearest surviving matches (least squares, once more without the matches it leaves off by more than the
RANSAC tolerance). `search_integer` finds where the subset around one reference point went in the deformed image, within a
square search window (OpenCV's matchTemplate, FFT-based for large windows): the seeds of propagation.
`row_search` does the same along the row only (rectified stereo: the match lies on the same row), and
`row_seed_search` wraps it as a seed search of the propagation.
Positions in pixels, (x, y) = (column, row) of the reference image.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from stereodic.dic.background import thread_map, threads
from stereodic.dic.kept import kept

MAX_FEATURES = 4000   # ORB features kept per image (the strongest corners)
DETECT_SIDE = 1024    # features are found on the image shrunk until its longer side is at most this (pixels)
RATIO = 0.8           # Lowe's ratio test: best match distance below RATIO times the second best
CELL_MATCHES = 40     # matches per RANSAC cell, on average
RANSAC_TOL_PX = 3.0   # a match off the local affine by more than this is an outlier, pixels
NEIGHBOURS = 12       # matches per point's local affine fit
MIN_INLIERS = 6       # fewer matches in a cell or a point's fit: no model there
MAX_NODES = 1024      # nodes of the lattice the local affines are fitted on, at most



@dataclass(frozen=True)
class Features:
    """ORB features of an image: pts (M, 2) float64 their positions, pixels (x = column, y = row);
    desc (M, 32) uint8 their binary descriptors."""

    pts: np.ndarray
    desc: np.ndarray


def image_features(img: np.ndarray, *, max_features: int = MAX_FEATURES) -> Features:
    """ORB features of an image (any real dtype; grey levels stretched between its 0.5 and 99.5
    percentiles, of every 4th pixel each way, to 8 bits first; found on the image shrunk by a power of 2
    until its longer side is at most DETECT_SIDE, so that their cost does not grow with the image: a match
    is then good to about a pixel, what IC-GN needs to converge). Those of a read-only array are kept while
    the array lives and returned again for it (a run's rectified reference pair: the rig check and the
    stereo start both match its features).

    Parameters
    ----------
    img : (H, W) array
        The image.
    max_features : int
        At most this many features, the strongest corners.

    Returns
    -------
    features : Features
        Positions (pixels, x = column, y = row) and descriptors; none on a blank image.
    """
    img = np.asarray(img)
    if img.flags.writeable:
        return _orb(img, max_features)
    return kept(("features", id(img), max_features), (img,), lambda: _orb(img, max_features))


def _orb(img: np.ndarray, max_features: int) -> Features:
    """`image_features` computed."""
    shrink = 1
    while max(img.shape) > DETECT_SIDE * shrink:
        shrink *= 2
    if shrink > 1:
        img = cv2.resize(img.astype(np.float32), None, fx=1 / shrink, fy=1 / shrink, interpolation=cv2.INTER_AREA)
    lo, hi = np.percentile(img[::4, ::4], (0.5, 99.5))
    u8 = np.clip((img.astype(np.float32) - lo) * (255.0 / max(float(hi - lo), 1e-12)), 0, 255).astype(np.uint8)
    kps, desc = cv2.ORB_create(max_features).detectAndCompute(u8, None)
    if desc is None:
        return Features(np.zeros((0, 2)), np.zeros((0, 32), np.uint8))
    # INTER_AREA: pixel i of the shrunk image covers pixels shrink i .. shrink (i + 1) - 1
    return Features((np.array([k.pt for k in kps], np.float64) + 0.5) * shrink - 0.5, desc)


def _matches(ref: Features, dfm: Features) -> tuple[np.ndarray, np.ndarray]:
    """Matched positions (K, 2) in the reference and deformed images that pass the ratio test."""
    if len(ref.pts) < 2 or len(dfm.pts) < 2:
        return np.zeros((0, 2)), np.zeros((0, 2))
    # the reference's descriptors in one block a thread (OpenCV releases the GIL): the same matches
    blocks = np.array_split(np.arange(len(ref.desc)), threads())
    pairs = [m for part in thread_map(lambda rows: _knn(ref.desc[rows], dfm.desc, rows[0] if rows.size else 0),
                                      blocks) for m in part]
    good = [m[0] for m in pairs if len(m) == 2 and m[0].distance < RATIO * m[1].distance]
    qi = np.array([m.queryIdx for m in good], np.int64)
    ti = np.array([m.trainIdx for m in good], np.int64)
    return ref.pts[qi].reshape(-1, 2), dfm.pts[ti].reshape(-1, 2)


def _knn(desc: np.ndarray, train: np.ndarray, first: int) -> list:
    """OpenCV's two nearest (Hamming) of `train` for each of `desc`, whose query indices start at `first`."""
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(desc, train, k=2) if len(desc) else []
    for m in pairs:
        for match in m:
            match.queryIdx += first
    return pairs


def _inliers(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(K,) bool: the matches p -> q that some cell's RANSAC affine (cells of about CELL_MATCHES matches,
    each fitted to the matches within half a cell of it) keeps within RANSAC_TOL_PX."""
    keep = np.zeros(len(p), bool)
    g = int(np.clip(round(np.sqrt(len(p) / CELL_MATCHES)), 1, 16))
    lo, hi = p.min(0), p.max(0) + 1e-9
    size = (hi - lo) / g
    for i in range(g):
        for j in range(g):
            a = lo + size * (i - 0.5, j - 0.5)
            b = lo + size * (i + 1.5, j + 1.5)
            sel = np.flatnonzero(np.all((p >= a) & (p <= b), axis=1))
            if sel.size < MIN_INLIERS:
                continue
            model, mask = cv2.estimateAffine2D(p[sel], q[sel], method=cv2.RANSAC,
                                               ransacReprojThreshold=RANSAC_TOL_PX, maxIters=500)
            if model is None or mask.sum() < MIN_INLIERS:
                continue
            keep[sel[mask.ravel() > 0]] = True
    return keep


def _local_affine(p: np.ndarray, q: np.ndarray, xs: np.ndarray, ys: np.ndarray, nbr: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares affine displacement about each point (xs, ys) from the matches nbr (N, k) (indices
    into p -> q, -1 = none): (N, 6) (u, ux, uy, v, vx, vy) and (N,) bool (at least MIN_INLIERS matches
    and a full-rank fit)."""
    have = nbr >= 0
    idx = np.where(have, nbr, 0)
    dx = p[idx, 0] - xs[:, None]
    dy = p[idx, 1] - ys[:, None]
    w = have.astype(np.float64)
    A = np.stack([np.ones_like(dx), dx, dy], -1) * w[..., None]
    ata = np.einsum("nki,nkj->nij", A, A)
    rhs = np.stack([np.einsum("nki,nk->ni", A, q[idx, 0] - p[idx, 0]),
                    np.einsum("nki,nk->ni", A, q[idx, 1] - p[idx, 1])], -1)
    # Hadamard's ratio det / product of the diagonal (1 for orthogonal columns, 0 for collinear matches)
    diag = np.einsum("nii->ni", ata).prod(1)
    ok = (have.sum(1) >= MIN_INLIERS) & (np.linalg.det(ata) > 1e-6 * diag)
    sol = np.zeros((len(xs), 3, 2))
    if ok.any():
        sol[ok] = np.linalg.solve(ata[ok], rhs[ok])
    return np.concatenate([sol[:, :, 0], sol[:, :, 1]], 1), ok


def consistent_matches(ref: Features, dfm: Features) -> tuple[np.ndarray, np.ndarray]:
    """The feature matches between two images that pass the ratio test and some cell's RANSAC affine
    (module docstring). Kept while both Features live and returned again for them (read-only arrays:
    the rig check and the stereo start match the reference pair's features).

    Parameters
    ----------
    ref, dfm : Features
        The reference and deformed images' features (`image_features`).

    Returns
    -------
    p, q : (K, 2) float64
        Matched positions in the reference and the deformed image, pixels (x = column, y = row); K may be 0.
    """
    return kept(("matches", id(ref), id(dfm)), (ref, dfm), lambda: _consistent(ref, dfm))


def _consistent(ref: Features, dfm: Features) -> tuple[np.ndarray, np.ndarray]:
    """`consistent_matches` computed (read-only arrays)."""
    p, q = _matches(ref, dfm)
    if len(p) < MIN_INLIERS:
        p, q = np.zeros((0, 2)), np.zeros((0, 2))
    else:
        keep = _inliers(p, q)
        p, q = p[keep], q[keep]
    for a in (p, q):
        a.flags.writeable = False
    return p, q


def feature_guess(matches: tuple[np.ndarray, np.ndarray], xs: np.ndarray, ys: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Starting affine warps of the points (xs, ys) of the reference image from consistent feature
    matches (module docstring).

    Parameters
    ----------
    matches : ((K, 2), (K, 2)) float64
        Matched positions in the reference and deformed images, pixels (`consistent_matches`).
    xs, ys : (N,) float
        The points, reference pixels (x = column, y = row).

    Returns
    -------
    warp : (N, 6) float64
        (u, ux, uy, v, vx, vy): the displacement at the point, pixels, and its gradient (the affine shape
        function of `stereodic.dic.icgn`).
    ok : (N,) bool
        Whether the point got a guess (at least MIN_INLIERS consistent matches around it).
    """
    xs = np.asarray(xs, np.float64)
    ys = np.asarray(ys, np.float64)
    p, q = matches
    if len(p) < MIN_INLIERS or xs.size == 0:
        return np.zeros((xs.size, 6)), np.zeros(xs.size, bool)
    if xs.size <= 4 * len(p):
        return _robust_affine(p, q, xs, ys)
    # more points than matches: fit on a lattice of about one node per match (at most MAX_NODES) over the
    # points' extent, then the bilinear blend of the four nodes around each point (the displacement and
    # its gradient)
    x0, y0, x1, y1 = xs.min(), ys.min(), xs.max(), ys.max()
    spacing = max(np.sqrt((x1 - x0 + 1) * (y1 - y0 + 1) / min(len(p), MAX_NODES)), 1.0)
    nx, ny = int(np.ceil((x1 - x0) / spacing)) + 1, int(np.ceil((y1 - y0) / spacing)) + 1
    gx, gy = np.meshgrid(x0 + spacing * np.arange(nx), y0 + spacing * np.arange(ny))
    node, node_ok = _robust_affine(p, q, gx.ravel(), gy.ravel())
    node = node.reshape(ny, nx, 6)
    node_ok = node_ok.reshape(ny, nx)
    fx, fy = (xs - x0) / spacing, (ys - y0) / spacing
    c, r = np.minimum(fx.astype(np.int64), max(nx - 2, 0)), np.minimum(fy.astype(np.int64), max(ny - 2, 0))
    c1, r1 = np.minimum(c + 1, nx - 1), np.minimum(r + 1, ny - 1)
    tx, ty = (fx - c)[:, None], (fy - r)[:, None]
    warp = ((1 - ty) * ((1 - tx) * node[r, c] + tx * node[r, c1]) + ty * ((1 - tx) * node[r1, c] + tx * node[r1, c1]))
    # each node's warp is about the node: move it to the point (u += ux dx + uy dy, v likewise)
    ok = node_ok[r, c] & node_ok[r, c1] & node_ok[r1, c] & node_ok[r1, c1]
    for corner_r, corner_c, weight in ((r, c, (1 - tx) * (1 - ty)), (r, c1, tx * (1 - ty)), (r1, c, (1 - tx) * ty),
                                       (r1, c1, tx * ty)):
        dx = (xs - gx[corner_r, corner_c])[:, None]
        dy = (ys - gy[corner_r, corner_c])[:, None]
        nd = node[corner_r, corner_c]
        warp[:, [0]] += weight * (nd[:, [1]] * dx + nd[:, [2]] * dy)
        warp[:, [3]] += weight * (nd[:, [4]] * dx + nd[:, [5]] * dy)
    return warp, ok


def _nearest(p: np.ndarray, xs: np.ndarray, ys: np.ndarray, k: int) -> np.ndarray:
    """(N, k) indices of the k points of p (M, 2) nearest to each (xs, ys) (of points at equal distances,
    either): every distance, by OpenCV's brute-force FLANN index (exact; float32 differences from the
    matches' mean, so near ties are told apart to about 1e-4 px), the points in blocks side by side on
    the run's threads (OpenCV releases the GIL; an index each). 1024 points among 4000 matches take 16 ms
    on one thread; scipy's k-d tree would be faster per query, but its first use in a process imports
    scipy.spatial: 0.24 s and 0.4 CPU-s, more than a run's guesses take."""
    centre = p.mean(axis=0) if len(p) else np.zeros(2)
    data = np.ascontiguousarray(p - centre, np.float32)
    queries = np.ascontiguousarray(np.column_stack([xs, ys]) - centre, np.float32)
    if not queries.size:
        return np.empty((0, k), np.int64)

    def block(rows: np.ndarray) -> np.ndarray:
        return cv2.flann_Index(data, {"algorithm": 0}).knnSearch(queries[rows], k)[0]   # 0: FLANN_INDEX_LINEAR

    parts = [r for r in np.array_split(np.arange(len(queries)), threads()) if r.size]
    return np.concatenate(thread_map(block, parts)).astype(np.int64).reshape(len(queries), k)


def _robust_affine(p: np.ndarray, q: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The local affine of each point (xs, ys) from its NEIGHBOURS nearest matches p -> q, fitted again
    without the matches it leaves off by more than RANSAC_TOL_PX; (N, 6) and (N,) bool as `_local_affine`."""
    nbr = _nearest(p, xs, ys, min(NEIGHBOURS, len(p)))
    warp, ok = _local_affine(p, q, xs, ys, nbr)
    dx = p[nbr, 0] - xs[:, None]
    dy = p[nbr, 1] - ys[:, None]
    ru = warp[:, [0]] + warp[:, [1]] * dx + warp[:, [2]] * dy - (q[nbr, 0] - p[nbr, 0])
    rv = warp[:, [3]] + warp[:, [4]] * dx + warp[:, [5]] * dy - (q[nbr, 1] - p[nbr, 1])
    nbr = np.where(np.hypot(ru, rv) <= RANSAC_TOL_PX, nbr, -1)
    warp2, ok2 = _local_affine(p, q, xs, ys, nbr)
    return np.where(ok2[:, None], warp2, warp), ok & ok2


def _as_f32(img: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(img, dtype=np.float32)


def _best(score: np.ndarray) -> tuple[int, int, float]:
    score = np.nan_to_num(score, nan=-1.0, posinf=-1.0, neginf=-1.0)
    r, c = np.unravel_index(int(np.argmax(score)), score.shape)
    return int(r), int(c), float(score[r, c])


def search_integer(ref: np.ndarray, dfm: np.ndarray, x: int, y: int, half: int, radius: int,
                   centre: tuple[int, int] = (0, 0)) -> tuple[int, int, float]:
    """Integer displacement (du, dv) of the subset of half-width `half` centred on pixel (x, y) of `ref`
    that maximises ZNCC in `dfm`, searched within `radius` pixels of `centre` = (du0, dv0).

    Returns (du, dv, zncc); zncc = -1 when the window leaves the image or the subset has no texture."""
    h, w = ref.shape
    if not (half <= x < w - half and half <= y < h - half):
        return 0, 0, -1.0
    tpl = _as_f32(ref[y - half:y + half + 1, x - half:x + half + 1])
    if float(tpl.std()) == 0.0:
        return 0, 0, -1.0
    x0 = max(0, x + centre[0] - radius - half)
    x1 = min(w, x + centre[0] + radius + half + 1)
    y0 = max(0, y + centre[1] - radius - half)
    y1 = min(h, y + centre[1] + radius + half + 1)
    if x1 - x0 < 2 * half + 1 or y1 - y0 < 2 * half + 1:
        return 0, 0, -1.0
    score = cv2.matchTemplate(_as_f32(dfm[y0:y1, x0:x1]), tpl, cv2.TM_CCOEFF_NORMED)
    r, c, z = _best(score)
    return x0 + c + half - x, y0 + r + half - y, z


def row_search(ref: np.ndarray, dfm: np.ndarray, xs: np.ndarray, ys: np.ndarray, *, half: int,
               dmin: int, dmax: int, rows: int = 0) -> tuple[np.ndarray, np.ndarray] | tuple[np.ndarray, ...]:
    """Integer disparities along the rows of a rectified pair: for each point of `ref`, the shift d in
    [dmin, dmax] along the same row of `dfm` (match at x + d) with the highest ZNCC (cv2.matchTemplate).

    Parameters
    ----------
    ref, dfm : (H, W) array
        The two images (e.g. left and right rectified).
    xs, ys : (N,) int
        The points in `ref`, pixels (x = column, y = row).
    half : int
        The subset's half-width, pixels (side 2 half + 1).
    dmin, dmax : int
        The range of shifts searched, pixels.
    rows : int
        Also search that many rows above and below (a band about the row, for a rig whose rows no longer
        line up exactly).

    Returns
    -------
    d : (N,) int64
        The best shift along the row, pixels.
    dv : (N,) int64
        The best row shift, pixels; returned only with `rows` > 0.
    zncc : (N,) float64
        Its ZNCC; -1 where no shift of the range keeps the subset in the image.
    """
    h, w = ref.shape
    d_out = np.zeros(len(xs), np.int64)
    dv_out = np.zeros(len(xs), np.int64)
    z_out = np.full(len(xs), -1.0)
    ref32 = _as_f32(ref)
    def32 = _as_f32(dfm)
    for k, (x, y) in enumerate(zip(np.asarray(xs, int), np.asarray(ys, int))):
        if not (half <= x < w - half and half <= y < h - half):
            continue
        lo = max(x + dmin, half)
        hi = min(x + dmax, w - 1 - half)
        top, bottom = max(y - rows, half), min(y + rows, h - 1 - half)
        if hi < lo:
            continue
        tpl = ref32[y - half:y + half + 1, x - half:x + half + 1]
        band = def32[top - half:bottom + half + 1, lo - half:hi + half + 1]
        r, c, z = _best(cv2.matchTemplate(band, tpl, cv2.TM_CCOEFF_NORMED))
        d_out[k] = lo + c - x
        dv_out[k] = top + r - y
        z_out[k] = z
    return (d_out, z_out) if rows == 0 else (d_out, dv_out, z_out)


def row_seed_search(dmin: int, dmax: int, rows: int = 0):
    """A seed search with `search_integer`'s signature that looks along the row only (or a band of `rows`
    rows either side of it), at shifts dmin..dmax (its radius and centre are ignored): the seeds of a
    rectified stereo pair."""
    def search(ref, dfm, x, y, half, radius, centre):
        if rows == 0:
            d, z = row_search(ref, dfm, [x], [y], half=half, dmin=dmin, dmax=dmax)
            return int(d[0]), 0, float(z[0])
        d, dv, z = row_search(ref, dfm, [x], [y], half=half, dmin=dmin, dmax=dmax, rows=rows)
        return int(d[0]), int(dv[0]), float(z[0])
    return search
