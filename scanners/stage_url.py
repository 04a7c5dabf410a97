"""The stage factory: a stage URL -> a connected `scanners.stage.Stage` (`open_stage`).

Stage URLs (documented in docs/real-bench.md):

    zaber:///dev/ttyUSB0?device=1&axis=1&microstep_um=0.047625     Zaber ASCII protocol on a serial port
    zaber://COM3                                                    (Windows port names work too)
    zaber+socket://192.168.1.20:9000                                the same over TCP (a serial server)
    grbl:///dev/ttyACM0?axis=X&feed=600                             a GRBL 1.1 controller
    grbl+socket://localhost:9001
    emulated:zaber   emulated:grbl                                  an in-process emulator behind a pty
    manual                                                          no motor: the user moves the stage

Options for every serial driver: baud (default 115200), timeout (seconds to wait for a reply, 1),
retries (times a lost reply is retried, 2), move_timeout (seconds a move may take, 120), home
(auto: home when the controller has no reference position; yes; no), tolerance_um (largest accepted
difference between target and reported position, 1). Zaber: device (1), axis (1), microstep_um
(0.047625, the microstep of most Zaber linear stages: read yours from its data sheet). GRBL: axis
(X, Y or Z; default X), feed (mm/min, 600). Emulated: speed (mm/s, 50), travel (mm, 300),
transport (pty or socket), fault=KIND@N (the emulator's fault KIND strikes move N, 0-based: timeout
means the stage never answers again; see scanners.stage_emulator) and axis_deg=AX,AY (the simulated
carriage travels AX degrees off the display's normal towards its +x and AY towards its +y, for the
simulated camera). Faults raise `HardwareError`; bad URLs raise `InputError`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from urllib.parse import parse_qsl, urlsplit

import numpy as np

from calib.errors import InputError
from scanners.stage import LinkOptions, ManualStage, SerialLink, Stage
from scanners.stage_grbl import GrblStage
from scanners.stage_zaber import ZaberStage


@dataclass(frozen=True)
class StageUrl:
    """A parsed stage URL: driver name, pyserial port (or emulator kind) and options."""

    driver: str
    port: str
    options: dict = field(default_factory=dict)


_DRIVERS = ("zaber", "grbl", "emulated", "manual")
_COMMON = {"baud", "timeout", "retries", "move_timeout", "home", "tolerance_um"}
_ALLOWED = {
    "zaber": _COMMON | {"device", "axis", "microstep_um"},
    "grbl": _COMMON | {"axis", "feed"},
    "emulated": _COMMON | {"device", "axis", "microstep_um", "feed", "speed", "travel", "transport", "fault",
                           "axis_deg"},
    "manual": set(),
}


def parse_stage_url(text: str) -> StageUrl:
    """Split a stage URL into driver, port and options; InputError if it is not one."""
    parts = urlsplit(text)
    scheme = parts.scheme.lower() or text.lower()
    transport = None
    if "+" in scheme:
        scheme, transport = scheme.split("+", 1)
    if scheme not in _DRIVERS:
        raise InputError("--stage", f"unknown stage {text!r} (drivers: {', '.join(_DRIVERS)})")
    options = dict(parse_qsl(parts.query, keep_blank_values=True))
    unknown = set(options) - _ALLOWED[scheme]
    if unknown:
        raise InputError("--stage", f"{text!r}: unknown option(s) {', '.join(sorted(unknown))} for "
                                    f"{scheme} (known: {', '.join(sorted(_ALLOWED[scheme])) or 'none'})")
    if scheme == "manual":
        return StageUrl("manual", "", {})
    if scheme == "emulated":
        kind = parts.path or parts.netloc
        if kind not in ("zaber", "grbl"):
            raise InputError("--stage", f"{text!r}: say emulated:zaber or emulated:grbl")
        return StageUrl("emulated", kind, options)
    if transport is not None:
        if transport != "socket" or not parts.netloc:
            raise InputError("--stage", f"{text!r}: expected {scheme}+socket://HOST:PORT")
        port = f"socket://{parts.netloc}"
    else:
        port = parts.netloc + parts.path
    if not port:
        raise InputError("--stage", f"{text!r} names no serial port (e.g. {scheme}:///dev/ttyUSB0)")
    return StageUrl(scheme, port, options)


def _opt(options: dict, key: str, kind, default, where: str):
    if key not in options:
        return default
    try:
        value = kind(options[key])
    except ValueError:
        raise InputError("--stage", f"{where}: option {key}={options[key]!r} is not a valid "
                                    f"{kind.__name__}") from None
    if kind in (int, float) and value < 0:
        raise InputError("--stage", f"{where}: option {key} must not be negative")
    return value


def _link_options(o: dict, where: str) -> LinkOptions:
    home = o.get("home", "auto")
    if home not in ("auto", "yes", "no"):
        raise InputError("--stage", f"{where}: home must be auto, yes or no")
    return LinkOptions(timeout_s=_opt(o, "timeout", float, 1.0, where),
                       retries=_opt(o, "retries", int, 2, where),
                       move_timeout_s=_opt(o, "move_timeout", float, 120.0, where),
                       home=home, tolerance_um=_opt(o, "tolerance_um", float, 1.0, where))


def _inject(emulator, fault: str, where: str) -> None:
    from scanners.stage_emulator import FAULT_KINDS
    kind, _, at = fault.partition("@")
    if kind not in FAULT_KINDS or not at.isdigit():
        emulator.close()
        raise InputError("--stage", f"{where}: fault must be KIND@MOVE with KIND one of {', '.join(FAULT_KINDS)}")
    emulator.inject(kind, at_move=int(at), count=10**9 if kind == "timeout" else 1)


def _travel_axis(emulator, text: str, where: str) -> tuple[float, float, float]:
    """The unit travel direction of `axis_deg=AX,AY` (degrees off the normal towards +x and +y)."""
    try:
        ax, ay = (np.radians(float(v)) for v in text.split(","))
        if not (abs(ax) < np.pi / 4 and abs(ay) < np.pi / 4):
            raise ValueError
    except ValueError:
        emulator.close()
        raise InputError("--stage", f"{where}: axis_deg must be AX,AY in degrees, each within +-45") from None
    a = np.array([np.tan(ax), np.tan(ay), 1.0])
    return tuple(float(x) for x in a / np.linalg.norm(a))


def open_stage(text: str) -> Stage:
    """Connect to the stage a URL names, home it if needed and return it ready to move."""
    url = parse_stage_url(text)
    o = url.options
    if url.driver == "manual":
        return ManualStage()
    link = _link_options(o, text)
    baud = _opt(o, "baud", int, 115200, text)
    emulator = None
    kind, port = url.driver, url.port
    if url.driver == "emulated":
        from scanners.stage_emulator import GrblEmulator, ZaberEmulator
        transport = o.get("transport", "pty")
        if transport not in ("pty", "socket"):
            raise InputError("--stage", f"{text}: transport must be pty or socket")
        common = dict(speed_mm_s=_opt(o, "speed", float, 50.0, text),
                      travel_mm=_opt(o, "travel", float, 300.0, text), transport=transport)
        if url.port == "zaber":
            emulator = ZaberEmulator(device=_opt(o, "device", int, 1, text),
                                     microstep_um=_opt(o, "microstep_um", float, 0.047625, text), **common)
        else:
            emulator = GrblEmulator(**common)
        kind, port = url.port, emulator.port
        if "fault" in o:
            _inject(emulator, o["fault"], text)
        if "axis_deg" in o:
            emulator.travel_axis = _travel_axis(emulator, o["axis_deg"], text)
    try:
        if kind == "zaber":
            stage = ZaberStage(SerialLink(port, baud, f"zaber stage {port}"), link,
                               device=_opt(o, "device", int, 1, text), axis=_opt(o, "axis", int, 1, text),
                               microstep_um=_opt(o, "microstep_um", float, 0.047625, text))
        else:
            axis = o.get("axis", "X").upper()
            if axis not in ("X", "Y", "Z"):
                raise InputError("--stage", f"{text}: GRBL axis must be X, Y or Z")
            stage = GrblStage(SerialLink(port, baud, f"grbl stage {port}"), link, axis=axis,
                              feed_mm_min=_opt(o, "feed", float, 600.0, text))
    except BaseException:
        if emulator is not None:
            emulator.close()
        raise
    stage.emulator = emulator
    return stage

