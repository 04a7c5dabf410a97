"""The Zaber ASCII driver against its emulator, through pyserial over a real pty or a TCP socket."""

import re
import time
from dataclasses import replace

import pytest

from scanners.errors import HardwareError
from scanners.stage_url import open_stage
from scanners.stage_zaber import ZaberReply, parse_reply

FAST = "speed=5000&retries=2"


@pytest.fixture(params=["pty", "socket"])
def stage(request):
    st = open_stage(f"emulated:zaber?{FAST}&transport={request.param}")
    yield st
    st.close()


def sent(st) -> list[str]:
    return bytes(st.emulator.wire_in).decode().splitlines()


@pytest.mark.parametrize("line, want", [
    ("@01 1 07 OK BUSY -- 0", ZaberReply(1, 1, 7, True, True, "--", "0")),
    ("@02 1 OK IDLE WR 1049869", ZaberReply(2, 1, None, True, False, "WR", "1049869")),
    ("@01 1 12 RJ IDLE -- BADDATA", ZaberReply(1, 1, 12, False, False, "--", "BADDATA")),
    ("@01 1 03 OK IDLE FS 0:5A", ZaberReply(1, 1, 3, True, False, "FS", "0")),
    ("@01 0 OK IDLE -- 02 FS WR\r", ZaberReply(1, 0, None, True, False, "--", "02 FS WR")),
])
def test_parse_reply(line, want):
    assert parse_reply(line) == want


@pytest.mark.parametrize("line", ["#01 1 info", "!01 1 IDLE --", ""])
def test_other_messages_are_not_replies(line):
    assert parse_reply(line) is None


@pytest.mark.parametrize("line", ["@01 1 OK", "@01 x OK IDLE -- 0", "@01 1 MAYBE IDLE -- 0"])
def test_garbled_reply(line):
    with pytest.raises(ValueError, match="garbled"):
        parse_reply(line)


def test_connect_homes_a_stage_without_reference(stage):
    lines = sent(stage)
    assert lines[0] == "/1 1 0"                 # status query first
    assert lines[1] == "/1 1 1 home"            # WR in the answer -> home
    assert "WR" in bytes(stage.emulator.wire_out).decode().splitlines()[0].split()
    assert stage.emulator.true_position_mm() == 0.0
    assert "WR" not in stage.emulator.flags


def test_move_converts_mm_to_microsteps(stage):
    before = len(sent(stage))
    assert stage.move_to(50.0) == pytest.approx(50.0, abs=0.047625e-3)
    cmd = sent(stage)[before]
    assert re.fullmatch(r"/1 1 \d+ move abs 1049869", cmd)   # 50 mm / 0.047625 um, rounded
    assert stage.emulator.true_position_mm() == pytest.approx(1049869 * 0.047625e-3)
    assert stage.position_mm() == pytest.approx(50.0, abs=0.047625e-3)


def test_other_microstep_size():
    with open_stage(f"emulated:zaber?{FAST}&microstep_um=0.1&device=3") as st:
        st.move_to(12.5)
        moves = [c for c in sent(st) if "move" in c]
        assert len(moves) == 1 and re.fullmatch(r"/3 1 \d+ move abs 125000", moves[0])
        assert st.emulator.true_position_mm() == 12.5


def test_busy_while_moving_and_returns_only_when_still():
    with open_stage("emulated:zaber?speed=100&timeout=0.5") as st:
        t0 = time.monotonic()
        st.move_to(20.0)                         # 20 mm at 100 mm/s: 0.2 s
        assert time.monotonic() - t0 >= 0.19
        assert st.emulator.true_position_mm() == pytest.approx(20.0, abs=1e-4)
        replies = bytes(st.emulator.wire_out).decode().splitlines()
        assert sum(" BUSY " in r for r in replies) >= 3     # polled while busy
        assert " IDLE " in replies[-1]


def test_lost_reply_is_retried_with_a_new_message_id(stage):
    stage.options = replace(stage.options, timeout_s=0.2)
    stage.emulator.inject("timeout", count=1)
    stage.move_to(30.0)
    moves = [c for c in sent(stage) if "move abs" in c]
    assert len(moves) == 2
    ids = [c.split()[2] for c in moves]
    assert ids[0] != ids[1]
    assert stage.emulator.true_position_mm() == pytest.approx(30.0, abs=1e-4)


def test_stage_that_stops_answering(stage):
    stage.options = replace(stage.options, timeout_s=0.2)
    stage.emulator.inject("timeout", count=1000)
    t0 = time.monotonic()
    with pytest.raises(HardwareError, match=r"no reply to 'move abs \d+' within 0.2 s \(3 tries\)"):
        stage.move_to(30.0)
    assert time.monotonic() - t0 < 2


def test_rejected_move(stage):
    stage.emulator.inject("reject")
    with pytest.raises(HardwareError, match=r"rejected 'move abs 629921': BADDATA"):
        stage.move_to(30.0)


def test_move_beyond_travel_is_rejected(stage):
    with pytest.raises(HardwareError, match="BADDATA"):
        stage.move_to(400.0)                     # travel is 300 mm


def test_stall_fault(stage):
    stage.move_to(10.0)
    stage.emulator.inject("alarm")
    with pytest.raises(HardwareError, match=r"fault FS \(stalled and stopped\)"):
        stage.move_to(50.0)
    assert stage.emulator.true_position_mm() == pytest.approx(30.0, abs=1e-4)   # stopped half way


def test_slipping_carriage_reports_the_move_but_stays(stage):
    stage.move_to(10.0)
    stage.emulator.inject("slip")
    assert stage.move_to(50.0) == pytest.approx(50.0, abs=1e-3)    # the controller is content
    assert stage.position_mm() == pytest.approx(50.0, abs=1e-3)
    assert stage.emulator.true_position_mm() == pytest.approx(10.0, abs=1e-4)
    stage.move_to(60.0)                                          # later moves work, 40 mm short
    assert stage.emulator.true_position_mm() == pytest.approx(20.0, abs=1e-4)


def test_dropped_line(stage):
    stage.emulator.inject("drop")
    with pytest.raises(HardwareError, match="lost the connection"):
        stage.move_to(30.0)


def test_fault_at_a_given_move(stage):
    stage.emulator.inject("reject", at_move=2)
    stage.move_to(1.0)
    stage.move_to(2.0)
    with pytest.raises(HardwareError, match="rejected"):
        stage.move_to(3.0)


def test_relative_move_is_never_retried(stage):
    stage.move_to(10.0)
    assert stage.move_by(5.0) == pytest.approx(15.0, abs=1e-4)
    assert re.fullmatch(r"/1 1 \d+ move rel 104987", [c for c in sent(stage) if "move rel" in c][0])
    stage.options = replace(stage.options, timeout_s=0.2)
    stage.emulator.inject("timeout", count=1)
    with pytest.raises(HardwareError, match=r"no reply to 'move rel 104987' within 0.2 s \(1 tries\)"):
        stage.move_by(5.0)                     # repeating it could move twice as far
    assert sum("move rel" in c for c in sent(stage)) == 2


def test_home_no_leaves_the_stage_unhomed():
    with open_stage(f"emulated:zaber?{FAST}&home=no") as st:
        assert not any("home" in c for c in sent(st))
        assert "WR" in st.emulator.flags
