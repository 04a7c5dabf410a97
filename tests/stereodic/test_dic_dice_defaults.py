"""A lab's first run on the dice-stereo-list case (../shared/data/dice-stereo-list: VIC-3D calibration,
six image pairs of a static specimen, DICe's committed result) with the defaults and nothing else:
`stereodic import cal.xml -o rig.npz`, then `stereodic dic rig.npz --images images -o out`.

The calibration does not fit these images (their rectified rows are 12-39 px apart), so the run must
find that by itself: re-orient the right camera from the reference pair's speckle, follow the rows that
remain off, find the specimen without a region of interest, and say what it corrected. Checked against
DICe's result as in test_dic_dice_stereo_list.py (which runs DICe's own settings): coverage of DICe's
valid points (our nearest grid point converged in every state) and the static displacement noise of
states 1-5, in the specimen's plane and along its normal, at those points; and the static strain, zero,
over all our points."""

import numpy as np
import pytest

from stereodic.cli import main
from stereodic.formats import import_calibration
from stereodic.virtual.camera import project_to_plane
from tests.stereodic.dice_gold import DATA, dice_fields, xyz

pytestmark = [pytest.mark.slow, pytest.mark.skipif(not DATA.is_dir(), reason="dice-stereo-list not present")]


def _components(d: np.ndarray, normal: np.ndarray) -> tuple[float, float]:
    """RMS (mm) of displacements d (N, 3) in the plane of `normal` and along it."""
    out = d @ normal
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1) - out ** 2))), float(np.sqrt(np.mean(out ** 2)))


def test_the_defaults_measure_what_dice_measured(tmp_path, capsys):
    rig = tmp_path / "rig.npz"
    assert main(["import", str(DATA / "cal.xml"), "-o", str(rig)]) == 0
    assert main(["dic", str(rig), "--images", str(DATA / "images"), "-o", str(tmp_path / "out")]) == 0
    text = capsys.readouterr().out
    assert "does not fit these images" in text and "turned by" in text and "before" in text and "after" in text

    with np.load(tmp_path / "out" / "dic.npz") as z:
        xs, ys, converged, disp = z["x"], z["y"], z["converged"], z["displacement"]
        strains = [(z["exx"][k], z["eyy"][k], z["strain_valid"][k].astype(bool)) for k in range(1, 6)]
    # the specimen does not move: its strain is zero; points centred off its edges (extrapolated from a strip
    # of speckle) spread it to 1454 microstrain, and every strain window that takes them
    for exx, eyy, valid in strains:
        for e in (exx[valid], eyy[valid]):
            assert abs(np.mean(e)) < 30e-6 and np.std(e) < 400e-6, (np.mean(e), np.std(e))
    f = dice_fields()
    ok = f["SIGMA"][0] >= 0
    uv0 = np.stack([f["SUBSET_COORDINATES_X"][0], f["SUBSET_COORDINATES_Y"][0]], 1)[ok]
    imp = import_calibration([DATA / "cal.xml"])
    q = project_to_plane(imp.prvms[0], imp.result.sensor)[uv0[:, 1].astype(int), uv0[:, 0].astype(int)]
    step = xs[1] - xs[0]
    gx, gy = (q[:, 0] - xs[0]) / step, (q[:, 1] - ys[0]) / step
    near = (np.clip(np.rint(gy).astype(int), 0, ys.size - 1), np.clip(np.rint(gx).astype(int), 0, xs.size - 1))
    matched = np.all([c[near] for c in converged], axis=0)
    assert matched.mean() >= 0.95

    model = xyz(f, "MODEL_COORDINATES", 0)[ok]
    c = model - model.mean(0)
    normal = np.linalg.svd(c, full_matrices=False)[2][2]
    ours = np.concatenate([d[near][matched] for d in disp[1:]])
    theirs = np.concatenate([xyz(f, "MODEL_DISPLACEMENT", s)[ok][matched] for s in range(1, 6)])
    own, dice = _components(ours, normal), _components(theirs, normal)
    print(f"matched {matched.mean():.3f}, noise in-plane {own[0] * 1e3:.2f} um (DICe {dice[0] * 1e3:.2f}), "
          f"out-of-plane {own[1] * 1e3:.2f} um (DICe {dice[1] * 1e3:.2f})")
    assert own[0] <= dice[0] and own[1] <= dice[1]


def test_a_start_point_in_the_original_image_lands_where_its_ray_meets_the_plane():
    """`dic --roi-frame original --start-point X,Y` on the imported VIC-3D rig: DICe's points (pixels of the
    original left image) moved onto the rectified pixel that samples them (`region.point_to_rectified`, the
    rig's IMM, as the run does; the left camera is the one a re-orientation keeps) land within a pixel of where
    their calibrated rays meet the rectified plane (`project_to_plane` of the imported PRVM: another route)."""
    from stereodic.dic.region import point_to_rectified
    imp = import_calibration([DATA / "cal.xml"])
    imm = imp.result.left.imm
    f = dice_fields()
    ok = f["SIGMA"][0] >= 0
    uv0 = np.stack([f["SUBSET_COORDINATES_X"][0], f["SUBSET_COORDINATES_Y"][0]], 1)[ok]
    q = project_to_plane(imp.prvms[0], imp.result.sensor)
    picked = uv0[np.linspace(0, len(uv0) - 1, 25).astype(int)]
    landed = np.array([point_to_rectified(u, v, imm.map_x, imm.map_y, imm.valid) for u, v in picked], float)
    assert np.abs(landed - q[picked[:, 1].astype(int), picked[:, 0].astype(int)]).max() < 1.0
    w, h = imm.real_size
    assert point_to_rectified(w + 30.0, h / 2, imm.map_x, imm.map_y, imm.valid) is None
