"""The states of a stereo DIC dataset (`capture.json` of kind "dic"): which camera is left and right,
every state checked before any work, and the rectified image pairs.

The rig's cameras are matched to the dataset's by name (the PRVMs' camera names, e.g. cam0 / cam1); a
dataset of exactly two cameras with other names is taken in sorted order (left first). States must be
0, 1, ..., N-1 with exactly one image per camera each, and every image the size of its rig camera
(`load_capture` checks every file's size against its camera before any work).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from calib.capture import Capture, Frame, load_capture
from calib.errors import InputError
from stereodic.rectify import rectify_pair
from stereodic.rig import Rig


@dataclass
class DicStates:
    """The checked dataset: capture, the left and right frame of every state (index = state)."""

    capture: Capture
    left: list[Frame]
    right: list[Frame]

    def __len__(self) -> int:
        return len(self.left)

    def rectified(self, rig: Rig) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """The rectified (left, right) images of each state, in order, read one state at a time."""
        cap = self.capture
        for lf, rf in zip(self.left, self.right):
            yield rectify_pair(rig, cap.read(lf), cap.read(rf), where=(str(cap.path(lf)), str(cap.path(rf))))


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
    frames = []
    for name, side in zip(names, ("left", "right")):
        cam = rig.camera(side)
        real = (int(cam.info.get("real_width", 0)), int(cam.info.get("real_height", 0)))
        if all(real) and tuple(cap.cameras[name]) != real:
            raise InputError(where, f"camera {name} is {cap.cameras[name][0]}x{cap.cameras[name][1]} but the "
                                    f"rig's {side} camera is {real[0]}x{real[1]}")
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
    return DicStates(cap, [frames[0][s] for s in range(n)], [frames[1][s] for s in range(n)])
