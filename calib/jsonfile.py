"""Reading the JSON files a user gives (a dataset's capture.json, a display response): one InputError
naming the file for each way it can be wrong. Writing is `calib.atomic.write_json`."""

from __future__ import annotations

import json
import os
from pathlib import Path

from calib.errors import InputError


def read_json(path: str | os.PathLike, what: str) -> dict:
    """The JSON object in the file at `path`; `what` names the file in messages ("dataset manifest",
    "display response"). InputError naming the file if it is missing, a directory, empty, not text, not
    valid JSON (with the line and column) or not a JSON object."""
    path = Path(path)
    if path.is_dir():
        raise InputError(path, f"is a directory, not a {what}")
    if not path.is_file():
        raise InputError(path, f"{what} is missing")
    data = path.read_bytes()
    if not data.strip():
        raise InputError(path, f"is empty, not a {what}")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(path, f"not a {what}: not a text file (binary content)") from None
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(path, f"not valid JSON (line {exc.lineno} column {exc.colno}: {exc.msg})") from None
    if not isinstance(d, dict):
        raise InputError(path, f"not a {what}: JSON, but not an object")
    return d
