"""A batch of independent outputs (scans, calibrated cameras) and the record of which are done, so that a
batch stopped half way (a crash, a lost cluster) is finished by the same command without doing again
what is done.

The record is a JSON file beside the outputs ("stereodic.batch/1"): `settings` (what decides every
output: the options, the software version) and, per item done, `inputs` (the SHA-256 of the files every
item shares, such as the rig, and a cheap `fingerprint` of each of its own input files) and `outputs`
(the files it wrote). An item counts as done when its entry matches the item's inputs now, the
settings are the same and its outputs exist (names relative to the record's folder); an item of other settings or inputs is done again (its
outputs are replaced atomically). Only the process that drives the batch writes the record, after each
item's outputs are complete.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from calib.atomic import write_json
from calib.errors import InputError

FORMAT = "stereodic.batch/1"
FINGERPRINT_BYTES = 16384


def fingerprint(path: str | os.PathLike) -> str:
    """'<size>:<SHA-1 of up to 16 KiB from the middle of the file>': cheap, and different for two
    captures of a speckle (its noise alone differs). A frame of a sequence file (`FILE::K`,
    `calib.sequences`): the file's fingerprint and the frame's name."""
    from calib.sequences import parse_frame_ref
    ref = parse_frame_ref(path)
    if ref is not None:
        return f"{fingerprint(ref[0])}#{os.fspath(path)[len(os.fspath(ref[0])) + 2:]}"
    path = Path(path)
    size = path.stat().st_size
    with open(path, "rb") as f:
        f.seek(max(0, size // 2 - FINGERPRINT_BYTES // 2))
        return f"{size}:{hashlib.sha1(f.read(FINGERPRINT_BYTES)).hexdigest()}"


def file_sha256(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


class BatchRecord:
    """The record file `path` of a batch run with `settings` (module docstring)."""

    def __init__(self, path: str | os.PathLike, settings: dict):
        self.path = Path(path)
        self.settings = json.loads(json.dumps(settings))
        self.items: dict[str, dict] = {}
        if self.path.is_file():
            try:
                old = json.loads(self.path.read_text())
            except json.JSONDecodeError:
                raise InputError(self.path, "is not valid JSON (remove it: the batch is then done again)") from None
            if old.get("format") != FORMAT:
                raise InputError(self.path, f"format is {old.get('format')!r}, expected {FORMAT!r}")
            if old.get("settings") == self.settings:
                self.items = old.get("items", {})

    def done(self, item: str, inputs: dict) -> bool:
        """Whether `item` was done with these inputs (and the settings) and its outputs are all there."""
        entry = self.items.get(item)
        return (entry is not None and entry.get("inputs") == json.loads(json.dumps(inputs))
                and all((self.path.parent / p).is_file() for p in entry.get("outputs", [])))

    def record(self, item: str, inputs: dict, outputs: list) -> None:
        """Record `item` done (its `outputs` written; kept relative to the record's folder, so that the
        folder may move), on disk at once."""
        base = self.path.parent.resolve()
        rel = [os.path.relpath(Path(p).resolve(), base) for p in outputs]
        self.items[item] = {"inputs": json.loads(json.dumps(inputs)), "outputs": rel}
        write_json(self.path, {"format": FORMAT, "settings": self.settings, "items": self.items})
