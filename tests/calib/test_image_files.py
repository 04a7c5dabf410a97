"""Image files on the command line: patterns in natural order, header checks (calib.image_files,
calib.imageio.image_size), and stacked npz files written slice by slice (calib.npz_stream)."""

import numpy as np
import pytest
from PIL import Image

from calib.errors import InputError
from calib.image_files import expand, natural_key
from calib.imageio import image_size
from calib.npz_stream import iter_slices, write_stacked_npz


def test_natural_order():
    names = ["img_10_0.tif", "img_9_0.tif", "img_100_0.tif", "IMG_2_0.tif", "img_2_1.tif"]
    assert sorted(names, key=natural_key) == ["IMG_2_0.tif", "img_2_1.tif", "img_9_0.tif", "img_10_0.tif",
                                              "img_100_0.tif"]


def test_expand(tmp_path):
    for k in (1, 2, 10, 11):
        (tmp_path / f"s{k}.png").write_bytes(b"")
    (tmp_path / "dir.png").mkdir()
    assert [p.name for p in expand(tmp_path / "s*.png")] == ["s1.png", "s2.png", "s10.png", "s11.png"]
    assert [p.name for p in expand(tmp_path / "s1?.png")] == ["s10.png", "s11.png"]
    assert expand(tmp_path / "plain.png") == [tmp_path / "plain.png"]       # no wildcard: itself
    with pytest.raises(InputError, match="matches no file") as e:
        expand(tmp_path / "x*.png")
    assert "x*.png" in str(e.value)


def test_image_size_checks_the_header_and_the_data(tmp_path):
    img = (np.arange(64 * 48) % 251).astype(np.uint8).reshape(48, 64)
    for ext, arr in ((".png", img), (".tif", img), (".tif", img.astype(np.uint16) * 200)):
        path = tmp_path / f"a{arr.dtype}{ext}"
        Image.fromarray(arr).save(path)
        assert image_size(path) == (64, 48)
        cut = tmp_path / f"cut{arr.dtype}{ext}"
        cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2 + 40])
        with pytest.raises(InputError) as e:
            image_size(cut)
        assert str(cut) in str(e.value)
    Image.fromarray(img.astype(np.float32)).save(tmp_path / "float.tif")
    with pytest.raises(InputError, match="pixel type 'F'"):
        image_size(tmp_path / "float.tif")
    with pytest.raises(InputError, match="missing"):
        image_size(tmp_path / "none.png")


def test_stacked_npz_is_what_savez_writes(tmp_path):
    rng = np.random.default_rng(1)
    slices = [rng.normal(size=(3, 4, 2)) for _ in range(5)]
    flags = [s[..., 0] > 0 for s in slices]
    plain = {"meta": np.array('{"format": "x"}'), "x": np.arange(4.0)}
    write_stacked_npz(tmp_path / "a.npz", plain, {"s": lambda: iter(slices), "f": lambda: iter(flags)}, 5)
    np.savez(tmp_path / "b.npz", **plain, s=np.stack(slices), f=np.stack(flags))
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
    assert all(np.array_equal(a, b) for a, b in zip(iter_slices(tmp_path / "a.npz", "s"), slices))
    with pytest.raises(ValueError, match="4 slices, expected 5"):
        write_stacked_npz(tmp_path / "c.npz", plain, {"s": lambda: iter(slices[:4])}, 5)
    assert not (tmp_path / "c.npz").exists()
