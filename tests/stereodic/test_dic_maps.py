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
from stereodic.strain.results import map_axes, open_result, state_labels

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


def test_many_workers_share_a_states_maps_and_draw_every_one(dic_sim, tmp_path, monkeypatch):
    from stereodic.dic3d.run import _map_parts
    names = ["Z", "dX", "dY", "dZ", "exx", "eyy", "exy"]
    for workers, states, tasks in ((2, 2, 1), (16, 2, 7), (16, 5, 3), (16, 40, 1), (0, 1, 1)):
        parts = _map_parts(names, workers, states)
        assert len(parts) == tasks and [q for part in parts for q in part] == names
    monkeypatch.setenv("OMP_NUM_THREADS", "6")     # 6 children, 2 states drawn: 3 tasks a state
    out = tmp_path / "run"
    assert main(["dic", str(dic_sim / "rig.npz"), str(dic_sim), "--step", "8", "--no-vtk", "--plot-every", "2",
                 "-o", str(out)]) == 0
    drawn = sorted(p.name for p in (out / "maps").glob("*.png"))
    assert drawn == sorted(f"state{k}_{q}.png" for k in (0, 2) for q in names)


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
        bars = {c.get_clim() for a in fig.axes if a.get_visible() for c in a.collections}   # the colour bar's
        assert bars - {(None, None)} == {(s.lo, s.hi)}                                      # (and its arrows)


def test_map_over_the_image_and_a_movie(tmp_path):
    import cv2

    from stereodic.dic.maps import Backdrop, MapMovie, MapPainter, map_figure
    image = (np.random.default_rng(1).random((220, 320)) * 255).astype(np.uint8)
    x, y = np.meshgrid(XS, YS)
    movie = MapMovie(tmp_path / "exx.mp4")
    painter = MapPainter()
    for k in range(3):
        options = dict(title=f"state {k}", quantity="exx", unit="microstrain", decimals=0,
                       backdrop=Backdrop(image, x + 0.5 * k, y))
        fig = map_figure(np.full(x.shape, 100.0 * k), pixel_axes(XS, YS), **options)
        assert len(fig.axes) == 3                     # the map, the map over the image, its colour bar
        assert fig.axes[1].images[0].get_array().shape[:2] == image.shape     # the image, pixel for pixel
        rgb = save_map(tmp_path / f"{k}.png", np.full(x.shape, 100.0 * k), pixel_axes(XS, YS), painter=painter,
                       **options)
        assert rgb.shape == (560, 1300, 3) and np.array_equal(cv2.imread(str(tmp_path / f"{k}.png"))[..., ::-1], rgb)
        movie.add(rgb)
    movie.close()
    cap = cv2.VideoCapture(str(tmp_path / "exx.mp4"))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 3


def _slanted():
    """The grid XS x YS seen slanted in an image: x, y (ny, nx) pixels."""
    x, y = np.meshgrid(XS, YS)
    return 1.1 * x + 0.05 * y + 3.0, 0.97 * y - 0.04 * x + 8.0


def test_a_colour_bar_drawn_once_gives_the_pixels_of_one_drawn_again():
    """A painter draws a quantity's colour bar once for its run scale (the same in every state) and
    pastes it in the maps after: pixel for pixel what a fresh painter draws, plain or over the image,
    with the bar's arrows as each map's values need them."""
    from stereodic.dic.maps import Backdrop, ColourScale, MapPainter
    rng = np.random.default_rng(3)
    image = (rng.random((220, 320)) * 255).astype(np.uint8)
    x, y = np.meshgrid(XS, YS)
    axes = pixel_axes(XS, YS)
    scale = ColourScale(-400.0, 400.0, "RdBu_r")
    states = [rng.normal(0.0, 100.0, x.shape), rng.normal(50.0, 150.0, x.shape), rng.normal(0.0, 300.0, x.shape)]
    for backdrop in (None, Backdrop(image, x, y)):
        painter = MapPainter()
        for k, values in enumerate(states):
            options = dict(title=f"state {k}", quantity="exx", unit="microstrain", decimals=0, scale=scale,
                           backdrop=backdrop)
            assert np.array_equal(painter.draw(values, axes, **options), MapPainter().draw(values, axes, **options))
        kept = painter._layouts[backdrop is not None].bar_pixels
        assert len(kept) == 2                 # without arrows (states 0, 1: drawn once), with (state 2)


def test_a_kept_colour_bar_is_pasted_without_updating_the_bar_and_a_figure_still_shows_its_own():
    """Quantities in turn (each its own run scale): a map whose bar was kept is drawn without updating the
    bar (left as the other quantity's), pixel for pixel what a fresh painter draws; the painter's next
    Figure (`figure`, for a caller that draws it) still carries its own bar's range, map and label."""
    from stereodic.dic.maps import ColourScale, MapPainter
    rng = np.random.default_rng(5)
    axes = pixel_axes(XS, YS)
    x, _ = np.meshgrid(XS, YS)
    quantities = {"exx": ColourScale(-400.0, 400.0, "RdBu_r"), "Z": ColourScale(10.0, 30.0, "viridis")}
    painter = MapPainter()
    for k in range(2):
        for quantity, scale in quantities.items():
            values = rng.uniform(scale.lo, scale.hi, x.shape)
            options = dict(title=f"state {k}", quantity=quantity, unit="u", decimals=0, scale=scale,
                           signed=quantity != "Z")
            assert np.array_equal(painter.draw(values, axes, **options), MapPainter().draw(values, axes, **options))
            if k == 1 and quantity == "exx":     # its bar pasted, the bar itself still Z's of state 0
                bar = next(b for b in painter._layouts[False].bars.values() if b.ax.get_visible())
                assert (bar.mappable.norm.vmin, bar.mappable.norm.vmax) == (10.0, 30.0)
    painter.figure(rng.uniform(-400.0, 400.0, x.shape), axes, title="again", quantity="exx", unit="u", decimals=0,
                   scale=quantities["exx"])
    bar = next(b for b in painter._layouts[False].bars.values() if b.ax.get_visible())
    assert (bar.mappable.norm.vmin, bar.mappable.norm.vmax) == (-400.0, 400.0)
    assert bar.mappable.get_cmap().name == "RdBu_r" and bar.ax.get_ylabel() == "exx (u)"


def test_the_image_panels_title_drawn_with_the_background_follows_the_backdrops_label():
    """The panel over the image is titled by its Backdrop's label, drawn once with the figure's background:
    a painter whose next map has another label draws what a fresh painter draws, and the two titles'
    pictures differ."""
    from stereodic.dic.maps import Backdrop, MapPainter
    rng = np.random.default_rng(7)
    image = (rng.random((220, 320)) * 255).astype(np.uint8)
    x, y = np.meshgrid(XS, YS)
    axes, values = pixel_axes(XS, YS), rng.normal(0.0, 1.0, x.shape)
    options = dict(title="state 1", quantity="u", unit="px", decimals=3)
    painter, drawn = MapPainter(), []
    for label in ("the deformed image", "the left camera's image of the state"):
        backdrop = Backdrop(image, x, y, label)
        drawn.append(painter.draw(values, axes, backdrop=backdrop, **options))
        assert np.array_equal(drawn[-1], MapPainter().draw(values, axes, backdrop=backdrop, **options))
    assert not np.array_equal(drawn[0], drawn[1])


def test_the_field_over_the_image_is_the_linear_interpolation_between_the_points():
    """Backdrop.raster against matplotlib's LinearTriInterpolator (an independent linear interpolation) on
    the same triangles, two per square of neighbouring grid points; a hole in the grid left blank, not
    bridged, and a stray point's long triangles left out."""
    from matplotlib.tri import LinearTriInterpolator, Triangulation

    from stereodic.dic.maps import Backdrop
    x, y = _slanted()
    values = np.sin(x / 40.0) + y / 100.0
    hx, hy = x[10, 13], y[10, 13]
    x[8:13, 10:16] = np.nan                                             # not seen: a hole
    x[3, 20] += 60.0                                                    # a stray point
    b = Backdrop(np.zeros((230, 340), np.uint8), x, y)
    field, extent = b.raster(values)
    assert extent == (-0.5, 339.5, 229.5, -0.5)                         # one cell a pixel below 600 px
    idx = np.arange(x.size).reshape(x.shape)
    a, c, d, e = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    tri = np.concatenate([np.stack([a, c, d], -1).reshape(-1, 3), np.stack([c, e, d], -1).reshape(-1, 3)])
    ok = np.isfinite(x.ravel()[tri]).all(1) & ~np.isin(tri, idx[3, 20]).any(1)
    gy, gx = np.mgrid[0:230, 0:340].astype(float)
    ref = LinearTriInterpolator(Triangulation(np.nan_to_num(x.ravel()), y.ravel(), tri[ok]), values.ravel())(gx, gy)
    ref = ref.filled(np.nan)
    assert np.isfinite(ref).sum() > 50000
    assert (np.isfinite(field) != np.isfinite(ref)).sum() <= 5          # cells on the outer edges, either way
    assert np.nanmax(np.abs(field - ref)) < 1e-9
    hole = (np.abs(gx - hx) < 5) & (np.abs(gy - hy) < 5)
    assert hole.any() and np.isnan(field[hole]).all()


def test_grid_cells_keep_to_the_raster_whatever_the_points():
    """A point thrown far off the raster (1e30: its triangles' boxes cover everything) leaves its
    triangles' cells on the raster only, and every other cell where matplotlib's triangle finder (an
    independent point-in-triangle test) puts it; a raster of the wrong weights' shape is refused."""
    from matplotlib.tri import Triangulation

    from stereodic.dic import _kernels
    from stereodic.dic.maps import grid_cells
    x, y = _slanted()
    x[5, 7] = 1e30
    cells = grid_cells(x, y, origin=(0.0, 0.0), cell=2.0, shape=(115, 170))
    idx = np.arange(x.size).reshape(x.shape)
    a, c, d, e = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    tri = np.concatenate([np.stack([a, c, d], -1).reshape(-1, 3), np.stack([c, e, d], -1).reshape(-1, 3)])
    tri = tri[~np.isin(tri, idx[5, 7]).any(1)]
    gy, gx = np.mgrid[0:115, 0:170] * 2.0
    found = Triangulation(x.ravel(), y.ravel(), tri).get_trifinder()(gx, gy).ravel() >= 0
    assert found.sum() > 10000
    mine = np.zeros(found.size, bool)
    mine[cells.index] = True
    assert (cells.index >= 0).all() and (cells.index < 115 * 170).all()
    far = cells.index[np.isin(cells.vertices, idx[5, 7]).any(1)]       # the huge triangles' cells
    assert far.size and (~np.isin(np.flatnonzero(mine & ~found), far)).sum() <= 5
    assert (found & ~mine).sum() <= 5                                   # cells on the outer edges, either way
    with pytest.raises(ValueError, match="weights"):
        _kernels.grid_cells(x.ravel().astype(float), y.ravel().astype(float), x.shape[1], np.inf,
                            np.full((10, 10), -1, np.int64), np.empty((10, 9, 2)))


def test_a_maps_pixels_are_the_colour_maps_colours_of_the_values(tmp_path):
    """The PNG's pixel at a grid point, in the plain map and over the image, is matplotlib's colour of
    the point's value: exactly in the plain map (the pixel is in the point's cell, 17 pixels across),
    within the change over one image pixel over the image (mixed with the image's gray at 55 %
    opacity), both within 2 of the colour table's 256 steps."""
    import cv2
    from matplotlib import colormaps

    from stereodic.dic.maps import Backdrop, ColourScale, MapPainter, map_figure
    x, y = _slanted()
    values = np.sin(np.meshgrid(XS, YS)[0] / 25.0)                     # up to 0.4 from a column to the next
    image = np.tile(np.linspace(0, 255, 340), (230, 1)).astype(np.uint8)
    painter = MapPainter()
    options = dict(title="state 1", quantity="u", unit="px", decimals=3, backdrop=Backdrop(image, x, y),
                   painter=painter, scale=ColourScale(-1.0, 1.0, "RdBu_r"))
    save_map(tmp_path / "u.png", values, pixel_axes(XS, YS), **options)
    png = cv2.imread(str(tmp_path / "u.png"))[..., ::-1].astype(float)
    fig = map_figure(values, pixel_axes(XS, YS), **options)
    plain, over = fig.axes[0], fig.axes[1]
    cmap = colormaps["RdBu_r"]
    rgb = lambda v: np.array(cmap((v + 1) / 2)[:3]) * 255                # noqa: E731
    for i, j in [(5, 7), (10, 14), (15, 22), (2, 3), (17, 25)]:
        v = values[i, j]
        per_px = abs(values[i, j + 1] - v) / (x[i, j + 1] - x[i, j])   # the value's change per image pixel
        change = lambda dv: max(np.abs(rgb(v + s) - rgb(v)).max() for s in (-dv, dv))   # noqa: E731
        gray = image[0, int(round(x[i, j]))]
        for ax, point, want, spread in [(plain, (XS[j], YS[i]), rgb(v), change(4 / 256) + 1),
                                        (over, (x[i, j], y[i, j]), 0.55 * rgb(v) + 0.45 * gray,
                                         0.55 * change(per_px + 4 / 256) + 0.45 * 2 + 1)]:
            cx, cy = ax.transData.transform(point)
            pixel = png[int(png.shape[0] - cy), int(cx)]
            assert np.abs(pixel - want).max() <= spread, (i, j, pixel, want)


def test_a_block_of_states_drawn_by_one_child_gives_the_maps_of_one_child_a_state(dic_sim, tmp_path, monkeypatch):
    """Many states' maps in children go in blocks of consecutive states, one painter for a block: its
    figures, drawn for the first state, must give every later state's maps exactly as a fresh painter does
    (pixel for pixel: a title, a colour bar or a picture left over from the state before would show)."""
    import cv2

    import stereodic.dic3d.run as run
    assert run._state_blocks(list(range(0, 40, 2)), 2) == [list(range(k, k + 10, 2)) for k in range(0, 40, 10)]
    assert run._state_blocks([0, 1, 2], 2) == [[0], [1], [2]]
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    outs = {}
    for name, blocks in (("one", lambda states, workers: [states]), ("each", lambda states, workers: [[k] for k in states])):
        monkeypatch.setattr(run, "_state_blocks", blocks)
        outs[name] = tmp_path / name
        assert main(["dic", str(dic_sim / "rig.npz"), str(dic_sim), "--step", "8", "--no-vtk", "-o", str(outs[name])]) == 0
    assert (outs["one"] / "dic.csv").read_bytes() == (outs["each"] / "dic.csv").read_bytes()
    drawn = sorted(p.name for p in (outs["one"] / "maps").glob("*.png"))
    assert len(drawn) == 3 * 7 and drawn == sorted(p.name for p in (outs["each"] / "maps").glob("*.png"))
    for png in drawn:
        assert np.array_equal(cv2.imread(str(outs["one"] / "maps" / png)), cv2.imread(str(outs["each"] / "maps" / png)))


def test_a_workers_tasks_share_the_runs_axes_and_the_background_drawn_on_them(monkeypatch):
    """Each task of a run's maps unpickles its own copy of the run's MapAxes: a worker takes the first copy
    it was given for the later ones (`run._run_axes`, by the axes' token), so that its painter draws the
    axes' background once for all its tasks; axes of another run are taken as given."""
    import pickle

    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from stereodic.dic.maps import MapPainter
    from stereodic.dic3d.run import _run_axes
    axes = pixel_axes(XS, YS)
    copies = [pickle.loads(pickle.dumps(axes)) for _ in range(2)]
    assert copies[0] is not copies[1] and copies[0].token == copies[1].token == axes.token
    draws = []
    real = FigureCanvasAgg.draw
    monkeypatch.setattr(FigureCanvasAgg, "draw", lambda canvas, *a: (draws.append(1), real(canvas, *a))[1])
    painter = MapPainter()
    x, _ = np.meshgrid(XS, YS)
    for copy in copies:             # two tasks
        painter.draw(x * 1.0, _run_axes(copy), title="state", quantity="u", unit="px", decimals=2)
    assert _run_axes(copies[1]) is _run_axes(copies[0]) and len(draws) == 1
    other = pixel_axes(XS, YS)
    assert other.token != axes.token and _run_axes(other) is other
