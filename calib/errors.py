"""The one exception type for bad user input.

Raise `InputError(path, problem)` wherever a file or an argument a user gave is wrong. The command line
turns it into one line `stereodic: <path>: <problem>` and exit status 2; library users catch it.
"""

from __future__ import annotations

import os


class InputError(ValueError):
    """Bad input from the user: names the file (or argument) and what is wrong with it."""

    def __init__(self, where: str | os.PathLike | None, problem: str):
        self.where = None if where is None else os.fspath(where)
        self.problem = problem
        super().__init__(problem if self.where is None else f"{self.where}: {problem}")

    def __reduce__(self):  # pickled as (where, problem): it crosses processes (a Dask worker -> the client)
        return type(self), (self.where, self.problem)
