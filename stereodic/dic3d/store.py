"""The run folder of `stereodic dic`: a manifest, one result file per state and the carry between states,
so that results stream to disk state by state and an interrupted run resumes where it stopped.

- `DIR/run.json` ("stereodic.dic-run/1"): `settings` (everything that decides the results, the software
  version included), `inputs` (the rig file's SHA-256; per state the left and right image files with
  their sizes and a SHA-1 of 16 KiB from the middle of each), `states` (how many), `done` (how many
  states are finished, from state 0 on), `outputs` (the options the combined files were last written
  with, once they were).
- `DIR/states/state{k:06d}.npz`: the result of state k (`output.state_arrays`: dic.npz's arrays of that
  state, and the combined status);
  `DIR/states/carry.npz`: what the state after the last finished one needs (`StereoCarry`);
  `DIR/states/state{k:06d}.csv`: state k's rows of dic.csv, where a cluster's task formatted them beside
  the chain (`output.csv_rows`), or a worker process beside the run's next state; taken into dic.csv;
  `DIR/states/state{k:06d}.vtp`: state k's VTK file, written beside the run's next state; moved into the
  run's vtk folder;
  `DIR/states/state{k:06d}.ranges.json`: the value ranges of state k's maps (`output.state_ranges`),
  written beside the run's next state, so that the maps' colour scales need not read the states again;
  these three are removed once the combined outputs are written (`remove_kept`).
Every file is written atomically, in the order state file, carry, manifest: wherever a run stops, the
folder is consistent and the run resumes after the carry's state (a state file beyond it is computed
again, to the same bytes). A run whose settings or inputs differ from the folder's is refused.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Iterator

import numpy as np

from calib.atomic import write_json, write_npz, write_text
from calib.errors import InputError
from stereodic.dic3d.output import state_arrays, state_from_arrays
from stereodic.dic3d.stereo import StereoCarry, StereoState
from stereodic.dic3d.vtk import polydata

FORMAT = "stereodic.dic-run/1"
MANIFEST = "run.json"


def _first_difference(old, new, where: str = "") -> str | None:
    """A description of the first place two JSON values differ, or None."""
    if isinstance(old, dict) and isinstance(new, dict):
        for k in list(old) + [k for k in new if k not in old]:
            d = _first_difference(old.get(k), new.get(k), f"{where}.{k}" if where else k)
            if d:
                return d
        return None
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        for i, (a, b) in enumerate(zip(old, new)):
            d = _first_difference(a, b, f"{where}[{i}]")
            if d:
                return d
        return None
    return None if old == new else f"{where}: {json.dumps(old)} then, {json.dumps(new)} now"


class RunStore:
    """The run folder (module docstring). `open` starts or resumes a run."""

    def __init__(self, folder: str | os.PathLike):
        self.folder = Path(folder)
        self.manifest_path = self.folder / MANIFEST
        self.states_dir = self.folder / "states"
        self.manifest: dict = {}

    def open(self, settings: dict, inputs: dict, states: int, restart: bool = False) -> int:
        """Start a run, or resume the one in the folder: returns how many states are finished. InputError
        naming the manifest when the folder holds a run of other settings or inputs (unless `restart`:
        then its state files are removed and the run starts over), or when the folder cannot be written."""
        try:
            self.states_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(self.folder, f"cannot create the output folder ({exc.strerror})") from None
        if not os.access(self.states_dir, os.W_OK):
            raise InputError(self.folder, "the output folder is not writable")
        new = {"format": FORMAT, "settings": settings, "inputs": inputs, "states": states}
        old = self._read_manifest()
        if old is not None and restart:
            for p in self.states_dir.glob("*.npz"):
                p.unlink()
            self.remove_kept()
            old = None
        if old is not None:
            for key in ("settings", "inputs"):
                diff = _first_difference(old.get(key), new[key])
                if diff:
                    raise InputError(self.manifest_path, f"this folder holds a run with other {key} ({diff}); "
                                                         f"use another output folder, or --restart")
            new["done"] = self._resume_point(states)
            if "outputs" in old and new["done"] == states:
                new["outputs"] = old["outputs"]
        else:
            new["done"] = 0
        self.manifest = new
        write_json(self.manifest_path, self.manifest)
        return new["done"]

    def _read_manifest(self) -> dict | None:
        if not self.manifest_path.is_file():
            return None
        try:
            m = json.loads(self.manifest_path.read_text())
        except json.JSONDecodeError:
            raise InputError(self.manifest_path, "is not valid JSON (remove it, or use --restart)") from None
        if m.get("format") != FORMAT:
            raise InputError(self.manifest_path, f"format is {m.get('format')!r}, expected {FORMAT!r}")
        return m

    def _resume_point(self, states: int) -> int:
        """The finished states: state 0 to the carry's state, if all their files exist (else none)."""
        carry = self.states_dir / "carry.npz"
        if not carry.is_file():
            return 0
        with np.load(carry) as z:
            last = min(int(z["state"]), states - 1)
        return last + 1 if all(self.state_path(k).is_file() for k in range(last + 1)) else 0

    def state_path(self, k: int) -> Path:
        return self.states_dir / f"state{k:06d}.npz"

    def rows_path(self, k: int) -> Path:
        return self.states_dir / f"state{k:06d}.csv"

    def write_rows(self, k: int, text: str) -> None:
        """Keep state k's rows of dic.csv (formatted where the state's other files are written)."""
        write_text(self.rows_path(k), text)

    def read_rows(self, k: int) -> str | None:
        """State k's rows of dic.csv if they were kept (`write_rows`), else None."""
        path = self.rows_path(k)
        return path.read_text() if path.is_file() else None

    def vtk_path(self, k: int) -> Path:
        return self.states_dir / f"state{k:06d}.vtp"

    def write_vtk(self, state: StereoState) -> None:
        """Keep a state's VTK file (`vtk.polydata`: the state as solved, in the rig's frame) for the run's
        vtk folder (`take_vtk`)."""
        write_text(self.vtk_path(state.state), polydata(state))

    def take_vtk(self, k: int, path: str | os.PathLike) -> bool:
        """Move state k's kept VTK file (`write_vtk`) to `path`; False if none was kept."""
        kept = self.vtk_path(k)
        if not kept.is_file():
            return False
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        os.replace(kept, path)
        return True

    def ranges_path(self, k: int) -> Path:
        return self.states_dir / f"state{k:06d}.ranges.json"

    def write_ranges(self, k: int, ranges: dict) -> None:
        """Keep state k's maps' value ranges (`output.state_ranges`) for the run's colour scales."""
        write_json(self.ranges_path(k), {name: None if r is None else list(r) for name, r in ranges.items()})

    def read_ranges(self, k: int) -> dict | None:
        """State k's kept value ranges (`write_ranges`), or None."""
        path = self.ranges_path(k)
        if not path.is_file():
            return None
        return {name: None if r is None else tuple(r) for name, r in json.loads(path.read_text()).items()}

    def remove_kept(self) -> None:
        """Remove what was kept for the combined outputs - rows, VTK files, value ranges - once they are
        written (or, written in another frame, do not take them)."""
        for pattern in ("state*.csv", "state*.vtp", "state*.ranges.json"):
            for p in self.states_dir.glob(pattern):
                p.unlink()

    def write_state(self, state: StereoState, carry: StereoCarry) -> None:
        """Save a finished state and the carry after it, then record it done."""
        self.write_result(state, carry)
        self.record_done(state.state)

    def write_result(self, state: StereoState, carry: StereoCarry) -> None:
        """Save a finished state and the carry after it (where the run is solved: a Dask worker too)."""
        write_npz(self.state_path(state.state), **state_arrays(state))
        write_npz(self.states_dir / "carry.npz", **carry.to_arrays())

    def record_done(self, k: int) -> None:
        """Record states 0 to k done in the manifest (after `write_result` of state k)."""
        self.manifest["done"] = k + 1
        self.manifest.pop("outputs", None)
        write_json(self.manifest_path, self.manifest)

    def record_saved(self) -> None:
        """Record done the states saved in the folder beyond those recorded (what a task that stopped
        half-way through its states had finished)."""
        saved = self._resume_point(self.manifest["states"])
        if saved > self.done:
            self.record_done(saved - 1)

    def attach(self) -> "RunStore":
        """The run already in the folder, to read and add states to without opening it again (a Dask
        worker's view of a run that the client opened); InputError naming the manifest if there is
        none."""
        manifest = self._read_manifest()
        if manifest is None:
            raise InputError(self.manifest_path, "is missing: the run folder must be on storage that every "
                                                 "worker sees")
        self.manifest = manifest
        return self

    def read_state(self, k: int) -> StereoState:
        with np.load(self.state_path(k)) as z:
            return state_from_arrays(z, self.manifest["settings"].get("stereo", {}).get("strain_measure"))

    def values(self, key: str) -> Iterator[np.ndarray]:
        """One array of every state's result file, state by state."""
        for k in range(self.manifest["states"]):
            with np.load(self.state_path(k)) as z:
                yield z[key]

    def states(self) -> Iterator[StereoState]:
        """Every state's result, read one at a time."""
        for k in range(self.manifest["states"]):
            yield self.read_state(k)

    def read_carry(self) -> StereoCarry:
        with np.load(self.states_dir / "carry.npz") as z:
            return StereoCarry.from_arrays(z)

    @property
    def done(self) -> int:
        return int(self.manifest.get("done", 0))

    def outputs_written(self, outputs: dict) -> bool:
        """Whether the combined files were already written, with these options, after the last state."""
        return self.manifest.get("outputs") == outputs

    def record_outputs(self, outputs: dict) -> None:
        self.manifest["outputs"] = outputs
        write_json(self.manifest_path, self.manifest)
