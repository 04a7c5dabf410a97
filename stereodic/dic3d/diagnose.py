"""Why a state of a stereo DIC run, or an image of a 2-D one, measured little: the likely cause from how
its points failed.

A state that measures under half of its active points gets one line naming the most frequent failure
(the combined status of `stereo.StereoState`: the left match, the right match, the rays, the
reference; or the 2-D engine's status of a `dic2d` image, read as a left match) and what it most likely
means, with what changes it:
- left no_texture / low_texture: no speckle there (the region, the subset);
- left or right outside: subsets reaching beyond the image or into the rectified pair's blank band;
- right failures in the reference state: the right camera does not find the left one's speckle: rows
  off the rig (a calibration that no longer fits) or the cameras swapped;
- left failures in a later state: motion beyond what the temporal seeds searched, or images out of
  order;
- right failures in a later state where the left matched: a camera that moved during the test;
- ray_gap: matches off the rows that the reference pair measured (the rig changed during the test);
- no_reference: points the reference state did not measure.
"""

from __future__ import annotations

from collections import Counter

import numpy as np


RAY_GAP = "ray_gap"        # a stereo state's combined statuses beyond the 2-D engine's (`stereo._combine`)
NO_REFERENCE = "no_reference"
NO_SPECKLE = ("no_texture", "low_texture")
OUTSIDE = ("outside",)


def _cause(status: str, reference: bool, search_px: int) -> str:
    side, _, what = status.rpartition(":")
    if status == RAY_GAP:
        return ("rows off the rig: the matches sit further off the rows measured in the reference pair than "
                "--max-gap allows (has a camera moved since the reference? raise --max-gap, or run the states "
                "after the move with a new reference)")
    if status == NO_REFERENCE:
        return "points that the reference state did not measure (see its own diagnosis)"
    if what in NO_SPECKLE:
        return ("no speckle: the subsets there have too little texture to register (give --roi or --mask on the "
                "specimen, or a larger --subset)")
    if what in OUTSIDE:
        return ("subsets beyond the image: they reach past its edge or into the rectified pair's blank band "
                "(a smaller --subset, or a region further inside)")
    if reference:
        return ("the right camera does not find the left one's speckle on these rows: rows off the rig (a "
                "calibration that does not fit: leave out --keep-rig, or widen --vertical-search) or the cameras "
                "swapped (--left-suffix/--right-suffix, --left/--right)")
    if side in ("left", ""):
        return (f"motion beyond what was searched (the temporal seeds search +-{search_px} px: raise --search) or "
                f"images out of order (check that the files sort in the order they were taken)")
    return ("a camera that moved: the right images no longer match the reference where the left ones do (a "
            "rig bumped during the test: run the states after it with a new reference)")


def diagnosis(converged: np.ndarray, status: np.ndarray, active: np.ndarray, *, label: str, reference: bool,
              search_px: int) -> str | None:
    """One line on why an image or state measured under half of its `active` points, or None when it
    measured more.

    Parameters
    ----------
    converged : (ny, nx) bool
        The points measured.
    status : (ny, nx) str
        Their statuses: the 2-D engine's names (`stereodic.dic.STATUS_NAMES`), for a stereo state
        prefixed 'left:' or 'right:', or `stereo.RAY_GAP`, `stereo.NO_REFERENCE`.
    active : (ny, nx) bool
        The grid's active points.
    label : str
        The state or image, as the line names it ("state 3", "image 2").
    reference : bool
        A stereo run's reference state (its right failures are the stereo match's).
    search_px : int
        The temporal seeds' search range, pixels (named in the advice).

    Returns
    -------
    line : str or None
        "<label>: only m of n points measured; most failed as <status> (count): likely <cause and what
        changes it>".
    """
    n = int(active.sum())
    measured = int((converged & active).sum())
    if n == 0 or 2 * measured >= n:
        return None
    failed = Counter(np.asarray(status)[active & ~converged].tolist())
    worst, count = failed.most_common(1)[0]
    return (f"{label}: only {measured} of {n} points measured; most failed as {worst} ({count}): likely "
            f"{_cause(worst, reference, search_px)}")
