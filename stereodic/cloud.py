"""Point clouds of scans as Open3D tensor clouds: normals, a per-point quality, statistical outlier
removal, the PLY file (binary, float32, readable by PCL and CloudCompare) and an optional Poisson mesh.

PLY properties: x y z (WCS mm), nx ny nz (unit normals, oriented towards the scanner), and the per-point
scalars given (e.g. `quality`, `gap_mm`), all float32.
"""

from __future__ import annotations

import os

import numpy as np

from calib.atomic import atomic_output


def make_cloud(points: np.ndarray, scalars: dict[str, np.ndarray], viewpoint: np.ndarray,
               neighbours: int = 20, std_ratio: float = 3.0, normal_neighbours: int = 12):
    """An Open3D tensor PointCloud of (N, 3) WCS points with float32 attributes `scalars` (name -> (N,)),
    after statistical outlier removal (points whose mean distance to their `neighbours` nearest is more
    than `std_ratio` standard deviations above the mean; neighbours=0 skips it), with normals from the
    `normal_neighbours` nearest points, oriented towards `viewpoint` (3,). Non-finite points are dropped.
    Returns (cloud, keep): keep (N,) bool marks the input points that are in the cloud."""
    import open3d as o3d
    points = np.asarray(points, np.float64).reshape(-1, 3)
    keep = np.isfinite(points).all(axis=1)
    for v in scalars.values():
        keep &= np.isfinite(v)
    idx = np.flatnonzero(keep)
    cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(points[idx].astype(np.float32)))
    for name, v in scalars.items():
        setattr(cloud.point, name, o3d.core.Tensor(np.asarray(v, np.float32)[idx, None]))
    if neighbours and len(idx) > neighbours:
        cloud, inlier = cloud.remove_statistical_outliers(nb_neighbors=neighbours, std_ratio=std_ratio)
        keep[idx[~inlier.numpy()]] = False
    if len(cloud.point.positions) >= 3:
        cloud.estimate_normals(max_nn=normal_neighbours)
        cloud.orient_normals_towards_camera_location(o3d.core.Tensor(np.asarray(viewpoint, np.float32)))
    return cloud, keep


def write_cloud(path: str | os.PathLike, cloud) -> None:
    """Write the cloud as a binary float32 PLY, atomically."""
    import open3d as o3d
    with atomic_output(path, suffix=".ply") as tmp:
        if not o3d.t.io.write_point_cloud(str(tmp), cloud, write_ascii=False):
            raise OSError(f"Open3D could not write {path}")


def poisson_mesh(cloud, depth: int = 9, trim_quantile: float = 0.02):
    """The Poisson surface (legacy Open3D TriangleMesh) of a cloud with normals: the
    vertices of the lowest `trim_quantile` density (far from any point) are removed."""
    import open3d as o3d
    mesh, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(cloud.to_legacy(), depth=depth)
    density = np.asarray(density)
    if density.size:
        mesh.remove_vertices_by_mask(density < np.quantile(density, trim_quantile))
    return mesh


def write_mesh(path: str | os.PathLike, mesh) -> None:
    """Write a mesh as a binary PLY, atomically."""
    import open3d as o3d
    with atomic_output(path, suffix=".ply") as tmp:
        if not o3d.io.write_triangle_mesh(str(tmp), mesh, write_ascii=False):
            raise OSError(f"Open3D could not write {path}")
