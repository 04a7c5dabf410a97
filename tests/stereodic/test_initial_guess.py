"""What is computed of a read-only image is computed once (`stereodic.dic.kept`): its features
(`initial_guess.image_features`), their matches, its B-spline (`BSplineImage.from_image`)."""

import gc

import numpy as np

from scanners.sim.speckle import make_speckle, render
from stereodic.dic import BSplineImage, kept as cache
from stereodic.dic.initial_guess import consistent_matches, image_features


def test_features_of_a_read_only_image_are_kept_while_it_lives():
    img = render(make_speckle(256, 192, seed=4), noise_sigma=1.0, seed=1)
    fresh = image_features(img)                     # a writeable image: computed at every call
    assert fresh.pts.shape[0] > 100 and image_features(img) is not fresh
    img.flags.writeable = False
    kept = image_features(img)
    assert image_features(img) is kept              # computed once
    np.testing.assert_array_equal(kept.pts, fresh.pts)
    np.testing.assert_array_equal(kept.desc, fresh.desc)
    other = img.copy()
    other.flags.writeable = False
    assert image_features(other) is not kept        # another array, even with the same pixels
    before = len(cache._KEPT)
    del img, other
    gc.collect()
    assert len(cache._KEPT) == before - 2   # forgotten with the image


def test_matches_of_kept_features_are_kept():
    sp = make_speckle(256, 192, seed=4)
    ref, dfm = render(sp, noise_sigma=1.0, seed=1), render(sp, (7.25, -3.5), noise_sigma=1.0, seed=2)
    p0, q0 = consistent_matches(image_features(ref), image_features(dfm))    # writeable: computed each time
    assert len(p0) > 50 and np.abs(np.median(q0 - p0, axis=0) - (7.25, -3.5)).max() < 0.5
    for img in (ref, dfm):
        img.flags.writeable = False
    kept = consistent_matches(image_features(ref), image_features(dfm))
    assert consistent_matches(image_features(ref), image_features(dfm)) is kept
    np.testing.assert_array_equal(kept[0], p0)
    np.testing.assert_array_equal(kept[1], q0)
    assert not kept[0].flags.writeable


def test_the_b_spline_of_a_read_only_image_is_kept_while_it_lives():
    img = render(make_speckle(256, 192, seed=4), noise_sigma=1.0, seed=1).astype(np.float32)
    fresh = BSplineImage.from_image(img, order=3, prefilter_sigma=0.7)
    assert BSplineImage.from_image(img, order=3, prefilter_sigma=0.7) is not fresh
    img.flags.writeable = False
    kept = BSplineImage.from_image(img, order=3, prefilter_sigma=0.7)
    assert BSplineImage.from_image(img, order=3, prefilter_sigma=0.7) is kept
    np.testing.assert_array_equal(kept.coef, fresh.coef)
    other = BSplineImage.from_image(img, order=5, prefilter_sigma=0.7)     # another order, another low-pass
    assert other is not kept and BSplineImage.from_image(img, order=3, prefilter_sigma=0.0) is not kept
    assert not np.array_equal(other.coef, kept.coef)
    before = len(cache._KEPT)
    del img
    gc.collect()
    assert len(cache._KEPT) == before - 3


def test_the_nearest_matches_are_the_true_nearest(monkeypatch):
    """`_nearest` gives each point the k matches a full sort of its float64 distances gives (random
    positions: no ties), on 1 and 2 threads, on a lattice of nodes as on scattered points, with as many
    neighbours as matches, and for no points at all."""
    import stereodic.dic.initial_guess as ig
    rng = np.random.default_rng(3)
    p = rng.uniform(0, 1900, (1500, 2))
    gx, gy = np.meshgrid(np.linspace(-50, 1950, 40), np.linspace(-50, 1250, 25))
    cases = [(rng.uniform(-50, 1950, 700), rng.uniform(-50, 1250, 700), p, 12), (gx.ravel(), gy.ravel(), p, 12),
             (rng.uniform(0, 100, 9), rng.uniform(0, 100, 9), p[:7], 7)]
    for threads in ("1", "2"):
        monkeypatch.setenv("OMP_NUM_THREADS", threads)
        for xs, ys, matches, k in cases:
            d = (xs[:, None] - matches[:, 0]) ** 2 + (ys[:, None] - matches[:, 1]) ** 2
            truth = np.sort(np.argsort(d, axis=1)[:, :k], axis=1)
            got = ig._nearest(matches, xs, ys, k)
            assert got.shape == (xs.size, k) and got.dtype == np.int64
            np.testing.assert_array_equal(np.sort(got, axis=1), truth)
        assert ig._nearest(p, np.empty(0), np.empty(0), 12).shape == (0, 12)


def test_the_first_deformed_states_matches_are_made_beside_the_reference_and_once(dic_sim, tmp_path, monkeypatch):
    """A stereo run on 2 threads: the first deformed state's feature matches with the reference (its left
    registration's start) are made by the thread that prepares its pair, beside the reference's
    correlation, and the state finds them kept; no pair of images has its matches made twice."""
    import threading

    import stereodic.dic.initial_guess as ig
    from stereodic.cli import main
    made = []
    real = ig._consistent

    def spy(ref, dfm):
        made.append((id(ref), id(dfm), threading.current_thread() is threading.main_thread()))
        return real(ref, dfm)

    monkeypatch.setattr(ig, "_consistent", spy)
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    assert main(["dic", str(dic_sim / "rig.npz"), str(dic_sim), "--step", "12", "--no-plot", "--no-vtk",
                 "-o", str(tmp_path / "out")]) == 0
    pairs = [(r, d) for r, d, _ in made]
    assert len(pairs) == len(set(pairs)) >= 2           # the rig check's (left, right), the first state's
    assert made[0][2] and not all(main_thread for _, _, main_thread in made)


def test_dic2d_matches_and_interpolates_the_first_image_beside_the_points_placement_once(tmp_path, monkeypatch):
    """`dic2d` on 2 threads: the first image's feature matches with the reference and its B-spline are
    made beside the points' placement (the specimen mask, on the main thread) and found kept by its
    registration."""
    import threading
    import time

    import stereodic.dic.initial_guess as ig
    import stereodic.dic.texture as texture
    from calib.imageio import read_gray, write_gray
    from stereodic.cli import main
    from stereodic.dic.interpolation import BSplineImage
    sp = make_speckle(320, 256, seed=5)
    write_gray(tmp_path / "ref.png", render(sp, noise_sigma=1.0, seed=1))
    write_gray(tmp_path / "def.png", render(sp, lambda x, y: (3.2, -1.7), noise_sigma=1.0, seed=2))
    deformed = read_gray(tmp_path / "def.png")
    made, splines = [], []
    real, computed = ig._consistent, BSplineImage._computed.__func__

    def spy(ref, dfm):
        made.append(threading.current_thread() is threading.main_thread())
        return real(ref, dfm)

    def spline_spy(cls, image, order, prefilter_sigma):
        if np.array_equal(image, deformed):
            splines.append(time.perf_counter())
        return computed(cls, image, order, prefilter_sigma)

    def mask_spy(*args, **kwargs):
        try:
            return mask(*args, **kwargs)
        finally:
            placed.append(time.perf_counter())

    mask, placed = texture.specimen_mask, []
    monkeypatch.setattr(ig, "_consistent", spy)
    monkeypatch.setattr(BSplineImage, "_computed", classmethod(spline_spy))
    monkeypatch.setattr(texture, "specimen_mask", mask_spy)
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    assert main(["dic2d", str(tmp_path / "ref.png"), str(tmp_path / "def.png"), "--step", "8",
                 "-o", str(tmp_path / "r.csv")]) == 0
    assert made == [False]
    assert len(splines) == 1 and splines[0] < placed[0]     # once, while the points were being placed
