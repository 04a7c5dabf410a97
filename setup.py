"""The compiled kernels (C with OpenMP), built at install; everything else about the package is in
pyproject.toml. Why compiled: docs/dic.md, "Start-up and the compiled kernels".

- stereodic.dic._kernels (stereodic/dic/src): B-splines, IC-GN, propagation, the maps' raster cells;
- stereodic.stereo._kernels (stereodic/stereo/src): the triangulation and the rays' distances;
- stereodic.strain._kernels (stereodic/strain/src): the 3-D strain fit.
Their arrays pass through stereodic/src/buffers.h."""

from setuptools import Extension, setup

# The fast-math set the kernels had under numba, {nsz, arcp, contract, afn, reassoc}: NaN and infinity
# checks stay meaningful (no -ffinite-math-only). -march=native: the extension is built where it runs
# (./run, pip install), and like numba's JIT it uses that CPU's instructions (AVX2/FMA: +15 % points/s).
FLAGS = ["-O3", "-march=native", "-fopenmp", "-fno-math-errno", "-funsafe-math-optimizations",
         "-ffp-contract=fast", "-std=c11"]


def kernels(package: str, names: tuple[str, ...], headers: tuple[str, ...] = ()) -> Extension:
    """The extension `package`._kernels from the C files `names` in the package's src folder."""
    src = package.replace(".", "/") + "/src"
    return Extension(f"{package}._kernels", sources=[f"{src}/{name}.c" for name in names],
                     depends=[f"{src}/{name}.h" for name in headers] + ["stereodic/src/buffers.h"],
                     include_dirs=["stereodic/src"], extra_compile_args=FLAGS, extra_link_args=["-fopenmp"])


setup(ext_modules=[kernels("stereodic.dic", ("module", "bspline", "icgn", "propagation", "raster"),
                           ("bspline", "icgn", "propagation", "raster")),
                   kernels("stereodic.stereo", ("module",)),
                   kernels("stereodic.strain", ("module",))])
