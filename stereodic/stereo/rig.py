"""The rectified virtual stereo pair (seed, "Virtual stereo camera"): building it from two PRVMs, and the
RIG file that holds it.

Geometry (WCS, mm). The optical centres C_L, C_R are fitted to each camera's rays
(`fit_optical_centre`); the baseline is b = C_R - C_L. The Rectified Common FOV Plane contains the
working point W (the mean of the points where the two central rays cross z = plane_z_mm) and is parallel
to the baseline: its normal n is the mean viewing direction (the unit vectors C_L -> W and C_R -> W)
with its baseline component removed. One virtual pixel grid lies on it, rows along b (axis_u = b / |b|,
axis_v = n x axis_u, so a left camera on the left gives an upright image): both virtual sensors are the
same pixels on the same plane. The grid is the largest one of the requested size that lies inside both
real fields (no blank pixel), so it covers the common field of view.

Each camera then has, on that grid, its IMM (the real image position sampled by every virtual pixel),
its pinhole-model Virtual PRVM (rays from its own centre through every virtual pixel centre), and its
model-less rays (the real ray crossing the plane there: the PRVM's direction interpolated at the IMM's
real position); the EVM is model-less minus pinhole unit directions. A scene point X is imaged at the
virtual pixel whose model-less ray passes through X; for central cameras that is where C -> X crosses
the plane, and both cameras see it on the same row (the epipolar plane through C_L, C_R and X cuts the
plane along a row).

Same WCS rule (`check_same_wcs`): a PRVM's WCS is named by its meta `wcs` (written by a registration,
`stereodic.stereo.register`) or else by its `dataset` (the calibration dataset: one display, one stage, one
WCS). Two PRVMs whose names are both given and differ do not share a WCS. Geometry adds: the working
point must lie in front of both centres, the centres must be apart (baseline >= 1e-3 x working
distance), and the two real fields must overlap on the plane.

RIG file (`.npz`, "stereodic.rig/1", no pickles): `meta` (0-d str JSON: format, model, sensor (the
VirtualSensor), baseline_mm, working_distance_mm, cameras: {left, right: name, centre, file, real
width/height, dataset, wcs}, world_from_rig (4x4 rows, the rig frame -> the world frame of its results;
absent = identity; from the PRVMs' meta of the same name, which must agree), software) and per side S in (left, right): `S_map_x`, `S_map_y` (Hv, Wv)
float32 (the IMM in cv2.remap form, -1 where blank), `S_valid` (Hv, Wv) bool, `S_direction`
(Hv, Wv, 3) float64 (model-less unit directions through each virtual pixel centre, NaN where blank), and
the camera's intensity matrix as `S_im_*` when its PRVM has one. A camera of a parametric model (`stereodic
import`) has instead its model in the meta (cameras.S.model: `calib.camera_models.CameraModel.to_dict`, in
the world frame of world_from_rig) and no S_map_*, S_valid, S_direction arrays: they are computed exactly
from the model when first used after the file is read (`exact_camera`), so the file stays small (a few
kB).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from calib import __version__
from calib.atomic import write_npz
from calib.camera_models import invert, transform
from calib.errors import InputError
from calib.intensity import IntensityMatrix
from calib.npzfile import read_npz
from calib.prvm_file import FORMAT as PRVM_FORMAT
from calib.prvm_file import PRVM, load_prvm
from stereodic.virtual.imm import BLANK, IMM, build_imm
from stereodic.virtual.undistort import intensity_matrix
from stereodic.virtual.camera import VirtualCamera, VirtualSensor, fit_optical_centre, project_to_plane
from stereodic.virtual.prvm import make_virtual

FORMAT = "stereodic.rig/1"
SIDES = ("left", "right")
RIG_MODELS = ("pinhole", "modelless")


@dataclass
class RigCamera:
    """One camera of the rig on the common virtual sensor.

    name: the camera's name; centre: (3,) fitted optical centre, WCS mm; imm: its IMM on the common
    sensor; direction: (Hv, Wv, 3) float64 model-less unit directions (WCS) of the real rays through the
    virtual pixel centres, NaN where blank; im: its intensity matrix or None; info: JSON data of where it
    came from (file, dataset, wcs, real width and height); model: the parametric camera
    (`calib.camera_models.CameraModel`, in the world frame `frame` = the rig's world_from_rig) whose
    IMM and directions are computed from it on the common `sensor` (`exact_camera`), or None. A model
    camera may be made with imm and direction None: they are computed the first time they are read (an
    import that only writes the rig file never needs them).
    """

    name: str
    centre: np.ndarray
    imm: IMM | None
    direction: np.ndarray | None
    im: IntensityMatrix | None = None
    info: dict = field(default_factory=dict)
    model: object = None
    frame: np.ndarray | None = None
    sensor: VirtualSensor | None = None

    def __post_init__(self):
        if self.model is not None and (self.imm is None or self.direction is None):
            if self.frame is None or self.sensor is None:
                raise ValueError("a model camera without its IMM needs its frame and sensor")
            del self.imm, self.direction        # __getattr__ computes them on first use

    def __getattr__(self, key):
        if key in ("imm", "direction") and self.__dict__.get("model") is not None:
            _, self.imm, self.direction = exact_camera(self.model, self.frame, self.sensor)
            return self.__dict__[key]
        raise AttributeError(key)


@dataclass
class Rig:
    """The rectified virtual stereo pair: one VirtualSensor on the Rectified Common FOV Plane and the two
    cameras on it. model: "pinhole" (the Virtual PRVMs are the pinhole rays, EVM = model-less - pinhole)
    or "modelless" (the Virtual PRVMs are the model-less rays, EVM zero); the images are the same.
    world_from_rig: (4, 4) float64 rigid transform from the rig's frame (the WCS of its rays) to the world
    frame its results are reported in (identity, except for a rig made by `stereodic import` from a file
    whose cameras look along -z: there it leads back to the calibration file's own world frame)."""

    sensor: VirtualSensor
    left: RigCamera
    right: RigCamera
    model: str = "pinhole"
    world_from_rig: np.ndarray = field(default_factory=lambda: np.eye(4))

    def camera(self, side: str) -> RigCamera:
        if side not in SIDES:
            raise ValueError(f"side must be one of {SIDES}, got {side!r}")
        return self.left if side == "left" else self.right

    @property
    def baseline(self) -> np.ndarray:
        """(3,) WCS mm, the baseline vector C_R - C_L."""
        return self.right.centre - self.left.centre

    @property
    def working_distance_mm(self) -> float:
        """Distance of both optical centres from the common plane (they are equal: the plane is parallel
        to the baseline)."""
        return float((self.sensor.origin - self.left.centre) @ self.sensor.normal)

    def to_world(self, points: np.ndarray, *, vector: bool = False) -> np.ndarray:
        """Rig-frame points in the reporting frame: world_from_rig applied.

        Parameters
        ----------
        points : (..., 3) float
            Points in the rig's frame (the WCS of its rays), mm; or vectors, with `vector`.
        vector : bool
            Apply the rotation alone (directions, displacements).

        Returns
        -------
        points : (..., 3) float64
            In the world frame, mm; the input itself when world_from_rig is the identity.
        """
        T = np.asarray(self.world_from_rig, np.float64)
        if np.array_equal(T, np.eye(4)):
            return points
        out = np.asarray(points, np.float64) @ T[:3, :3].T
        return out if vector else out + T[:3, 3]

    def virtual_camera(self, side: str) -> VirtualCamera:
        """The pinhole virtual camera of `side`: the common sensor and that camera's centre."""
        return VirtualCamera(self.sensor, "pinhole", self.camera(side).centre)

    def pinhole_direction(self, side: str) -> np.ndarray:
        """(Hv, Wv, 3) unit directions from the camera's centre through each virtual pixel centre."""
        d = self.sensor.grid() - self.camera(side).centre
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def evm(self, side: str) -> np.ndarray:
        """(Hv, Wv, 3) the Error Vector Matrix: model-less minus the Virtual PRVM's unit directions (zero
        for a model-less rig), NaN where blank."""
        cam = self.camera(side)
        if self.model == "modelless":
            return np.where(np.isfinite(cam.direction), 0.0, np.nan)
        return cam.direction - self.pinhole_direction(side)

    def virtual_prvm(self, side: str) -> PRVM:
        """The Virtual PRVM of `side` (the model's rays) as a PRVM, origins on the common plane's
        reference z of the WCS (z = 0 plane crossing)."""
        cam = self.camera(side)
        d = cam.direction if self.model == "modelless" else self.pinhole_direction(side)
        valid = cam.imm.valid & np.isfinite(cam.direction).all(axis=-1)
        p = self.sensor.grid()
        origin = p - (p[..., 2] / d[..., 2])[..., None] * d
        return PRVM(origin, np.where(valid[..., None], d, np.nan), valid, None,
                    {"camera": f"{cam.name}-virtual", "reference_z_mm": 0.0,
                     "virtual": self.virtual_camera(side).to_dict()})

    def meta(self) -> dict:
        return {"format": FORMAT, "model": self.model, "sensor": self.sensor.to_dict(),
                "baseline_mm": self.baseline.tolist(), "working_distance_mm": self.working_distance_mm,
                "cameras": {s: {"name": self.camera(s).name, "centre": self.camera(s).centre.tolist(),
                                **self.camera(s).info,
                                **({"model": self.camera(s).model.to_dict()} if self.camera(s).model else {})}
                            for s in SIDES},
                "world_from_rig": np.asarray(self.world_from_rig, np.float64).tolist(),
                "software": f"stereodic {__version__}"}


# ------------------------------------------------------------------------------------------ checks

def check_camera_sizes(rig: Rig, sizes: dict, names: tuple[str, str], where) -> None:
    """InputError naming `where` (a dataset's manifest) unless its cameras `names` (the rig's left and
    right camera, in that order) have the sizes of the rig's real cameras; `sizes`: camera name ->
    (width, height) in pixels."""
    for name, side in zip(names, SIDES):
        real = tuple(rig.camera(side).imm.real_size)
        if name in sizes and tuple(sizes[name]) != real:
            raise InputError(where, f"camera {name} is {sizes[name][0]}x{sizes[name][1]} but the rig's {side} "
                                    f"camera is {real[0]}x{real[1]}")


def wcs_name(prvm: PRVM) -> str:
    """The name of a PRVM's WCS: meta `wcs` (set by a registration) or else its calibration `dataset`,
    normalised; "" when it has neither."""
    name = prvm.meta.get("wcs") or prvm.meta.get("dataset") or ""
    return os.path.normpath(str(name)) if name else ""


def check_same_wcs(left: PRVM, right: PRVM, where: tuple) -> None:
    """InputError naming the right camera's file if the two PRVMs are known to be in different WCSs
    (see the module docstring), or are not the same kind of file (reference planes aside)."""
    a, b = wcs_name(left), wcs_name(right)
    if a and b and a != b:
        how = "registered into" if "wcs" in left.meta or "wcs" in right.meta else "calibrated in"
        raise InputError(where[1], f"does not share a WCS with {where[0]}: {how} different frames ({b!r} vs "
                                   f"{a!r}); calibrate both cameras from one dataset, or register them "
                                   f"(stereodic rig ... --register LEFT_REG.npz RIGHT_REG.npz)")


def _central_ray(prvm: PRVM) -> tuple[np.ndarray, np.ndarray]:
    """(origin, direction) of the valid real ray nearest the image centre."""
    ys, xs = np.nonzero(prvm.valid)
    if len(ys) == 0:
        raise InputError(None, "the PRVM has no valid pixel")
    k = np.argmin((xs - (prvm.width - 1) / 2) ** 2 + (ys - (prvm.height - 1) / 2) ** 2)
    return prvm.origin[ys[k], xs[k]], prvm.direction[ys[k], xs[k]]


def rectified_plane(left: PRVM, right: PRVM, c_left: np.ndarray, c_right: np.ndarray,
                    plane_z_mm: float | None, where: tuple) -> VirtualSensor:
    """A unit-pitch 1x1 VirtualSensor on the Rectified Common FOV Plane: through the working point,
    parallel to the baseline, axis_u along the baseline (see the module docstring)."""
    z = left.reference_z_mm if plane_z_mm is None else float(plane_z_mm)
    hits = []
    for prvm in (left, right):
        o, d = _central_ray(prvm)
        hits.append(o + (z - o[2]) / d[2] * d)
    through = (hits[0] + hits[1]) / 2
    b = c_right - c_left
    look = [through - c for c in (c_left, c_right)]
    if any(v @ _central_ray(p)[1] <= 0 for v, p in zip(look, (left, right))):
        raise InputError(where[1], f"the working point {np.round(through, 1).tolist()} is not in front of both "
                                   f"fitted optical centres: the two cameras do not share a WCS")
    distance = float(np.mean([np.linalg.norm(v) for v in look]))
    if np.linalg.norm(b) < 1e-3 * distance:
        raise InputError(where[1], f"its optical centre coincides with {where[0]}'s (baseline "
                                   f"{np.linalg.norm(b):.3g} mm at a working distance of {distance:.0f} mm): "
                                   f"no stereo")
    axis_u = b / np.linalg.norm(b)
    n = sum(v / np.linalg.norm(v) for v in look)
    n -= (n @ axis_u) * axis_u
    if np.linalg.norm(n) < 1e-6:
        raise InputError(where[1], "the cameras look along the baseline: no common plane parallel to it")
    n /= np.linalg.norm(n)
    return VirtualSensor(through, axis_u, np.cross(n, axis_u), 1.0, 1, 1)


def common_field(prvms: list[PRVM], plane: VirtualSensor, width: int, height: int, pitch_mm=None,
                 raster: int = 512, where=None) -> VirtualSensor:
    """The biggest width x height grid on `plane` (its origin and axes) whose every pixel lies inside all
    the real fields of `prvms` (no blank virtual pixel in any camera). With `pitch_mm`, the grid keeps
    that pitch and is centred where it fits best; InputError if it does not fit.

    Method: a probe grid of about raster x raster points over the overlap of the fields' bounding boxes,
    scaled so that the wanted grid becomes a square; a probe point is inside when every camera's IMM is
    valid there (`build_imm`); the largest inscribed square is the maximum of the chessboard distance
    transform, less 2 probe cells of margin.
    """
    unit = VirtualSensor(plane.origin, plane.axis_u, plane.axis_v, 1.0, 1, 1)
    lo, hi = np.full(2, -np.inf), np.full(2, np.inf)
    for prvm in prvms:
        q = project_to_plane(prvm, unit).reshape(-1, 2)
        q = q[np.isfinite(q).all(axis=1)]
        lo, hi = np.maximum(lo, q.min(axis=0)), np.minimum(hi, q.max(axis=0))
    if np.any(hi <= lo):
        raise InputError(where, "the cameras' fields do not overlap on the common plane")
    aspect = (width - 1) / max(height - 1, 1)
    cell_u = max((hi[0] - lo[0]) / raster, (hi[1] - lo[1]) * aspect / raster)
    cell_v = cell_u / aspect
    nu, nv = int(np.ceil((hi[0] - lo[0]) / cell_u)) + 1, int(np.ceil((hi[1] - lo[1]) / cell_v)) + 1
    probe = VirtualSensor(plane.origin + lo[0] * plane.axis_u + lo[1] * plane.axis_v, plane.axis_u,
                          plane.axis_v, (cell_u, cell_v), nu, nv)
    inside = np.ones((nv, nu), bool)
    for prvm in prvms:
        inside &= build_imm(prvm, probe, tol_px=1e-3).valid
    mask = np.zeros((nv + 2, nu + 2), np.uint8)
    mask[1:-1, 1:-1] = inside
    dist = cv2.distanceTransform(mask, cv2.DIST_C, 3)[1:-1, 1:-1]
    row, col = np.unravel_index(np.argmax(dist), dist.shape)
    half = float(dist[row, col]) - 2.0
    if half <= 0:
        raise InputError(where, "the cameras' fields do not overlap on the common plane")
    biggest = 2 * half * cell_u / (width - 1)
    if pitch_mm is None:
        pitch_mm = (biggest, biggest)
    else:
        pu, pv = np.broadcast_to(np.asarray(pitch_mm, np.float64), (2,))
        if (width - 1) * pu > 2 * half * cell_u or (height - 1) * pv > 2 * half * cell_v:
            raise InputError(where, f"a {width}x{height} grid at pitch {pu:g} x {pv:g} mm is larger than the "
                                    f"common field (largest square pitch that fits: {biggest:.6g} mm)")
        pitch_mm = (pu, pv)
    return probe.with_field((col * cell_u, row * cell_v), pitch_mm, width, height)


# --------------------------------------------------------------------------------------- building

def exact_camera(camera, frame: np.ndarray, sensor: VirtualSensor, *, rows: int = 256
                 ) -> tuple[np.ndarray, IMM, np.ndarray]:
    """A parametric camera (`calib.camera_models.CameraModel`) on the common sensor, from its model
    exactly: (its centre (3,) in the rig frame, its IMM, its (Hv, Wv, 3) unit directions). Each virtual
    pixel centre is projected through the model (`calib.camera_models.image_of`): no ray is interpolated
    between real pixels and nothing is inverted. `frame` is world_from_rig (4, 4): the rig frame -> the
    model's world frame. Blank: outside the model's valid region or the real image [0, W-1] x [0, H-1].
    Done `rows` virtual rows at a time (bounded memory)."""
    import dataclasses

    from calib.camera_models import image_of
    centre = transform(invert(frame), camera.centre)
    # the model's pose composed with the frame: one affine map from rig-frame points to its camera frame
    in_rig = dataclasses.replace(camera, R=camera.R @ frame[:3, :3], t=camera.R @ frame[:3, 3] + camera.t)
    hv, wv = sensor.height, sensor.width
    map_x = np.full((hv, wv), BLANK, np.float32)
    map_y = np.full((hv, wv), BLANK, np.float32)
    valid = np.zeros((hv, wv), bool)
    direction = np.full((hv, wv, 3), np.nan)
    for r0 in range(0, hv, rows):
        v, uu = np.mgrid[r0:min(r0 + rows, hv), 0:wv].astype(np.float64)
        p = sensor.points(uu, v)
        uv, ok = image_of(in_rig, p.reshape(-1, 3))
        ok &= (uv[:, 0] >= 0) & (uv[:, 0] <= camera.width - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= camera.height - 1)
        ok = ok.reshape(v.shape)
        uv = uv.reshape(v.shape + (2,))
        map_x[r0:r0 + len(v)] = np.where(ok, uv[..., 0], BLANK)
        map_y[r0:r0 + len(v)] = np.where(ok, uv[..., 1], BLANK)
        valid[r0:r0 + len(v)] = ok
        d = p - centre
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        direction[r0:r0 + len(v)] = np.where(ok[..., None], d, np.nan)
    return centre, IMM(map_x, map_y, valid, (camera.width, camera.height)), direction


def build_rig(left: PRVM, right: PRVM, *, model: str = "pinhole", width: int | None = None,
              height: int | None = None, pitch_mm=None, plane_z_mm: float | None = None,
              where: tuple = ("left", "right"), cameras: tuple | None = None) -> Rig:
    """The rectified virtual stereo pair of two calibrated cameras in one WCS (module docstring).

    Parameters
    ----------
    left, right : PRVM
        The two cameras' rays, in one WCS (mm).
    model : {"pinhole", "modelless"}
        The rays of the Virtual PRVMs: the pinhole rays (EVM = model-less - pinhole) or the model-less
        ones (EVM zero); the rectified images are the same.
    width, height : int, optional
        The virtual image size; None: the left camera's.
    pitch_mm : float or (float, float), optional
        The virtual pixel pitch on the common plane, mm; None: the largest common field.
    plane_z_mm : float, optional
        WCS z of the working point, mm; None: the left PRVM's reference_z_mm.
    where : (str, str)
        Names of the two inputs (file names) for messages and the cameras' ``info``.
    cameras : (CameraModel, CameraModel), optional
        The parametric models (`calib.camera_models`) whose rays the PRVMs sample, in the world frame
        of the PRVMs' world_from_rig (`stereodic import`): the PRVMs (which may then sample every n-th
        pixel) only place the plane and the common field; centres, IMMs and directions come from the
        models exactly (`exact_camera`).

    Returns
    -------
    rig : Rig
        One (Hv, Wv) VirtualSensor on the Rectified Common FOV Plane (WCS, mm) and the two cameras on it
        (centre, IMM, model-less directions, intensity matrix). InputError for PRVMs that do not share a
        WCS, coincident centres or fields that do not overlap.
    """
    if model not in RIG_MODELS:
        raise InputError("--model", f"a stereo rig is {' or '.join(RIG_MODELS)} (a telecentric pair has no "
                                    f"optical centres to put a baseline through), got {model!r}")
    check_same_wcs(left, right, where)
    centres = []
    for prvm, name in zip((left, right), where):
        try:
            centres.append(fit_optical_centre(prvm)[0])
        except InputError as exc:
            raise InputError(name, exc.problem) from None
    frames = [world_from_rig(p.meta, name) for p, name in zip((left, right), where)]
    if not np.allclose(frames[0], frames[1], atol=1e-12):
        raise InputError(where[1], f"its rays are in another internal frame than {where[0]}'s (their "
                                   f"world_from_rig differ): import both cameras from one calibration file")
    plane = rectified_plane(left, right, centres[0], centres[1], plane_z_mm, where)
    real = [(p.width, p.height) for p in (left, right)] if cameras is None else \
        [(c.width, c.height) for c in cameras]
    width = real[0][0] if width is None else int(width)
    height = real[0][1] if height is None else int(height)
    sensor = common_field([left, right], plane, width, height, pitch_mm, where=where[1])
    cams = []
    for i, (prvm, centre, name) in enumerate(zip((left, right), centres, where)):
        info = {"file": os.fspath(name), "dataset": prvm.meta.get("dataset", ""), "wcs": wcs_name(prvm),
                "real_width": real[i][0], "real_height": real[i][1]}
        camera_name = prvm.meta.get("camera", Path(os.fspath(name)).stem)
        if cameras is None:
            setup = make_virtual(prvm, VirtualCamera(sensor, "pinhole", centre))
            direction = setup.prvm.direction + setup.evm
            direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
            info["blank_pixels"] = int((~setup.imm.valid).sum())
            cams.append(RigCamera(camera_name, centre, setup.imm, direction, intensity_matrix(prvm), info))
        else:     # the model's centre; its IMM and rays when first used (RigCamera, exact_camera)
            centre = transform(invert(frames[0]), cameras[i].centre)
            cams.append(RigCamera(camera_name, centre, None, None, intensity_matrix(prvm), info, cameras[i],
                                  frames[0], sensor))
    return Rig(sensor, cams[0], cams[1], model, frames[0])


def rig_from_files(left: str | os.PathLike, right: str | os.PathLike, *, model: str = "pinhole",
                   width: int | None = None, height: int | None = None, pitch_mm=None,
                   plane_z_mm: float | None = None) -> Rig:
    """`build_rig` of two PRVM files.

    Parameters
    ----------
    left, right : path
        The two cameras' PRVM files, in one WCS; their paths name the cameras in messages and in the
        rig's ``info``.
    model, width, height, pitch_mm, plane_z_mm
        As in `build_rig`.

    Returns
    -------
    rig : Rig
        As `build_rig`.
    """
    return build_rig(load_prvm(left), load_prvm(right), model=model, width=width, height=height,
                     pitch_mm=pitch_mm, plane_z_mm=plane_z_mm, where=(os.fspath(left), os.fspath(right)))


# ------------------------------------------------------------------------------------------- file

def save_rig(path: str | os.PathLike, rig: Rig) -> None:
    """Write the RIG file (module docstring), atomically.

    Parameters
    ----------
    path : path
        The output ``.npz``.
    rig : Rig
        The rectified pair (`build_rig`).

    Returns
    -------
    None
    """
    arrays = {"meta": np.array(json.dumps(rig.meta()))}
    for side in SIDES:
        cam = rig.camera(side)
        if cam.im is not None:
            arrays.update(cam.im.to_arrays(prefix=f"{side}_im_"))
        if cam.model is not None:     # the model is in the meta: the maps and rays are computed on load
            continue
        arrays.update({f"{side}_map_x": cam.imm.map_x.astype(np.float32),
                       f"{side}_map_y": cam.imm.map_y.astype(np.float32),
                       f"{side}_valid": cam.imm.valid.astype(bool),
                       f"{side}_direction": cam.direction.astype(np.float64)})
    write_npz(path, **arrays)


def load_rig(path: str | os.PathLike) -> Rig:
    """Read a RIG file (module docstring).

    Parameters
    ----------
    path : path
        A file written by `save_rig` (``stereodic rig``, ``stereodic import``).

    Returns
    -------
    rig : Rig
        The sensor and both cameras. InputError naming the file if it is missing or not a rig file.
    """
    meta, arrays = read_npz(path, FORMAT, "rig", advice={
        PRVM_FORMAT: "a camera file: build a rig with `stereodic rig LEFT.npz RIGHT.npz`"}, mapped=True)
    sensor = VirtualSensor.from_dict(meta["sensor"])
    frame = world_from_rig(meta, path)
    cams = []
    for side in SIDES:
        info = dict(meta["cameras"][side])
        im = IntensityMatrix.from_arrays(arrays, prefix=f"{side}_im_") if f"{side}_im_offset" in arrays else None
        if "model" in info:      # a parametric camera: its maps and rays from the model (exact_camera)
            from calib.camera_models import CameraModel
            try:
                model = CameraModel.from_dict(info.pop("model"))
            except (KeyError, TypeError, ValueError) as exc:
                raise InputError(path, f"the {side} camera's model is not readable ({exc})") from None
            name, centre = info.pop("name"), np.asarray(info.pop("centre"), np.float64)
            cams.append(RigCamera(name, centre, None, None, im, info, model, frame, sensor))
            continue
        need = [f"{side}_{k}" for k in ("map_x", "map_y", "valid", "direction")]
        if any(k not in arrays for k in need):
            raise InputError(path, f"not a rig file: lacks {', '.join(k for k in need if k not in arrays)}")
        name, centre = info.pop("name"), np.asarray(info.pop("centre"), np.float64)
        shape = (sensor.height, sensor.width)
        if arrays[f"{side}_map_x"].shape != shape or arrays[f"{side}_direction"].shape != shape + (3,):
            raise InputError(path, f"{side} arrays do not match the {sensor.width}x{sensor.height} sensor")
        imm = IMM(arrays[f"{side}_map_x"], arrays[f"{side}_map_y"], arrays[f"{side}_valid"].astype(bool),
                  (int(info["real_width"]), int(info["real_height"])))
        cams.append(RigCamera(name, centre, imm, arrays[f"{side}_direction"].astype(np.float64, copy=False), im, info))
    return Rig(sensor, cams[0], cams[1], meta.get("model", "pinhole"), frame)


def world_from_rig(meta: dict, path) -> np.ndarray:
    """The meta's world_from_rig (identity when absent); InputError naming the file unless it is a 4x4
    rigid transform (rotation with determinant +1, last row 0 0 0 1)."""
    if "world_from_rig" not in meta:
        return np.eye(4)
    try:
        T = np.asarray(meta["world_from_rig"], np.float64)
    except (TypeError, ValueError):
        T = np.zeros(0)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise InputError(path, "world_from_rig is not a 4x4 matrix of numbers")
    R = T[:3, :3]
    if (np.abs(R.T @ R - np.eye(3)).max() > 1e-9 or np.linalg.det(R) < 0
            or np.abs(T[3] - (0, 0, 0, 1)).max() > 1e-12):
        raise InputError(path, "world_from_rig is not a rigid transform (rotation and translation)")
    return T
