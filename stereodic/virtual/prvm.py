"""The Virtual PRVM, the Error Vector Matrix (EVM), and the virtual camera file that holds them.

Every virtual pixel P (its centre on the virtual sensor plane) has two rays, both through P:
- the model-less ray: the real ray that crosses the plane at P, i.e. the PRVM's direction interpolated
  bilinearly at the IMM's real position (u, v) (the same interpolation that makes the virtual image);
- the modelled ray: from the fitted optical centre C through P (pinhole), or parallel to the fitted
  direction (telecentric).
The Virtual PRVM holds the camera model's rays (the model-less ones for the model-less camera); the EVM
is the vector difference of the unit directions, model-less minus modelled, so that
`direction_modelless = direction_modelled + EVM` exactly. Because both rays pass through P, the EVM is all
the error there is: a point on the modelled ray at a distance h (mm, along the plane normal n) from the
plane lies h * (d_ml / (d_ml . n) - d_mod / (d_mod . n)) away from the model-less ray's point at that
distance, and zero on the plane itself.

The virtual camera file is a PRVM file ("stereodic.prvm/1", loadable by `load_prvm`) of the Virtual
PRVM, with the extra arrays `imm_map_x`, `imm_map_y` ((Hv, Wv) float32, the IMM in cv2.remap form) and
`evm` ((Hv, Wv, 3) float64, NaN where blank; zeros for a model-less camera), and in its meta `virtual`
(the VirtualCamera: model, centre or direction, sensor plane) and `real` (width, height, camera of the
real camera the IMM applies to).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from calib.errors import InputError
from calib.prvm_file import PRVM, load_prvm
from stereodic.virtual.imm import IMM, build_imm
from stereodic.virtual.sampling import bilinear
from stereodic.virtual.camera import VirtualCamera


@dataclass
class VirtualSetup:
    """A virtual camera with everything derived from it: its IMM, its Virtual PRVM (the model's rays) and
    the EVM ((Hv, Wv, 3), model-less minus modelled unit directions)."""

    camera: VirtualCamera
    imm: IMM
    prvm: PRVM
    evm: np.ndarray


def make_virtual(real: PRVM, camera: VirtualCamera) -> VirtualSetup:
    """Build the IMM, the Virtual PRVM and the EVM of a virtual camera for a real one.

    Parameters
    ----------
    real : PRVM
        The real camera's (H, W) rays, WCS mm.
    camera : VirtualCamera
        The virtual sensor (Hv, Wv) and ray model (`stereodic.virtual.camera.default_camera`).

    Returns
    -------
    setup : VirtualSetup
        The camera, its IMM (`build_imm`), its modelled (Hv, Wv) rays (`virtual_rays`) and its EVM
        (`error_vectors`).
    """
    imm = build_imm(real, camera.sensor)
    modelless = virtual_rays(real, camera, imm, modelled=False)
    modelled = virtual_rays(real, camera, imm, modelled=True)
    return VirtualSetup(camera, imm, modelled, error_vectors(modelless, modelled))


def virtual_rays(real: PRVM, camera: VirtualCamera, imm: IMM, *, modelled: bool = True) -> PRVM:
    """The Virtual PRVM: a ray for every virtual pixel, through its centre on the sensor plane.

    Parameters
    ----------
    real : PRVM
        The real camera's (H, W) rays, WCS mm.
    camera : VirtualCamera
        The virtual sensor (Hv, Wv) and ray model.
    imm : IMM
        The camera's Inverse Mapping Matrix (`build_imm`).
    modelled : bool
        True: the camera's model (pinhole through its centre, telecentric along its direction; the same
        as model-less for a model-less camera); False: the model-less rays (the real directions
        interpolated at the IMM's positions).

    Returns
    -------
    prvm : PRVM
        (Hv, Wv) rays, WCS mm, origins on the real PRVM's plane z = reference_z_mm; valid where the
        virtual pixel is not blank (NaN directions elsewhere).
    """
    p = camera.sensor.grid()
    if not modelled or camera.model == "modelless":
        d = bilinear(real.direction, imm.map_x, imm.map_y)
    elif camera.model == "pinhole":
        d = p - camera.centre
        d *= np.sign(d[..., 2:3])
    else:
        d = np.broadcast_to(camera.direction, p.shape).copy()
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    valid = imm.valid & np.isfinite(d).all(axis=-1) & (d[..., 2] > 0)
    d[~valid] = np.nan
    z = real.reference_z_mm
    origin = p + ((z - p[..., 2]) / d[..., 2])[..., None] * d
    meta = {"camera": f"{real.meta.get('camera', 'cam')}-virtual", "width": camera.sensor.width,
            "height": camera.sensor.height, "reference_z_mm": z,
            "dataset": real.meta.get("dataset", ""), "virtual": camera.to_dict(),
            "real": {"camera": real.meta.get("camera", ""), "width": real.width, "height": real.height}}
    return PRVM(origin, d, valid, None, meta)


def error_vectors(modelless: PRVM, modelled: PRVM) -> np.ndarray:
    """The Error Vector Matrix of a virtual camera.

    Parameters
    ----------
    modelless, modelled : PRVM
        Its (Hv, Wv) model-less and modelled rays (`virtual_rays`), WCS.

    Returns
    -------
    evm : (Hv, Wv, 3) float64
        Model-less minus modelled unit directions, WCS, dimensionless; NaN where either is not valid.
    """
    evm = modelless.direction - modelled.direction
    evm[~(modelless.valid & modelled.valid)] = np.nan
    return evm


def save_virtual(path: str | os.PathLike, setup: VirtualSetup) -> None:
    """Write the virtual camera file (module docstring), atomically.

    Parameters
    ----------
    path : path
        The output ``.npz``.
    setup : VirtualSetup
        The virtual camera (`make_virtual`).

    Returns
    -------
    None
    """
    prvm = setup.prvm
    extra = dict(prvm.extra, imm_map_x=setup.imm.map_x, imm_map_y=setup.imm.map_y, evm=setup.evm)
    PRVM(prvm.origin, prvm.direction, prvm.valid, prvm.residual_mm, prvm.meta, extra).save(path)


def load_virtual(path: str | os.PathLike) -> VirtualSetup:
    """Read a virtual camera file.

    Parameters
    ----------
    path : path
        A file written by `save_virtual` (``stereodic undistort``).

    Returns
    -------
    setup : VirtualSetup
        The camera, IMM, Virtual PRVM and EVM. InputError if `path` is a PRVM file but not a virtual
        camera's.
    """
    prvm = load_prvm(path)
    if not is_virtual(prvm):
        raise InputError(path, "not a virtual camera file (a real camera's PRVM?)")
    return as_virtual(prvm)


def is_virtual(prvm: PRVM) -> bool:
    """Whether a loaded PRVM file is a virtual camera file."""
    return "virtual" in prvm.meta and "imm_map_x" in prvm.extra


def as_virtual(prvm: PRVM) -> VirtualSetup:
    """The VirtualSetup held by a loaded virtual camera file (`is_virtual(prvm)`)."""
    camera = VirtualCamera.from_dict(prvm.meta["virtual"])
    real = prvm.meta["real"]
    extra = dict(prvm.extra)
    map_x, map_y = extra.pop("imm_map_x").astype(np.float32), extra.pop("imm_map_y").astype(np.float32)
    evm = extra.pop("evm")
    imm = IMM(map_x, map_y, map_x >= 0, (int(real["width"]), int(real["height"])))
    return VirtualSetup(camera, imm, PRVM(prvm.origin, prvm.direction, prvm.valid, prvm.residual_mm,
                                          prvm.meta, extra), evm)
