"""Every notebook in notebooks/ runs from top to bottom (small inputs). A notebook that reads data beside
the repository names it in its metadata (`"stereodic": {"needs": ["../shared/data/..."]}`, paths relative
to the repository) and finds it through STEREODIC_REPO, set here, since it runs in a temporary folder."""

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))


def test_there_are_notebooks():
    assert NOTEBOOKS


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_runs(path, tmp_path, monkeypatch):
    nb = nbformat.read(path, as_version=4)
    missing = [n for n in nb.metadata.get("stereodic", {}).get("needs", []) if not (ROOT / n).exists()]
    if missing:
        pytest.skip(f"needs {', '.join(missing)}")
    monkeypatch.setenv("STEREODIC_REPO", str(ROOT))
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors
