"""Progress for long work: a tqdm bar on a terminal, silent otherwise (pipes, CI, tests)."""

from __future__ import annotations

import sys
from typing import Iterable, TypeVar

from tqdm import tqdm

T = TypeVar("T")


def progress(items: Iterable[T], desc: str, total: int | None = None) -> Iterable[T]:
    """Wrap `items` in a progress bar on stderr when stderr is a terminal."""
    return tqdm(items, desc=desc, total=total, disable=not sys.stderr.isatty(), leave=False,
                dynamic_ncols=True)
