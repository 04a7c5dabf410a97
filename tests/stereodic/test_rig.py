"""The rectified virtual stereo pair: its geometry against the simulator's truth."""

import numpy as np
import pytest

from stereodic.stereo.rig import load_rig, save_rig
from tests.stereodic.rig_cases import inside, pair, seen_at, volume_points


@pytest.mark.parametrize("families", [("brown", "brown"), ("brown", "freeform"), ("scheimpflug", "freeform")])
def test_points_in_the_working_volume_land_on_one_row(families):
    """Central lenses: a world point anywhere within +-60 mm of the plane is on the same row in both
    rectified images (within 0.01 px RMS)."""
    ll, lr, pl, pr, rig = pair(*families)
    x = volume_points(rig, 3000, 60.0)
    left, right = seen_at(rig, ll, pl, x), seen_at(rig, lr, pr, x)
    ok = inside(rig, left, right)
    assert ok.sum() > 2000
    rms = np.sqrt(np.mean((left[ok, 1] - right[ok, 1]) ** 2))
    assert rms < 0.01
    assert np.ptp(left[ok, 0] - right[ok, 0]) > 20       # the depth range shows as disparity


def test_geometry_matches_the_seed():
    ll, lr, pl, pr, rig = pair()
    s = rig.sensor
    # the fitted centres are the true ones (central lenses, exact rays)
    assert np.allclose(rig.left.centre, ll.centre_mm, atol=1e-6)
    assert np.allclose(rig.right.centre, lr.centre_mm, atol=1e-6)
    b = rig.baseline / np.linalg.norm(rig.baseline)
    assert abs(b @ s.normal) < 1e-12                    # plane parallel to the baseline
    assert np.allclose(s.axis_u, b)                      # rows along it
    d_left = (s.origin - rig.left.centre) @ s.normal
    d_right = (s.origin - rig.right.centre) @ s.normal
    assert d_left == pytest.approx(d_right, rel=1e-12) and d_left > 0
    # the plane is where the cameras look: the display at z = 0, ~400 mm away
    assert abs(s.centre[2]) < 5 and 390 < rig.working_distance_mm < 410
    # same pixels on the same plane, no blank pixel in either camera
    assert rig.left.imm.valid.all() and rig.right.imm.valid.all()
    # the pinhole virtual rays converge on each camera's own centre; the EVM of a central lens is ~0
    for side, lens in (("left", ll), ("right", lr)):
        vp = rig.virtual_prvm(side)
        p = vp.origin - lens.centre_mm
        miss = np.linalg.norm(p - np.einsum("...i,...i->...", p, vp.direction)[..., None] * vp.direction, axis=-1)
        assert miss.max() < 1e-6
        assert np.nanmax(np.linalg.norm(rig.evm(side), axis=-1)) < 1e-5


def test_common_field_is_largest_inside_both():
    """Growing the grid by a few pixels on each side makes some pixels blank in one of the cameras."""
    from stereodic.virtual.imm import build_imm
    ll, lr, pl, pr, rig = pair()
    s = rig.sensor
    bigger = s.with_field(((s.width - 1) / 2 * s.pitch_mm[0], (s.height - 1) / 2 * s.pitch_mm[1]),
                          s.pitch_mm[0] * 1.03, s.width, s.height)
    assert np.allclose(bigger.centre, s.centre)
    assert not (build_imm(pl, bigger).valid.all() and build_imm(pr, bigger).valid.all())


def test_noncentral_evm_is_the_real_ray_correction():
    ll, lr, pl, pr, rig = pair("noncentral", "brown")
    evm = rig.evm("left")
    assert np.nanmax(np.linalg.norm(evm, axis=-1)) > 1e-5
    # pinhole + EVM = the true ray through each virtual pixel centre
    d = rig.pinhole_direction("left") + evm
    o, true_d = ll.rays(rig.left.imm.map_x.astype(float), rig.left.imm.map_y.astype(float))
    assert np.nanmax(np.linalg.norm(d - true_d, axis=-1)) < 1e-6


def test_save_and_load(tmp_path):
    *_, rig = pair()
    save_rig(tmp_path / "rig.npz", rig)
    with np.load(tmp_path / "rig.npz", allow_pickle=False) as z:     # plain arrays, no pickles
        assert z["left_map_x"].dtype == np.float32 and z["right_direction"].dtype == np.float64
    back = load_rig(tmp_path / "rig.npz")
    assert np.array_equal(back.left.imm.map_x, rig.left.imm.map_x)
    assert np.array_equal(back.right.direction, rig.right.direction, equal_nan=True)
    assert np.allclose(back.sensor.origin, rig.sensor.origin) and back.model == rig.model
    assert np.allclose(back.baseline, rig.baseline)


def test_modelless_rig_has_the_same_images_and_no_evm():
    from stereodic.stereo.rig import build_rig
    ll, lr, pl, pr, rig = pair("noncentral", "brown")
    ml = build_rig(pl, pr, model="modelless")
    assert np.array_equal(ml.left.imm.map_x, rig.left.imm.map_x)
    assert np.nanmax(np.abs(ml.evm("left"))) == 0
    assert np.allclose(ml.virtual_prvm("left").direction, rig.left.direction, equal_nan=True)
