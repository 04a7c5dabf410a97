"""The PRVM file format of DESIGN.md: round trip, ray geometry and rejection of other files."""

import json

import numpy as np
import pytest

from calib.errors import InputError
from calib.prvm_file import PRVM, load_prvm


def pinhole_prvm(w=8, h=6, centre=(1.0, -2.0, -400.0), ref_z=10.0):
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    d = np.stack([(u - w / 2) * 0.01, (v - h / 2) * 0.01, np.ones_like(u)], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    c = np.asarray(centre)
    origin = c + d * ((ref_z - c[2]) / d[..., 2])[..., None]
    return PRVM(origin, d, np.ones((h, w), bool), None, {"camera": "cam0", "reference_z_mm": ref_z},
                {"uncertainty_mm": np.full((h, w), 0.001, np.float32)})


def test_round_trip_keeps_keys_and_extras(tmp_path):
    p = pinhole_prvm()
    p.save(tmp_path / "cam.npz")
    back = load_prvm(tmp_path / "cam.npz")
    assert np.array_equal(back.origin, p.origin) and np.array_equal(back.direction, p.direction)
    assert back.meta["format"] == "stereodic.prvm/1" and back.meta["width"] == 8 and back.meta["height"] == 6
    assert back.reference_z_mm == 10.0 and np.isnan(back.residual_mm).all()
    assert np.allclose(back.extra["uncertainty_mm"], 0.001)
    with np.load(tmp_path / "cam.npz") as z:
        assert z["origin"].dtype == np.float64 and z["valid"].dtype == bool
        assert z["residual_mm"].dtype == np.float32
        assert json.loads(str(z["meta"]))["camera"] == "cam0"


def test_at_z_points_lie_on_the_rays():
    p = pinhole_prvm()
    pts = p.at_z(-400.0)            # every ray passes through the centre
    assert np.allclose(pts, [1.0, -2.0, -400.0], atol=1e-9)
    assert np.allclose(p.at_z(10.0), p.origin)


def test_not_a_prvm_is_rejected(tmp_path):
    np.savez(tmp_path / "x.npz", a=np.zeros(3))
    with pytest.raises(InputError, match="x.npz: not a PRVM file"):
        load_prvm(tmp_path / "x.npz")
    (tmp_path / "y.npz").write_text("junk")
    with pytest.raises(InputError, match="y.npz: not a readable"):
        load_prvm(tmp_path / "y.npz")
    with pytest.raises(InputError, match="missing"):
        load_prvm(tmp_path / "none.npz")


def test_outputs_get_ordinary_permissions(tmp_path):
    import os
    import stat
    pinhole_prvm().save(tmp_path / "cam.npz")
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(os.stat(tmp_path / "cam.npz").st_mode) == 0o666 & ~mask


def test_stereodic_npz_files_are_told_apart(tmp_path):
    """One reader for every stereodic .npz: the wrong kind of file is named, with advice where given."""
    from calib.npzfile import read_npz
    pinhole_prvm().save(tmp_path / "cam.npz")
    meta, arrays = read_npz(tmp_path / "cam.npz", "stereodic.prvm/1", "PRVM")
    assert meta["width"] == 8 and "meta" not in arrays and arrays["origin"].shape == (6, 8, 3)
    with pytest.raises(InputError, match=r"cam.npz: format is 'stereodic.prvm/1', expected 'stereodic.rig/1' "
                                         r"\(a camera file\)"):
        read_npz(tmp_path / "cam.npz", "stereodic.rig/1", "rig", advice={"stereodic.prvm/1": "a camera file"})
    np.savez(tmp_path / "m.npz", meta=np.array("{not json"))
    with pytest.raises(InputError, match="m.npz: 'meta' is not valid JSON"):
        read_npz(tmp_path / "m.npz", "stereodic.rig/1", "rig")
    with pytest.raises(InputError, match="gone.npz: rig file is missing"):
        read_npz(tmp_path / "gone.npz", "stereodic.rig/1", "rig")
