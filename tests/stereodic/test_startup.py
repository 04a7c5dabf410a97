"""The start-up budget, guarded by what a command imports (not by time: `stereodic bench startup` has the
times). `--help` loads no library at all; a 2D DIC run of one pair loads numpy and OpenCV but neither
numba nor scipy (its kernels are compiled ahead of time: stereodic/dic/src), a stereo run no numba, nor Pillow (its few images
are read whole, not checked by their headers first), matplotlib, Open3D or tqdm (no bar without a
terminal), nor Dask (only with --scheduler), nor the maps' module without --plot; and of the command
line's modules only its own."""

import json
import subprocess
import sys

import numpy as np
import pytest

from calib.imageio import write_gray
from stereodic.cli import COMMANDS

HEAVY = ["numpy", "numba", "scipy", "cv2", "matplotlib", "open3d", "PIL", "tqdm", "skimage", "pygame", "dask",
         "distributed"]
NOT_FOR_DIC2D = ["numba", "scipy", "matplotlib", "open3d", "tqdm", "skimage", "pygame", "dask", "distributed"]


def _imported(argv: list[str], *, top_level: bool = True) -> set[str]:
    """The modules imported by `stereodic ARGV` in a fresh interpreter (`top_level`: their top-level
    packages)."""
    code = ("import sys, json\nfrom stereodic.cli import main\ntry:\n    main(json.loads(sys.argv[1]))\n"
            "except SystemExit:\n    pass\n"
            "print('MODULES=' + ' '.join(sorted(sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code, json.dumps(argv)], capture_output=True, text=True,
                         timeout=300)
    line = [t for t in out.stdout.splitlines() if t.startswith("MODULES=")]
    assert line, out.stderr
    modules = set(line[0][len("MODULES="):].split())
    return {m.split(".")[0] for m in modules} if top_level else modules


@pytest.mark.parametrize("argv", [["--help"]] + [[c, "--help"] for c in COMMANDS], ids=lambda a: a[0])
def test_help_imports_no_library(argv):
    assert not _imported(argv) & set(HEAVY)


def test_a_small_dic2d_imports_neither_numba_nor_scipy(tmp_path):
    rng = np.random.default_rng(0)
    img = (rng.random((64, 64)) * 255).astype(np.uint8)
    write_gray(tmp_path / "a.png", img)
    write_gray(tmp_path / "b.png", np.roll(img, 1, axis=1))
    modules = _imported(["dic2d", str(tmp_path / "a.png"), str(tmp_path / "b.png"), "--roi", "25,25,35,35",
                         "-o", str(tmp_path / "r.csv")], top_level=False)
    found = {m.split(".")[0] for m in modules}
    assert (tmp_path / "r.csv").exists() and {"numpy", "cv2"} <= found
    assert not found & set(NOT_FOR_DIC2D)
    assert {m for m in modules if m.startswith("stereodic.cli.")} == {"stereodic.cli.common", "stereodic.cli.dic2d"}
    assert "stereodic.dic.maps" not in modules     # no --plot: no maps


def test_a_stereo_run_imports_neither_numba_nor_scipy(tmp_path, monkeypatch):
    """`dic` (the correlation, the triangulation, the rays' distances, the strain fit: compiled ahead of
    time, stereodic/*/src) runs without numba, whose start-up (0.3 s of imports and the kernels' loading,
    holding the interpreter's lock) would be serial work of every run; and on two threads without scipy,
    whose k-d tree the feature guess's nearest matches took (`initial_guess._nearest`: 0.4 CPU-s of
    imports beside the first state's correlation)."""
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    from scanners.sim.dic import DicState
    from tests.stereodic.dic_cases import simulate_dic_with_rig
    simulate_dic_with_rig(tmp_path / "d", [DicState("reference"), DicState("shift", translation_mm=(0.3, 0.0, 0.0))],
                          width=320, height=256, supersample=1)
    modules = _imported(["dic", str(tmp_path / "d" / "rig.npz"), str(tmp_path / "d"), "--subset", "21", "--step", "8",
                         "--no-plot", "--no-vtk", "-o", str(tmp_path / "out")])
    assert (tmp_path / "out" / "dic.npz").is_file() and "numpy" in modules
    assert "numba" not in modules and "scipy" not in modules
