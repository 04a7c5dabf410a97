"""Results kept while the objects they were computed from live.

A run computes some things of its reference pair more than once: the rig check and the stereo start both
match the rectified pair's features, and the rig check, the specimen's region and the correlation all
interpolate its images. The pair is read-only (`stereodic.dic3d.dataset.DicStates.rectified_pair`), so a
result of it can be kept for as long as the arrays live (weak references: nothing is kept alive by the
cache) and given again for the same arrays. `kept` is that cache; a caller keeps only results of objects
that do not change (read-only arrays, frozen dataclasses).
"""

from __future__ import annotations

import weakref
from typing import Callable, TypeVar

T = TypeVar("T")

_KEPT: dict = {}   # key -> (weak references to the owners, the value)


def kept(key: tuple, owners: tuple, compute: Callable[[], T]) -> T:
    """`compute()`, kept under `key` while every one of `owners` lives and returned again for the same
    owners (`key` names the result and its owners, e.g. ("bspline", id(image), order); an owner's id may
    be reused after it dies, so the owners themselves are checked)."""
    entry = _KEPT.get(key)
    if entry is not None and len(entry[0]) == len(owners) and all(r() is o for r, o in zip(entry[0], owners)):
        return entry[1]
    value = compute()
    refs: list = []

    def forget(dead) -> None:
        if _KEPT.get(key, (None,))[0] is refs:
            del _KEPT[key]

    refs.extend(weakref.ref(o, forget) for o in owners)
    _KEPT[key] = (refs, value)
    return value
