"""2D DIC on the real DIC-Challenge sample 5 images, against the displacements their README states."""

from pathlib import Path

import numpy as np
import pytest

from calib.imageio import read_gray
from stereodic.dic import DicSettings, correlate_pair, make_grid

DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "dic-challenge-sample5"
pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason="DIC challenge sample 5 images not present")

# (file, true u, true v) from the folder's README
CASES = [("shift_x0.10_y0.10.tif", 0.10, 0.10), ("shift_x0.00_y0.00.tif", 0.0, 0.0)]


@pytest.mark.parametrize("subset", [21, 35])
@pytest.mark.parametrize("name,true_u,true_v", CASES)
def test_mean_displacement_within_0_0015_px(name, true_u, true_v, subset):
    ref = read_gray(DATA / "reference.tif")
    dfm = read_gray(DATA / name)
    grid = make_grid(ref.shape[1], ref.shape[0], subset=subset, step=6, roi=(40, 40, 471, 471))
    field = correlate_pair(ref, dfm, grid, settings=DicSettings(subset=subset))
    assert field.ok.all()
    assert abs(np.mean(field.u) - true_u) < 0.0015
    assert abs(np.mean(field.v) - true_v) < 0.0015
    # the random error of such images is a few thousandths of a pixel
    assert np.std(field.u) < 0.006 and np.std(field.v) < 0.006
