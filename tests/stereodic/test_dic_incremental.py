"""Points switch to incremental (updated-reference) DIC when their match against the reference
decorrelates, and keep their displacements relative to the reference: on a twist (a rotation fading
with the radius, which no affine subset follows once it is large) growing state by state, against the
simulators' truth (`scanners.sim.speckle` in 2-D, `scanners.sim.dic` in stereo)."""

import numpy as np
import pytest

from scanners.sim.dic import DicState, load_dic_truth, truth_at_pixels
from scanners.sim.speckle import make_speckle, render
from stereodic.dic import DicSettings, correlate_sequence, make_grid
from stereodic.dic3d.dataset import load_states
from stereodic.dic3d.stereo import StereoDic, StereoSettings
from stereodic.stereo.rig import load_rig
from tests.stereodic.dic_cases import simulate_dic_with_rig

N, RADIUS = 256, 40.0


def _twist(deg):
    """The displacement field (pixels) of a twist of `deg` degrees about the image centre."""
    def field(x, y):
        dx, dy = x - N / 2, y - N / 2
        th = np.radians(deg) * np.exp(-(dx * dx + dy * dy) / (2 * RADIUS ** 2))
        return (np.cos(th) - 1) * dx - np.sin(th) * dy, np.sin(th) * dx + (np.cos(th) - 1) * dy
    return field


@pytest.fixture(scope="module")
def twist2d():
    sp = make_speckle(N, N, seed=3)
    angles = list(range(10, 100, 10))
    images = [render(sp, _twist(a), noise_sigma=1.0, seed=k + 1, supersample=3) for k, a in enumerate(angles)]
    return render(sp, noise_sigma=1.0, seed=0), images, angles


def _run2d(twist2d, **kw):
    ref, images, angles = twist2d
    grid = make_grid(N, N, subset=21, step=8, roi=(40, 40, N - 41, N - 41))
    X, Y = grid.points()
    act = grid.active.ravel()
    out = []
    for f, a in zip(correlate_sequence(ref, images, grid, settings=DicSettings(subset=21), **kw), angles):
        tu, tv = _twist(a)(X, Y)
        ok = f.ok.ravel() & act
        err = np.hypot(f.u.ravel() - tu, f.v.ravel() - tv)[ok]
        out.append((ok.sum() / act.sum(), np.sqrt(np.mean(err ** 2)), f))
    return out


def test_2d_points_switch_when_the_reference_decorrelates(twist2d):
    direct = _run2d(twist2d, switch_zncc=0.0)
    auto = _run2d(twist2d)                                       # the default threshold, 0.9
    forced = _run2d(twist2d, incremental=True)
    assert direct[-1][0] < 0.8 and all(c > 0.999 for c, _, _ in direct[:4])   # direct matching fails late
    assert all(c >= 0.99 for c, _, _ in auto)                   # the switched points are kept
    switched = [int(f.incremental.sum()) for _, _, f in auto]
    assert switched[:3] == [0, 0, 0] and switched[-1] > 50        # late, and only where the twist is strong
    assert switched[-1] < 0.8 * auto[-1][2].grid.active.sum()
    for (_, _, fd), (_, _, fa) in zip(direct[:3], auto[:3]):     # before the decorrelation: the same result
        assert np.array_equal(fd.u, fa.u, equal_nan=True)
    for (_, ea, _), (_, ei, _) in zip(auto, forced):
        assert ea <= 1.2 * ei + 0.01                            # against the truth, as good as incremental
    assert auto[-1][1] < 0.8                                    # (pixels; the affine subsets' own bias)


@pytest.mark.slow
def test_stereo_points_switch_on_a_growing_twist(tmp_path):
    """Stereo, 9 states of a twist growing by 10 degrees: direct matching loses some of the points where
    the twist is strong; with switching (default) every point in view is measured, with errors against the truth no
    larger than incremental DIC's, and relative to the reference."""
    states = [DicState("reference")] + [DicState(f"twist {10 * k}", twist_deg=10.0 * k, twist_radius_mm=40.0)
                                        for k in range(1, 10)]
    simulate_dic_with_rig(tmp_path, states, width=320, height=256, supersample=2)
    rig = load_rig(tmp_path / "rig.npz")
    data = load_states(tmp_path, rig)
    W, H = rig.sensor.width, rig.sensor.height
    grid = make_grid(W, H, subset=21, step=6, roi=(30, 30, W - 31, H - 31))
    X, Y = grid.points()
    truth = truth_at_pixels(load_dic_truth(tmp_path), rig.left.imm.real_position(X, Y))
    act = grid.active.ravel()

    def run(**kw):
        out = []
        for st in StereoDic(rig, grid, settings=StereoSettings(DicSettings(subset=21), strain_window=5, **kw)).run(
                data.rectified(rig)):
            c = st.converged.ravel() & act
            err = np.linalg.norm(st.displacement.reshape(-1, 3)[c] - truth["displacement"][st.state][c], axis=1)
            # of the points in view: a subset the twist carries into a rectified image's blank band is
            # 'outside', which no reference updating cures
            seen = act & ~np.char.endswith(st.status.ravel().astype(str), ":outside")
            out.append((c.sum() / seen.sum(), np.sqrt(np.mean(err ** 2)) if c.any() else np.inf,
                        int(st.incremental.sum()), st))
        return out

    direct, auto, forced = run(switch_zncc=0.0), run(), run(incremental=True)
    # direct matching (warps carried from state to state, started from the last change) keeps most
    # points to the end, but not all: 94 % at 90 degrees since the velocity-based starts
    assert direct[-1][0] < 0.97 and min(c for c, *_ in auto) > 0.995
    # points switch late, not early, and at least as many as direct matching loses
    assert auto[1][2] == 0 and auto[-1][2] >= (1 - direct[-1][0]) * act.sum()
    assert np.array_equal(auto[1][3].displacement, direct[1][3].displacement, equal_nan=True)
    for (_, ea, _, _), (_, ei, _, _) in zip(auto[1:], forced[1:]):
        assert ea <= 1.15 * ei
    fov = W * rig.sensor.pitch_mm[0]
    assert auto[-1][1] < fov / 400                               # the twist moves points by up to ~40 mm
