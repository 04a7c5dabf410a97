"""Scans of one object from several sides (a turntable, or the object moved) registered into one frame
and merged (Open3D).

Registration of view k into view 0's frame (`register_views`):
 1. global, unless approximate transforms are given (a turntable's nominal angles): each view
    down-sampled to voxels of `voxel_mm`, FPFH features, RANSAC on feature matches against the views
    already placed;
 2. fine: point-to-plane ICP of the full-resolution view against all the views already placed;
 3. a last pass: ICP of every view but the first against all the others, in view 0's frame.
Each view's residual is the RMS point-to-plane distance of its last ICP's correspondences (mm), its
fitness the share of its points that found a partner within `max_mm`.

`merge_views` puts the registered views into one cloud, voxel-averaged where they overlap.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np


@dataclass
class Registration:
    """Per view: transforms (K, 4, 4) float64 mapping view k's points (mm) into view 0's frame (view 0:
    identity); residual_mm (K,) RMS point-to-plane distance of the last ICP; fitness (K,) its share of
    points with a partner."""

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


def _icp(source, target, init: np.ndarray, max_mm: float):
    import open3d as o3d
    reg = o3d.pipelines.registration
    return reg.registration_icp(source, target, max_mm, init, reg.TransformationEstimationPointToPlane(),
                                reg.ICPConvergenceCriteria(relative_fitness=1e-10, relative_rmse=1e-10,
                                                           max_iteration=200))


def _global(small: list, feats: list, transforms: list, k: int, voxel_mm: float) -> np.ndarray:
    """RANSAC on FPFH matches of view k against the views already placed (their transforms)."""
    import open3d as o3d
    reg = o3d.pipelines.registration
    target = _placed(small, transforms, range(k))
    feature = reg.Feature()
    feature.data = np.hstack([feats[j].data for j in range(k)])
    checks = [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
              reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel_mm)]
    return reg.registration_ransac_based_on_feature_matching(
        small[k], target, feats[k], feature, True, 1.5 * voxel_mm, reg.TransformationEstimationPointToPoint(False),
        3, checks, reg.RANSACConvergenceCriteria(400_000, 0.9999)).transformation


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
        Each view's transform into view 0's frame, its ICP residual (mm) and fitness.
    """
    import open3d as o3d
    o3d.utility.random.seed(seed)
    full = [_cloud(v, 2 * voxel_mm) for v in views]
    small, feats = [], []
    if initial is None:
        reg = o3d.pipelines.registration
        for pc in full:
            s = pc.voxel_down_sample(voxel_mm)
            s.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel_mm, max_nn=30))
            small.append(s)
            feats.append(reg.compute_fpfh_feature(s, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel_mm,
                                                                                          max_nn=100)))
    transforms = [np.eye(4)]
    for k in range(1, len(views)):
        start = np.asarray(initial[k], np.float64) if initial is not None else \
            _global(small, feats, transforms, k, voxel_mm)
        coarse = _icp(full[k], _placed(full, transforms, range(k)), start, 4 * max_mm).transformation
        transforms.append(_icp(full[k], _placed(full, transforms, range(k)), coarse, max_mm).transformation)
    residual, fitness = np.zeros(len(views)), np.ones(len(views))
    for k in range(1, len(views)):
        res = _icp(full[k], _placed(full, transforms, [j for j in range(len(views)) if j != k]), transforms[k],
                   max_mm)
        transforms[k], residual[k], fitness[k] = res.transformation, res.inlier_rmse, res.fitness
    return Registration(np.asarray(transforms), residual, fitness)


def merge_views(views: list[np.ndarray], registration: Registration, *, voxel_mm: float = 0.25) -> np.ndarray:
    """(M, 3) float64: the views' points moved into view 0's frame (`register_views`), averaged in
    voxels of `voxel_mm` (mm) where the views overlap."""
    import open3d as o3d
    pts = np.vstack([np.asarray(v, np.float64) @ t[:3, :3].T + t[:3, 3]
                     for v, t in zip(views, registration.transforms)])
    return np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)).voxel_down_sample(voxel_mm).points)
