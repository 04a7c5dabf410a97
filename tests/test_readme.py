"""The README stays a page a newcomer reads: under 250 lines, every headline figure beside the command that
gives it, and the demo's figures as the demo prints them (the demo is run here)."""

import re
from pathlib import Path

from stereodic.cli import main

README = Path(__file__).resolve().parents[1] / "README.md"


def _text() -> str:
    return README.read_text()


def test_readme_fits_on_a_screen_or_two():
    assert len(_text().splitlines()) < 250


def test_every_headline_figure_names_its_command():
    text = _text()
    table = text[text.index("## Headline figures"):]
    table = table[:table.index("\n## ", 1)]
    rows = [r for r in table.splitlines() if r.startswith("| ") and not r.startswith("| what")]
    assert len(rows) >= 10
    groups = {"sim", "calib", "rectify", "scan", "dic", "align", "startup", "cluster"}
    root = README.parent
    for row in rows:
        source = row.strip("| ").split(" | ")[-1].strip("`")
        if source.startswith("bench "):
            assert source.split()[1] in groups, row
        else:
            assert (root / source).is_file(), row


def _quoted_demo_lines() -> list[str]:
    text = _text()
    block = re.search(r"demo prints its error against the truth.*?```text\n(.*?)```", text, re.S)
    assert block, "README: the demo's figures block is missing"
    return [line for line in block.group(1).splitlines() if line.strip()]


def test_the_readme_quotes_what_the_demo_prints(tmp_path, capsys):
    quoted = _quoted_demo_lines()
    assert len(quoted) >= 4
    assert main(["demo", "-o", str(tmp_path / "demo")]) == 0
    printed = set(capsys.readouterr().out.splitlines())
    assert [line for line in quoted if line not in printed] == []
