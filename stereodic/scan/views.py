"""Scans of one object from several sides (a turntable, or the object moved) registered into one frame
and merged (Open3D).

Registration of view k into view 0's frame (`register_views`):
 1. global, unless approximate transforms are given (a turntable's nominal angles): each view
    down-sampled to voxels of `voxel_mm`, FPFH features, RANSAC on feature matches against the views
    already placed;
 2. fine: point-to-plane ICP of the full-resolution view against all the views already placed;
 3. a last pass: ICP of every view but the first against all the others, in view 0's frame.

A whole turn (`register_turn`): each view registered to the one before it, then every overlapping pair
(the last view and the first among them) as loop closures, all in Open3D's pose graph, optimised so that
the error does not accumulate round the turn; then the same last pass.

A turntable's turn (`register_turntable`): `register_turn`, then one axis and one angle per view fitted to
its transforms (`fit_turntable`), then that axis (4 unknowns) and the angles (K - 1) refined together by a
robust point-to-plane fit over all the overlapping pairs of views (`refine_turntable`): every view turned
about the same axis, so that no view's own shape bias tilts or shifts it alone.

Each view's residual is the RMS point-to-plane distance (mm) of its points to their nearest point of the
other views within `max_mm` (the other view's normal), its fitness the share of its points that have one.

`merged_cloud` puts the registered views into one cloud, voxel-averaged where they overlap, with their
normals (oriented outwards by each view's scanner) for the Poisson mesh.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np


@dataclass
class Registration:
    """Per view: transforms (K, 4, 4) float64 mapping view k's points (mm) into view 0's frame (view 0:
    identity); residual_mm (K,) the RMS point-to-plane distance of each view's points to the other views;
    fitness (K,) the share of its points with a partner there (module docstring)."""

    transforms: np.ndarray
    residual_mm: np.ndarray
    fitness: np.ndarray


def _cloud(points: np.ndarray, normal_mm: float):
    import open3d as o3d
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=normal_mm, max_nn=30))
    return pc


def _placed(clouds: list, transforms: list, which):
    """The clouds `which`, each moved by its transform, as one."""
    import open3d as o3d
    out = o3d.geometry.PointCloud()
    for j in which:
        out += copy.deepcopy(clouds[j]).transform(transforms[j])
    return out


def _icp(source, target, init: np.ndarray, max_mm: float, robust_mm: float | None = None):
    """Point-to-plane ICP, correspondences within `max_mm`; with `robust_mm`, Tukey's biweight of that
    scale (mm) weighs them, so that a scan's local systematic errors (creases, edges) hardly count."""
    import open3d as o3d
    reg = o3d.pipelines.registration
    kernel = [] if robust_mm is None else [reg.TukeyLoss(k=robust_mm)]
    return reg.registration_icp(source, target, max_mm, init, reg.TransformationEstimationPointToPlane(*kernel),
                                reg.ICPConvergenceCriteria(relative_fitness=1e-10, relative_rmse=1e-10,
                                                           max_iteration=200))


def _global(source, source_feature, target, target_feature, voxel_mm: float) -> np.ndarray:
    """(4, 4) source into target: RANSAC on FPFH feature matches of the down-sampled clouds."""
    import open3d as o3d
    reg = o3d.pipelines.registration
    checks = [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
              reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel_mm)]
    return reg.registration_ransac_based_on_feature_matching(
        source, target, source_feature, target_feature, True, 1.5 * voxel_mm,
        reg.TransformationEstimationPointToPoint(False), 3, checks,
        reg.RANSACConvergenceCriteria(400_000, 0.9999)).transformation


def _features(full: list, voxel_mm: float) -> tuple[list, list]:
    """Each cloud down-sampled to voxels of `voxel_mm` (normals over 2 voxels) and its FPFH features
    (over 5 voxels)."""
    import open3d as o3d
    small, feats = [], []
    for pc in full:
        s = pc.voxel_down_sample(voxel_mm)
        s.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel_mm, max_nn=30))
        small.append(s)
        feats.append(o3d.pipelines.registration.compute_fpfh_feature(
            s, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel_mm, max_nn=100)))
    return small, feats


def register_views(views: list[np.ndarray], *, voxel_mm: float = 2.0, max_mm: float = 0.5,
                   initial: np.ndarray | None = None, seed: int = 0) -> Registration:
    """Register scans of one object from several sides into the first one's frame (module docstring).

    Parameters
    ----------
    views : list of (N_k, 3) float arrays
        Each view's points, mm, in the scanner's frame; each view must overlap those before it.
    voxel_mm : float
        The global step's down-sampling, mm (normals over 2 voxels, features over 5).
    max_mm : float
        The largest ICP correspondence distance, mm (the first ICP of a view: 4 times it).
    initial : (K, 4, 4) float, optional
        Approximate transforms into view 0's frame (a turntable's nominal angles): no global step.
    seed : int
        Seeds RANSAC.

    Returns
    -------
    registration : Registration
        Each view's transform into view 0's frame, its residual (mm) and fitness (module docstring).
    """
    import open3d as o3d
    o3d.utility.random.seed(seed)
    full = [_cloud(v, 2 * voxel_mm) for v in views]
    small, feats = _features(full, voxel_mm) if initial is None else ([], [])
    transforms = [np.eye(4)]
    for k in range(1, len(views)):
        if initial is not None:
            start = np.asarray(initial[k], np.float64)
        else:
            feature = o3d.pipelines.registration.Feature()
            feature.data = np.hstack([feats[j].data for j in range(k)])
            start = _global(small[k], feats[k], _placed(small, transforms, range(k)), feature, voxel_mm)
        coarse = _icp(full[k], _placed(full, transforms, range(k)), start, 4 * max_mm).transformation
        transforms.append(_icp(full[k], _placed(full, transforms, range(k)), coarse, max_mm).transformation)
    transforms = _refine(full, np.asarray(transforms), max_mm)
    return Registration(transforms, *_residuals(full, transforms, max_mm))


def _refine(full: list, transforms: np.ndarray, max_mm: float, robust_mm: float | None = None,
            passes: int = 1) -> np.ndarray:
    """The transforms after `passes` rounds of an ICP of every view but the first against all the
    others, in view 0's frame."""
    transforms = transforms.copy()
    for _ in range(passes):
        for k in range(1, len(full)):
            transforms[k] = _icp(full[k], _placed(full, transforms, [j for j in range(len(full)) if j != k]),
                                 transforms[k], max_mm, robust_mm).transformation
    return transforms


def _pair(source, target, start: np.ndarray, max_mm: float, robust_mm: float):
    """ICP of source onto target from `start` (4 x `max_mm`, then `max_mm` with Tukey's weights of
    `robust_mm`): the (4, 4) transform, its fitness and the 6 x 6 information matrix of its
    correspondences (Open3D's, for the pose graph)."""
    import open3d as o3d
    coarse = _icp(source, target, start, 4 * max_mm).transformation
    fine = _icp(source, target, coarse, max_mm, robust_mm)
    info = o3d.pipelines.registration.get_information_matrix_from_point_clouds(source, target, max_mm,
                                                                               fine.transformation)
    return fine.transformation, fine.fitness, info


def _residuals(full: list, transforms: np.ndarray, max_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Per view: the RMS point-to-plane distance (mm) of its points, placed, to their nearest point of
    the other views within `max_mm`, and the share of its points that have one."""
    from scipy.spatial import cKDTree
    placed = [(np.asarray(pc.points) @ t[:3, :3].T + t[:3, 3], np.asarray(pc.normals) @ t[:3, :3].T)
              for pc, t in zip(full, transforms)]
    residual, fitness = np.zeros(len(full)), np.zeros(len(full))
    for k, (points, _) in enumerate(placed):
        others = [j for j in range(len(full)) if j != k]
        target = np.vstack([placed[j][0] for j in others])
        normal = np.vstack([placed[j][1] for j in others])
        dist, idx = cKDTree(target).query(points, distance_upper_bound=max_mm)
        hit = np.isfinite(dist)
        along = np.einsum("ij,ij->i", points[hit] - target[idx[hit]], normal[idx[hit]])
        residual[k] = np.sqrt(np.mean(along ** 2)) if hit.any() else np.nan
        fitness[k] = hit.mean()
    return residual, fitness


def register_turn(views: list[np.ndarray], *, voxel_mm: float = 2.0, max_mm: float = 0.5,
                  robust_mm: float = 0.01, initial: np.ndarray | None = None, min_overlap: float = 0.2,
                  passes: int = 2, seed: int = 0) -> Registration:
    """Register scans taken all the way round an object (a turntable's whole turn), view to view, and
    close the loop with a pose graph so that the error does not accumulate round it.

    1. odometry: each view k is registered to view k - 1 (global step: FPFH + RANSAC between the two,
       unless `initial` is given; then point-to-plane ICP), which chains the views into view 0's frame;
    2. loop closures: every other pair (i, j), the last view and the first among them, is ICP-registered
       from the chained transforms; those with at least `min_overlap` of points paired are kept;
    3. Open3D's pose graph (odometry edges certain, loop closures uncertain, each weighted by the
       information matrix of its correspondences) is optimised by Levenberg-Marquardt, view 0 fixed
       (Choi, Zhou and Koltun, "Robust reconstruction of indoor scenes", CVPR 2015);
    4. a last pass: ICP of every view but the first against all the others (its neighbours on both sides).

    Parameters
    ----------
    views : list of (N_k, 3) float arrays
        Each view's points, mm, in the scanner's frame, in the order of the turn; each view overlaps the
        one before it.
    voxel_mm : float
        The global step's down-sampling, mm (normals over 2 voxels, features over 5).
    max_mm : float
        The largest ICP correspondence distance, mm (each ICP starts at 4 times it).
    robust_mm : float
        The scale of Tukey's biweight in the fine ICPs, mm: a few times the scans' noise; points farther
        than it from the other view (a scan's systematic errors at creases and edges) do not count.
    initial : (K, 4, 4) float, optional
        Approximate transforms into view 0's frame (a turntable's nominal angles): no global step.
    min_overlap : float
        The share of a pair's points that must find a partner for a loop closure to be kept.
    passes : int
        Rounds of the last pass (step 4).
    seed : int
        Seeds RANSAC.

    Returns
    -------
    registration : Registration
        Each view's transform into view 0's frame, its residual (RMS point-to-plane distance to the other
        views, mm) and fitness (the share of its points within `max_mm` of another view).
    """
    full = [_cloud(v, 2 * voxel_mm) for v in views]
    transforms = _turn(full, voxel_mm, max_mm, robust_mm, initial, min_overlap, passes, seed)
    return Registration(transforms, *_residuals(full, transforms, max_mm))


def _turn(full: list, voxel_mm: float, max_mm: float, robust_mm: float, initial: np.ndarray | None,
          min_overlap: float, passes: int, seed: int) -> np.ndarray:
    """(K, 4, 4) `register_turn`'s transforms of the Open3D clouds `full` (with normals)."""
    import open3d as o3d
    reg = o3d.pipelines.registration
    o3d.utility.random.seed(seed)
    small, feats = _features(full, voxel_mm) if initial is None else ([], [])
    graph, poses = reg.PoseGraph(), [np.eye(4)]
    graph.nodes.append(reg.PoseGraphNode(np.eye(4)))
    for k in range(1, len(full)):          # edge source k - 1 -> target k: view k - 1 into view k's frame
        start = (np.linalg.inv(initial[k]) @ initial[k - 1] if initial is not None else
                 _global(small[k - 1], feats[k - 1], small[k], feats[k], voxel_mm))
        t, _, info = _pair(full[k - 1], full[k], np.asarray(start, np.float64), max_mm, robust_mm)
        poses.append(poses[k - 1] @ np.linalg.inv(t))
        graph.nodes.append(reg.PoseGraphNode(poses[k]))
        graph.edges.append(reg.PoseGraphEdge(k - 1, k, t, info, uncertain=False))
    for i in range(len(full)):
        for j in range(i + 2, len(full)):
            start = np.linalg.inv(poses[j]) @ poses[i]
            if reg.evaluate_registration(full[i], full[j], 4 * max_mm, start).fitness < min_overlap:
                continue
            t, fitness, info = _pair(full[i], full[j], start, max_mm, robust_mm)
            if fitness >= min_overlap:
                graph.edges.append(reg.PoseGraphEdge(i, j, t, info, uncertain=True))
    reg.global_optimization(graph, reg.GlobalOptimizationLevenbergMarquardt(),
                            reg.GlobalOptimizationConvergenceCriteria(),
                            reg.GlobalOptimizationOption(max_correspondence_distance=max_mm, edge_prune_threshold=0.25,
                                                         preference_loop_closure=1.0, reference_node=0))
    return _refine(full, np.asarray([np.asarray(node.pose) for node in graph.nodes]), max_mm, robust_mm, passes)


@dataclass
class Turntable:
    """A turntable's turn: one rigid axis and one angle per view. point_mm (3,) a point of the axis and
    direction (3,) its unit direction, in view 0's (the scanner's) frame, mm; angles_deg (K,) how far the
    object is turned from view 0 to view k, degrees, right-handed about `direction`, in [0, 360).
    `transforms()`: each view's points into view 0's frame."""

    point_mm: np.ndarray
    direction: np.ndarray
    angles_deg: np.ndarray

    def transforms(self) -> np.ndarray:
        """(K, 4, 4) view k's points into view 0's frame: turned back by angles_deg[k] about the axis."""
        from scipy.spatial.transform import Rotation
        axis = np.asarray(self.direction, np.float64) / np.linalg.norm(self.direction)
        point = np.asarray(self.point_mm, np.float64)
        out = np.tile(np.eye(4), (len(self.angles_deg), 1, 1))
        out[:, :3, :3] = Rotation.from_rotvec(-np.radians(self.angles_deg)[:, None] * axis).as_matrix()
        out[:, :3, 3] = point - out[:, :3, :3] @ point
        return out


@dataclass
class TurntableRegistration(Registration):
    """`Registration` of a turntable's views (`register_turntable`): the transforms are the `turntable`'s
    (the fitted axis and angles)."""

    turntable: Turntable


def turntable_transforms(views: int, point_mm, direction) -> np.ndarray:
    """(views, 4, 4) the nominal transforms of a whole turn in equal steps: view k's points into view 0's
    frame, for an object turned by 360 / views degrees (right-handed about `direction`) from one view to
    the next about the axis through `point_mm` (3,) (the scanner's frame, mm); `register_turn`'s initial."""
    return Turntable(point_mm, direction, 360.0 * np.arange(views) / views).transforms()


def fit_turntable(transforms: np.ndarray, *, near_mm=None) -> Turntable:
    """The turntable (one axis, one angle per view) that best explains rigid transforms of its views.

    The direction is the principal eigenvector of sum_k (1 - cos phi_k) a_k a_k^T, the views' rotation
    axes a_k weighted as their rotations' angles phi_k make them certain (the symmetric part of each
    rotation); each angle the least-squares one (Frobenius) about that direction; the point the linear
    least-squares solution of t_k = (I - R_k) p with those rotations. The direction's sign makes the
    steps from one view to the next turn forwards (the sum of their sines positive).

    Parameters
    ----------
    transforms : (K, 4, 4) float
        Each view's points into view 0's frame (`register_turn`'s), mm.
    near_mm : (3,) float, optional
        The axis point returned is the one nearest to this (default: the frame's origin), mm.

    Returns
    -------
    turntable : Turntable
        The axis (view 0's frame, mm) and each view's angle (view 0's: 0 for an identity transform).
    """
    t = np.asarray(transforms, np.float64)
    r, shift = t[:, :3, :3], t[:, :3, 3]
    trace = np.trace(r, axis1=1, axis2=2)
    scatter = ((r + r.transpose(0, 2, 1)) / 2 - ((trace - 1) / 2)[:, None, None] * np.eye(3)).sum(axis=0)
    direction = np.linalg.eigh(scatter)[1][:, -1]
    skew = np.stack([r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0], r[:, 1, 0] - r[:, 0, 1]], axis=1)
    turn = np.arctan2(skew @ direction, trace - np.einsum("i,kij,j->k", direction, r, direction))
    angles = -turn                  # the transforms turn view k back by its angle
    if np.sum(np.sin(np.diff(angles))) < 0:
        direction, angles = -direction, -angles
    table = Turntable(np.zeros(3), direction, np.degrees(angles) % 360.0)
    lhs = np.eye(3) - table.transforms()[:, :3, :3]
    point = np.linalg.lstsq(lhs.reshape(-1, 3), shift.reshape(-1), rcond=None)[0]
    near = np.zeros(3) if near_mm is None else np.asarray(near_mm, np.float64)
    table.point_mm = point + direction * (direction @ (near - point))
    return table


def _tukey(r: np.ndarray, scale: float) -> np.ndarray:
    """Tukey's biweight of residuals `r` for the scale `scale` (same units): (1 - (r / scale)^2)^2, 0 beyond."""
    return np.where(np.abs(r) < scale, (1 - (r / scale) ** 2) ** 2, 0.0)


def _turn_y(angle_rad: float) -> np.ndarray:
    """(3, 3) the rotation by `angle_rad` right-handed about y."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _axis_frame(direction: np.ndarray) -> np.ndarray:
    """(3, 3) orthonormal columns, the second one `direction` (unit)."""
    other = np.eye(3)[np.argmin(np.abs(direction))]
    first = np.cross(direction, other)
    first /= np.linalg.norm(first)
    return np.stack([first, direction, np.cross(first, direction)], axis=1)


def refine_turntable(views: list[np.ndarray], normals: list[np.ndarray], turntable: Turntable, *,
                     max_mm: float = 0.5, robust_mm: float = 0.01, min_overlap: float = 0.2, rounds: int = 5,
                     steps: int = 3) -> Turntable:
    """The turntable (axis: 4 degrees of freedom; the K - 1 angles of views 1..K-1) that best registers
    all the overlapping pairs of views at once: every view turned about the same axis.

    A robust point-to-plane fit: every point of view i with a nearest point of view j (j != i) within
    `max_mm`, both placed by the turntable, gives the distance along view j's normal there; each pair of
    views with at least `min_overlap` of view i's points paired counts. `rounds` times the points are
    paired anew and `steps` Gauss-Newton steps taken, each weighting the distances by Tukey's biweight of
    `robust_mm` (iteratively reweighted least squares). The axis moves in its own frame (two tilts, two
    shifts across it; a turn about it or a shift along it changes nothing). Six unknowns per view would
    let each view's own shape bias (a scan's systematic error, different from each side) tilt and shift
    it; one axis for all leaves 4 + K - 1.

    Parameters
    ----------
    views : list of (N_k, 3) float arrays
        Each view's points, mm, in the scanner's frame.
    normals : list of (N_k, 3) float arrays
        Their unit normals (either sign).
    turntable : Turntable
        The start (`fit_turntable`): close enough that the pairs' points are within `max_mm`.
    max_mm : float
        The largest correspondence distance, mm.
    robust_mm : float
        Tukey's scale, mm: a few times the scans' noise.
    min_overlap : float
        The share of view i's points paired in view j for the pair to count.
    rounds, steps : int
        Pairings, and Gauss-Newton steps with each.

    Returns
    -------
    turntable : Turntable
        The refined axis (its point the one nearest to the start's point) and angles (view 0's kept).
    """
    from scipy.spatial import cKDTree
    from scipy.spatial.transform import Rotation
    views = [np.asarray(v, np.float64) for v in views]
    normals = [np.asarray(n, np.float64) for n in normals]
    trees = [cKDTree(v) for v in views]
    point, frame = np.asarray(turntable.point_mm, np.float64), _axis_frame(
        np.asarray(turntable.direction, np.float64) / np.linalg.norm(turntable.direction))
    angles = np.radians(np.asarray(turntable.angles_deg, np.float64))
    n_views = len(views)
    free = [0, 1, 2, 3] + [4 + k for k in range(1, n_views)]            # view 0's angle fixed
    for _ in range(rounds):
        placed = Turntable(point, frame[:, 1], np.degrees(angles)).transforms()
        pairs = []
        for i in range(n_views):
            for j in range(n_views):
                if i == j:
                    continue
                rel = np.linalg.inv(placed[j]) @ placed[i]          # view i's points into view j's frame
                dist, idx = trees[j].query(views[i] @ rel[:3, :3].T + rel[:3, 3], distance_upper_bound=max_mm)
                hit = np.isfinite(dist)
                if hit.mean() >= min_overlap:
                    pairs.append((i, j, views[i][hit], views[j][idx[hit]], normals[j][idx[hit]]))
        for _ in range(steps):
            # unknowns: the axis frame's tilts (about its x, z) and shifts (along x, z), then the angles
            lhs, rhs = np.zeros((4 + n_views, 4 + n_views)), np.zeros(4 + n_views)
            for i, j, x, z, n in pairs:
                turn = _turn_y(angles[j] - angles[i])                  # i into j, in the axis frame
                xt, zt, nt = (x - point) @ frame, (z - point) @ frame, n @ frame
                qt = xt @ turn.T
                r = np.einsum("ij,ij->i", nt, qt - zt)
                w = _tukey(r, robust_mm)
                back = nt @ turn                                       # turn^T n
                c = np.cross(qt, nt)
                jac = np.column_stack([(c - np.cross(xt, back))[:, [0, 2]], (nt - back)[:, [0, 2]],
                                       -c[:, 1], c[:, 1]])
                cols = [0, 1, 2, 3, 4 + i, 4 + j]
                lhs[np.ix_(cols, cols)] += jac.T @ (w[:, None] * jac)
                rhs[cols] += jac.T @ (w * r)
            delta = np.zeros(4 + n_views)
            delta[free] = np.linalg.solve(lhs[np.ix_(free, free)], -rhs[free])
            angles = angles + delta[4:]
            point = point + frame @ np.array([delta[2], 0.0, delta[3]])
            frame = frame @ Rotation.from_rotvec([delta[0], 0.0, delta[1]]).as_matrix()
    start = np.asarray(turntable.point_mm, np.float64)
    direction = frame[:, 1]
    return Turntable(point + direction * (direction @ (start - point)), direction, np.degrees(angles) % 360.0)


def register_turntable(views: list[np.ndarray], *, initial: np.ndarray | None = None,
                       normals: list[np.ndarray] | None = None, voxel_mm: float = 2.0, max_mm: float = 0.5,
                       robust_mm: float = 0.01, min_overlap: float = 0.2, passes: int = 2,
                       rounds: int = 5, seed: int = 0) -> TurntableRegistration:
    """Register the views of a turntable's turn as turns about one axis: `register_turn`, then
    `fit_turntable` to its transforms, then `refine_turntable` on all the overlapping pairs' points.

    Parameters
    ----------
    views : list of (N_k, 3) float arrays
        Each view's points, mm, in the scanner's frame, in the order of the turn.
    initial : (K, 4, 4) float, optional
        The nominal turn (`turntable_transforms`): no global step.
    normals : list of (N_k, 3) float arrays, optional
        Each view's unit normals for `refine_turntable` (default: `register_turn`'s, fitted to the points
        within 2 x `voxel_mm`, at most 30).
    voxel_mm, max_mm, robust_mm, min_overlap, passes, seed
        As `register_turn`'s (normals over 2 x `voxel_mm`); `max_mm`, `robust_mm` and `min_overlap` also
        `refine_turntable`'s.
    rounds : int
        `refine_turntable`'s pairings.

    Returns
    -------
    registration : TurntableRegistration
        The fitted turntable (axis in view 0's frame, mm; each view's angle, degrees), its transforms,
        each view's residual (RMS point-to-plane distance to the other views, mm) and fitness.
    """
    full = [_cloud(v, 2 * voxel_mm) for v in views]
    start = _turn(full, voxel_mm, max_mm, robust_mm, initial, min_overlap, passes, seed)
    table = refine_turntable(views, [np.asarray(pc.normals) for pc in full] if normals is None else normals,
                             fit_turntable(start, near_mm=np.mean(views[0], axis=0)),
                             max_mm=max_mm, robust_mm=robust_mm, min_overlap=min_overlap, rounds=rounds)
    transforms = table.transforms()
    return TurntableRegistration(transforms, *_residuals(full, transforms, max_mm), table)


def merged_cloud(views: list[np.ndarray], registration: Registration, *, normals: list[np.ndarray] | None = None,
                 voxel_mm: float = 0.25):
    """The views moved into view 0's frame (`register_views`, `register_turn`) as one cloud, averaged in
    voxels of `voxel_mm` (mm) where they overlap.

    Parameters
    ----------
    views : list of (N_k, 3) float arrays
        Each view's points, mm, in the scanner's frame.
    registration : Registration
        Each view's transform into view 0's frame.
    normals : list of (N_k, 3) float arrays, optional
        Each view's unit normals, oriented towards its scanner (outwards from the object: `make_cloud`);
        moved with the points they keep pointing outwards, so the merged normals are consistent (what
        `stereodic.scan.cloud.poisson_mesh` needs).
    voxel_mm : float
        The averaging voxel, mm.

    Returns
    -------
    cloud : open3d.t.geometry.PointCloud
        float32 positions (view 0's frame, mm; as `make_cloud`'s, for the PLY) and, with `normals`, their unit
        normals.
    """
    import open3d as o3d
    r = [t[:3, :3] for t in registration.transforms]
    moved = [np.asarray(v, np.float64) @ rk.T + t[:3, 3] for v, rk, t in zip(views, r, registration.transforms)]
    legacy = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.vstack(moved)))
    if normals is not None:
        legacy.normals = o3d.utility.Vector3dVector(np.vstack([np.asarray(n, np.float64) @ rk.T
                                                               for n, rk in zip(normals, r)]))
    merged = legacy.voxel_down_sample(voxel_mm)
    if normals is not None:
        merged.normalize_normals()
    return o3d.t.geometry.PointCloud.from_legacy(merged, o3d.core.float32)
