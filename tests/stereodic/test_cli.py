"""The command line skeleton: every command of DESIGN.md has --help; exit statuses 0/1/2."""

import subprocess
import sys

import pytest

from stereodic.cli import COMMANDS, main

DESIGN_COMMANDS = ["demo", "simulate", "patterns", "calibrate", "undistort", "rig", "rectify", "scan",
                   "dic2d", "dic", "strain", "gauge", "speckle", "import", "export", "bench", "acquire", "show"]


def test_all_design_commands_exist():
    assert set(DESIGN_COMMANDS) <= set(COMMANDS)


@pytest.mark.parametrize("cmd", DESIGN_COMMANDS)
def test_help_on_every_command(cmd, capsys):
    with pytest.raises(SystemExit) as e:
        main([cmd, "--help"])
    assert e.value.code == 0
    assert cmd in capsys.readouterr().out


def test_bad_usage_exits_2(capsys):
    with pytest.raises(SystemExit) as e:
        main(["no-such-command"])
    assert e.value.code == 2


def test_console_script_runs():
    out = subprocess.run([sys.executable, "-m", "stereodic", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.startswith("stereodic ")


def test_the_parsers_defaults_are_the_librarys():
    """cli.common repeats two library constants so that --help imports nothing heavy."""
    from stereodic.cli import common
    from stereodic.dic.sequence import SWITCH_ZNCC
    from stereodic.strain.measures import MEASURES
    assert common.SWITCH_ZNCC == SWITCH_ZNCC and common.STRAIN_MEASURES == MEASURES


def test_the_process_command_freezes_its_objects_for_the_shutdown_and_a_caller_keeps_its_collector(monkeypatch):
    """`main()` (the process's own command) leaves its objects frozen for the interpreter's shutdown; a
    caller that gives the arguments (a test, a notebook) keeps its garbage collector as it was."""
    import gc
    gc.unfreeze()
    with pytest.raises(SystemExit):
        main(["--version"])
    assert gc.get_freeze_count() == 0
    monkeypatch.setattr(sys, "argv", ["stereodic", "--version"])
    try:
        with pytest.raises(SystemExit):
            main()
        assert gc.get_freeze_count() > 1000
    finally:
        gc.unfreeze()
