"""A 2-D DIC sequence (`sequence.correlate_sequence`) on a Dask cluster (`stereodic.cluster`): the same
fields, bit for bit, in the same order.

Each image starts from the warps the previous one leaves (`TrackCarry`) and tracks incremental points
from the previous image, so the images are a chain; beside it, the next images are read and prepared
(their B-splines) as independent tasks, up to `window` ahead:
- dic2d-prepare k: image k read (the caller's `read`: a module-level function, pickled by name) and
  its B-spline, held on the worker that made it;
- dic2d-track k: `track_image` of image k against the reference from the carry of image k - 1, which
  the client holds and sends with the task (by value: a task of a chain that Dask had to recompute
  would otherwise recompute the chain before it); returns the field and the next carry.
The reference image is read and prepared once per worker (`stereodic.cluster.per_worker`) from its file,
which must be on storage every worker sees under the same path (so must the deformed images).
"""

from __future__ import annotations

import hashlib
import os
import pickle
from dataclasses import dataclass
from typing import Callable, Iterator, Sequence

import numpy as np

from calib.batch import fingerprint
from stereodic.cluster import per_worker, result, run_id, submit, threads
from stereodic.dic.correlate import DicField, DicSettings, ImageRef, seed_indices
from stereodic.dic.grid import Grid
from stereodic.dic.interpolation import BSplineImage
from stereodic.dic.sequence import SWITCH_ZNCC, TrackCarry, track_image

TRACK, PREPARE = 1, 0    # task priorities: the chain first


@dataclass(frozen=True)
class SequenceSpec:
    """What a task needs: the reference image file (absolute path), `read` (a file -> its image, checked),
    the grid, the settings, the seeds' grid indices, the switch ZNCC and `token` (names the per-worker
    copy of the reference)."""

    reference: str
    read: Callable[[str], np.ndarray]
    grid: Grid
    settings: DicSettings
    seeds: tuple
    switch_zncc: float
    token: str


def _reference(spec: SequenceSpec) -> ImageRef:
    return per_worker(f"dic2d-ref:{spec.token}", lambda: ImageRef.prepare(spec.read(spec.reference), spec.settings))


def prepare_task(spec: SequenceSpec, path: str) -> tuple[np.ndarray, BSplineImage]:
    """dic2d-prepare: one image and its B-spline."""
    img = spec.read(path)
    return img, BSplineImage.from_image(img, order=spec.settings.order,
                                        prefilter_sigma=spec.settings.prefilter_sigma)


def track_task(spec: SequenceSpec, carry: TrackCarry, image, previous) -> tuple[DicField, TrackCarry]:
    """dic2d-track: one image from the last one's carry (`previous` None: the last image is the reference)."""
    ref = _reference(spec)
    return track_image(ref, ref if previous is None else ImageRef(*previous), *image, spec.grid, carry,
                       spec.settings, seeds=list(spec.seeds), switch_zncc=spec.switch_zncc)


def correlate_sequence_on(client, reference: str, paths: Sequence[str], read: Callable[[str], np.ndarray],
                          grid: Grid, settings: DicSettings = DicSettings(), seeds=(), incremental: bool = False,
                          switch_zncc: float = SWITCH_ZNCC) -> Iterator[DicField]:
    """`correlate_sequence` of the image files `paths` against the image file `reference` on the cluster
    of `client` (module docstring): one DicField per image, in order."""
    reference = os.path.abspath(reference)
    key = pickle.dumps((reference, fingerprint(reference), grid.xs, grid.ys, grid.active, settings))
    spec = SequenceSpec(reference, read, grid, settings, tuple(seed_indices(grid, seeds)), switch_zncc,
                        hashlib.sha1(key).hexdigest()[:16])
    run, window = run_id(), max(2, threads(client))
    images: dict[int, object] = {}
    carry = TrackCarry.initial(grid, incremental)
    for k in range(len(paths)):
        for j in range(k, min(len(paths), k + 1 + window)):
            if j not in images:
                images[j] = submit(client, f"dic2d-prepare-{j}-{run}", prepare_task, spec, os.path.abspath(paths[j]),
                                   priority=PREPARE)
        job = submit(client, f"dic2d-track-{k}-{run}", track_task, spec, carry, images[k], images.get(k - 1),
                     priority=TRACK)
        field, carry = result(job)
        images.pop(k - 1, None)
        yield field
