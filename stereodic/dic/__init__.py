"""2D subset digital image correlation (DIC).

Modules, one job each: `interpolation` (B-spline coefficients and sampling), `icgn` (IC-GN registration
of one subset, ZNSSD), `initial_guess` (integer ZNCC searches, also along rows for stereo),
`propagation` (reliability-guided wavefronts over a grid), `grid` (points from ROI and mask), `region`
(polygons with holes, a region of the original image on the rectified one), `texture` (noise, SSSIG,
where the specimen's speckle is),
`correlate` (one deformed image), `sequence` (series, switching point by point to incremental DIC),
`output` (CSV, NPZ, PNG).

Public API (pixels; x = column, y = row; u along x):
- `BSplineImage.from_image(img, *, order, prefilter_sigma)`: interpolant of an image.
- `correlate_points(ref, dfm, xs, ys, guess, *, settings) -> PointResult`: register a list of points from
  initial guesses (the building block for stereo matching).
- `row_search(ref_img, dfm_img, xs, ys, *, half, dmin, dmax)`: integer match along rows (rectified
  stereo); `row_seed_search(dmin, dmax)`: the same as the seed search of `correlate_pair(..., search=)`.
- `make_grid(width, height, *, subset, step)`, `correlate_pair(ref, dfm, grid, *, settings)`,
  `correlate_sequence`: full-field DIC.
"""

try:
    from stereodic.dic import _kernels  # noqa: F401 - compiled at install (setup.py, stereodic/dic/src)
except ImportError as exc:
    raise ImportError("stereodic's compiled DIC kernels are not built: install the package with ./run "
                      "(or pip install -e .)") from exc
from stereodic.dic.correlate import DicField, DicSettings, ImageRef, PointResult, correlate_pair, correlate_points
from stereodic.dic.grid import Grid, make_grid
from stereodic.dic.icgn import STATUS_NAMES
from stereodic.dic.initial_guess import row_search, row_seed_search, search_integer
from stereodic.dic.interpolation import BSplineImage
from stereodic.dic.sequence import SWITCH_ZNCC, correlate_sequence

__all__ = ["BSplineImage", "DicField", "DicSettings", "Grid", "ImageRef", "PointResult", "STATUS_NAMES", "SWITCH_ZNCC",
           "correlate_pair",
           "correlate_points", "correlate_sequence", "make_grid", "row_search", "row_seed_search",
           "search_integer"]
