"""Point clouds of scans as Open3D tensor clouds: normals, a per-point quality, statistical outlier
removal, the PLY file (binary, float32, readable by PCL and CloudCompare) and an optional Poisson mesh.

PLY properties: x y z (WCS mm), nx ny nz (unit normals, oriented towards the scanner), and the per-point
scalars given (e.g. `quality`, `gap_mm`), all float32.
"""

from __future__ import annotations

import os

import numpy as np

from calib.atomic import atomic_output


def make_cloud(points: np.ndarray, scalars: dict[str, np.ndarray], viewpoint: np.ndarray, *,
               neighbours: int = 20, std_ratio: float = 3.0, normal_neighbours: int = 12):
    """An Open3D tensor point cloud with per-point scalars, outliers removed, normals oriented.

    Parameters
    ----------
    points : (N, 3) float
        WCS mm; non-finite points (or points with a non-finite scalar) are dropped.
    scalars : dict of str to (N,) float
        Per-point attributes (e.g. ``quality``, ``gap_mm``), stored as float32.
    viewpoint : (3,) float
        WCS mm: the normals are oriented towards it (the scanner).
    neighbours : int
        Statistical outlier removal: a point whose mean distance to its `neighbours` nearest is more than
        `std_ratio` standard deviations above the mean is removed; 0 skips it.
    std_ratio : float
        See `neighbours`.
    normal_neighbours : int
        The nearest points each normal is fitted to.

    Returns
    -------
    cloud : open3d.t.geometry.PointCloud
        float32 positions (WCS mm), normals and the scalars.
    keep : (N,) bool
        The input points that are in the cloud.
    """
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
    """Write a cloud as a binary float32 PLY (module docstring), atomically.

    Parameters
    ----------
    path : path
        The output ``.ply``.
    cloud : open3d.t.geometry.PointCloud
        The cloud (`make_cloud`).

    Returns
    -------
    None
        OSError if Open3D cannot write the file.
    """
    import open3d as o3d
    with atomic_output(path, suffix=".ply") as tmp:
        if not o3d.t.io.write_point_cloud(str(tmp), cloud, write_ascii=False):
            raise OSError(f"Open3D could not write {path}")


def poisson_mesh(cloud, *, depth: int = 9, trim_quantile: float = 0.02, max_gap_mm: float | None = None):
    """The Poisson surface of a cloud with normals, trimmed where it balloons beyond the data.

    Parameters
    ----------
    cloud : open3d.t.geometry.PointCloud
        A cloud with consistently oriented normals (`make_cloud`, `stereodic.scan.views.merged_cloud`), mm.
    depth : int
        The Poisson octree depth.
    trim_quantile : float
        The vertices of this lowest quantile of density (far from any point) are removed.
    max_gap_mm : float, optional
        The vertices farther than this from every point of the cloud (mm) are removed too: the surface
        Poisson closes over the parts no view saw.

    Returns
    -------
    mesh : open3d.geometry.TriangleMesh
        A legacy Open3D mesh, in the cloud's frame, mm.
    """
    import open3d as o3d
    mesh, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(cloud.to_legacy(), depth=depth)
    density = np.asarray(density)
    if density.size:
        far = density < np.quantile(density, trim_quantile)
        if max_gap_mm is not None:
            from scipy.spatial import cKDTree
            gap, _ = cKDTree(cloud.point.positions.numpy()).query(np.asarray(mesh.vertices),
                                                                 distance_upper_bound=max_gap_mm)
            far |= ~np.isfinite(gap)
        mesh.remove_vertices_by_mask(far)
    return mesh


def write_mesh(path: str | os.PathLike, mesh) -> None:
    """Write a mesh as a binary PLY, atomically."""
    import open3d as o3d
    with atomic_output(path, suffix=".ply") as tmp:
        if not o3d.io.write_triangle_mesh(str(tmp), mesh, write_ascii=False):
            raise OSError(f"Open3D could not write {path}")
