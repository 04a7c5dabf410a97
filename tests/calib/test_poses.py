"""The joint estimation of display poses and generic rays (calib.poses), against data built here from
known rays and poses (ray-plane intersections written in the test)."""

import numpy as np
import pytest

from calib.poses import (OUT_OF_FAMILY, PoseSample, _Problem, exp_so3, free_basis, log_so3, pose_sample,
                         refine_poses, staged_basis)


def _rotation(axis, deg):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = np.radians(deg)
    return np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k


def _scene(m=6, n=400, central=False, tilt=30.0):
    """N rays of a camera of sqrt(N) x sqrt(N) pixels (row-major; slopes +-0.3 with a wavy distortion,
    non-central: origins spread over 20 mm, also varying with the pixel) and M display poses around
    400 mm, tilted up to `tilt` degrees; returns (display-frame points (M, N, 2) mm, rotations,
    translations, ray origins, directions)."""
    side = int(round(np.sqrt(n)))
    v, u = np.mgrid[0:side, 0:side].reshape(2, -1) / (side - 1) * 2 - 1
    slope = 0.3 * np.column_stack([u, v]) + 0.01 * np.column_stack([np.sin(5 * v), np.cos(4 * u)])
    d = np.column_stack([slope, np.ones(len(u))])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.zeros((len(u), 3)) if central else np.column_stack([10 * u * v, 10 * np.sin(3 * u), np.zeros(len(u))])
    rot, trans, pts = [], [], []
    for k in range(m):
        r = _rotation([np.cos(2 * np.pi * k / m), np.sin(2 * np.pi * k / m), 0.1], tilt * (0.3 + 0.7 * k / m)) \
            @ _rotation([0, 0, 1], 10 * np.sin(k))
        centre = np.array([0.0, 0.0, 380.0 + 40 * k])
        t = centre - r @ np.array([150.0, 100.0, 0.0])
        normal = r[:, 2]
        s = ((t - o) @ normal) / (d @ normal)
        x = o + s[:, None] * d
        pts.append(((x - t) @ r)[:, :2])
        rot.append(r)
        trans.append(t)
    return np.array(pts), np.array(rot), np.array(trans), o, d


def _sample(points, weights=None):
    n = points.shape[1]
    side = int(np.ceil(np.sqrt(n)))
    pixels = np.column_stack([np.arange(n) % side, np.arange(n) // side]).astype(float)
    return PoseSample(points, np.ones(points.shape[:2]) if weights is None else weights, pixels, 1)


def test_normal_equations_match_a_finite_difference_jacobian():
    """J^T J and J^T r from the structure equal those of the Jacobian by central differences (the
    points slightly off their lines, so that Kaufman's and the exact Jacobian agree to that order)."""
    pts, rot, trans, _, _ = _scene(m=4, n=64)
    rng = np.random.default_rng(1)
    w = rng.uniform(0.5, 2.0, pts.shape[:2])
    w[1, :7] = 0.0                                            # a few points missing
    for basis in (free_basis(4), staged_basis(np.array([0.0, 10.0, 25.0, 50.0]))):
        prob = _Problem(pts + rng.normal(0, 1e-4, pts.shape), w, rot, trans, basis)
        p = rng.normal(0, 1e-4, basis.shape[1])
        h = 1e-6
        jac = np.stack([(prob.residual(p + h * e) - prob.residual(p - h * e)) / (2 * h)
                        for e in np.eye(len(p))], axis=1)
        jtj, jtr, cost = prob.normal_equations(p)
        r = prob.residual(p)
        assert np.abs(jtj - jac.T @ jac).max() <= 1e-5 * np.abs(jtj).max()
        assert np.abs(jtr - jac.T @ r).max() <= 1e-6 * np.abs(jtr).max()
        assert cost == pytest.approx(r @ r)


@pytest.mark.parametrize("central", [False, True])
def test_refine_recovers_the_true_poses_of_a_generic_camera(central):
    """From poses off by ~1 mm and ~0.5 degree, the refinement returns the true poses (relative to
    pose 0) to 1e-6 mm and 1e-6 degrees, for a non-central and a central ray field."""
    pts, rot, trans, _, _ = _scene(central=central)
    rng = np.random.default_rng(2)
    start_r = np.array([exp_so3(rng.normal(0, 0.008, 3)) @ r for r in rot])
    start_r[0] = rot[0]
    start_t = trans + rng.normal(0, 1.0, trans.shape)
    start_t[0] = trans[0]
    fit = refine_poses(_sample(pts), start_r, start_t)
    for k in range(len(rot)):
        assert np.degrees(np.linalg.norm(log_so3(fit.rotation[k] @ rot[k].T))) < 1e-6
        assert np.abs(fit.translation[k] - trans[k]).max() < 1e-6
    assert fit.cost < 1e-12 * fit.cost_start


def test_uncertainty_matches_the_scatter_of_the_estimates():
    """With Gaussian noise on the points, the reported 1-sigma of the poses matches the scatter of the
    estimates over repeated noise draws (within 30 %)."""
    pts, rot, trans, _, _ = _scene(m=5, n=289)
    rng = np.random.default_rng(4)
    errs, sds = [], []
    for _ in range(30):
        fit = refine_poses(_sample(pts + rng.normal(0, 0.01, pts.shape)), rot, trans)
        q = fit.rotation[3].T @ (fit.centre[3] - fit.translation[3])     # the centre, display frame
        errs.append(fit.centre[3] - (rot[3] @ q + trans[3]))
        sds.append(np.sqrt(np.diag(fit.covariance[3])[3:]))
    scatter = np.std(np.array(errs), axis=0)
    assert np.allclose(scatter, np.mean(sds, axis=0), rtol=0.3)


def test_a_pose_of_two_displays_is_out_of_family():
    """A pose whose column coordinates come from one display pose and its row coordinates from another
    (the display moved between its x and y fringes) is out of family; the others are not."""
    pts, rot, trans, o, d = _scene(m=7, n=900)
    moved_r = _rotation([0.3, -0.5, 1.0], 0.1) @ rot[4]
    moved_t = trans[4] + np.array([0.1, -0.15, 0.1])
    s = ((moved_t - o) @ moved_r[:, 2]) / (d @ moved_r[:, 2])
    pts[4, :, 1] = ((o + s[:, None] * d - moved_t) @ moved_r)[:, 1]
    noisy = pts + np.random.default_rng(6).normal(0, 0.005, pts.shape)
    fit = refine_poses(_sample(noisy), rot, trans)
    assert fit.out_of_family[4] and np.argmax(fit.chi) == 4
    # without it the others are in family (in the first fit they were pulled towards it)
    keep = [k for k in range(7) if k != 4]
    again = refine_poses(_sample(noisy[keep]), rot[keep], trans[keep])
    assert not again.out_of_family.any() and again.chi.max() < OUT_OF_FAMILY / 2


def test_staged_basis_leaves_the_trend_of_the_travel_fixed():
    """The staged parameters never move pose 0 and never change the linear trend of the translations
    along the nominal positions (the gauge of parallel planes)."""
    z = np.array([0.0, 20.0, 35.0, 50.0])
    basis = staged_basis(z)
    assert basis.shape == (24, 3 * 3 + 3 * 2)
    assert np.abs(basis[:6]).max() == 0
    trans = basis.reshape(4, 6, -1)[:, 3:, :]                  # (M, 3 axes, P)
    assert np.abs(np.einsum("k,kap->ap", z - z[0], trans)).max() < 1e-12


def test_block_means_lie_on_the_block_centre_ray():
    """Block means of the exact display points of a pinhole camera seeing a tilted plane lie within
    0.2 um of the point of the block centre's ray (the second-order effect of the block size)."""
    h, w, f, block = 96, 128, 400.0, 8
    v, u = np.mgrid[0:h, 0:w].astype(float)
    r = _rotation([1, 1, 0], 35.0)
    t = np.array([-60.0, -40.0, 300.0])

    def display_point(uu, vv):
        d = np.stack([(uu - (w - 1) / 2) / f, (vv - (h - 1) / 2) / f, np.ones_like(uu)], axis=-1)
        s = (t @ r[:, 2]) / (d @ r[:, 2])
        return np.moveaxis((s[..., None] * d - t) @ r, -1, 0)[:2]

    coord = display_point(u, v) / 0.25                        # display pixels of 0.25 mm
    sample = pose_sample([coord], [np.ones((h, w))], (0.25, 0.25), block=block, margin=0)
    exact = display_point(sample.pixels[:, 0], sample.pixels[:, 1]).T
    assert np.abs(sample.points[0] - exact).max() < 2e-4
