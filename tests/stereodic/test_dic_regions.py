"""Regions of interest as a user draws them: polygons with holes (JSON or CSV) in the original left image,
moved onto the rectified one through the rig; and the specimen found by itself without any region."""

import json

import numpy as np
import pytest

from calib.errors import InputError
from stereodic.cli import main
from stereodic.dic import ImageRef
from stereodic.dic.region import polygon_mask, read_polygons
from stereodic.dic.texture import specimen_mask
from stereodic.stereo.rig import load_rig

OUTER = [[40, 30], [200, 30], [200, 160], [40, 160]]
HOLE = [[100, 70], [150, 70], [150, 120], [100, 120]]


def test_json_and_csv_polygons_with_holes_agree(tmp_path):
    parts = [{"outer": OUTER, "holes": [HOLE]}, {"outer": [[5, 5], [20, 5], [5, 20]]}]
    (tmp_path / "p.json").write_text(json.dumps(parts))
    rings = "\n\n".join("\n".join(f"{x},{y}" for x, y in ring) for ring in (OUTER, HOLE))
    (tmp_path / "p.csv").write_text(f"# x,y\n{rings}\npart\n5,5\n20,5\n5,20\n")
    a = polygon_mask(read_polygons(tmp_path / "p.json"), 240, 192, where="p.json", image="image")
    b = polygon_mask(read_polygons(tmp_path / "p.csv"), 240, 192, where="p.csv", image="image")
    assert np.array_equal(a, b)
    assert a[50, 50] and not a[95, 125] and a[8, 8] and not a[3, 3] and not a[180, 220]
    assert a.sum() == pytest.approx(161 * 131 - 51 * 51 + 16 * 17 / 2, rel=0.05)
    with pytest.raises(InputError, match="outside the 100x100"):
        polygon_mask(read_polygons(tmp_path / "p.json"), 100, 100, where="p.json", image="image")


def test_a_polygon_in_the_original_left_image(dic_sim, tmp_path):
    """The points of a run given a polygon with a hole in the ORIGINAL left image: every active point
    samples (through the rig's IMM) a pixel inside the outline and outside the hole, and the points well
    inside it are all active."""
    (tmp_path / "roi.json").write_text(json.dumps({"outer": OUTER, "holes": [HOLE]}))
    out = tmp_path / "out"
    assert main(["dic", str(dic_sim / "rig.npz"), str(dic_sim), "--roi-polygon", str(tmp_path / "roi.json"),
                 "--roi-frame", "original", "--subset", "21", "--step", "6", "--no-vtk", "--no-plot",
                 "--strain-window", "0", "-o", str(out)]) == 0
    rig = load_rig(dic_sim / "rig.npz")
    with np.load(out / "dic.npz") as z:
        xs, ys, active = z["x"], z["y"], z["active"]
    X, Y = np.meshgrid(xs, ys)
    real = rig.left.imm.real_position(X, Y)
    inside = polygon_mask([*read_polygons(tmp_path / "roi.json")], 240, 192, where="", image="")
    u, v = np.rint(real[..., 0]).astype(int), np.rint(real[..., 1]).astype(int)
    assert active.sum() > 100 and inside[v[active], u[active]].all()
    (tmp_path / "shrunk.json").write_text(json.dumps({"outer": [[44, 34], [196, 34], [196, 156], [44, 156]],
                                                      "holes": [[[96, 66], [154, 66], [154, 124], [96, 124]]]}))
    deep = polygon_mask(read_polygons(tmp_path / "shrunk.json"), 240, 192, where="", image="")
    half = 10
    fits = (X >= half) & (X < rig.sensor.width - half) & (Y >= half) & (Y < rig.sensor.height - half)
    well = fits & np.isfinite(real).all(-1)
    well[well] = deep[v[well], u[well]]
    assert well.sum() > 100 and active[well].all()


def test_the_specimen_is_found_on_a_dark_background():
    """Speckle on a patch of a dark, noisy background: the mask covers the patch (less half a subset at its
    edges) and none of the background."""
    rng = np.random.default_rng(3)
    img = rng.normal(12, 2.0, (160, 200))
    dots = np.zeros((70, 90))
    for _ in range(500):
        y, x = rng.integers(0, 70), rng.integers(0, 90)
        dots[max(y - 1, 0):y + 2, max(x - 1, 0):x + 2] = 1
    img[40:110, 60:150] = 60 + 120 * dots + rng.normal(0, 2.0, (70, 90))
    img = np.clip(img, 0, 255).astype(np.uint8)
    mask = specimen_mask(img, subset=21)
    assert mask[50:100, 70:140].mean() > 0.99
    background = np.ones_like(mask)
    background[30:120, 50:160] = False
    assert not mask[background].any()
    # the noise estimate the DIC's reference keeps gives the same mask; one 4x too high loses the patch
    assert np.array_equal(specimen_mask(img, subset=21, noise=ImageRef.prepare(img).sigma), mask)
    assert specimen_mask(img, subset=21, noise=4 * ImageRef.prepare(img).sigma).sum() < mask.sum() / 2


def test_a_small_image_all_speckle_is_all_specimen():
    """An image smaller than four subsets' area, speckled all over (a small camera window, a test's
    frames): every subset centre that fits in it is usable; the same size blank is not."""
    from scipy import ndimage
    rng = np.random.default_rng(5)
    img = ndimage.gaussian_filter(rng.random((48, 64)), 2.0, mode="wrap")
    img = (20 + 215 * (img - img.min()) / np.ptp(img)).round().astype(np.uint8)
    mask = specimen_mask(img, subset=21)
    assert mask[10:38, 10:54].all() and mask.sum() == 28 * 44
    assert not specimen_mask(np.full_like(img, 90) + rng.integers(0, 3, img.shape).astype(np.uint8), subset=21).any()


def test_a_start_point_in_the_original_left_image(dic_sim, tmp_path):
    """--start-point with --roi-frame original is a pixel of the original left image: it lands on the
    rectified pixel that samples it (the rig's own IMM says where each rectified pixel samples), and a point
    outside the original image is refused in one line, exit 2."""
    from stereodic.dic.region import point_to_rectified
    imm = load_rig(dic_sim / "rig.npz").left.imm
    rng = np.random.default_rng(5)
    for _ in range(20):
        c, r = int(rng.integers(20, imm.map_x.shape[1] - 20)), int(rng.integers(20, imm.map_x.shape[0] - 20))
        if not imm.valid[r, c]:
            continue
        x, y = float(imm.map_x[r, c]), float(imm.map_y[r, c])
        cc, rr = point_to_rectified(x, y, imm.map_x, imm.map_y, imm.valid)
        assert np.hypot(imm.map_x[rr, cc] - x, imm.map_y[rr, cc] - y) <= 1e-6 or (cc, rr) == (c, r)
    assert point_to_rectified(-50.0, -50.0, imm.map_x, imm.map_y, imm.valid) is None
    (tmp_path / "roi.json").write_text(json.dumps({"outer": OUTER}))
    common = [str(dic_sim / "rig.npz"), str(dic_sim), "--roi-polygon", str(tmp_path / "roi.json"), "--roi-frame",
              "original", "--subset", "21", "--step", "8", "--no-vtk", "--no-plot", "--strain-window", "0"]
    assert main(["dic", *common, "--start-point", "5000,10", "-o", str(tmp_path / "bad")]) == 2
    assert main(["dic", *common, "--start-point", "120,95", "-o", str(tmp_path / "out")]) == 0
