"""Zaber linear stages over the Zaber ASCII protocol.

Commands are `/<device> <axis> <id> <command>` lines; every reply is
`@<device> <axis> <id> <OK|RJ> <IDLE|BUSY> <warning flag> <data>`, e.g. `@01 1 07 OK BUSY -- 0`.
The message id (0-99) pairs each reply with its command, so a late reply to a command that timed out
and was sent again is never taken for the answer to another. Positions travel as integer microsteps:
mm = microsteps * microstep_um / 1000.

Warning flags: F* are faults (the stage stops: stall, driver disabled, encoder error, ...) and raise
`HardwareError`; WR (no reference position) means the stage must be homed; WL (unexpected limit) is a
fault here too; the others (N*: notices, WT/WV: temperature and voltage) are not.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from scanners.errors import HardwareError
from scanners.stage import LinkOptions, SerialLink, SerialStage

FAULT_FLAGS = {
    "FD": "driver disabled", "FQ": "encoder error", "FS": "stalled and stopped", "FT": "excessive twist",
    "FB": "stream bounds error", "FP": "interpolated path deviation", "FE": "limit error",
    "FZ": "peripheral inactive", "FO": "overdrive limit exceeded", "WL": "unexpected limit trigger",
}
NOT_HOMED_FLAGS = ("WR", "WH")


@dataclass(frozen=True)
class ZaberReply:
    """One reply line: address, message id (None if the command had none), accepted, busy, flag, data."""

    device: int
    axis: int
    id: int | None
    ok: bool
    busy: bool
    warning: str
    data: str


def parse_reply(line: str) -> ZaberReply | None:
    """Parse a reply line; None for other messages (`#` info, `!` alerts, blank); ValueError if garbled."""
    line = line.strip()
    if not line.startswith("@"):
        return None
    body = line[1:]
    if ":" in body:  # an optional checksum ":CC" ends the message
        body = body.rsplit(":", 1)[0]
    t = body.split()
    try:
        device, axis = int(t[0]), int(t[1])
        i = 2
        msg_id = None
        if t[i].isdigit():
            msg_id, i = int(t[i]), i + 1
        flag, status, warning = t[i], t[i + 1], t[i + 2]
    except (IndexError, ValueError):
        raise ValueError(f"garbled reply {line!r}") from None
    if flag not in ("OK", "RJ") or status not in ("IDLE", "BUSY") or len(warning) != 2:
        raise ValueError(f"garbled reply {line!r}")
    return ZaberReply(device, axis, msg_id, flag == "OK", status == "BUSY", warning, " ".join(t[i + 3:]))


class ZaberStage(SerialStage):
    """One axis of a Zaber device. Connecting checks that it answers and homes it if needed."""

    def __init__(self, link: SerialLink, options: LinkOptions, device: int = 1, axis: int = 1,
                 microstep_um: float = 0.047625):
        super().__init__(link, options)
        if microstep_um <= 0:
            raise HardwareError(f"{self.name}: microstep_um must be positive")
        self.device, self.axis, self.microstep_um = device, axis, microstep_um
        self._next_id = 0
        try:
            reply = self.command("", retry=True, check_flags=False)  # the status query: is it there?
            self._raise_fault(reply, "connect")
            if options.home == "yes" or (options.home == "auto" and reply.warning in NOT_HOMED_FLAGS):
                self.home()
        except BaseException:
            self.link.close()
            raise

    # -- units
    def to_steps(self, mm: float) -> int:
        """Millimetres -> microsteps (rounded to the nearest)."""
        return round(mm * 1000.0 / self.microstep_um)

    def to_mm(self, steps: int) -> float:
        return steps * self.microstep_um / 1000.0

    # -- protocol
    def command(self, text: str, retry: bool, check_flags: bool = True) -> ZaberReply:
        """Send one command and return its accepted reply. A lost reply is retried (if `retry`: only
        commands that are safe to repeat) up to options.retries times; a rejection, a fault flag or
        no reply at all raise HardwareError."""
        tries = 1 + (self.options.retries if retry else 0)
        for _ in range(tries):
            msg_id = self._next_id
            self._next_id = (self._next_id + 1) % 100
            self.link.send(f"/{self.device} {self.axis} {msg_id} {text}".rstrip().encode() + b"\n")
            reply = self._await_reply(msg_id)
            if reply is None:
                self.link.discard_input()
                continue
            if not reply.ok:
                raise HardwareError(f"{self.name}: rejected '{text}': {reply.data or 'no reason given'}")
            if check_flags:
                self._raise_fault(reply, text)
            return reply
        raise HardwareError(f"{self.name}: no reply to '{text}' within {self.options.timeout_s:g} s "
                            f"({tries} tries)")

    def _await_reply(self, msg_id: int) -> ZaberReply | None:
        deadline = time.monotonic() + self.options.timeout_s
        while (left := deadline - time.monotonic()) > 0:
            line = self.link.read_line(left)
            if line is None:
                return None
            try:
                reply = parse_reply(line)
            except ValueError as exc:
                raise HardwareError(f"{self.name}: {exc}") from None
            if reply and reply.device == self.device and reply.axis == self.axis and reply.id == msg_id:
                return reply
        return None

    def _raise_fault(self, reply: ZaberReply, text: str) -> None:
        if reply.warning in FAULT_FLAGS or reply.warning.startswith("F"):
            what = FAULT_FLAGS.get(reply.warning, "fault")
            raise HardwareError(f"{self.name}: fault {reply.warning} ({what}) after '{text}'")

    def _wait_idle(self, what: str) -> float:
        """Poll the position until the axis is idle; return it in mm."""
        deadline = time.monotonic() + self.options.move_timeout_s
        while True:
            reply = self.command("get pos", retry=True)
            if not reply.busy:
                return self._position(reply)
            if time.monotonic() > deadline:
                self.command("stop", retry=True, check_flags=False)
                raise HardwareError(f"{self.name}: {what} did not finish within "
                                    f"{self.options.move_timeout_s:g} s")
            time.sleep(self.options.poll_s)

    # -- Stage
    def home(self) -> None:
        self.command("home", retry=True)
        self._wait_idle("homing")
        reply = self.command("", retry=True)
        if reply.warning in NOT_HOMED_FLAGS:
            raise HardwareError(f"{self.name}: still no reference position after homing")

    def move_to(self, z_mm: float) -> float:
        self.command(f"move abs {self.to_steps(z_mm)}", retry=True)  # absolute: safe to repeat
        return self._check_arrival(self.to_mm(self.to_steps(z_mm)), self._wait_idle(f"move to {z_mm:g} mm"))

    def move_by(self, dz_mm: float) -> float:
        """Relative move (never retried: a repeated `move rel` would move twice); returns the position."""
        self.command(f"move rel {self.to_steps(dz_mm)}", retry=False)
        return self._wait_idle(f"move by {dz_mm:g} mm")

    def position_mm(self) -> float:
        return self._position(self.command("get pos", retry=True))

    def _position(self, reply: ZaberReply) -> float:
        try:
            return self.to_mm(int(reply.data.split()[0]))
        except (IndexError, ValueError):
            raise HardwareError(f"{self.name}: bad position {reply.data!r}") from None


__all__ = ["ZaberStage", "ZaberReply", "parse_reply", "FAULT_FLAGS"]
