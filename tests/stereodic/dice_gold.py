"""DICe's committed result of the `stereo_list` case (../shared/data/dice-stereo-list), read from its
Exodus II file (netCDF classic; the node variables are named in `name_nod_var`), and the VIC-3D camera
model of its cal.xml written out independently of stereodic (the README's documented model)."""

from pathlib import Path

import numpy as np
from scipy.io import netcdf_file

DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "dice-stereo-list"


def dice_fields() -> dict[str, np.ndarray]:
    """name -> (states, points) float64 of every node variable."""
    f = netcdf_file(DATA / "dice-gold" / "DICe_solution_list.e", "r", mmap=False)
    names = [b"".join(row).decode().strip() for row in f.variables["name_nod_var"][:]]
    out = {n: f.variables[f"vals_nod_var{i + 1}"][:].astype(np.float64) for i, n in enumerate(names)}
    f.close()
    return out


def xyz(fields, prefix, state):
    """(points, 3) of fields prefix_X, _Y, _Z at a state."""
    return np.stack([fields[f"{prefix}_{c}"][state] for c in "XYZ"], axis=1)


def vic_cameras() -> list[dict]:
    """cal.xml's two cameras by the README: cx cy fx fy skew kappa1..3, Cardan-Bryant angles (degrees) and
    tx ty tz (mm), parsed here with plain string handling."""
    text = (DATA / "cal.xml").read_text(encoding="latin-1")
    cams = []
    for block in text.split('<camera id="')[1:]:
        intr, rest = block.split(">", 1)[1].split("<orientation>")
        pose = rest.split("</orientation>")[0]
        cx, cy, fx, fy, skew, k1, k2, k3 = (float(v) for v in intr.split())
        a, b, g, tx, ty, tz = (float(v) for v in pose.split())
        a, b, g = np.radians([a, b, g])
        rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
        ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
        rz = np.array([[np.cos(g), -np.sin(g), 0], [np.sin(g), np.cos(g), 0], [0, 0, 1]])
        cams.append(dict(K=np.array([[fx, skew, cx], [0, fy, cy], [0, 0, 1]]), k=(k1, k2, k3), R=rz @ ry @ rx,
                         t=np.array([tx, ty, tz])))
    return cams


def vic_project(cam: dict, points: np.ndarray) -> np.ndarray:
    """(N, 2) pixels of world points by the VIC-3D model: radial kappa1 r^2 + kappa2 r^4 + kappa3 r^6 on
    the normalised coordinates, then K with its skew."""
    p = points @ cam["R"].T + cam["t"]
    x, y = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
    r2 = x * x + y * y
    s = 1 + cam["k"][0] * r2 + cam["k"][1] * r2 ** 2 + cam["k"][2] * r2 ** 3
    h = np.stack([x * s, y * s, np.ones_like(x)], axis=1) @ cam["K"].T
    return h[:, :2]


def vic_undistort(cam: dict, uv: np.ndarray) -> np.ndarray:
    """(N, 2) normalised coordinates of pixels: K^-1 with skew, then the radial model inverted by
    fixed-point iteration (converges for this lens's small kappa)."""
    h = np.concatenate([uv, np.ones((len(uv), 1))], axis=1) @ np.linalg.inv(cam["K"]).T
    xd = h[:, :2]
    xu = xd.copy()
    for _ in range(100):
        r2 = (xu ** 2).sum(axis=1)
        xu = xd / (1 + cam["k"][0] * r2 + cam["k"][1] * r2 ** 2 + cam["k"][2] * r2 ** 3)[:, None]
    return xu


def midpoints(cams: list[dict], xy0: np.ndarray, xy1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Midpoints (N, 3) of the closest points of the two cameras' rays through normalised coordinates,
    world frame, and the rays' distance (N,)."""
    o = [-c["R"].T @ c["t"] for c in cams]
    d = [np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ c["R"] for xy, c in zip((xy0, xy1), cams)]
    d = [v / np.linalg.norm(v, axis=1, keepdims=True) for v in d]
    w = o[0] - o[1]
    b = (d[0] * d[1]).sum(1)
    e0, e1 = d[0] @ w, d[1] @ w
    den = 1 - b * b
    s, t = (b * e1 - e0) / den, (e1 - b * e0) / den
    p0, p1 = o[0] + s[:, None] * d[0], o[1] + t[:, None] * d[1]
    return (p0 + p1) / 2, np.linalg.norm(p0 - p1, axis=1)


def rigid_fit(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Residuals (N, 3) of points a after the rigid motion that best maps them onto b (Kabsch)."""
    ca, cb = a.mean(0), b.mean(0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.diag([1, 1, np.sign(np.linalg.det(u @ vt))])
    r = (u @ d @ vt).T
    return (a - ca) @ r.T + cb - b
