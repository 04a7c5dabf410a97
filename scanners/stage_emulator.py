"""Emulated stages behind a real serial port, for tests, the demo and acquisition without hardware.

An emulator serves one protocol (Zaber ASCII or GRBL 1.1) on the far end of a pseudo-terminal pair
(`transport="pty"`: `port` is the slave's device name, e.g. /dev/pts/7) or on a TCP socket on the
loopback interface (`transport="socket"`: `port` is `socket://127.0.0.1:N`), so the drivers talk to it
through pyserial exactly as to a stage: same bytes, same framing. A thread answers; the stage moves with
finite speed, reports busy while moving and starts without a reference position (it must be homed).

Faults are injected with `inject(kind, at_move=None, count=1)`; they strike at the move command number
`at_move` (0-based, counted from the emulator's start; None: the next one):
- "timeout": that command and the next count-1 lines get no answer (they are still carried out);
- "reject": the move is refused (Zaber `RJ ... BADDATA`, GRBL `error:20`);
- "alarm": the stage stops half way with a fault (Zaber flag FS, GRBL `ALARM:1` and the Alarm state);
- "drop": the line goes dead (the pty master or the socket is closed);
- "slip": the move is carried out and reported as usual, but the carriage does not move (a slipping
  coupling or a motor turning without its load): its true position stays where it was, and stays off
  by that move from then on. Only a measurement (`scanners.align`) can tell.
`travel_axis` is the direction the carriage travels in the simulated rig's WCS (a unit vector, default along
the display normal, DESIGN.md `stage.axis`): the simulated camera sees the display at
`DisplayPose.staged(true_position_mm(), axis)`.
`wire_in`/`wire_out` keep every byte received and sent.
"""

from __future__ import annotations

import math
import os
import re
import select
import socket
import threading
import time
import tty
from abc import ABC, abstractmethod
from dataclasses import dataclass

FAULT_KINDS = ("timeout", "reject", "alarm", "drop", "slip")


class Motion:
    """One axis moving at constant speed (mm/s) from `start` to `target`, started at time `t0` (s)."""

    def __init__(self, position_mm: float):
        self.start = self.target = position_mm
        self.t0 = 0.0
        self.speed = 1.0

    def position(self, now: float) -> float:
        d = self.target - self.start
        travelled = self.speed * (now - self.t0)
        return self.target if travelled >= abs(d) else self.start + math.copysign(travelled, d)

    def busy(self, now: float) -> bool:
        return self.position(now) != self.target

    def go(self, target_mm: float, speed_mm_s: float, now: float) -> None:
        self.start, self.target, self.t0, self.speed = self.position(now), target_mm, now, speed_mm_s

    def stop(self, now: float) -> None:
        self.start = self.target = self.position(now)


@dataclass
class _Fault:
    kind: str
    at_move: int | None
    count: int


class StageEmulator(ABC):
    """The serial end and the thread; subclasses speak a protocol through `_on_line`/`_realtime`."""

    def __init__(self, speed_mm_s: float = 50.0, travel_mm: float = 300.0, transport: str = "pty",
                 start_mm: float = 37.5):
        if transport not in ("pty", "socket"):
            raise ValueError("transport must be 'pty' or 'socket'")
        self.speed_mm_s, self.travel_mm = speed_mm_s, travel_mm
        self.motion = Motion(start_mm)
        self.travel_axis = (0.0, 0.0, 1.0)
        self._slip_from: float | None = None     # the true position held during a slipping move
        self._slipped_mm = 0.0                    # reported minus true position after slipped moves
        self.wire_in, self.wire_out = bytearray(), bytearray()
        self.moves = 0
        self._faults: list[_Fault] = []
        self._mute = 0
        self._stall = False
        self._rx = bytearray()
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._conn: socket.socket | None = None
        self._server: socket.socket | None = None
        self._master: int | None = None
        self._slave: int | None = None
        if transport == "pty":
            self._master, self._slave = os.openpty()
            tty.setraw(self._slave)  # no echo, no CR/LF translation: bytes as on a serial line
            self.port = os.ttyname(self._slave)
        else:
            self._server = socket.create_server(("127.0.0.1", 0))
            self.port = f"socket://127.0.0.1:{self._server.getsockname()[1]}"
        self._thread = threading.Thread(target=self._run, name=f"{type(self).__name__} {self.port}", daemon=True)
        self._thread.start()

    # ---------------------------------------------------------------- public
    def inject(self, kind: str, at_move: int | None = None, count: int = 1) -> None:
        """Arrange a fault (see the module docstring)."""
        if kind not in FAULT_KINDS:
            raise ValueError(f"fault kind must be one of {FAULT_KINDS}")
        with self._lock:
            self._faults.append(_Fault(kind, at_move, count))

    def true_position_mm(self) -> float:
        """Where the carriage really is now (mm from the home switch)."""
        with self._lock:
            if self._slip_from is not None:
                return self._slip_from
            return self.motion.position(time.monotonic()) - self._slipped_mm

    def close(self) -> None:
        self._stop.set()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout=2)
        self._drop()
        for fd in (self._master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = None
        if self._server is not None:
            self._server.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ---------------------------------------------------------------- for subclasses
    @abstractmethod
    def _on_line(self, line: str, now: float) -> None:
        """Handle one received line (terminator removed)."""

    def _realtime(self, byte: int, now: float) -> bool:
        """Handle a real-time byte outside the line stream; True if it was one."""
        return False

    def _tick(self, now: float) -> None:
        """Called often: finish motions, send replies that wait for them."""

    def _send(self, text: str) -> None:
        if self._mute > 0:
            return
        data = text.encode() + b"\r\n"
        self.wire_out += data
        try:
            if self._master is not None:
                os.write(self._master, data)
            elif self._conn is not None:
                self._conn.sendall(data)
        except OSError:
            pass

    def _move_fault(self) -> str | None:
        """Count a move command and return the fault that strikes it, if any."""
        n = self.moves
        self.moves += 1
        for f in self._faults:
            if f.at_move is None or f.at_move == n:
                self._faults.remove(f)
                if f.kind == "timeout":
                    self._mute = f.count
                elif f.kind == "drop":
                    self._drop()
                return f.kind
        return None

    def _go(self, fault: str | None, target_mm: float, speed_mm_s: float, now: float) -> None:
        """Start a move (half way and stall on an "alarm" fault, without the carriage on a "slip")."""
        if fault == "alarm":
            return self._stall_half_way(target_mm, now)
        if fault == "slip":
            self._slip_from = self.motion.position(now) - self._slipped_mm
        self.motion.go(target_mm, speed_mm_s, now)

    def _end_slip(self, now: float) -> None:
        if self._slip_from is not None and not self.motion.busy(now):
            self._slipped_mm = self.motion.position(now) - self._slip_from
            self._slip_from = None

    def _stall_half_way(self, target_mm: float, now: float) -> None:
        """Start a move that will stop with a fault half way."""
        here = self.motion.position(now)
        self.motion.go(here + (target_mm - here) / 2, self.speed_mm_s, now)
        self._stall = True

    # ---------------------------------------------------------------- transport
    def _drop(self) -> None:
        if self._master is not None:
            try:
                os.close(self._master)
            except OSError:
                pass
            self._master = None
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def _run(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                fd = self._master if self._master is not None else self._conn
                if fd is None and self._server is not None:
                    fd = self._server
            if fd is None:  # the pty was dropped: nothing more to serve
                time.sleep(0.01)
                continue
            try:
                ready, _, _ = select.select([fd], [], [], 0.002)
            except (OSError, ValueError):
                ready = []
            data = b""
            if ready:
                try:
                    if fd is self._server:
                        self._conn, _ = self._server.accept()
                        self._on_connect()
                        continue
                    data = os.read(fd, 4096) if isinstance(fd, int) else fd.recv(4096)
                    if not data and fd is self._conn:
                        self._conn.close()
                        self._conn = None
                except OSError:
                    data = b""
            with self._lock:
                now = time.monotonic()
                for b in data:
                    self._byte(b, now)
                self._end_slip(now)
                self._tick(now)

    def _on_connect(self) -> None:
        """A client connected to the socket."""

    def _byte(self, b: int, now: float) -> None:
        self.wire_in.append(b)
        if self._realtime(b, now):
            return
        if b in (10, 13):
            line, self._rx = self._rx.decode("ascii", errors="replace"), bytearray()
            if line.strip():
                self._on_line(line.strip(), now)
                if self._mute > 0:  # this line's answer was swallowed
                    self._mute -= 1
        else:
            self._rx.append(b)


# ================================================================================= Zaber ASCII

_FLAG_ORDER = "FWN"  # faults before warnings before notices


class ZaberEmulator(StageEmulator):
    """A one-axis Zaber device (address `device`) speaking the ASCII protocol, positions in microsteps."""

    def __init__(self, device: int = 1, microstep_um: float = 0.047625, **kw):
        self.device, self.microstep_um = device, microstep_um
        self.flags = {"WR"}  # no reference position until homed
        self._homing = False
        super().__init__(**kw)

    def steps(self, mm: float) -> int:
        return round(mm * 1000 / self.microstep_um)

    def _flag(self) -> str:
        return min(self.flags, key=lambda f: (_FLAG_ORDER.index(f[0]), f)) if self.flags else "--"

    def _reply(self, axis: int, msg_id: int | None, ok: bool, now: float, data: str = "0") -> None:
        status = "BUSY" if self.motion.busy(now) else "IDLE"
        mid = "" if msg_id is None else f" {msg_id:02d}"
        self._send(f"@{self.device:02d} {axis}{mid} {'OK' if ok else 'RJ'} {status} {self._flag()} {data}")

    def _on_line(self, line: str, now: float) -> None:
        if not line.startswith("/"):
            return
        body = line[1:].split(":", 1)[0]  # drop an optional checksum
        tokens = body.split()
        nums: list[int] = []
        while tokens and tokens[0].isdigit() and len(nums) < 3:
            nums.append(int(tokens.pop(0)))
        device = nums[0] if nums else 0
        axis = nums[1] if len(nums) > 1 else 0
        msg_id = nums[2] if len(nums) > 2 else None
        if device not in (0, self.device):
            return
        cmd = " ".join(tokens)
        if axis not in (0, 1):
            return self._reply(axis, msg_id, False, now, "BADAXIS")
        if cmd == "":
            return self._reply(axis, msg_id, True, now)
        if cmd == "get pos":
            return self._reply(axis, msg_id, True, now, str(self.steps(self.motion.position(now))))
        if cmd == "home":
            self._homing = True
            self.motion.go(0.0, self.speed_mm_s, now)
            return self._reply(axis, msg_id, True, now)
        if cmd in ("stop", "estop"):
            self.motion.stop(now)
            return self._reply(axis, msg_id, True, now)
        if cmd in ("warnings", "warnings clear"):
            data = " ".join([f"{len(self.flags):02d}", *sorted(self.flags)])
            if cmd == "warnings clear":
                self.flags -= {f for f in self.flags if f != "WR"}
            return self._reply(axis, msg_id, True, now, data)
        m = re.fullmatch(r"move (abs|rel) (-?\d+)", cmd)
        if not m:
            return self._reply(axis, msg_id, False, now, "BADCOMMAND")
        here = self.steps(self.motion.position(now))
        target = int(m.group(2)) + (here if m.group(1) == "rel" else 0)
        if not 0 <= target <= self.steps(self.travel_mm):
            return self._reply(axis, msg_id, False, now, "BADDATA")
        fault = self._move_fault()
        if fault == "drop":
            return
        if fault == "reject":
            return self._reply(axis, msg_id, False, now, "BADDATA")
        self._go(fault, target * self.microstep_um / 1000, self.speed_mm_s, now)
        self._reply(axis, msg_id, True, now)

    def _tick(self, now: float) -> None:
        if self.motion.busy(now):
            return
        if self._homing:
            self._homing = False
            self.flags.discard("WR")
        if self._stall:
            self._stall = False
            self.flags.add("FS")


# ================================================================================= GRBL 1.1

class GrblEmulator(StageEmulator):
    """A GRBL 1.1 controller with homing enabled and one motorised axis (`axis`), millimetres."""

    BANNER = "Grbl 1.1h ['$' for help]"

    def __init__(self, axis: str = "X", **kw):
        self.axis = axis
        self.state = "Alarm"
        self.others = {a: 0.0 for a in "XYZ" if a != axis}
        self.absolute = True
        self.feed = 0.0
        self._held: str | None = None  # the reply that waits for the motion to end (G4, $H)
        self._queued: list[str] = []  # lines received meanwhile
        self._wco_sent = False
        super().__init__(**kw)
        with self._lock:
            self._greet()

    def _greet(self) -> None:
        self._send("")
        self._send(self.BANNER)
        if self.state == "Alarm":
            self._send("[MSG:'$H'|'$X' to unlock]")

    def _on_connect(self) -> None:
        self._greet()

    def _status(self, now: float) -> str:
        pos = dict(self.others, **{self.axis: self.motion.position(now)})
        busy = self.motion.busy(now)
        state = self.state if self.state in ("Alarm", "Home") else ("Run" if busy else "Idle")
        text = f"<{state}|MPos:{pos['X']:.3f},{pos['Y']:.3f},{pos['Z']:.3f}|FS:{self.feed if busy else 0:g},0"
        if not self._wco_sent:
            text += "|WCO:0.000,0.000,0.000"
            self._wco_sent = True
        return text + ">"

    def _realtime(self, byte: int, now: float) -> bool:
        if byte == ord("?"):
            self._send(self._status(now))
        elif byte == 0x18:  # soft reset
            if self.motion.busy(now):
                self.motion.stop(now)
                self.state = "Alarm"
                self._send("ALARM:3")
            self._held, self._queued = None, []
            self._rx.clear()
            self._wco_sent = False
            self._greet()
        elif byte in (ord("!"), ord("~")):
            pass  # feed hold / resume: not modelled
        else:
            return False
        return True

    def _on_line(self, line: str, now: float) -> None:
        line = line.replace(" ", "").upper()
        if self._held is not None:  # GRBL reads no further line while a G4 or $H blocks
            self._queued.append(line)
            return
        self._execute(line, now)

    def _execute(self, line: str, now: float) -> None:
        if line.startswith("$"):
            if line == "$H":
                self.state = "Home"
                self.motion.go(0.0, self.speed_mm_s, now)
                self._held = "ok"
            elif line == "$X":
                self.state = "Idle"
                self._send("[MSG:Caution: Unlocked]")
                self._send("ok")
            elif line in ("$$", "$#", "$G", "$I"):
                self._send("ok")
            else:
                self._send("error:3")
            return
        if self.state == "Alarm":
            return self._send("error:9")
        words = re.findall(r"([A-Z])([-+]?\d*\.?\d*)", line)
        if "".join(w[0] + w[1] for w in words) != line:
            return self._send("error:1")
        target = None
        dwell = False
        for letter, value in words:
            try:
                v = float(value)
            except ValueError:
                return self._send("error:2")
            if letter == "G" and v in (0, 1, 21, 90, 91, 4):
                self.absolute = {90: True, 91: False}.get(int(v), self.absolute)
                dwell = dwell or v == 4
            elif letter == "F":
                self.feed = v
            elif letter == self.axis:
                target = v if self.absolute else self.motion.target + v
            elif letter in self.others:
                self.others[letter] = v
            elif letter != "P":
                return self._send("error:20")
        if dwell:
            self._held = "ok"
            return
        if target is not None:
            fault = self._move_fault()
            if fault == "drop":
                return
            if fault == "reject":
                return self._send("error:20")
            if not 0 <= target <= self.travel_mm:
                self.state = "Alarm"
                return self._send("ALARM:2")
            self._go(fault, target, min(self.speed_mm_s, self.feed / 60) if self.feed > 0 else self.speed_mm_s,
                     now)
        self._send("ok")

    def _tick(self, now: float) -> None:
        if self.motion.busy(now):
            return
        if self._stall:
            self._stall = False
            self.state = "Alarm"
            self._held, self._queued = None, []
            self._send("ALARM:1")
            return
        if self._held is None:
            return
        if self.state == "Home":
            self.state = "Idle"
        self._send(self._held)
        self._held = None
        queued, self._queued = self._queued, []
        for line in queued:
            self._on_line(line, now)


__all__ = ["StageEmulator", "ZaberEmulator", "GrblEmulator", "Motion", "FAULT_KINDS"]
