"""Progress for long work: a tqdm bar on a terminal (items per second and time left), silent otherwise
(pipes, CI, tests); `note` prints a line without breaking the bar.

tqdm is imported only when a bar is shown, so that a command run from a script does not pay for it.
"""

from __future__ import annotations

import sys
from typing import Iterable, TypeVar

T = TypeVar("T")


def progress(items: Iterable[T], desc: str, total: int | None = None, initial: int = 0,
             unit: str = "it") -> Iterable[T]:
    """Wrap `items` in a progress bar on stderr when stderr is a terminal; `initial`: items already done
    before these (a resumed run), `unit`: what an item is ("state": the bar shows states/s)."""
    if not sys.stderr.isatty():
        return items
    from tqdm import tqdm
    return tqdm(items, desc=desc, total=total, initial=initial, unit=unit, leave=False, dynamic_ncols=True)


def note(text: str) -> None:
    """Print a line on stdout, above a progress bar if one is shown."""
    if not sys.stderr.isatty():
        print(text, flush=True)
        return
    from tqdm import tqdm
    tqdm.write(text, file=sys.stdout)
