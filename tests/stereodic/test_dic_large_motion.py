"""Large motion with the defaults: a real speckle image (DIC Challenge sample 5) moved by a known rigid
motion far beyond any fixed search range, measured by `stereodic dic2d` without options, against the exact
truth of the warp applied, and against the small-motion accuracy of the same images and pipeline."""

from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy import ndimage

from calib.imageio import read_gray, write_gray
from stereodic.cli import main

DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "dic-challenge-sample5"
pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason="DIC challenge sample 5 images not present")
SUBSET, STEP = 21, 6


def _motion(shape: tuple[int, int], angle_deg: float, shift: tuple[float, float], stretch: float = 1.0
            ) -> np.ndarray:
    """The 2x3 map from reference to deformed pixel positions: a stretch along x, a rotation by angle_deg
    (both about the image centre), then a translation (pixels)."""
    h, w = shape
    M = cv2.getRotationMatrix2D((w / 2, h / 2), angle_deg, 1.0)
    M[:, :2] = M[:, :2] @ np.diag([stretch, 1.0])
    M[:, 2] = np.array([w / 2, h / 2]) - M[:, :2] @ [w / 2, h / 2] + shift
    return M


def _warped(img: np.ndarray, M: np.ndarray) -> np.ndarray:
    """The image as a continuous function (its quintic B-spline interpolant) moved by the map M (2x3,
    reference to deformed pixels): the deformed image sampled exactly there (float, no quantisation)."""
    h, w = img.shape
    inv = cv2.invertAffineTransform(M)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    src_x = inv[0, 0] * xx + inv[0, 1] * yy + inv[0, 2]
    src_y = inv[1, 0] * xx + inv[1, 1] * yy + inv[1, 2]
    return ndimage.map_coordinates(img.astype(np.float64), [src_y, src_x], order=5, mode="constant",
                                   cval=float(img.mean()))


def _errors(tmp_path: Path, ref: np.ndarray, M: np.ndarray, name: str):
    """`dic2d` with the defaults on (ref, ref moved by M): per point of the specimen (whose moved subset
    lies inside the image), its error against the truth (u, v), pixels, and whether it was measured."""
    dfm = _warped(ref, M)
    # 16-bit images, 256 levels per grey level of the original: the warp's rounding is negligible
    write_gray(tmp_path / "ref.png", ref.astype(np.uint16) * 256)
    write_gray(tmp_path / f"{name}.png", np.clip(np.rint(dfm * 256), 0, 65535).astype(np.uint16))
    out = tmp_path / f"{name}.npz"
    assert main(["dic2d", str(tmp_path / "ref.png"), str(tmp_path / f"{name}.png"), "-o",
                 str(tmp_path / f"{name}.csv"), "--npz", str(out)]) == 0
    f = np.load(out)
    X, Y = np.meshgrid(f["x"], f["y"])
    tx = M[0, 0] * X + M[0, 1] * Y + M[0, 2]
    ty = M[1, 0] * X + M[1, 1] * Y + M[1, 2]
    h, w = ref.shape
    r = SUBSET // 2 * np.sqrt(2) + 3     # the moved subset, any rotation, with the B-spline's margin
    specimen = f["active"] & (tx >= r) & (tx <= w - 1 - r) & (ty >= r) & (ty <= h - 1 - r)
    eu = f["u"][0] - (tx - X)
    ev = f["v"][0] - (ty - Y)
    return eu[specimen], ev[specimen], (f["status"][0] == 0)[specimen]


@pytest.mark.parametrize("angle_deg,shift,stretch", [
    (20.0, (70 * np.cos(0.6), 70 * np.sin(0.6)), 1.0),   # 70 px and 20 degrees
    (-30.0, (-128.0, 0.0), 1.2),                         # a quarter of the image, 30 degrees, 20 % strain
])
def test_dic2d_defaults_measure_large_motion_as_well_as_a_small_one(tmp_path, angle_deg, shift, stretch):
    ref = read_gray(DATA / "reference.tif")
    su, sv, s_ok = _errors(tmp_path, ref, _motion(ref.shape, 0.5, (0.3, -0.2)), "small")
    lu, lv, l_ok = _errors(tmp_path, ref, _motion(ref.shape, angle_deg, shift, stretch), "large")
    assert s_ok.all() and l_ok.all(), f"measured {s_ok.mean():.1%} (small), {l_ok.mean():.1%} (large)"
    assert l_ok.size > 2500                        # the moved specimen still covers much of the image
    for small, large in ((su, lu), (sv, lv)):
        assert abs(np.mean(large)) <= abs(np.mean(small)) + 0.002
        assert np.std(large) <= np.std(small) + 0.002
        assert np.abs(large).max() < 0.05


def test_stereo_dic_defaults_follow_80px_and_10_percent_strain(tmp_path):
    """A simulated stereo sequence: a small motion (2 px, 1 % tension) and a large one (80 px of image
    motion, 10 % tension), through `stereodic dic` with the defaults: every point of the reference
    measured in both, the large one as accurately as the small (mean displacement error within 0.002 px,
    strain within 50 microstrain or 0.05 % of the strain, with the default subset 29)."""
    from scanners.sim.dic import DicState, dic_lenses, load_dic_truth, mm_per_pixel, truth_at_pixels
    from stereodic.stereo.rig import load_rig
    from tests.stereodic.dic_cases import simulate_dic_with_rig

    mm = mm_per_pixel(dic_lenses(320, 256)[0])
    states = [DicState("reference"), DicState("small", stretch=(1.01, 0.997), translation_mm=(2 * mm, -mm, 0.0)),
              DicState("large", stretch=(1.10, 0.97), translation_mm=(80 * mm, 0.0, 0.0))]
    simulate_dic_with_rig(tmp_path, states, width=320, height=256, supersample=2)
    # the points whose subsets stay in view after 80 px and 10 % along x
    assert main(["dic", str(tmp_path / "rig.npz"), str(tmp_path), "--roi", "20,20,190,235", "--no-vtk", "--no-plot",
                 "-o", str(tmp_path / "out")]) == 0
    z = np.load(tmp_path / "out" / "dic.npz")
    X, Y = np.meshgrid(z["x"], z["y"])
    rig = load_rig(tmp_path / "rig.npz")
    truth = truth_at_pixels(load_dic_truth(tmp_path), rig.left.imm.real_position(X.ravel(), Y.ravel()))
    ref_ok = z["converged"][0].astype(bool)
    assert ref_ok.sum() > 0.9 * z["active"].sum()
    err = {}
    for k in (1, 2):
        c = z["converged"][k].astype(bool)
        assert c[ref_ok].all(), f"state {k}: {c[ref_ok].mean():.1%} of the reference's points"
        d = z["displacement"][k].reshape(-1, 3)[c.ravel()] - truth["displacement"][k][c.ravel()]
        err[k] = d.mean(0) / mm                            # pixels (out of plane: at the plate's scale)
        sv = z["strain_valid"][k].ravel().astype(bool)
        for e in ("exx", "eyy", "exy"):   # 50 microstrain, or 0.05 % of a large strain (10 %: 52 microstrain)
            true = truth[e][k][sv]
            assert abs(np.mean(z[e][k].ravel()[sv] - true)) < max(50e-6, 5e-4 * abs(np.mean(true)))
    assert (np.abs(err[2][:2]) <= np.abs(err[1][:2]) + 0.002).all(), err
    # depth: the triangulation scales an image error by distance / baseline (400 / 200 mm)
    assert abs(err[2][2]) <= abs(err[1][2]) + 2 * 0.002, err


def test_search_below_one_pixel_is_bad_input(tmp_path, capsys):
    ref = read_gray(DATA / "reference.tif")
    write_gray(tmp_path / "ref.png", ref)
    assert main(["dic2d", str(tmp_path / "ref.png"), str(tmp_path / "ref.png"), "--search", "0",
                 "-o", str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err
    assert "--search" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o.csv").exists()
