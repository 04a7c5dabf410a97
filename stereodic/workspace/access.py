"""Who may ask the workspace's server for what: the token rule and the served paths.

- Bound to a loopback address (127.0.0.1, ::1, localhost) the server needs no token, as a local Jupyter
  may run without one; bound to any other address it must have a token, and every request must carry it
  (`?token=T` in the address, then a cookie set from it), else 403: the server would otherwise hand the
  lab's files to anyone on the network.
- Files are served only from under the paths the server was started on (`Access.resolve`), and the
  image files that a result opened there names as its own (a run folder's reference images, which live in
  its dataset: `Access.allow_files`, each file alone, not its folder). A path is resolved (symbolic links
  followed, `..` taken away) before it is compared, so that `../` in a URL or a parameter cannot leave
  them.
"""

from __future__ import annotations

import hmac
import os
import secrets
from dataclasses import dataclass, field
from pathlib import Path

from calib.errors import InputError
from calib.sequences import frame_ref, parse_frame_ref

LOOPBACK = ("127.0.0.1", "::1", "localhost")
COOKIE = "stereodic_token"


def check_host(host: str, token: str | None) -> None:
    """InputError naming --host unless `host` is a loopback address or a token is given (module
    docstring); InputError naming --token for a token too short to guess at (fewer than 16 characters)."""
    if token is not None and len(token) < 16:
        raise InputError("--token", f"must have at least 16 characters, got {len(token)}")
    if host not in LOOPBACK and token is None:
        raise InputError("--host", f"{host} is reachable from other machines: give --token T (at least 16 "
                                   f"characters; the address printed then carries it), or leave --host out to "
                                   f"serve on 127.0.0.1 only")


def new_token() -> str:
    """A random token (32 hexadecimal characters) for `--token auto`."""
    return secrets.token_hex(16)


@dataclass
class Access:
    """The served paths (`roots`: folders and files, resolved) and the token (None: none needed).

    Parameters
    ----------
    roots : list of Path
        What the server was started on; a file root serves its folder's files too (a PRVM file's
        neighbours, a PLY's dataset).
    token : str or None
        The token every request must carry, or None on a loopback address.
    """

    roots: list[Path]
    token: str | None = None
    _folders: list[Path] = field(init=False, repr=False)
    _files: set[Path] = field(init=False, repr=False, default_factory=set)

    def __post_init__(self):
        self.roots = [Path(r).resolve() for r in self.roots]
        self._folders = [r if r.is_dir() else r.parent for r in self.roots]

    @property
    def folders(self) -> list[Path]:
        """The served folders (a file root's folder)."""
        return list(self._folders)

    def allow_files(self, paths) -> None:
        """Serve these files too (each alone): the images a result under the served folders names (a frame
        of a video, `FILE::K`: its file)."""
        self._files.update(Path(ref[0] if (ref := parse_frame_ref(p)) else p).resolve() for p in paths)

    def resolve(self, path: str | os.PathLike) -> Path:
        """`path` (absolute, or relative to the first served folder) resolved, if it lies under a served
        folder; InputError naming it otherwise (outside, or through `..`). A frame of a sequence file
        (`FILE::K[:left|right]`, `calib.sequences`) is its file's frame, the file resolved and checked."""
        ref = parse_frame_ref(path)
        if ref is not None:
            return frame_ref(self.resolve(ref[0]), ref[1], ref[2])
        p = Path(path)
        p = (p if p.is_absolute() else self._folders[0] / p).resolve()
        if p not in self._files and not any(p == f or p.is_relative_to(f) for f in self._folders):
            raise InputError(path, "is outside the folders this workspace serves")
        return p

    def allows(self, token: str | None) -> bool:
        """Whether a request carrying `token` (from its address or its cookie) may be answered."""
        if self.token is None:
            return True
        return token is not None and hmac.compare_digest(token.encode(), self.token.encode())
