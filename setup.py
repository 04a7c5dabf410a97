"""The compiled DIC kernels (stereodic/dic/src, C with OpenMP), built at install; everything else about
the package is in pyproject.toml. Why compiled: docs/dic.md, "Start-up and the compiled kernels"."""

from setuptools import Extension, setup

# numba's fast-math set for these kernels was {nsz, arcp, contract, afn, reassoc}: the same here, and
# like there NaN and infinity checks stay meaningful (no -ffinite-math-only).
FLAGS = ["-O3", "-fopenmp", "-fno-math-errno", "-funsafe-math-optimizations", "-ffp-contract=fast",
         "-std=c11"]

setup(ext_modules=[Extension(
    "stereodic.dic._kernels",
    sources=[f"stereodic/dic/src/{name}.c" for name in ("module", "bspline", "icgn", "propagation")],
    depends=[f"stereodic/dic/src/{name}.h" for name in ("bspline", "icgn", "propagation")],
    extra_compile_args=FLAGS, extra_link_args=["-fopenmp"])])
