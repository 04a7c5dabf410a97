"""Stage URLs, the manual stage and opening failures."""

import re

import numpy as np
import pytest

from calib.errors import InputError
from scanners.errors import HardwareError
from scanners.stage import ManualStage
from scanners.stage_url import StageUrl, open_stage, parse_stage_url


@pytest.mark.parametrize("text, want", [
    ("zaber:///dev/ttyUSB0?device=2&axis=1&microstep_um=0.1",
     StageUrl("zaber", "/dev/ttyUSB0", {"device": "2", "axis": "1", "microstep_um": "0.1"})),
    ("zaber://COM3", StageUrl("zaber", "COM3", {})),
    ("zaber+socket://10.0.0.5:9000?timeout=3", StageUrl("zaber", "socket://10.0.0.5:9000", {"timeout": "3"})),
    ("grbl:///dev/ttyACM0?axis=Z&feed=900", StageUrl("grbl", "/dev/ttyACM0", {"axis": "Z", "feed": "900"})),
    ("grbl+socket://localhost:9001", StageUrl("grbl", "socket://localhost:9001", {})),
    ("emulated:zaber?speed=100", StageUrl("emulated", "zaber", {"speed": "100"})),
    ("emulated:grbl", StageUrl("emulated", "grbl", {})),
    ("manual", StageUrl("manual", "", {})),
])
def test_parse_stage_url(text, want):
    assert parse_stage_url(text) == want


@pytest.mark.parametrize("text, says", [
    ("thorlabs:///dev/ttyUSB0", "unknown stage"),
    ("zaber:///dev/ttyUSB0?speed=3", "unknown option(s) speed"),
    ("grbl:///dev/ttyACM0?device=1", "unknown option(s) device"),
    ("zaber://", "names no serial port"),
    ("zaber+telnet://host:23", "zaber+socket://HOST:PORT"),
    ("emulated:thorlabs", "emulated:zaber or emulated:grbl"),
])
def test_bad_stage_urls(text, says):
    with pytest.raises(InputError, match=re.escape(says)):
        parse_stage_url(text)


def test_emulated_travel_direction():
    with open_stage("emulated:grbl?speed=5000&axis_deg=0.5,-1.0") as st:
        ax, ay, az = st.emulator.travel_axis
        assert st.emulator.axis == "X"                          # the motor's letter is another thing
    assert ax ** 2 + ay ** 2 + az ** 2 == pytest.approx(1.0)
    assert ax / az == pytest.approx(np.tan(np.radians(0.5))) and ay / az == pytest.approx(np.tan(np.radians(-1.0)))
    with open_stage("emulated:zaber?speed=5000") as st:
        assert st.emulator.travel_axis == (0.0, 0.0, 1.0)


@pytest.mark.parametrize("text, says", [
    ("emulated:zaber?axis_deg=1", "axis_deg must be AX,AY in degrees"),
    ("emulated:zaber?axis_deg=60,0", "each within +-45"),
    ("emulated:zaber?device=one", "device='one' is not a valid int"),
    ("emulated:grbl?axis=A", "axis must be X, Y or Z"),
    ("emulated:zaber?home=maybe", "home must be auto, yes or no"),
    ("emulated:zaber?timeout=-1", "must not be negative"),
])
def test_bad_stage_options(text, says):
    with pytest.raises(InputError, match=re.escape(says)):
        open_stage(text)


def test_missing_port_is_a_hardware_error(tmp_path):
    with pytest.raises(HardwareError, match="cannot open"):
        open_stage(f"zaber://{tmp_path}/no-such-port")


def test_manual_stage_asks_once_per_position(capsys):
    asked = []
    stage = ManualStage(ask=asked.append)
    assert stage.move_to(0.0) == 0.0
    assert stage.move_to(0.0) == 0.0
    assert stage.move_to(50.0) == 50.0
    assert len(asked) == 2
    assert stage.position_mm() == 50.0
    err = capsys.readouterr().err
    assert "z = 0 mm" in err and "z = 50 mm" in err


def test_manual_stage_without_an_answer():
    def eof(_):
        raise EOFError
    with pytest.raises(HardwareError, match="no answer"):
        ManualStage(ask=eof).move_to(10.0)
