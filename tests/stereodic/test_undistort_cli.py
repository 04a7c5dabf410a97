"""`stereodic undistort` on files: outputs named after the inputs, same bit depth, the IM applied, and
clear errors for bad input."""

import cv2
import numpy as np
import pytest
import tifffile

from calib.imageio import read_gray
from calib.intensity import IntensityMatrix
from calib.patterns import DisplayResponse
from stereodic.cli import main
from stereodic.virtual.imm import apply_imm
from stereodic.virtual.prvm import load_virtual
from virtual_cases import H, W, opencv_camera, smooth_texture


@pytest.fixture()
def cam(tmp_path):
    prvm = opencv_camera()[-1]
    path = tmp_path / "cam.npz"
    prvm.save(path)
    return path


def test_undistort_writes_one_virtual_image_per_input(tmp_path, cam, capsys):
    img8, img16 = smooth_texture(), smooth_texture(seed=2).astype(np.uint16) * 257
    cv2.imwrite(str(tmp_path / "a.png"), img8)
    cv2.imwrite(str(tmp_path / "b.tif"), img16)
    out = tmp_path / "out"
    assert main(["undistort", str(cam), str(tmp_path / "a.png"), str(tmp_path / "b.tif"), "-o", str(out),
                 "--save-virtual", str(tmp_path / "vcam.npz")]) == 0
    written = [line.split(":")[0] for line in capsys.readouterr().out.splitlines()]
    assert written == [f"wrote {tmp_path / 'vcam.npz'}", f"wrote {out / 'a.png'}", f"wrote {out / 'b.tif'}"]
    a, b = read_gray(out / "a.png"), read_gray(out / "b.tif")
    assert a.dtype == np.uint8 and b.dtype == np.uint16 and a.shape == b.shape == (H, W)
    setup = load_virtual(tmp_path / "vcam.npz")
    assert setup.imm.valid.all() and setup.camera.model == "pinhole"
    assert np.array_equal(a, apply_imm(img8, setup.imm))
    # the saved virtual camera gives the same images
    again = tmp_path / "again"
    assert main(["undistort", str(tmp_path / "vcam.npz"), str(tmp_path / "a.png"), "-o", str(again)]) == 0
    assert np.array_equal(read_gray(again / "a.png"), a)


def test_intensity_matrix_is_applied_before_mapping(tmp_path):
    prvm = opencv_camera()[-1]
    v, u = np.mgrid[0:H, 0:W]
    gain = (150 * (1 - 0.3 * ((u - W / 2) ** 2 + (v - H / 2) ** 2) / (W * W / 4))).astype(np.float32)
    offset = np.full((H, W), 10, np.float32)
    levels = np.linspace(0, 255, 16)
    prvm.extra.update(IntensityMatrix(offset, gain, DisplayResponse(levels, (levels / 255) ** 2.2)).to_arrays())
    prvm.save(tmp_path / "cam.npz")
    flat = np.rint(offset + gain * 0.8).astype(np.uint8)  # a uniform scene of luminance 0.8, vignetted
    cv2.imwrite(str(tmp_path / "flat.png"), flat)
    assert main(["undistort", str(tmp_path / "cam.npz"), str(tmp_path / "flat.png"), "-o", str(tmp_path)]) == 0
    out = read_gray(tmp_path / "flat.png").astype(float)
    expected = 10 + np.median(gain) * 0.8
    assert np.abs(out[5:-5, 5:-5] - expected).max() <= 1.5 and out[5:-5, 5:-5].std() < 0.6 and flat.std() > 10
    cv2.imwrite(str(tmp_path / "deep.png"), flat.astype(np.uint16) * 257)
    assert main(["undistort", str(tmp_path / "cam.npz"), str(tmp_path / "deep.png"), "-o", str(tmp_path / "o")]) == 2


def test_bad_inputs_exit_2_with_a_reason(tmp_path, cam, capsys):
    cv2.imwrite(str(tmp_path / "small.png"), np.zeros((H - 1, W), np.uint8))
    tifffile.imwrite(tmp_path / "float.tif", np.zeros((H, W), np.float32))
    cv2.imwrite(str(tmp_path / "ok.png"), smooth_texture())
    out = str(tmp_path / "out")
    cases = [([str(tmp_path / "small.png")], [], "the camera is 320x240"),
             ([str(tmp_path / "float.tif")], [], "pixel type float32"),
             ([str(tmp_path / "ok.png")], ["--virtual-pitch-mm", "50"], "larger than the real field"),
             ([str(tmp_path / "ok.png")], ["--virtual-size", "640x480", "--virtual-pitch-mm", "1.0"], "larger than the real field")]
    for images, opts, reason in cases:
        assert main(["undistort", str(cam), *images, "-o", out, *opts]) == 2
        err = capsys.readouterr().err
        assert reason in err and err.count("\n") == 1
    assert not (tmp_path / "out" / "ok.png").exists()
