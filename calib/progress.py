"""Progress for long work: a tqdm bar on a terminal, silent otherwise (pipes, CI, tests).

tqdm is imported only when a bar is shown, so that a command run from a script does not pay for it.
"""

from __future__ import annotations

import sys
from typing import Iterable, TypeVar

T = TypeVar("T")


def progress(items: Iterable[T], desc: str, total: int | None = None) -> Iterable[T]:
    """Wrap `items` in a progress bar on stderr when stderr is a terminal."""
    if not sys.stderr.isatty():
        return items
    from tqdm import tqdm
    return tqdm(items, desc=desc, total=total, leave=False, dynamic_ncols=True)
