"""`stereodic demo`: the end-to-end run on the built-in simulated rig, no hardware needed."""

from __future__ import annotations


def register(sub):
    p = sub.add_parser("demo", help="end-to-end run on the built-in simulated rig, no hardware",
                       description="Simulate a calibration bench, calibrate, and show the results.")
    p.add_argument("-o", "--output", default="demo-out", help="output folder (default: demo-out)")
    p.set_defaults(func=run)


def run(args) -> int:
    from stereodic.demo import run_demo
    return run_demo(args.output)
