"""Undistorting one camera's images: the intensity matrix (if the calibration has one), then the IMM.

The intensity matrix (IM, `calib.intensity.IntensityMatrix`, stored in the PRVM file's `im_*` arrays)
turns each pixel's raw value into the relative luminance it saw; here that luminance is mapped back to
camera values with the field's median offset and gain, so the output keeps the input's scale and bit
depth with every pixel's dark level and sensitivity (vignetting, pixel gain) evened out. Pixels the IM
could not calibrate keep their raw value.
"""

from __future__ import annotations

import numpy as np

from calib.errors import InputError
from calib.intensity import IntensityMatrix
from calib.prvm_file import PRVM
from stereodic.virtual.imm import IMM, apply_imm


def intensity_matrix(prvm: PRVM) -> IntensityMatrix | None:
    """The intensity matrix a PRVM file keeps (module docstring).

    Parameters
    ----------
    prvm : PRVM
        A calibration (`calib.prvm_file.load_prvm`).

    Returns
    -------
    im : IntensityMatrix or None
        Each (H, W) pixel's offset, gain and response, from its ``im_*`` arrays; None when it has none.
    """
    return IntensityMatrix.from_arrays(prvm.extra) if "im_offset" in prvm.extra else None


def check_image(image: np.ndarray, imm: IMM, im: IntensityMatrix | None, where) -> None:
    """InputError naming `where` if `image` does not fit: size differs from the real camera's, pixel type
    not 8/16-bit unsigned, or bit depth other than the IM's (an IM whose bright level exceeds 255 was
    measured on 16-bit images)."""
    w, h = imm.real_size
    if image.ndim != 2 or image.shape != (h, w):
        raise InputError(where, f"image is {image.shape[1] if image.ndim > 1 else '?'}x{image.shape[0]}"
                                f"{'' if image.ndim == 2 else ' with channels'} but the camera is {w}x{h}")
    if image.dtype not in (np.uint8, np.uint16):
        raise InputError(where, f"pixel type {image.dtype} is not supported (8- or 16-bit grayscale)")
    if im is not None:
        im_16 = float(np.nanmedian(im.offset + im.gain)) > 255
        if im_16 != (image.dtype == np.uint16):
            raise InputError(where, f"{8 * image.itemsize}-bit image, but the camera's intensity matrix was "
                                    f"measured on {16 if im_16 else 8}-bit images")


def linearise(image: np.ndarray, im: IntensityMatrix) -> np.ndarray:
    """The image with each pixel's response evened out by the IM, same dtype (see the module doc)."""
    y = im.luminance(image)
    out = np.nanmedian(im.offset) + np.nanmedian(im.gain) * y
    out = np.where(np.isfinite(out), out, image)
    top = np.iinfo(image.dtype).max
    return np.clip(np.rint(out), 0, top).astype(image.dtype)


def undistort_image(image: np.ndarray, imm: IMM, *, im: IntensityMatrix | None = None,
                    fixed_point: bool = False, where=None, exact: bool = False) -> np.ndarray:
    """The virtual image of a real image: checked, linearised by the intensity matrix if given, mapped.

    Parameters
    ----------
    image : (H, W) uint8 or uint16
        The real image, the camera's size.
    imm : IMM
        The virtual camera's Inverse Mapping Matrix (`stereodic.virtual.imm.build_imm`).
    im : IntensityMatrix, optional
        The camera's intensity matrix (`intensity_matrix`); its bit depth must be the image's.
    fixed_point : bool
        OpenCV's 1/32-pixel maps instead of the exact float maps.
    where : str or path, optional
        The image's name in messages.
    exact : bool
        float32 output: the interpolated grey levels not rounded back to integers (for measuring on the
        virtual image, e.g. DIC, where that rounding would add its noise).

    Returns
    -------
    virtual : (Hv, Wv) array
        The image's dtype (float32 with `exact`); blank pixels 0. InputError naming `where` if the size,
        pixel type or bit depth does not fit.
    """
    check_image(image, imm, im, where)
    if im is not None:
        image = linearise(image, im)
    if exact:
        image = image.astype(np.float32)
    return apply_imm(image, imm, fixed_point=fixed_point)
