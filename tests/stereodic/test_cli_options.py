"""One spelling of every option across the commands (stereodic.cli.common.SPELLINGS), checked by walking
every sub-parser of `stereodic.cli`."""

import argparse
from collections import defaultdict

from stereodic.cli import build_parser
from stereodic.cli.common import DEPRECATED, SPELLINGS, SYNONYMS


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
            if action.option_strings and not isinstance(action, argparse._HelpAction) and not _deprecated(action):
                yield command, action.dest, tuple(action.option_strings)


def _deprecated(action) -> bool:
    """An earlier spelling kept for a release (stereodic.cli.common.deprecated)."""
    return type(action).__name__.startswith("Deprecated")


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


def _deprecated_aliases():
    """(command, parser, old spelling, the action it aliases) of every earlier spelling still accepted."""
    for command, parser in _parsers(build_parser()):
        for action in parser._actions:
            if _deprecated(action):
                (old,) = action.option_strings
                now = [a for a in parser._actions if a.dest == action.dest and a is not action]
                yield command, parser, old, now


def test_each_earlier_spelling_is_listed_and_aliases_a_visible_option():
    seen = set()
    for command, _, old, now in _deprecated_aliases():
        seen.add(old)
        assert old in DEPRECATED, (command, old)
        assert len(now) == 1 and now[0].help != argparse.SUPPRESS, (command, old)
        assert old not in now[0].option_strings
    assert seen == set(DEPRECATED)


def test_an_earlier_spelling_still_works_with_a_note(capsys):
    from stereodic.cli import main
    # the strain window, spelt as before, on a saved result that is not there: the note, then the refusal
    parser = build_parser("strain")
    args = parser.parse_args(["strain", "r.npz", "--window", "9", "-o", "out"])
    assert args.strain_window == 9
    assert "--window is deprecated, use --strain-window" in capsys.readouterr().err
    args = parser.parse_args(["strain", "r.npz", "--strain-window", "7", "-o", "out"])
    assert args.strain_window == 7 and capsys.readouterr().err == ""
    assert main(["rig", "l.npz", "r.npz", "--size", "64x48", "-o", "rig.npz"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "stereodic: note: --size is deprecated, use --virtual-size"
    assert err[1].startswith("stereodic: l.npz")


def test_no_option_spelling_means_two_things():
    """One idea, one spelling: the same option string names the same value (its dest) in every
    command; `--seed` is a random seed and `--start-point` a DIC start point, `--strain-window` the strain
    window and `--regularise-window` the calibration's, `--size` the camera's image size and
    `--virtual-size` the virtual one, the pitches say whose they are."""
    dests = defaultdict(set)
    for _, dest, opts in _options():
        for o in opts:
            dests[o].add(dest)
    assert {o: d for o, d in dests.items() if len(d) > 1} == {}
    assert dests["--seed"] == {"seed"} and dests["--start-point"] == {"start_point"}
    assert dests["--size"] == {"size"} and dests["--virtual-size"] == {"virtual_size"}
    # earlier spellings live on only as hidden aliases (--seed and --size keep their one meaning elsewhere)
    assert (set(DEPRECATED) - {"--seed", "--size"}).isdisjoint(dests)


def test_help_fits_80_columns(monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    too_wide = [(command, line) for command, parser in _parsers(build_parser())
                for line in parser.format_help().splitlines() if len(line) > 80]
    assert too_wide == []
    monkeypatch.setenv("COLUMNS", "120")                  # and it uses a wider terminal
    scan = dict(_parsers(build_parser("scan")))["scan"]
    assert max(len(line) for line in scan.format_help().splitlines()) > 90
