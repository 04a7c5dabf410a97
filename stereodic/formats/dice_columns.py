"""DICe's solution files: its column names and layout, so that scripts written for DICe's output run on
our results (`dic2d --columns dice`, `dic --columns dice`).

DICe writes one file per image (state): a block of lines starting with '***' (the run's description),
one line of column names, then one comma-separated row per point, every value as %.4E (its
DICe_solution_<k>.txt; ../shared/data/dice-stereo-list/dice-gold/ holds real ones). The columns are
DICe's field names:
- 2-D, one file per deformed image: SUBSET_ID; COORDINATE_X, COORDINATE_Y (the point in the reference
  image, px); DISPLACEMENT_X, DISPLACEMENT_Y (px); SIGMA (the match's predicted random error, px - DICe's
  "sigma" is its own noise prediction - and -1 where the point failed, DICe's mark of a failed point);
  GAMMA (the ZNSSD of the unit-normalised subsets, 2 (1 - ZNCC): DICe's "gamma"); with strains
  VSG_STRAIN_XX, VSG_STRAIN_YY, VSG_STRAIN_XY (the run's strain measure, Green-Lagrange by default).
- stereo, per state k: DICe_solution_<k>.txt for the left camera - SUBSET_ID, COORDINATE_X,
  COORDINATE_Y (the point in the ORIGINAL left reference image), DISPLACEMENT_X, DISPLACEMENT_Y (its
  motion in the original left images), STEREO_COORDINATES_X, STEREO_COORDINATES_Y (the point in the
  original right reference image), SIGMA, GAMMA, MODEL_COORDINATES_X/Y/Z (its reference position, mm),
  MODEL_DISPLACEMENT_X/Y/Z (mm) and the VSG strains; DICe_solution_stereo_<k>.txt for the right camera -
  SUBSET_ID, COORDINATE_X, COORDINATE_Y (original right reference image), DISPLACEMENT_X, DISPLACEMENT_Y,
  SIGMA, GAMMA.
DICe's BETA (its uniqueness measure), STATUS_FLAG and UNCERTAINTY have no counterpart here and are left
out. File numbers are zero-padded to the digits of the last one, as DICe does. Values we do not have
(a failed point's displacement) stay NaN.
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from calib import __version__
from calib.atomic import write_text
from stereodic.dic.grid import Grid


def numbered(prefix: str | os.PathLike, k: int, count: int, suffix: str = ".txt") -> Path:
    """prefix_<k><suffix>, k zero-padded to the digits of count - 1 (DICe's file names)."""
    return Path(f"{os.fspath(prefix)}_{k:0{len(str(max(count - 1, 0)))}d}{suffix}")


def header(reference: str, deformed: str, subset: int, step: int, shape: str, incremental: str,
           gauge_px: int | None) -> list[str]:
    """The '***' block of a solution file."""
    return ["***", f"*** stereodic {__version__}, written in DICe's solution-file layout", "***",
            f"*** Reference image: {reference} ", f"*** Deformed image: {deformed} ", "*** DIC method : local ",
            "*** Correlation method: ZNSSD", f"*** Shape functions: {shape}",
            f"*** Incremental correlation: {incremental}", f"*** Subset size: {subset}",
            f"*** Step size: x {step} y {step} (-1 implies not regular grid)",
            "*** Strain window: N/A" if gauge_px is None else
            f"*** Strain window size in pixels: {gauge_px} (only first strain post-processor is reported)",
            "*** Coordinates given with (0,0) as upper left corner of image, x positive right, y positive down",
            "***"]


def write_solution(path: str | os.PathLike, head: Sequence[str], columns: Sequence[tuple[str, np.ndarray]]) -> None:
    """One solution file: the header lines, the column names, one row per point (values as %.4E)."""
    out = io.StringIO()
    out.write("\n".join(head) + "\n" + ",".join(name for name, _ in columns) + "\n")
    cols = [["%.4E" % v for v in np.asarray(a, np.float64).tolist()] for _, a in columns]
    out.write("".join(",".join(row) + "\n" for row in zip(*cols)))
    write_text(path, out.getvalue())


def sigma_gamma(noise_px: np.ndarray, zncc: np.ndarray, ok: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """DICe's SIGMA (predicted error, -1 where failed) and GAMMA (2 (1 - ZNCC)) columns."""
    return [("SIGMA", np.where(ok, noise_px, -1.0)), ("GAMMA", 2.0 * (1.0 - zncc))]


def strain_columns(measure) -> list[tuple[str, np.ndarray]]:
    if measure is None:
        return []
    return [(f"VSG_STRAIN_{c.upper()}", getattr(measure, f"e{c}")) for c in ("xx", "yy", "xy")]


def gauge_px(window: int | None, step: int, subset: int) -> int | None:
    """The strain gauge length in pixels: (window - 1) * step + subset."""
    return None if not window else (window - 1) * step + subset


class StereoDiceWriter:
    """Writes the stereo solution files (module docstring) of each state given, in order from state 0
    (which holds the reference positions): call it with each StereoState. data: the experiment's
    `DicStates` (image names for the headers), settings: its `StereoSettings`, step: the grid step."""

    def __init__(self, folder: str | os.PathLike, grid: Grid, data, settings, step: int,
                 prefix: str = "DICe_solution"):
        self.folder, self.grid, self.data, self.s, self.step, self.prefix = Path(folder), grid, data, settings, step, prefix
        self.ref = None

    def __call__(self, st) -> None:
        act = self.grid.active
        if st.state == 0:
            self.ref = {"left": st.left.real[act], "right": st.right.real[act], "points": st.points[act]}
        n = len(self.data)
        s = self.s
        incremental = "true" if s.incremental else f"per point, below ZNCC {s.switch_zncc:g}" if s.switch_zncc else "false"
        common = dict(subset=s.dic.subset, step=self.step, shape=s.dic.shape, incremental=incremental,
                      gauge_px=gauge_px(s.strain_window, self.step, s.dic.subset))
        ids = [("SUBSET_ID", np.arange(int(act.sum())))]
        ref_l, ref_r = self.ref["left"], self.ref["right"]
        left, right = st.left, st.right
        cols = ids + [("COORDINATE_X", ref_l[:, 0]), ("COORDINATE_Y", ref_l[:, 1]),
                      ("DISPLACEMENT_X", left.real[act][:, 0] - ref_l[:, 0]),
                      ("DISPLACEMENT_Y", left.real[act][:, 1] - ref_l[:, 1]),
                      ("STEREO_COORDINATES_X", ref_r[:, 0]), ("STEREO_COORDINATES_Y", ref_r[:, 1])]
        cols += sigma_gamma(left.noise_px[act], left.zncc[act], st.converged[act])
        cols += [(f"MODEL_COORDINATES_{c}", self.ref["points"][:, i]) for i, c in enumerate("XYZ")]
        cols += [(f"MODEL_DISPLACEMENT_{c}", st.displacement[act][:, i]) for i, c in enumerate("XYZ")]
        cols += [(name, a[act]) for name, a in strain_columns(st.measure)]
        write_solution(numbered(self.folder / self.prefix, st.state, n),
                       header(str(self.data.left[0]), str(self.data.left[st.state]), **common), cols)
        cols = ids + [("COORDINATE_X", ref_r[:, 0]), ("COORDINATE_Y", ref_r[:, 1]),
                      ("DISPLACEMENT_X", right.real[act][:, 0] - ref_r[:, 0]),
                      ("DISPLACEMENT_Y", right.real[act][:, 1] - ref_r[:, 1])]
        cols += sigma_gamma(right.noise_px[act], right.zncc[act], st.converged[act])
        write_solution(numbered(self.folder / f"{self.prefix}_stereo", st.state, n),
                       header(str(self.data.right[0]), str(self.data.right[st.state]), **common), cols)
