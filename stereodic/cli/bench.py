"""`stereodic bench`: measure speed, memory and accuracy; print a table (or JSON)."""

from __future__ import annotations

import json
import os
import platform


def register(sub):
    from stereodic.bench import GROUPS
    p = sub.add_parser("bench", help="speed, memory and accuracy figures beside their references",
                       description="Run the benchmarks and print each figure beside its reference.")
    p.add_argument("group", nargs="?", default="all", choices=GROUPS + ["all"], metavar="GROUP",
                   help=f"the group to run: {', '.join(GROUPS)} or all (default all)")
    out = p.add_mutually_exclusive_group()
    out.add_argument("--json", action="store_true", help="print JSON instead of a table")
    out.add_argument("--markdown", action="store_true", help="print a Markdown table (as in docs/figures.md)")
    p.add_argument("--quick", action="store_true", help="smaller inputs (for a smoke test)")
    p.set_defaults(func=run)


def run(args) -> int:
    from stereodic.bench import GROUPS, format_markdown, format_table, run_groups
    names = GROUPS if args.group == "all" else [args.group]
    figures = run_groups(names, quick=args.quick)
    machine = {"cpus": os.cpu_count(), "machine": platform.machine(), "python": platform.python_version()}
    if args.json:
        print(json.dumps({"machine": machine, "figures": [f.as_dict() for f in figures]}, indent=1))
    elif args.markdown:
        print(f"{machine['cpus']} cores, {machine['machine']}, Python {machine['python']}\n")
        print(format_markdown(figures))
    else:
        print(f"# {machine['cpus']} cores, {machine['machine']}, Python {machine['python']}")
        print(format_table(figures))
    return 0
