"""One spelling of every option across the commands (stereodic.cli.common.SPELLINGS), checked by walking
every sub-parser of `stereodic.cli`."""

import argparse
from collections import defaultdict

from stereodic.cli import build_parser
from stereodic.cli.common import SPELLINGS, SYNONYMS


def _parsers(parser, path=()):
    """(command path, parser) of every sub-parser, depth first."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, path + (name,))
    if path:
        yield " ".join(path), parser


def _options():
    """(command, dest, option strings) of every optional argument of every command."""
    for command, parser in _parsers(build_parser()):
        for action in parser._actions:
            if action.option_strings and not isinstance(action, argparse._HelpAction):
                yield command, action.dest, tuple(action.option_strings)


def test_the_walk_sees_every_command():
    commands = {c for c, _ in _parsers(build_parser())}
    assert {"dic2d", "simulate calibration", "simulate dic", "acquire calibration", "rectify", "export"} <= commands


def test_common_options_have_their_one_spelling():
    wrong = [(c, d, o) for c, d, o in _options() if d in SPELLINGS and not set(o) <= set(SPELLINGS[d])]
    assert not wrong, f"options spelled otherwise than stereodic.cli.common.SPELLINGS: {wrong}"


def test_no_second_spelling_of_a_meaning():
    found = [(c, o) for c, _, opts in _options() for o in opts if o in SYNONYMS]
    assert not found, f"second spellings (use the one in SPELLINGS): {found}"


def test_one_option_string_means_one_thing_and_one_thing_has_one_spelling():
    dests_of = defaultdict(set)        # option string -> dests
    spellings_of = defaultdict(set)    # dest -> {command: its option strings}
    per_command = defaultdict(set)
    for command, dest, opts in _options():
        for o in opts:
            dests_of[o].add(dest)
        per_command[(dest, command)] |= set(opts)
    for (dest, command), opts in per_command.items():
        spellings_of[dest].add(frozenset(opts))
    assert not {o: d for o, d in dests_of.items() if len(d) > 1}
    assert not {d: s for d, s in spellings_of.items() if len(s) > 1}


def test_every_command_that_writes_spells_it_o_output():
    for command, parser in _parsers(build_parser()):
        for p in parser.get_default("_paths") or []:
            if p.output and p.dest == "output":
                assert p.name == "-o/--output", command
    outputs = {c for c, d, o in _options() if d == "output"}
    assert {"dic2d", "dic", "rectify", "export", "scan", "undistort", "rig", "show", "calibrate", "patterns",
            "demo", "simulate calibration", "acquire dic"} <= outputs
