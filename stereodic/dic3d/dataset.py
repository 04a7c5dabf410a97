"""The states of a stereo DIC experiment: which image is left and right in every state, every file checked
before any work, and the rectified image pairs read one state at a time.

Three ways to name the images (state 0 is the reference):
- a dataset (`capture.json` of kind "dic"): the rig's cameras are matched to the dataset's by name (the
  PRVMs' camera names, e.g. cam0 / cam1); a dataset of exactly two cameras with other names is taken in
  sorted order (left first). States must be 0, 1, ..., N-1 with exactly one image per camera each;
- two shell-style patterns, one per camera (`states_from_patterns`): the files each matches, in natural
  order, pair up one to one;
- a folder and two name suffixes (`states_from_folder`), DICe's and VIC-3D's naming: img_0003_0.tif is
  the left image of the state whose right image is img_0003_1.tif (suffixes _0 and _1); states in the
  natural order of the names.
Every image must exist, be a readable 8- or 16-bit PNG or TIFF and have its rig camera's size
(`calib.imageio.image_size` reads the headers), and left and right must pair up; otherwise an
InputError names the file (or pattern) and the problem.
"""

from __future__ import annotations

import os
import weakref
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from calib.capture import Frame, load_capture
from calib.errors import InputError
from calib.image_files import expand, natural_key
from calib.imageio import IMAGE_SUFFIXES, check_size, read_gray
from stereodic.stereo.rectify import rectify_pair
from stereodic.stereo.rig import SIDES, Rig, check_camera_sizes


@dataclass
class DicStates:
    """The checked image files of an experiment: left[k] and right[k] are the images of state k;
    `source` says where they were named (the dataset, the patterns, the folder); `names`: the states'
    names where the dataset gives them (a simulated dataset's `simulated.states`), else None."""

    left: list[Path]
    right: list[Path]
    source: str
    names: list[str] | None = None
    _last: tuple | None = field(default=None, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.left)

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_last": None}     # the kept pair stays in this process

    def label(self, k: int) -> str:
        """State k in words, for titles: "state 3: tension", or "state 3 (img_0003_0.tif)"."""
        return f"state {k}: {self.names[k]}" if self.names else f"state {k} ({self.left[k].name})"

    def read(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The raw (left, right) images of state k (uint8 or uint16)."""
        return read_gray(self.left[k]), read_gray(self.right[k])

    def rectified_pair(self, rig: Rig, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The rectified (left, right) images of state k, float32 (`rectify_pair(exact=True)`: grey levels
        not rounded, which would add noise to every match). The last pair is kept (the reference pair is
        asked for by the rig check, the specimen's region and the run), read-only."""
        last = self._last
        if last is not None and last[0] == k and last[1]() is rig:
            return last[2]
        pair = rectify_pair(rig, *self.read(k), where=(str(self.left[k]), str(self.right[k])), exact=True)
        for image in pair:
            image.flags.writeable = False
        self._last = (k, weakref.ref(rig), pair)
        return pair

    def rectified(self, rig: Rig) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """The rectified (left, right) images of each state, in order, read one state at a time."""
        for k in range(len(self)):
            yield self.rectified_pair(rig, k)


def _check_sizes(rig: Rig, files: dict[str, list[Path]]) -> None:
    """InputError naming the first image that is unreadable or not its rig camera's size."""
    for side in SIDES:
        for path in files[side]:
            check_size(path, rig.camera(side).imm.real_size, f"the rig's {side} camera")


def load_states(dataset: str | os.PathLike, rig: Rig) -> DicStates:
    """Read and check a DIC dataset against `rig` (module docstring); InputError naming the file."""
    cap = load_capture(dataset)
    where = cap.manifest_path
    if cap.kind != "dic":
        raise InputError(where, f"kind is {cap.kind!r}, expected 'dic'")
    names = [rig.left.name, rig.right.name]
    if not all(n in cap.cameras for n in names):
        if len(cap.cameras) != 2:
            raise InputError(where, f"has cameras {sorted(cap.cameras)}; the rig's are {names}")
        names = sorted(cap.cameras)
    check_camera_sizes(rig, cap.cameras, names, where)
    frames = []
    for name in names:
        by_state: dict[int, Frame] = {}
        for f in cap.frames:
            if f.camera == name:
                if f.state in by_state:
                    raise InputError(where, f"state {f.state} has two images of camera {name}")
                by_state[int(f.state)] = f
        frames.append(by_state)
    states = sorted(set(frames[0]) | set(frames[1]))
    if not states:
        raise InputError(where, "has no images")
    for s in range(max(states) + 1):
        for name, by_state in zip(names, frames):
            if s not in by_state:
                raise InputError(where, f"state {s} of camera {name} is missing (states must be 0..{max(states)}, "
                                        f"found {', '.join(map(str, sorted(by_state)))})")
    n = max(states) + 1
    names = (cap.extra.get("simulated") or {}).get("states")
    names = [str(v) for v in names] if isinstance(names, list) and len(names) == n else None
    return DicStates([cap.path(frames[0][s]) for s in range(n)], [cap.path(frames[1][s]) for s in range(n)],
                     os.fspath(dataset), names)


def states_from_patterns(left: str, right: str, rig: Rig) -> DicStates:
    """The states named by a shell-style pattern per camera (module docstring); InputError naming the
    pattern that matches nothing or whose count differs from the other's, or the first bad image."""
    files = {"left": expand(left), "right": expand(right)}
    if len(files["left"]) != len(files["right"]):
        raise InputError(right, f"matches {len(files['right'])} images but the left pattern {left!r} matches "
                                f"{len(files['left'])}")
    _check_sizes(rig, files)
    return DicStates(files["left"], files["right"], f"--left {left} --right {right}")


def states_from_folder(folder: str | os.PathLike, left_suffix: str, right_suffix: str, rig: Rig) -> DicStates:
    """The states of a folder of pairs named NAME<left_suffix>.EXT / NAME<right_suffix>.EXT (module
    docstring); InputError naming the folder when it holds no such pair, or the image whose partner is
    missing, or the first bad image."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(folder, "is not a folder")
    if not left_suffix or not right_suffix or left_suffix == right_suffix:
        raise InputError("--left-suffix/--right-suffix", f"need two different suffixes, got {left_suffix!r} and "
                                                         f"{right_suffix!r}")
    images = {p.name: p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES}
    sides = {"left": {}, "right": {}}
    for name, path in images.items():
        stem = path.stem
        for side, suffix in (("left", left_suffix), ("right", right_suffix)):
            if stem.endswith(suffix):
                sides[side][(stem[:-len(suffix)], path.suffix)] = path
    if not sides["left"] and not sides["right"]:
        raise InputError(folder, f"holds no image named *{left_suffix}.tif/.png or *{right_suffix}.tif/.png")
    for side, other, suffix in (("left", "right", right_suffix), ("right", "left", left_suffix)):
        for (base, ext), path in sorted(sides[side].items(), key=lambda kv: natural_key(kv[1])):
            if (base, ext) not in sides[other]:
                raise InputError(path, f"has no {other} partner image {base}{suffix}{ext} in {folder}")
    keys = sorted(sides["left"], key=lambda k: natural_key(sides["left"][k]))
    files = {side: [sides[side][k] for k in keys] for side in SIDES}
    _check_sizes(rig, files)
    return DicStates(files["left"], files["right"], f"--images {folder} --left-suffix {left_suffix} "
                                                    f"--right-suffix {right_suffix}")
