"""The compiled DIC kernels (stereodic/dic/src, C with OpenMP), built at install; everything else about
the package is in pyproject.toml. Why compiled: docs/dic.md, "Start-up and the compiled kernels"."""

from setuptools import Extension, setup

# The fast-math set the kernels had under numba, {nsz, arcp, contract, afn, reassoc}: NaN and infinity
# checks stay meaningful (no -ffinite-math-only). -march=native: the extension is built where it runs
# (./run, pip install), and like numba's JIT it uses that CPU's instructions (AVX2/FMA: +15 % points/s).
FLAGS = ["-O3", "-march=native", "-fopenmp", "-fno-math-errno", "-funsafe-math-optimizations",
         "-ffp-contract=fast", "-std=c11"]

setup(ext_modules=[Extension(
    "stereodic.dic._kernels",
    sources=[f"stereodic/dic/src/{name}.c" for name in ("module", "bspline", "icgn", "propagation", "raster")],
    depends=[f"stereodic/dic/src/{name}.h" for name in ("bspline", "icgn", "propagation", "raster")],
    extra_compile_args=FLAGS, extra_link_args=["-fopenmp"])])
