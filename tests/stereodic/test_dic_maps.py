"""The DIC maps' geometry and words (stereodic.dic.maps): axes in mm from the reference surface, oriented
as the left camera sees it; the load case named from the dataset; tick precision."""

import json
from pathlib import Path

import numpy as np
import pytest

from stereodic.cli import main
from stereodic.dic.maps import _decimals, active_box, pixel_axes, save_map, surface_axes
from stereodic.dic3d.dataset import DicStates
from stereodic.dic3d.store import RunStore
from stereodic.strain_results import map_axes, open_result, state_labels

XS, YS = np.arange(10, 300, 10.0), np.arange(5, 200, 10.0)


def _surface(f):
    """(ny, nx, 3) points of the grid XS x YS through the mapping f(x_px, y_px) -> (X, Y) mm."""
    x, y = np.meshgrid(XS, YS)
    X, Y = f(x, y)
    return np.stack([X, Y, np.zeros_like(X)], -1)


def test_surface_axes_are_the_reference_positions_with_holes_filled():
    """A plate seen in perspective (a homography from pixels to mm, as for a pinhole camera), X to the
    right and Y up: the axes give every point's X, Y - measured or not - to well below a cell, and
    the vertical axis is not flipped (Y grows up the image)."""
    def homography(x, y):
        w = 1 + 2e-4 * x + 1e-4 * y
        return (0.2 * x + 15) / w, (-0.2 * y + 60) / w
    pts = _surface(homography)
    truth = pts.copy()
    pts[3:6, 4:9] = np.nan                     # a hole (no texture)
    pts[10, 10] += (5.0, -3.0, 0.0)            # a wrong match
    axes = surface_axes(XS, YS, pts)
    assert axes.unit == "mm" and axes.names == ("X", "Y")
    assert not axes.flip_x and not axes.flip_y
    err = np.hypot(axes.x - truth[..., 0], axes.y - truth[..., 1])
    assert err.max() < 0.02 * 10 * 0.2        # 2 % of a cell (10 px of 0.2 mm)
    assert err[3:6, 4:9].max() < 0.04 and err[10, 10] < 0.04


def test_surface_axes_follow_the_camera_view():
    """X decreasing along the image's columns flips the horizontal axis; Y growing down the rows flips
    the vertical one (the map looks as the left image does); X running down the rows (the frame turned
    a quarter) puts Y across and X down."""
    flipped = surface_axes(XS, YS, _surface(lambda x, y: (-0.1 * x, 0.1 * y)))
    assert flipped.flip_x and flipped.flip_y and flipped.names == ("X", "Y")
    turned = surface_axes(XS, YS, _surface(lambda x, y: (0.1 * y, 0.1 * x)))
    assert turned.names == ("Y", "X") and not turned.flip_x and turned.flip_y
    assert np.allclose(turned.x, 0.1 * np.meshgrid(XS, YS)[0])


def test_too_few_positions_give_pixel_axes():
    pts = np.full((len(YS), len(XS), 3), np.nan)
    axes = surface_axes(XS, YS, pts)
    assert axes.unit == "px" and axes.flip_y and np.array_equal(axes.x[0], XS)


@pytest.mark.parametrize("step, decimals", [(250.0, 0), (1.0, 0), (0.5, 1), (0.25, 2), (0.002, 3)])
def test_tick_decimals_follow_the_step(step, decimals):
    assert _decimals(step) == decimals


def test_a_map_is_written(tmp_path):
    values = np.where(np.arange(len(XS))[None, :] > 3, 1e4 + np.zeros((len(YS), len(XS))), np.nan)
    save_map(tmp_path / "m.png", values, pixel_axes(XS, YS), title="state 3: tension - exx", quantity="exx",
             unit="microstrain", decimals=0)
    assert (tmp_path / "m.png").read_bytes()[:4] == b"\x89PNG"


def test_a_map_spans_its_grids_active_points():
    """A grid over the whole image with a ROI (the active points) in one corner: the map is cut to the
    ROI's rows and columns, and the axes carry the active points (the title counts them)."""
    active = np.zeros((len(YS), len(XS)), bool)
    active[2:7, 10:19] = True
    active[4, 22] = True
    assert active_box(active) == (slice(2, 7), slice(10, 23))
    assert active_box(np.zeros_like(active)) == (slice(None), slice(None))
    axes = surface_axes(XS, YS, _surface(lambda x, y: (0.2 * x, -0.2 * y)), active)
    assert axes.active is active and pixel_axes(XS, YS, active).active is active


def test_states_are_named_from_the_dataset_or_their_files():
    files = [Path("pairs/img_0000_0.tif"), Path("pairs/img_0001_0.tif")]
    assert DicStates(files, files, "--images pairs").label(1) == "state 1 (img_0001_0.tif)"
    assert DicStates(files, files, "d", ["reference", "tension"]).label(1) == "state 1: tension"


def test_a_run_records_its_state_names_and_maps_in_mm(dic_sim, tmp_path):
    out = tmp_path / "run"
    assert main(["dic", str(dic_sim / "rig.npz"), str(dic_sim), "--step", "8", "--strain-window", "5", "--no-vtk",
                 "--plot-every", "2", "-o", str(out)]) == 0
    names = json.loads((dic_sim / "capture.json").read_text())["simulated"]["states"]
    result = open_result(out)
    assert state_labels(result) == [f"state {k}: {n}" for k, n in enumerate(names)]
    axes = map_axes(result)
    with np.load(out / "dic.npz") as z:
        reference = z["points"][0]
    ok = np.isfinite(reference[..., 0])
    assert np.abs(axes.x[ok] - reference[..., 0][ok]).max() < 0.05     # mm, grid step ~1 mm
    assert np.abs(axes.y[ok] - reference[..., 1][ok]).max() < 0.05
    assert sorted(p.name for p in (out / "maps").glob("*_exx.png")) == ["state0_exx.png", "state2_exx.png"]
    # the maps' titles name the measure that the run folder's states are read back with
    assert RunStore(out).attach().read_state(2).measure.measure == "green-lagrange"


def test_run_scales_fix_each_quantitys_colours_over_the_run():
    """The same limits for every state (the widest 1st-99th percentile), centred on zero for a change,
    with a floor for a quantity at rest (the reference's strain), and a given range kept as it is."""
    from stereodic.dic.maps import RunScales, map_figure
    rng = np.random.default_rng(0)
    scales = RunScales(floor={"exx": 100.0}, given={"dY": (-0.5, 0.8)})
    states = [np.zeros((len(YS), len(XS))), 3000 + 50 * rng.standard_normal((len(YS), len(XS))),
              9000 + 50 * rng.standard_normal((len(YS), len(XS)))]
    for v in states:
        scales.add("exx", v, signed=True)
        scales.add("Z", 400 + v / 1000, signed=False)
    s = scales.scale("exx")
    assert s.cmap == "RdBu_r" and s.lo == -s.hi and 9000 < s.hi < 9200
    assert scales.scale("Z").cmap == "viridis" and scales.scale("Z").lo < 400.01 and scales.scale("Z").hi > 409
    rest = RunScales(floor={"exx": 100.0})
    rest.add("exx", states[0], signed=True)
    assert (rest.scale("exx").lo, rest.scale("exx").hi) == (-100.0, 100.0)
    assert (scales.scale("dY").lo, scales.scale("dY").hi) == (-0.5, 0.8) and scales.scale("dZ") is None
    for v in states:                                  # every state's map drawn with the run's limits
        fig = map_figure(v, pixel_axes(XS, YS), title="t", quantity="exx", unit="microstrain", decimals=0, scale=s)
        assert fig.axes[0].collections[0].get_clim() == (s.lo, s.hi)


def test_map_over_the_image_and_a_movie(tmp_path):
    import cv2

    from stereodic.dic.maps import Backdrop, MapMovie, map_figure
    image = (np.random.default_rng(1).random((220, 320)) * 255).astype(np.uint8)
    x, y = np.meshgrid(XS, YS)
    movie = MapMovie(tmp_path / "exx.mp4")
    for k in range(3):
        fig = map_figure(np.full(x.shape, 100.0 * k), pixel_axes(XS, YS), title=f"state {k}", quantity="exx",
                         unit="microstrain", decimals=0, backdrop=Backdrop(image, x + 0.5 * k, y))
        assert len(fig.axes) == 3                     # the map, its colour bar, the map over the image
        over = fig.axes[1] if fig.axes[1].images else fig.axes[2]
        assert over.images[0].get_array().shape == image.shape
        movie.add(fig)
    movie.close()
    cap = cv2.VideoCapture(str(tmp_path / "exx.mp4"))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 3


def test_the_field_over_the_image_is_the_linear_interpolation_between_the_points():
    """Backdrop.raster against scipy's griddata (an independent linear interpolation on the same
    Delaunay points), a hole in the grid left blank, not bridged."""
    from scipy.interpolate import griddata

    from stereodic.dic.maps import Backdrop
    x, y = np.meshgrid(XS, YS)
    x, y = 1.1 * x + 0.05 * y + 3.0, 0.97 * y - 0.04 * x + 8.0          # seen slanted
    values = np.sin(x / 40.0) + y / 100.0
    hx, hy = x[10, 13], y[10, 13]
    x[8:13, 10:16] = np.nan                                             # not seen: a hole
    b = Backdrop(np.zeros((230, 340), np.uint8), x, y)
    field, extent = b.raster(values)
    ok = np.isfinite(x)
    step = int(round(-2 * extent[0]))
    gy, gx = np.mgrid[0:230:step, 0:340:step].astype(float)
    ref = griddata(np.column_stack([x[ok], y[ok]]), values[ok], (gx, gy))
    both = np.isfinite(field)
    assert both.sum() > 0.5 * np.isfinite(ref).sum()
    assert np.abs(field[both] - ref[both]).max() < 1e-9
    hole = (np.abs(gx - hx) < 5) & (np.abs(gy - hy) < 5)
    assert hole.any() and np.isnan(field[hole]).all()
