"""Scenes for the simulated scanner: exact surfaces, ray-traced analytically (WCS, mm).

Surfaces: `Plane` (a rectangular plate), `Sphere`, `HeightField` (a smooth free-form part z = h(x, y) in
its own frame, intersected by bisection and Newton), `Blob` (a closed smooth free-form part, star-shaped
about its centre, intersected by marching and bisection). A `Scene` is a list of surfaces; a ball bar is two
spheres (`ball_bar`). Every surface has a Lambertian albedo that varies smoothly over it (a printed
texture of +-`texture`) and optionally a specular lobe (a metal part: Blinn-Phong, `specular` the lobe's
peak reflectance, `shininess` its exponent), and a `distance` to its exact shape: the truth the scans are
checked against.

`Scene.intersect(origin, direction)` gives, per ray, the nearest hit: distance t (inf for a miss), point,
unit normal (towards the ray's origin), albedo, the specular lobe's parameters and surface index (-1 for a
miss). `Scene.blocked(p, q)`
tells which segments p -> q cross a surface (shadows).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

EPS_MM = 1e-6


def _texture(points: np.ndarray, base: float, texture: float, seed: int) -> np.ndarray:
    """Smoothly varying albedo: base * (1 + texture * s), s in [-1, 1] from two crossed waves (periods
    17-41 mm), fixed by `seed`."""
    rng = np.random.default_rng(seed)
    k = rng.normal(size=(2, 3))
    k *= (2 * np.pi / rng.uniform(17, 41, (2, 1))) / np.linalg.norm(k, axis=1, keepdims=True)
    s = np.sin(points @ k[0] + rng.uniform(0, 6)) * np.cos(points @ k[1] + rng.uniform(0, 6))
    return base * (1 + texture * s)


@dataclass
class Surface:
    """Common albedo parameters: `albedo` (mean reflectance 0..1), `texture` (relative variation);
    `specular`: the peak reflectance of a Blinn-Phong lobe (n.h)^shininess (0: matte)."""

    albedo: float = 0.7
    texture: float = 0.2
    seed: int = 0
    specular: float = 0.0
    shininess: float = 40.0

    def reflectance(self, points: np.ndarray) -> np.ndarray:
        return _texture(points, self.albedo, self.texture, self.seed)


@dataclass
class Plane(Surface):
    """A rectangular plate: `centre` (3,), unit `normal`, in-plane unit `axis` (the plate's length);
    `size_mm` (length along axis, width across)."""

    centre: np.ndarray = field(default_factory=lambda: np.zeros(3))
    normal: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -1.0]))
    axis: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))
    size_mm: tuple[float, float] = (200.0, 50.0)

    def __post_init__(self):
        self.centre = np.asarray(self.centre, np.float64)
        self.normal = np.asarray(self.normal, np.float64) / np.linalg.norm(self.normal)
        a = np.asarray(self.axis, np.float64)
        a = a - (a @ self.normal) * self.normal
        self.axis = a / np.linalg.norm(a)

    def intersect(self, o, d):
        den = d @ self.normal
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((self.centre - o) @ self.normal) / den
        p = o + t[:, None] * d
        q = p - self.centre
        across = np.cross(self.normal, self.axis)
        inside = (np.abs(q @ self.axis) <= self.size_mm[0] / 2) & (np.abs(q @ across) <= self.size_mm[1] / 2)
        t = np.where(inside & (t > EPS_MM) & (np.abs(den) > 1e-12), t, np.inf)
        return t, np.broadcast_to(self.normal, o.shape)

    def distance(self, points):
        """Signed distance (mm) from the plane (along its normal)."""
        return (points - self.centre) @ self.normal

    def describe(self) -> dict:
        return {"type": "plane", "centre_mm": self.centre.tolist(), "normal": self.normal.tolist(),
                "axis": self.axis.tolist(), "size_mm": list(self.size_mm)}


@dataclass
class Sphere(Surface):
    """centre (3,) WCS mm, radius_mm."""

    centre: np.ndarray = field(default_factory=lambda: np.zeros(3))
    radius_mm: float = 25.0

    def __post_init__(self):
        self.centre = np.asarray(self.centre, np.float64)

    def intersect(self, o, d):
        w = o - self.centre
        b = np.einsum("ij,ij->i", w, d)
        c = np.einsum("ij,ij->i", w, w) - self.radius_mm ** 2
        disc = b * b - c
        root = np.sqrt(np.maximum(disc, 0))
        t1, t2 = -b - root, -b + root
        t = np.where(t1 > EPS_MM, t1, np.where(t2 > EPS_MM, t2, np.inf))
        t = np.where(disc >= 0, t, np.inf)
        with np.errstate(invalid="ignore"):
            n = (o + np.where(np.isfinite(t), t, 0)[:, None] * d - self.centre) / self.radius_mm
        return t, n

    def distance(self, points):
        """Signed radial distance (mm) from the sphere, positive outside."""
        return np.linalg.norm(points - self.centre, axis=-1) - self.radius_mm

    def describe(self) -> dict:
        return {"type": "sphere", "centre_mm": self.centre.tolist(), "radius_mm": self.radius_mm}


@dataclass
class HeightField(Surface):
    """A free-form part: in its own frame (origin `centre`, axes the columns of `rotation`, z towards the
    cameras' -z) the surface is z = h(x, y) = sum_k a_k exp(-|(x, y) - c_k|^2 / (2 s_k^2)) + tilt terms,
    for |x|, |y| <= half_mm. `bumps`: (n, 4) rows (cx, cy, s, a) in mm."""

    centre: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rotation: np.ndarray = field(default_factory=lambda: np.diag([1.0, -1.0, -1.0]))
    half_mm: float = 40.0
    bumps: np.ndarray = field(default_factory=lambda: np.array([[-15.0, -10.0, 14.0, 12.0],
                                                                [18.0, 12.0, 10.0, -6.0],
                                                                [5.0, 20.0, 8.0, 5.0],
                                                                [-20.0, 22.0, 12.0, 4.0]]))

    def __post_init__(self):
        self.centre = np.asarray(self.centre, np.float64)
        self.rotation = np.asarray(self.rotation, np.float64)
        self.bumps = np.asarray(self.bumps, np.float64).reshape(-1, 4)

    def height(self, x, y):
        """h and its gradient (dh/dx, dh/dy) at local (x, y) mm."""
        h = np.zeros_like(x)
        hx, hy = np.zeros_like(x), np.zeros_like(x)
        for cx, cy, s, a in self.bumps:
            g = a * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * s * s))
            h += g
            hx -= g * (x - cx) / (s * s)
            hy -= g * (y - cy) / (s * s)
        return h, hx, hy

    def _bounds(self):
        a = self.bumps[:, 3]
        return float(min(0.0, a[a < 0].sum()) - 1), float(max(0.0, a[a > 0].sum()) + 1)

    def intersect(self, o, d):
        lo_ = (o - self.centre) @ self.rotation
        ld = d @ self.rotation
        zmin, zmax = self._bounds()
        with np.errstate(divide="ignore", invalid="ignore"):
            ta, tb = (zmax - lo_[:, 2]) / ld[:, 2], (zmin - lo_[:, 2]) / ld[:, 2]
        t0, t1 = np.minimum(ta, tb), np.maximum(ta, tb)
        ok = np.isfinite(t0) & np.isfinite(t1) & (t1 > 0)
        for t in (t0, t1):      # rays that pass the part's box within the slab only
            p = lo_ + np.where(ok, t, 0)[:, None] * ld
            ok &= (np.abs(p[:, 0]) <= 2 * self.half_mm) & (np.abs(p[:, 1]) <= 2 * self.half_mm)
        idx = np.flatnonzero(ok)
        t_out = np.full(len(o), np.inf)
        n_out = np.zeros((len(o), 3))
        if idx.size == 0:
            return t_out, n_out
        po, pd = lo_[idx], ld[idx]
        a, b = np.maximum(t0[idx], 0), t1[idx]

        def g(t):
            p = po + t[:, None] * pd
            return p[:, 2] - self.height(p[:, 0], p[:, 1])[0]

        # first crossing: march in steps short enough for the bumps' slopes, then bisect
        n = 24
        ga = g(a)
        hit = np.zeros(len(a), bool)
        lo, hi, prev = a.copy(), b.copy(), a
        for k in range(1, n + 1):
            tk = a + (b - a) * k / n
            gk = g(tk)
            new = ~hit & (np.sign(gk) != np.sign(ga)) & (ga != 0)
            lo[new], hi[new] = prev[new], tk[new]
            hit |= new
            prev, ga = tk, np.where(hit, ga, gk)
        glo = g(lo)
        for _ in range(32):
            mid = (lo + hi) / 2
            gm = g(mid)
            same = np.sign(gm) == np.sign(glo)
            lo, glo = np.where(same, mid, lo), np.where(same, gm, glo)
            hi = np.where(same, hi, mid)
        t = (lo + hi) / 2
        p = po + t[:, None] * pd
        inside = hit & (np.abs(p[:, 0]) <= self.half_mm) & (np.abs(p[:, 1]) <= self.half_mm) & (t > EPS_MM)
        _, hx, hy = self.height(p[:, 0], p[:, 1])
        nl = np.stack([-hx, -hy, np.ones_like(hx)], axis=-1)
        nl /= np.linalg.norm(nl, axis=-1, keepdims=True)
        t_out[idx] = np.where(inside, t, np.inf)
        n_out[idx] = nl @ self.rotation.T
        return t_out, n_out

    def distance(self, points):
        """Height of points above the surface along its local z (mm); close to the normal distance
        where the surface is gently sloped."""
        p = (points - self.centre) @ self.rotation
        return p[:, 2] - self.height(p[:, 0], p[:, 1])[0]

    def describe(self) -> dict:
        return {"type": "heightfield", "centre_mm": self.centre.tolist(), "rotation": self.rotation.tolist(),
                "half_mm": self.half_mm, "bumps_mm": self.bumps.tolist()}


@dataclass
class Blob(Surface):
    """A closed free-form part, star-shaped about `centre` (3,) WCS mm: in the direction of unit u from
    the centre its surface is at r(u) = radius_mm * (1 + sum_k a_k exp(-(1 - u.c_k) / s_k^2)), lobes of
    relative height a_k about unit directions c_k, of angular width about s_k (radians). `lobes`: (n, 5)
    rows (c_x, c_y, c_z, s, a) in the WCS (c normalised here); r must stay positive."""

    centre: np.ndarray = field(default_factory=lambda: np.zeros(3))
    radius_mm: float = 35.0
    lobes: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))

    def __post_init__(self):
        self.centre = np.asarray(self.centre, np.float64)
        self.lobes = np.asarray(self.lobes, np.float64).reshape(-1, 5).copy()
        self.lobes[:, :3] /= np.linalg.norm(self.lobes[:, :3], axis=1, keepdims=True)
        # r over 20000 near-uniform directions (Fibonacci sphere), far closer than the lobes' widths
        k = np.arange(20000) + 0.5
        z, phi = 1 - 2 * k / k.size, np.pi * (1 + 5 ** 0.5) * k
        u = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], axis=1)
        r = 1 - self._g(self.centre + u)
        if r.min() <= 0:
            raise ValueError(f"the lobes make r(u) negative ({r.min():g} mm): r(u) must stay positive")
        self._r_max = 1.02 * r.max()

    def _g(self, points: np.ndarray, gradient: bool = False):
        """g = |q| - r(q/|q|), q = points - centre (mm; negative inside) and, with `gradient`, its gradient."""
        q = points - self.centre
        rho = np.linalg.norm(q, axis=-1)
        u = q / np.maximum(rho, 1e-12)[:, None]
        w = self.lobes[:, 4] * np.exp(-(1 - u @ self.lobes[:, :3].T) / self.lobes[:, 3] ** 2)   # (N, n)
        g = rho - self.radius_mm * (1 + w.sum(axis=1))
        if not gradient:
            return g
        dr_du = self.radius_mm * (w / self.lobes[:, 3] ** 2) @ self.lobes[:, :3]        # (N, 3)
        tangential = dr_du - np.einsum("ij,ij->i", dr_du, u)[:, None] * u
        return g, u - tangential / np.maximum(rho, 1e-12)[:, None]

    def intersect(self, o, d):
        w = o - self.centre
        b = np.einsum("ij,ij->i", w, d)
        disc = b * b - (np.einsum("ij,ij->i", w, w) - self._r_max ** 2)
        idx = np.flatnonzero(disc > 0)
        t_out, n_out = np.full(len(o), np.inf), np.zeros((len(o), 3))
        if idx.size == 0:
            return t_out, n_out
        root = np.sqrt(disc[idx])
        a, b = np.maximum(-b[idx] - root, 0), -b[idx] + root
        po, pd = o[idx], d[idx]

        def g(t, sel=slice(None)):
            return self._g(po[sel] + t[:, None] * pd[sel])

        # first crossing from outside: march in steps short enough for the lobes (the rays not yet in),
        # then bisect
        n = 64
        hit = np.zeros(len(a), bool)
        lo, hi = a.copy(), b.copy()
        for k in range(1, n + 1):
            todo = np.flatnonzero(~hit)
            tk = a[todo] + (b[todo] - a[todo]) * k / n
            new = todo[g(tk, todo) <= 0]
            lo[new], hi[new] = a[new] + (b[new] - a[new]) * (k - 1) / n, a[new] + (b[new] - a[new]) * k / n
            hit[new] = True
        for _ in range(24):
            mid = (lo + hi) / 2
            inside = g(mid) <= 0
            lo, hi = np.where(inside, lo, mid), np.where(inside, mid, hi)
        t = (lo + hi) / 2
        _, grad = self._g(po + t[:, None] * pd, gradient=True)
        t_out[idx] = np.where(hit & (t > EPS_MM), t, np.inf)
        n_out[idx] = grad / np.linalg.norm(grad, axis=1, keepdims=True)
        return t_out, n_out

    def distance(self, points):
        """Signed distance (mm, positive outside) from the surface to first order: g / |grad g|, with g the
        radial distance |q| - r(u) (exact to within g^2 times the surface's curvature)."""
        g, grad = self._g(np.asarray(points, np.float64).reshape(-1, 3), gradient=True)
        return g / np.linalg.norm(grad, axis=1)

    def describe(self) -> dict:
        return {"type": "blob", "centre_mm": self.centre.tolist(), "radius_mm": self.radius_mm,
                "lobes": self.lobes.tolist()}


@dataclass
class Hit:
    """Nearest hits of N rays: t (N,) mm (inf: miss), point (N, 3), normal (N, 3) unit facing the ray,
    albedo (N,), surface (N,) index into the scene's surfaces (-1: miss), specular and shininess (N,) of
    the surface hit (0 and 1 on a miss)."""

    t: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray
    surface: np.ndarray
    specular: np.ndarray
    shininess: np.ndarray


@dataclass
class Scene:
    """Surfaces of one scan state; `name` says what it is (e.g. "sphere", "ball bar pose 3")."""

    surfaces: list
    name: str = ""

    def intersect(self, o: np.ndarray, d: np.ndarray) -> Hit:
        o, d = o.reshape(-1, 3), d.reshape(-1, 3)
        best = np.full(len(o), np.inf)
        normal = np.zeros((len(o), 3))
        index = np.full(len(o), -1)
        for k, s in enumerate(self.surfaces):
            t, n = s.intersect(o, d)
            closer = t < best
            best = np.where(closer, t, best)
            normal[closer] = n[closer]
            index[closer] = k
        point = o + np.where(np.isfinite(best), best, 0)[:, None] * d
        facing = np.einsum("ij,ij->i", normal, d) > 0
        normal[facing] *= -1
        albedo, specular, shininess = np.zeros(len(o)), np.zeros(len(o)), np.ones(len(o))
        for k, s in enumerate(self.surfaces):
            sel = index == k
            albedo[sel] = s.reflectance(point[sel])
            specular[sel], shininess[sel] = s.specular, s.shininess
        return Hit(best, point, normal, albedo, index, specular, shininess)

    def blocked(self, p: np.ndarray, q: np.ndarray) -> np.ndarray:
        """(N,) bool: the segment from points p (N, 3) (just off a surface) to q (3,) crosses a surface."""
        v = q - p
        length = np.linalg.norm(v, axis=-1)
        d = v / length[:, None]
        out = np.zeros(len(p), bool)
        for s in self.surfaces:
            t, _ = s.intersect(p, d)
            out |= t < length
        return out

    def describe(self) -> dict:
        return {"name": self.name, "surfaces": [s.describe() for s in self.surfaces]}


def ball_bar(centre, direction, length_mm: float = 150.0, radius_mm: float = 12.5, **albedo) -> list[Sphere]:
    """Two spheres of `radius_mm` whose centres are `length_mm` apart along unit `direction`, about
    `centre` (WCS mm)."""
    c = np.asarray(centre, np.float64)
    u = np.asarray(direction, np.float64) / np.linalg.norm(direction)
    return [Sphere(centre=c - u * length_mm / 2, radius_mm=radius_mm, seed=1, **albedo),
            Sphere(centre=c + u * length_mm / 2, radius_mm=radius_mm, seed=2, **albedo)]


def surface_from_dict(d: dict):
    """A surface from its `describe()` record (for truth files).

    Parameters
    ----------
    d : dict
        The record (`load_truth(...)["states"][k]["surfaces"]`), WCS mm.

    Returns
    -------
    surface : Plane, Sphere, HeightField or Blob
        The exact surface. ValueError for an unknown type.
    """
    kind = d["type"]
    if kind == "plane":
        return Plane(centre=d["centre_mm"], normal=d["normal"], axis=d["axis"], size_mm=tuple(d["size_mm"]))
    if kind == "sphere":
        return Sphere(centre=d["centre_mm"], radius_mm=d["radius_mm"])
    if kind == "blob":
        return Blob(centre=d["centre_mm"], radius_mm=d["radius_mm"], lobes=np.asarray(d["lobes"]))
    if kind == "heightfield":
        return HeightField(centre=d["centre_mm"], rotation=np.asarray(d["rotation"]), half_mm=d["half_mm"],
                           bumps=np.asarray(d["bumps_mm"]))
    raise ValueError(f"unknown surface type {kind!r}")
