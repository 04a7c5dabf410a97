"""The bench's tables: one row per figure, goals met or missed shown as such."""

from stereodic.bench import Figure, format_markdown, format_table


def test_tables_show_every_figure_and_its_verdict():
    figs = [Figure("calib", "ray error | RMS", 0.0147, "px", "OpenCV", 0.0077, "<= 0.02", True),
            Figure("calib", "5 MP time", 10.9, "s", goal="<= 10 s", ok=False),
            Figure("sim", "memory", 709.3, "MiB")]
    md = format_markdown(figs).splitlines()
    assert len(md) == 2 + len(figs)
    assert md[2].count("|") == 8 and "ray error / RMS" in md[2] and "0.0077 px" in md[2] and md[2].endswith("yes |")
    assert md[3].endswith("NO |") and md[4].endswith("|  |")
    txt = format_table(figs).splitlines()
    assert len(txt) == 1 + len(figs) and txt[2].rstrip().endswith("NO")


def test_figures_from_numpy_measurements_serialise():
    import json

    import numpy as np
    f = Figure("rectify", "row error", np.float64(1e-5), "px", "OpenCV", np.float32(0.0076), "<= 0.01",
               np.bool_(True))
    assert json.loads(json.dumps(f.as_dict()))["ok"] is True
