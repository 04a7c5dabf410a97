"""numba never compiles in silence: the `numba_extensions` entry point (calib.compile_notice) writes a
line for the first kernel of each module it compiles and the total time at exit; a cached kernel, loaded
instead of compiled, says nothing."""

import subprocess
import sys

KERNEL = """
import numpy as np
from numba import njit

@njit(cache={cache})
def inner(x):
    return np.sum(x)

@njit(cache={cache})
def outer(x):
    return inner(x) + 1.0

print(outer(np.ones(4)))
"""


def _run(tmp_path, cache: bool) -> str:
    script = tmp_path / "kernel.py"
    script.write_text(KERNEL.format(cache=cache))
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, cwd=tmp_path, timeout=300,
                          env={"PATH": "/usr/bin:/bin", "NUMBA_CACHE_DIR": str(tmp_path / "cache")})
    assert done.returncode == 0 and done.stdout.strip() == "5.0", done.stderr
    return done.stderr


def test_a_compile_is_announced_and_a_cache_load_is_not(tmp_path):
    err = _run(tmp_path, cache=True).splitlines()
    assert err[0] == ("stereodic: compiling the numba kernels of __main__ (once after an install; later runs "
                      "load them from the cache)")
    assert err[-1].startswith("stereodic: compiled 1 numba kernel of 1 module in ") and len(err) == 2
    assert _run(tmp_path, cache=True) == ""
