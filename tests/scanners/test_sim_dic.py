"""The simulated stereo DIC experiment: exact truth (strains, ray intersections) and the dataset."""

import numpy as np
import pytest

from calib.capture import load_capture
from calib.prvm_file import load_prvm
from scanners.sim.dic import (DicState, DicTruth, Specimen, dic_lenses, load_dic_truth, simulate_dic,
                              standard_states)


def test_truth_strains_are_green_lagrange_of_the_map():
    truth = DicTruth(Specimen(tilt_deg=20.0), standard_states(strain=0.01, poisson=0.3, bulge_mm=3.0))
    X1, X2 = np.meshgrid(np.linspace(-40, 40, 7), np.linspace(-30, 30, 5))
    e11, e22, e12 = truth.strain(3, X1, X2)            # tension
    assert np.allclose(e11, 0.5 * (1.01 ** 2 - 1)) and np.allclose(e22, 0.5 * (0.997 ** 2 - 1))
    assert np.allclose(e12, 0)
    for state in range(len(truth.states)):          # finite differences of the positions
        h = 1e-4
        p = lambda a, b: truth.position(state, a, b)  # noqa: E731
        g1 = (p(X1 + h, X2) - p(X1 - h, X2)) / (2 * h)
        g2 = (p(X1, X2 + h) - p(X1, X2 - h)) / (2 * h)
        e11, e22, e12 = truth.strain(state, X1, X2)
        assert np.allclose(0.5 * ((g1 * g1).sum(-1) - 1), e11, atol=1e-8)
        assert np.allclose(0.5 * ((g2 * g2).sum(-1) - 1), e22, atol=1e-8)
        assert np.allclose(0.5 * (g1 * g2).sum(-1), e12, atol=1e-8)
    rigid = truth.strain(2, X1, X2)                  # a rotation does not strain
    assert max(np.abs(e).max() for e in rigid) < 1e-12


def test_rays_meet_the_deformed_plate_at_the_material_point():
    truth = DicTruth(Specimen(), [DicState("bulge", bulge_mm=4.0, rotation_deg=(1, 2, 3), translation_mm=(1, 2, 3))])
    X = np.column_stack([np.linspace(-50, 50, 9), np.linspace(30, -30, 9)])
    p = truth.position(0, X[:, 0], X[:, 1])
    camera = np.array([100.0, 150.0, -400.0])
    d = p - camera
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    assert np.allclose(truth.material_at(np.broadcast_to(camera, p.shape), d, 0), X, atol=1e-8)


def test_twist_strain_and_rays_are_exact():
    """A twist (rotation fading with the radius) with stretch, bulge and a rigid motion: the analytic
    Green-Lagrange strain equals finite differences of the positions, and rays find the material point."""
    state = DicState("twist", stretch=(1.1, 0.95), bulge_mm=5.0, twist_deg=60.0, twist_radius_mm=30.0,
                     rotation_deg=(3, -2, 10), translation_mm=(1, 2, 3))
    truth = DicTruth(Specimen(), [state])
    X1, X2 = np.meshgrid(np.linspace(-45, 45, 7), np.linspace(-35, 35, 5))
    h = 1e-5
    p = lambda a, b: truth.position(0, a, b)  # noqa: E731
    g1 = (p(X1 + h, X2) - p(X1 - h, X2)) / (2 * h)
    g2 = (p(X1, X2 + h) - p(X1, X2 - h)) / (2 * h)
    e11, e22, e12 = truth.strain(0, X1, X2)
    assert np.abs(e12).max() > 0.1                                 # the twist shears
    assert np.allclose(0.5 * ((g1 * g1).sum(-1) - 1), e11, atol=1e-8)
    assert np.allclose(0.5 * ((g2 * g2).sum(-1) - 1), e22, atol=1e-8)
    assert np.allclose(0.5 * (g1 * g2).sum(-1), e12, atol=1e-8)
    pts = p(X1.ravel(), X2.ravel())
    camera = np.array([-80.0, 40.0, -400.0])
    d = pts - camera
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    X = truth.material_at(np.broadcast_to(camera, pts.shape), d, 0)
    assert np.allclose(X, np.column_stack([X1.ravel(), X2.ravel()]), atol=1e-8)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("dic")
    states = [DicState("reference"), DicState("tension", stretch=(1.02, 0.994))]
    return simulate_dic(out, states, width=96, height=80, supersample=2)


def test_dataset_has_states_true_cameras_and_truth(dataset):
    cap = load_capture(dataset.root)
    assert cap.kind == "dic" and sorted(cap.cameras) == ["cam0", "cam1"]
    assert cap.states("cam0") == cap.states("cam1") == [0, 1]
    imgs = [cap.read(f) for f in cap.frames]
    assert all(i.shape == (80, 96) and i.dtype == np.uint8 for i in imgs)
    assert all(i.std() > 10 for i in imgs)                          # speckled
    assert not np.array_equal(imgs[0], imgs[2])                     # cam0 state 0 vs state 1
    lenses = dic_lenses(96, 80)
    for name, lens in zip(("cam0", "cam1"), lenses):              # the true rays, for `stereodic rig`
        prvm = load_prvm(dataset.root / f"truth_{name}.npz")
        o, d = lens.rays(*lens.pixel_grid())
        assert prvm.meta["camera"] == name and np.array_equal(prvm.direction, d)
    assert not (dataset.root / "rig.npz").exists()
    truth = load_dic_truth(dataset.root)
    assert [ln.family for ln in truth.lenses()] == [ln.family for ln in lenses]
    assert truth.states[1].stretch == (1.02, 0.994)
    with np.load(dataset.root / "truth.npz") as z:
        assert z["displacement"].shape[0] == 2 and np.allclose(z["exx"][1], 0.5 * (1.02 ** 2 - 1))


def test_default_lenses_see_the_same_field_at_any_size():
    small, big = dic_lenses(320, 256)[0], dic_lenses(1280, 1024)[0]
    assert small.pixel_mm == pytest.approx(4 * big.pixel_mm)


@pytest.mark.parametrize("plate", [(0.0, 1.0), (0.5, -0.3)])
def test_a_plate_of_no_size_is_bad_input_before_any_file(tmp_path, plate):
    from calib.errors import InputError
    with pytest.raises(InputError, match="plate"):
        simulate_dic(tmp_path / "out", plate=plate)
    assert not (tmp_path / "out").exists()
