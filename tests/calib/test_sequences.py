"""Sequence files read frame by frame with their timestamps: videos (lossless and lossy), TIFF stacks,
.cine and .mraw made by their documented layouts (tests/calib/sequence_files.py), side-by-side halves."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import tifffile

from calib.batch import fingerprint
from calib.errors import InputError
from calib.image_files import expand
from calib.imageio import image_size, read_gray
from calib.sequences import frame_times
from tests.calib.sequence_files import write_cine, write_mraw


def _frames(n=6, h=24, w=40, dtype=np.uint16, top=4095, seed=0):
    rng = np.random.default_rng(seed)
    return rng.integers(0, top + 1, (n, h, w)).astype(dtype)


def test_cine_frames_and_timestamps(tmp_path):
    frames = _frames()
    times = 1_700_000_000 + 0.25 + np.arange(6) / 1000.0
    write_cine(tmp_path / "a.cine", frames, times)
    refs = expand(tmp_path / "a.cine")
    assert len(refs) == 6 and image_size(refs[0]) == (40, 24)
    for k, ref in enumerate(refs):
        assert np.array_equal(read_gray(ref), frames[k])
    assert np.allclose(frame_times(refs), times, atol=1e-6)


@pytest.mark.parametrize("bits", [8, 12, 16])
def test_mraw_frames_and_timestamps(tmp_path, bits):
    frames = _frames(top=2 ** bits - 1, dtype=np.uint8 if bits == 8 else np.uint16)
    write_mraw(tmp_path / "b", frames, bits=bits, fps=5000, start=10)
    refs = expand(tmp_path / "b.cih")
    for k, ref in enumerate(refs):
        assert np.array_equal(read_gray(ref), frames[k])
    assert np.allclose(frame_times(refs), (10 + np.arange(6)) / 5000)


def test_tiff_stack_and_side_by_side_video(tmp_path):
    frames = _frames(dtype=np.uint8, top=255)
    tifffile.imwrite(tmp_path / "s.tif", frames)
    refs = expand(tmp_path / "s.tif")
    assert [np.array_equal(read_gray(r), f) for r, f in zip(refs, frames)] == [True] * 6
    assert frame_times(refs) is None
    writer = cv2.VideoWriter(str(tmp_path / "v.avi"), cv2.VideoWriter_fourcc(*"FFV1"), 25, (40, 24), isColor=False)
    for f in frames:
        writer.write(f)
    writer.release()
    refs = expand(tmp_path / "v.avi")
    assert [np.array_equal(read_gray(r), f) for r, f in zip(refs, frames)] == [True] * 6    # lossless
    assert np.allclose(frame_times(refs), np.arange(6) / 25)
    assert np.array_equal(read_gray(refs[3]), frames[3]) and np.array_equal(read_gray(refs[1]), frames[1])
    left, right = expand(f"{tmp_path / 'v.avi'}:left"), expand(f"{tmp_path / 'v.avi'}:right")
    assert image_size(left[2]) == (20, 24)
    assert np.array_equal(read_gray(left[2]), frames[2][:, :20]) and np.array_equal(read_gray(right[2]), frames[2][:, 20:])
    assert fingerprint(left[2]) != fingerprint(right[2]) != fingerprint(refs[2])


def test_damaged_files_name_themselves(tmp_path):
    (tmp_path / "bad.mp4").write_bytes(np.random.default_rng(1).bytes(5000))
    with pytest.raises(InputError, match="bad.mp4: cannot be decoded"):
        expand(tmp_path / "bad.mp4")
    (tmp_path / "bad.cine").write_bytes(b"XX" + bytes(100))
    with pytest.raises(InputError, match="bad.cine: is not a Phantom cine"):
        expand(tmp_path / "bad.cine")
    frames = _frames()
    write_mraw(tmp_path / "c", frames, bits=16, fps=100)
    (tmp_path / "c.mraw").write_bytes((tmp_path / "c.mraw").read_bytes()[:1000])
    with pytest.raises(InputError, match="c.mraw: is cut short"):
        expand(tmp_path / "c.mraw")
    with pytest.raises(InputError, match="frame 9 does not exist"):
        tifffile.imwrite(tmp_path / "t.tif", _frames(dtype=np.uint8, top=255))
        read_gray(f"{tmp_path / 't.tif'}::9")
