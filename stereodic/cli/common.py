"""Small helpers shared by the sub-command modules."""

from __future__ import annotations

import argparse
import sys


def planned(sub, name: str, help_text: str, issue: int) -> argparse.ArgumentParser:
    """Register a command of DESIGN.md that this version does not have yet: it says so and exits 1."""
    p = sub.add_parser(name, help=f"{help_text} [not in this version yet]",
                       description=f"{help_text}\n\nNot in this version yet (tracked as issue {issue}).")
    p.add_argument("args", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)

    def run(args) -> int:
        print(f"stereodic {name}: not in this version yet (issue {issue})", file=sys.stderr)
        return 1

    p.set_defaults(func=run)
    return p


def parse_size(text: str) -> tuple[int, int]:
    """'1920x1080' -> (1920, 1080); argparse type."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
        if w <= 0 or h <= 0:
            raise ValueError
        return w, h
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None


def parse_floats(text: str) -> list[float]:
    """'60,360,1920' -> [60.0, 360.0, 1920.0]; argparse type."""
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
