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
    import open3d as o3d
    reg = o3d.pipelines.registration
    o3d.utility.random.seed(seed)
    full = [_cloud(v, 2 * voxel_mm) for v in views]
    small, feats = _features(full, voxel_mm) if initial is None else ([], [])
    graph, poses = reg.PoseGraph(), [np.eye(4)]
    graph.nodes.append(reg.PoseGraphNode(np.eye(4)))
    for k in range(1, len(views)):          # edge source k - 1 -> target k: view k - 1 into view k's frame
        start = (np.linalg.inv(initial[k]) @ initial[k - 1] if initial is not None else
                 _global(small[k - 1], feats[k - 1], small[k], feats[k], voxel_mm))
        t, _, info = _pair(full[k - 1], full[k], np.asarray(start, np.float64), max_mm, robust_mm)
        poses.append(poses[k - 1] @ np.linalg.inv(t))
        graph.nodes.append(reg.PoseGraphNode(poses[k]))
        graph.edges.append(reg.PoseGraphEdge(k - 1, k, t, info, uncertain=False))
    for i in range(len(views)):
        for j in range(i + 2, len(views)):
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
    transforms = _refine(full, np.asarray([np.asarray(node.pose) for node in graph.nodes]), max_mm, robust_mm,
                         passes)
    return Registration(transforms, *_residuals(full, transforms, max_mm))


def turntable_transforms(views: int, point_mm, direction) -> np.ndarray:
    """(views, 4, 4) the nominal transforms of a whole turn in equal steps: view k's points into view 0's
    frame, for an object turned by 360 / views degrees (right-handed about `direction`) from one view to
    the next about the axis through `point_mm` (3,) (the scanner's frame, mm); `register_turn`'s initial."""
    from scipy.spatial.transform import Rotation
    axis = np.asarray(direction, np.float64) / np.linalg.norm(direction)
    point = np.asarray(point_mm, np.float64)
    out = np.tile(np.eye(4), (views, 1, 1))
    for k in range(views):
        r = Rotation.from_rotvec(-np.radians(360.0 * k / views) * axis).as_matrix()
        out[k, :3, :3], out[k, :3, 3] = r, point - r @ point
    return out


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
