"""PNG pictures of gauges over a test (matplotlib, atomic): extensometers.png (strain against state or
time), points.png and areas.png (displacements and strains against state or time, an area's mean with
its +-1 standard deviation band), lines.png (profiles along each line, one curve per profiled state),
stress_strain.png (with the fitted modulus). Titles name the frame; axes their units."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from calib.atomic import atomic_output
from stereodic.gauge.gauges import GaugeTables


def _frame_words(frame: dict) -> str:
    name = frame.get("frame", "rig")
    words = {"rig": "rig's world frame", "specimen": "specimen's frame", "image": "reference image"}[name]
    if frame.get("rigid_motion_removed"):
        words += ", rigid motion removed"
    return words


def _save(fig, path: Path) -> None:
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=100)


def _x(tables: GaugeTables, times_s):
    S = len(tables.labels)
    return (np.arange(S), "state") if times_s is None else (np.asarray(times_s), "time (s)")


def _displacements(tables: GaugeTables) -> list[str]:
    return [q for q in ("dX", "dY", "dZ", "dX_def", "dY_def", "dZ_def", "u", "v") if q in tables.units
            and not (q in ("u", "v") and "dX" in tables.units)]


def plot_extensometers(path: str | os.PathLike, tables: GaugeTables, times_s=None) -> None:
    """extensometers.png: each extensometer's engineering strain (microstrain) against state or time."""
    from matplotlib.figure import Figure
    fig = Figure(figsize=(7.2, 4.4), layout="constrained")
    ax = fig.subplots()
    x, xl = _x(tables, times_s)
    for e in tables.extensometers:
        L0 = e.length[0]
        ax.plot(x, e.strain * 1e6, ".-", label=f"{e.gauge.name} (L0 {L0:.4g} {tables.unit})")
    ax.set_xlabel(xl)
    ax.set_ylabel("engineering strain dL/L0 (microstrain)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"virtual extensometers - {_frame_words(tables.frame)}", fontsize=10)
    _save(fig, Path(path))


def _history(path: Path, tables: GaugeTables, series, title: str, times_s, band: bool) -> None:
    from matplotlib.figure import Figure
    fig = Figure(figsize=(9.0, 6.4), layout="constrained")
    ax_d, ax_e = fig.subplots(2, 1, sharex=True)
    x, xl = _x(tables, times_s)
    disp = _displacements(tables)
    for name, mean, std in series:
        for q in disp:
            line, = ax_d.plot(x, mean[q], ".-", label=f"{name} {q}")
            if band and std is not None:
                ax_d.fill_between(x, mean[q] - std[q], mean[q] + std[q], color=line.get_color(), alpha=0.15)
        for q in ("exx", "eyy", "exy"):
            line, = ax_e.plot(x, mean[q] * 1e6, ".-", label=f"{name} {q}")
            if band and std is not None:
                ax_e.fill_between(x, (mean[q] - std[q]) * 1e6, (mean[q] + std[q]) * 1e6, color=line.get_color(),
                                  alpha=0.15)
    unit = tables.units[disp[0]] if disp else ""
    ax_d.set_ylabel(f"displacement ({unit})")
    ax_e.set_ylabel("strain (microstrain)")
    ax_e.set_xlabel(xl)
    for ax in (ax_d, ax_e):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=3)
    ax_d.set_title(f"{title} - {_frame_words(tables.frame)}", fontsize=10)
    _save(fig, path)


def plot_points(path: str | os.PathLike, tables: GaugeTables, times_s=None) -> None:
    """points.png: each point's displacements and strains against state or time."""
    _history(Path(path), tables, [(s.gauge.name, s.values, None) for s in tables.points], "points", times_s, False)


def plot_areas(path: str | os.PathLike, tables: GaugeTables, times_s=None) -> None:
    """areas.png: each area's mean displacements and strains, +-1 standard deviation shaded."""
    _history(Path(path), tables, [(a.gauge.name, a.mean, a.std) for a in tables.areas],
             "areas (mean, +-1 std shaded)", times_s, True)


def plot_lines(path: str | os.PathLike, tables: GaugeTables) -> None:
    """lines.png: per line, the out-of-plane (or first) displacement and exx along it, a curve per state."""
    from matplotlib.figure import Figure
    n = len(tables.lines)
    fig = Figure(figsize=(9.0, 3.2 * n + 0.6), layout="constrained")
    axes = np.atleast_2d(fig.subplots(n, 2, squeeze=False))
    disp = _displacements(tables)
    dq = "dZ_def" if "dZ_def" in disp else "dZ" if "dZ" in disp else disp[0]
    for (ax_d, ax_e), ln in zip(axes, tables.lines):
        for r, k in enumerate(ln.states):
            ax_d.plot(ln.distance, ln.values[dq][r], label=tables.labels[k])
            ax_e.plot(ln.distance, ln.values["exx"][r] * 1e6, label=tables.labels[k])
        ax_d.set_ylabel(f"{dq} ({tables.units[dq]})")
        ax_e.set_ylabel("exx (microstrain)")
        for ax in (ax_d, ax_e):
            ax.set_xlabel(f"distance along {ln.gauge.name} ({tables.unit})")
            ax.grid(alpha=0.3)
        ax_d.legend(fontsize=7)
        ax_d.set_title(f"line {ln.gauge.name} - {_frame_words(tables.frame)}", fontsize=10)
    _save(fig, Path(path))


def plot_stress_strain(path: str | os.PathLike, strain, stress_mpa, *, true_mpa=None, modulus_mpa=None,
                       intercept_mpa=0.0, source: str = "") -> None:
    """stress_strain.png: engineering (and true) stress, MPa, against strain (percent), with the fitted
    modulus's line."""
    from matplotlib.figure import Figure
    fig = Figure(figsize=(7.2, 5.0), layout="constrained")
    ax = fig.subplots()
    e = np.asarray(strain) * 100
    ax.plot(e, stress_mpa, ".-", label="engineering stress")
    if true_mpa is not None:
        ax.plot(e, true_mpa, ".--", label="true stress")
    title = f"stress-strain, strain of {source}"
    if modulus_mpa is not None and np.isfinite(modulus_mpa):
        ax.plot(e, intercept_mpa + modulus_mpa * np.asarray(strain), ":", color="grey",
                label=f"modulus {modulus_mpa / 1000:.4g} GPa")
        title += f": E = {modulus_mpa / 1000:.4g} GPa"
    ax.set_xlabel("strain (%)")
    ax.set_ylabel("stress (MPa)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title, fontsize=10)
    _save(fig, Path(path))


