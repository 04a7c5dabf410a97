"""A stereo DIC experiment run through its run folder (`store.RunStore`): the states solved one after the
other (`stereo.solve_state`), each saved as soon as it is done, an interrupted run resumed after its
last finished state, and the combined outputs (CSV, NPZ, VTK, PNG, DICe's files) written at the end
from the state files, one state in memory at a time, the files side by side on every thread
(`stereodic.dic.background`).

Per run the reference pair (state 0) is read and prepared once (on a resumed run too); per state the
next pair is read, rectified and prepared in a worker thread while the current one is solved. Memory
therefore holds the rig, the reference, the previous, current and next pairs and one state's result,
whatever the length of the sequence.
"""

from __future__ import annotations

import contextlib
import functools
import shutil
from pathlib import Path
from typing import Callable, Iterator, Sequence

import numpy as np

from calib.atomic import write_npz as save_npz
from calib.imageio import read_gray
from calib.progress import progress
from stereodic.dic.background import Background, threads
from stereodic.dic.grid import Grid
from stereodic.dic.maps import MapAxes, MapMovie, MapPainter, RunScales, load_matplotlib, surface_axes
from stereodic.dic.sequence import prefetch
from stereodic.dic3d.dataset import DicStates
from stereodic.dic3d.output import (STRAIN_FLOOR, csv_rows, plot_state, state_arrays, state_maps, state_ranges,
                                    write_csv, write_npz)
from stereodic.dic3d.stereo import PreparedPair, StereoRun, StereoSettings, StereoState, solve_state
from stereodic.dic3d.store import RunStore
from stereodic.dic3d.vtk import state_file, write_collection, write_state
from stereodic.stereo.rig import Rig


def prepare_pair(data: DicStates, rig: Rig, settings: StereoSettings, k: int) -> PreparedPair:
    """State k's pair read, rectified and prepared (B-splines) for `solve_state`."""
    return PreparedPair.prepare(*data.rectified_pair(rig, k), settings.dic)


def run_states(store: RunStore, data: DicStates, rig: Rig, grid: Grid, seeds, settings: StereoSettings, *,
               report: Callable[[StereoState], None] = lambda state: None, rows: bool = False,
               vtk: bool = False, ranges: bool = False, background: Background | None = None) -> StereoState:
    """Solve the states the store has not finished (`store.open` first), saving each; `report` is called
    with each state solved (state 0 also when it is read back). `rows`: also keep each solved state's rows
    of dic.csv in the store (`RunStore.write_rows`), `vtk`: its VTK file (`RunStore.write_vtk`), `ranges`:
    its maps' value ranges (`RunStore.write_ranges`), made by a worker process from the state's file while
    the next state is solved (`background`, the command's `stereodic.dic.background.Background`, one made
    here if None; with one thread, by the caller from the state in memory), so that `write_outputs` need
    not read the states back for them nor make them after the run: for outputs in the rig's frame (the
    states as solved). The last state's are left to `write_outputs`, which makes them beside its maps
    rather than after the run. The next state's pair is read and prepared while a state is solved, the
    reference's included. Returns state 0."""
    n = len(data)
    done = store.done
    pair0 = prepare_pair(data, rig, settings, 0)
    run = StereoRun.prepare(rig, grid, settings, seeds, pair0)
    keeping = rows or vtk or ranges
    with _background(background, threads() if keeping and threads() > 1 else 0) as bg:
        def keep(state: StereoState, carry) -> None:
            store.write_state(state, carry)
            if keeping and state.state < n - 1:
                bg.submit(functools.partial(_keep_files, store, grid, _portable(bg, state), rows=rows, vtk=vtk,
                                            ranges=ranges),
                          f"the CSV rows, VTK file and value ranges of state {state.state}", limit=threads() - 1)
            report(state)

        def prepare(k: int) -> PreparedPair:
            if k == 0:
                return pair0
            pair = prepare_pair(data, rig, settings, k)
            if k == 1 and settings.dic.feature_guess:
                # the first deformed state's left registration has no motion before it to start from: its
                # feature matches with the reference, made here beside the reference's correlation
                run.ref.matches(pair.left)
            return pair

        pairs = prefetch(range(done, n), prepare)
        carry = None
        if done:
            state0, carry = store.read_state(0), store.read_carry()
            report(state0)
            run = run.with_reference(state0)
        previous = pair0 if done <= 1 else prepare_pair(data, rig, settings, done - 1)
        for k, pair in progress(pairs, "dic", total=n, initial=done, unit="state"):
            state, carry = solve_state(run, k, pair, carry, previous)
            keep(state, carry)
            if k == 0:
                state0 = state
                run = run.with_reference(state0)
            previous = pair
    return state0


def write_state_files(folder: str | Path, st: StereoState, *, vtk: bool, plot_every: int, axes: MapAxes | None,
                      label: str, **maps) -> None:
    """One state's own outputs: folder/vtk/state{k:03d}.vtp (with `vtk`) and its PNG maps in folder/maps/
    (when it is a `plot_every`-th state; 0 = none) on `axes` (`stereodic.dic.maps.surface_axes` of state
    0's points), titled `label` (its load case); `maps`: `output.plot_state`'s options (run scales, the
    left image, the frame's name, movies)."""
    folder = Path(folder)
    if vtk:
        write_state(folder / "vtk", st)
    if plot_every and st.state % plot_every == 0:
        plot_state(folder / "maps", st, axes, label, **maps)


def _framed_store(store: RunStore, folder: Path, frame: Callable[[StereoState], StereoState]) -> RunStore:
    """A store over folder/.frame/ holding every state of `store` turned by `frame` (the reporting frame:
    `stereodic.dic3d.frame.ReportingFrame`), written one state at a time."""
    n = store.manifest["states"]
    view = RunStore(folder / ".frame")
    view.states_dir.mkdir(parents=True, exist_ok=True)
    view.manifest = {"states": n, "settings": store.manifest["settings"]}
    for st in progress(store.states(), "frame", total=n, unit="state"):
        save_npz(view.state_path(st.state), **state_arrays(frame(st)))
    return view


def write_outputs(store: RunStore, grid: Grid, folder: str | Path, settings: StereoSettings, info: dict, *,
                  vtk: bool = True, plot_every: int = 0, dice: Callable[[StereoState], None] | None = None,
                  csv: bool = True, state_files: bool = True, labels: list[str] | None = None,
                  frame: Callable[[StereoState], StereoState] | None = None,
                  left_images: Sequence[str] | None = None, frame_name: str = "rig's frame",
                  animate: tuple[str, ...] = (), limits: dict[str, tuple[float, float]] | None = None,
                  background: Background | None = None) -> None:
    """The combined outputs from the store's state files (module docstring): folder/dic.csv (unless
    `dice` writes DICe's files instead, or not `csv`), folder/dic.npz, folder/vtk/ (with `vtk`),
    folder/maps/ (every `plot_every`-th state, 0 = none; titled by `labels`, one per state, default
    "state k"). Not `state_files`: each state's VTK file was written already (`write_state_files`, by a
    cluster's tasks); the rest is written here, the maps always (they need the whole run's scales). `frame`: every state turned
    into another reporting frame first (the specimen's), its VTK files and maps written here, titled
    `frame_name`. The maps written here share the run's colour scales (`stereodic.dic.maps.RunScales`),
    and are also drawn over the state's original left image, the file `left_images[k]`, when they are
    given; `animate`:
    the quantities (those of `output.state_maps`) whose maps also make folder/maps/<quantity>.mp4;
    `limits`: quantity -> (lo, hi), colour limits given instead of the run's.
    `info["frame"]["rigid_motion_removed"]`: the states carry their deformation (dic.csv's dX_def...).
    The files are written side by side by the worker processes of `background` (the command's
    `stereodic.dic.background.Background`; one made here if None), the caller handing out the tasks."""
    folder = Path(folder)
    options = dict(vtk=vtk, plot_every=plot_every, dice=dice, csv=csv, labels=labels, left_images=left_images,
                   frame_name=frame_name, animate=animate, limits=limits, background=background)
    if frame is None:
        _write_outputs(store, grid, folder, settings, info, state_files=state_files, **options)
    else:
        view = _framed_store(store, folder, frame)
        try:
            _write_outputs(view, grid, folder, settings, info, state_files=True, **options)
        finally:
            shutil.rmtree(folder / ".frame", ignore_errors=True)
    store.remove_kept()               # written, or (kept in the rig's frame) not these


def _run_scales(store: RunStore, every: int, active, limits: dict | None = None,
                each: Callable[[int, Callable[[], StereoState]], None] | None = None) -> RunScales:
    """The colour scales of the maps of every `every`-th state (`limits`: those given), from the value
    ranges the run kept (`RunStore.read_ranges`), else from the state read here; `each(k, state)` is
    called for every state k with a callable that reads it (once: a task that may need the states anyway)."""
    scales = RunScales(given=limits, floor={c: STRAIN_FLOOR for c in ("exx", "eyy", "exy")})
    for k in range(store.manifest["states"]):
        state = functools.cache(functools.partial(store.read_state, k))
        if each is not None:
            each(k, state)
        if k % every == 0:
            ranges = store.read_ranges(k)
            for name, lo_hi in (state_ranges(state(), active) if ranges is None else ranges).items():
                scales.add_range(name, lo_hi, signed=name != "Z")
    return scales


def _write_outputs(store: RunStore, grid: Grid, folder: Path, settings: StereoSettings, info: dict, *,
                   vtk: bool, plot_every: int, dice, csv: bool, state_files: bool, labels, left_images, frame_name,
                   animate, limits, background: Background | None) -> None:
    n = store.manifest["states"]
    has_strain = bool(settings.strain_window)
    has_def = bool(info.get("frame", {}).get("rigid_motion_removed"))
    # the files are independent: written side by side by threads() worker processes, the caller handing
    # out the tasks (with one thread, the caller writes them)
    with _background(background, threads() if threads() > 1 else 0,
                     prepare=load_matplotlib if plot_every else None) as bg:
        # dic.csv: each state's rows as the run or a cluster's task kept them, or formatted here; beside
        # workers, one task a state (kept in the store, joined below while the maps are drawn), but for the
        # last state without them, whose rows the join formats itself rather than wait (a run's last state)
        missing = [k for k in range(n if csv and bg.workers else 0) if not store.rows_path(k).is_file()]
        rows = [bg.submit(functools.partial(_keep_rows, store, grid, k), f"the CSV rows of state {k}")
                for k in missing[:-1]]
        bg.submit(functools.partial(write_npz, folder / "dic.npz", grid, store.values, n, has_strain, settings,
                                    info, has_def), "dic.npz")
        vtk_here = vtk and state_files        # a cluster's tasks wrote the VTK files; the maps are drawn here

        def write_vtk(k: int, state: Callable[[], StereoState]) -> None:   # moved from the store where the run
            if not store.take_vtk(k, folder / "vtk" / state_file(k)):          # kept it, else made
                bg.submit(functools.partial(_write_vtk, store, folder / "vtk", k if bg.workers else state()),
                          f"the VTK file of state {k}")

        if vtk_here or plot_every or dice is not None:
            axes = None
            maps = {}
            if plot_every:
                # the VTK files written while the states are read for the maps' scales: the workers busy
                # while the caller reads, the long tasks (the maps) handed out together after
                maps = dict(scales=_run_scales(store, plot_every, grid.active, limits,
                                               each=write_vtk if vtk_here else None),
                            frame=frame_name, movies={q: MapMovie(folder / "maps" / f"{q}.mp4") for q in animate})
            drawn = list(range(0, n, plot_every)) if plot_every else []
            # many states' maps in the workers: blocks of states, each drawn by one worker (its painter)
            blocks = bool(drawn) and not maps["movies"] and 0 < bg.workers <= len(drawn)
            if blocks:
                axes = surface_axes(grid.xs, grid.ys, store.read_state(0).points, grid.active)
                for part in _state_blocks(drawn, bg.workers):
                    bg.submit(functools.partial(_draw_block, store, folder / "maps", part, axes, labels, left_images,
                                                **maps), f"the maps of states {part[0]}..{part[-1]}")
            # every state when each needs something here (DICe's files, VTK files without maps), else the
            # states whose maps are handed out here, one by one (the scales' pass read them all already)
            every = plot_every if plot_every and dice is None else 1
            reads = range(0, n, every) if dice is not None or not blocks else range(0)
            try:
                for st in progress((store.read_state(k) for k in reads), "writing", total=len(reads), unit="state"):
                    if axes is None and plot_every:  # state 0: the reference surface gives every map its mm axes
                        axes = surface_axes(grid.xs, grid.ys, st.points, grid.active)
                    if plot_every and st.state % plot_every == 0 and not blocks:
                        if maps["movies"]:      # a movie takes its frames in order, in this process
                            _draw_block(store, folder / "maps", [st], axes, labels, left_images, **maps)
                        else:                   # in the workers (`stereodic.dic.maps.load_matplotlib`)
                            for part in _map_parts(list(state_maps(st)), bg.workers, len(drawn)):
                                bg.submit(functools.partial(_draw_block, store, folder / "maps",
                                                            [_portable(bg, st)], axes, labels, left_images,
                                                            names=part, **maps),
                                          f"the maps of state {st.state} ({', '.join(part)})")
                    if vtk_here and not plot_every:
                        write_vtk(st.state, lambda st=st: st)
                    if dice is not None:
                        dice(st)
            finally:
                for movie in maps.get("movies", {}).values():
                    movie.close()
        if csv:           # here, while the workers draw the maps: once the rows of every state are formatted
            bg.wait_for(rows)
            write_csv(folder / "dic.csv", (store.read_rows(k) or csv_rows(grid, store.read_state(k)) for k in range(n)),
                      has_strain=has_strain, has_deformation=has_def)
    if vtk:
        write_collection(folder / "vtk", range(n))


def _draw_block(store: RunStore, folder: Path, states: list[int | StereoState], axes: MapAxes,
                labels: list[str] | None, left_images: Sequence[str] | None, **options) -> None:
    """`output.plot_state` of each of `states` (a state number, read from the store here, in the task
    that draws it; or the state), titled by `labels` (default "state k"), over its original left image
    (the file `left_images[k]`, read here) when they are given; `options`: `plot_state`'s, drawn with this
    process's painter (`_painter`: its figures, fonts and drawn axes serve every map the process draws) on
    this process's copy of `axes` (`_run_axes`)."""
    axes = _run_axes(axes)
    for st in states:
        st = _state_of(store, st)
        k = st.state
        plot_state(folder, st, axes, labels[k] if labels else f"state {k}",
                   image=None if left_images is None else read_gray(left_images[k]), painter=_painter(), **options)


@functools.cache
def _painter() -> MapPainter:
    """This process's MapPainter (made on first use: a worker's lives from task to task)."""
    return MapPainter()


_AXES: list[MapAxes] = []     # this process's copy of the last run's axes


def _run_axes(axes: MapAxes) -> MapAxes:
    """This process's copy of `axes` (by its token): the first it was given, which keeps its raster cells
    and is the axes whose drawn background the painter keeps (`MapPainter.draw`), for every later task of
    the run: each task unpickles a new copy, on which the painter drew the axes again (0.15 s)."""
    if not _AXES or _AXES[0].token != axes.token:
        _AXES[:] = [axes]
    return _AXES[0]


def _portable(bg: Background, state: StereoState) -> int | StereoState:
    """What a task of `bg` is given of a state: its number (a worker reads the state's file: `_state_of`),
    or the state itself in memory when the caller runs the tasks (0 workers)."""
    return state.state if bg.workers else state


def _state_of(store: RunStore, state: int | StereoState) -> StereoState:
    """The state: read from the store when given by its number."""
    return store.read_state(state) if isinstance(state, int) else state


@contextlib.contextmanager
def _background(given: Background | None, workers: int, *,
                prepare: Callable[[], None] | None = None) -> Iterator[Background]:
    """`given`, its tasks waited for after the block (the workers left running for its owner), else a
    Background of `workers` (`prepare`: its workers' start) made for the block and ended after it."""
    if given is None:
        with Background(workers, prepare=prepare) as bg:
            yield bg
    else:
        yield given
        given.wait()


def _write_vtk(store: RunStore, folder: Path, state: int | StereoState) -> None:
    """The VTK file of a state (its number, read from the store, or the state) in `folder`."""
    write_state(folder, _state_of(store, state))


def _state_blocks(states: list[int], workers: int) -> list[list[int]]:
    """The states to draw split into blocks of consecutive states for `workers` worker processes (at
    least as many states as workers): two blocks a worker, so that a task draws its states' axes once
    (`MapPainter`) and the blocks still even out."""
    return [b.tolist() for b in np.array_split(np.array(states), min(len(states), 2 * workers))]


def _map_parts(names: list[str], workers: int, states: int) -> list[list[str]]:
    """A state's map quantities `names` split into tasks when the run has fewer states to draw than
    `workers` (worker processes): each state's maps shared among its share of the workers (a task pays once
    for reading the state and its picture over the image: not one a map); one task a state otherwise."""
    parts = max(1, min(len(names), workers // max(states, 1)))
    return [list(part) for part in np.array_split(np.array(names, dtype=object), parts)]


def _keep_files(store: RunStore, grid: Grid, state: int | StereoState, *, rows: bool, vtk: bool,
                ranges: bool) -> None:
    """Keep a solved state's (its number, read from the store, or the state) rows of dic.csv (with
    `rows`), its VTK file (with `vtk`) and its maps' value ranges (with `ranges`) in the store."""
    state = _state_of(store, state)
    if rows:
        _keep_rows(store, grid, state)
    if vtk:
        store.write_vtk(state)
    if ranges:
        store.write_ranges(state.state, state_ranges(state, grid.active))


def _keep_rows(store: RunStore, grid: Grid, state: int | StereoState) -> None:
    """Format a state's (its number, read from the store, or the state) rows of dic.csv and keep them in
    the store (`RunStore.write_rows`)."""
    state = _state_of(store, state)
    store.write_rows(state.state, csv_rows(grid, state))
