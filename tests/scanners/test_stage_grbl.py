"""The GRBL 1.1 driver against its emulator, through pyserial over a real pty or a TCP socket."""

import time
from dataclasses import replace

import pytest

from scanners.errors import HardwareError
from scanners.stage_url import open_stage
from scanners.stage_grbl import GrblStatus, parse_status

FAST = "speed=5000&feed=300000&retries=2"


@pytest.fixture(params=["pty", "socket"])
def stage(request):
    st = open_stage(f"emulated:grbl?{FAST}&transport={request.param}")
    yield st
    st.close()


def wire(st) -> bytes:
    return bytes(st.emulator.wire_in)


@pytest.mark.parametrize("line, want", [
    ("<Idle|MPos:0.000,0.000,12.500|FS:0,0>", GrblStatus("Idle", (0.0, 0.0, 12.5), True)),
    ("<Run|WPos:1.000,2.000,3.000|FS:500,0>", GrblStatus("Run", (1.0, 2.0, 3.0), False)),
    ("<Hold:0|MPos:5.000,0.000,0.000|FS:0,0|WCO:1.000,0.000,0.000>",
     GrblStatus("Hold", (5.0, 0.0, 0.0), True, (1.0, 0.0, 0.0))),
    ("ok", None), ("ALARM:1", None),
])
def test_parse_status(line, want):
    assert parse_status(line) == want


@pytest.mark.parametrize("line", ["<Idle|FS:0,0>", "<Idle|MPos:a,b,c>", "<|MPos:0,0,0>"])
def test_garbled_status(line):
    with pytest.raises(ValueError, match="garbled"):
        parse_status(line)


def test_connect_resets_homes_and_selects_mm(stage):
    # soft reset, status (Alarm after power-up: homing required), home, mm + absolute
    assert wire(stage) == b"\x18?$H\nG21 G90\n"
    assert stage.emulator.true_position_mm() == 0.0
    assert stage.emulator.state == "Idle"


def test_move_bytes_and_position(stage):
    n = len(wire(stage))
    assert stage.move_to(50.0) == pytest.approx(50.0)
    assert wire(stage)[n:] == b"G90 G1 X50.0000 F300000\nG4 P0\n?"
    assert stage.emulator.true_position_mm() == 50.0
    assert stage.position_mm() == 50.0


def test_other_axis_and_feed():
    with open_stage("emulated:grbl?speed=5000&feed=123456&axis=Z") as st:
        n = len(wire(st))
        st.move_to(7.25)
        assert wire(st)[n:] == b"G90 G1 Z7.2500 F123456\nG4 P0\n?"


def test_waits_for_the_motion_to_end():
    with open_stage("emulated:grbl?speed=100&feed=6000&timeout=0.5") as st:   # 100 mm/s
        t0 = time.monotonic()
        st.move_to(20.0)
        assert time.monotonic() - t0 >= 0.19
        assert st.emulator.true_position_mm() == 20.0
        assert st.emulator.motion.busy(time.monotonic()) is False


def test_lost_ok_is_retried(stage):
    stage.options = replace(stage.options, timeout_s=0.2)
    stage.emulator.inject("timeout", count=1)
    n = len(wire(stage))
    stage.move_to(30.0)
    assert wire(stage)[n:] == b"G90 G1 X30.0000 F300000\nG90 G1 X30.0000 F300000\nG4 P0\n?"
    assert stage.emulator.true_position_mm() == 30.0


def test_controller_that_stops_answering(stage):
    stage.options = replace(stage.options, timeout_s=0.2)
    stage.emulator.inject("timeout", count=1000)
    with pytest.raises(HardwareError, match=r"no answer to 'G90 G1 X30.0000 F300000' within 0.2 s \(3 tries\)"):
        stage.move_to(30.0)


def test_error_reply(stage):
    stage.emulator.inject("reject")
    with pytest.raises(HardwareError, match=r"rejected 'G90 G1 X30.0000 F300000': error:20 \(unsupported"):
        stage.move_to(30.0)


def test_alarm_during_a_move(stage):
    stage.emulator.inject("alarm")
    with pytest.raises(HardwareError, match=r"ALARM:1 \(hard limit triggered\)"):
        stage.move_to(40.0)
    assert stage.emulator.true_position_mm() == 20.0
    assert stage.emulator.state == "Alarm"


def test_soft_limit_alarm(stage):
    with pytest.raises(HardwareError, match=r"ALARM:2 \(soft limit"):
        stage.move_to(400.0)


def test_dropped_line(stage):
    stage.emulator.inject("drop")
    with pytest.raises(HardwareError, match="lost the connection"):
        stage.move_to(30.0)


def test_locked_controller_without_homing():
    with pytest.raises(HardwareError, match=r"in alarm; home it"):
        open_stage(f"emulated:grbl?{FAST}&home=no")
