"""Linear stages driven by a GRBL 1.1 controller (G-code over a serial line, millimetres).

Every line sent is answered by `ok` or `error:N`; `ALARM:N` comes whenever the controller locks up
(limit switch, failed homing, reset while moving). `?` is a real-time command answered at once with a
status report `<State|MPos:x,y,z|FS:feed,speed|...>` (or `WPos:`; `WCO:` gives the work offset).
`\\x18` (ctrl-x) is a soft reset, answered by the banner `Grbl 1.1x ['$' for help]`.

A move is `G90 G1 <axis><mm> F<feed>`, then `G4 P0`, whose `ok` comes only once the motion has ended;
the status report then gives the position reached.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from scanners.errors import HardwareError
from scanners.stage import LinkOptions, SerialLink, SerialStage

ERRORS = {
    1: "expected command letter", 2: "bad number format", 3: "invalid $ statement",
    5: "homing not enabled ($22)", 8: "$ command only valid when idle", 9: "G-code locked out during alarm",
    15: "jog target exceeds travel", 20: "unsupported or invalid G-code", 22: "feed rate not set",
    33: "invalid motion target",
}
ALARMS = {
    1: "hard limit triggered", 2: "soft limit: target beyond travel", 3: "reset while in motion",
    4: "probe fail", 5: "probe fail", 6: "homing fail: reset during homing", 7: "homing fail: door open",
    8: "homing fail: could not clear the limit switch", 9: "homing fail: limit switch not found",
}
AXES = "XYZ"


@dataclass(frozen=True)
class GrblStatus:
    """A status report: the state (`Idle`, `Run`, `Alarm`, `Hold`, ...; sub-state dropped) and the
    machine position (mm, X Y Z) if it reported `MPos`, the work position if it reported `WPos`."""

    state: str
    position: tuple[float, float, float]
    is_machine: bool
    wco: tuple[float, float, float] | None = None


def parse_status(line: str) -> GrblStatus | None:
    """Parse `<...>`; None for other lines; ValueError if garbled."""
    line = line.strip()
    if not (line.startswith("<") and line.endswith(">")):
        return None
    fields = line[1:-1].split("|")
    state = fields[0].split(":")[0]
    pos, machine, wco = None, True, None
    try:
        for f in fields[1:]:
            key, _, value = f.partition(":")
            xyz = tuple(float(v) for v in value.split(",")[:3]) if key in ("MPos", "WPos", "WCO") else None
            if key in ("MPos", "WPos"):
                pos, machine = xyz, key == "MPos"
            elif key == "WCO":
                wco = xyz
    except ValueError:
        raise ValueError(f"garbled status report {line!r}") from None
    if not state or pos is None or len(pos) != 3:
        raise ValueError(f"garbled status report {line!r}")
    return GrblStatus(state, pos, machine, wco)


class GrblStage(SerialStage):
    """One axis of a GRBL controller, in work coordinates. Connecting resets the controller, waits for
    its banner, homes it if it is locked (home=auto) and selects mm and absolute moves."""

    def __init__(self, link: SerialLink, options: LinkOptions, axis: str = "X", feed_mm_min: float = 600.0):
        super().__init__(link, options)
        self.axis, self.feed = axis, feed_mm_min
        self._wco = (0.0, 0.0, 0.0)
        try:
            self._reset()
            state = self.status().state
            if options.home == "yes" or (options.home == "auto" and state == "Alarm"):
                self.home()
            elif state == "Alarm":
                raise HardwareError(f"{self.name}: controller is in alarm; home it ($H) or use home=auto")
            self.command("G21 G90", retry=True)
        except BaseException:
            self.link.close()
            raise

    def _reset(self) -> None:
        wait = max(2.5, 3 * self.options.timeout_s)
        for _ in range(1 + self.options.retries):
            self.link.send(b"\x18")
            deadline = time.monotonic() + wait
            while (left := deadline - time.monotonic()) > 0:
                line = self.link.read_line(left)
                if line is None:
                    break
                if line.startswith("Grbl "):
                    return
        raise HardwareError(f"{self.name}: no GRBL banner after a reset")

    def _raise_if_alarm(self, line: str, text: str) -> None:
        if line.startswith("ALARM:"):
            code = int(line[6:]) if line[6:].isdigit() else -1
            raise HardwareError(f"{self.name}: ALARM:{code} ({ALARMS.get(code, 'alarm')}) during '{text}'")

    def command(self, text: str, retry: bool, timeout_s: float | None = None) -> None:
        """Send one line and wait for its `ok`; error:N, ALARM:N or no answer raise HardwareError.
        A lost answer is retried when `retry` (commands that are safe to repeat)."""
        timeout_s = self.options.timeout_s if timeout_s is None else timeout_s
        tries = 1 + (self.options.retries if retry else 0)
        for _ in range(tries):
            self.link.send(text.encode() + b"\n")
            deadline = time.monotonic() + timeout_s
            while (left := deadline - time.monotonic()) > 0:
                line = self.link.read_line(left)
                if line is None:
                    break
                if line == "ok":
                    return
                self._raise_if_alarm(line, text)
                if line.startswith("error:"):
                    code = int(line[6:]) if line[6:].isdigit() else -1
                    raise HardwareError(f"{self.name}: rejected '{text}': error:{code} "
                                        f"({ERRORS.get(code, 'error')})")
            self.link.discard_input()
        raise HardwareError(f"{self.name}: no answer to '{text}' within {timeout_s:g} s ({tries} tries)")

    def status(self) -> GrblStatus:
        """Ask for a status report (`?`, retried when lost)."""
        for _ in range(1 + self.options.retries):
            self.link.send(b"?")
            deadline = time.monotonic() + self.options.timeout_s
            while (left := deadline - time.monotonic()) > 0:
                line = self.link.read_line(left)
                if line is None:
                    break
                self._raise_if_alarm(line, "?")
                try:
                    st = parse_status(line)
                except ValueError as exc:
                    raise HardwareError(f"{self.name}: {exc}") from None
                if st is not None:
                    if st.wco is not None:
                        self._wco = st.wco
                    return st
        raise HardwareError(f"{self.name}: no status report within {self.options.timeout_s:g} s")

    def _work_position(self, st: GrblStatus) -> float:
        i = AXES.index(self.axis)
        return st.position[i] - self._wco[i] if st.is_machine else st.position[i]

    def home(self) -> None:
        self.command("$H", retry=False, timeout_s=self.options.move_timeout_s)

    def move_to(self, z_mm: float) -> float:
        self.command(f"G90 G1 {self.axis}{z_mm:.4f} F{self.feed:g}", retry=True)
        self.command("G4 P0", retry=True, timeout_s=self.options.move_timeout_s)  # ok once still
        st = self.status()
        if st.state != "Idle":
            raise HardwareError(f"{self.name}: state {st.state} after the move to {z_mm:g} mm")
        return self._check_arrival(z_mm, self._work_position(st))

    def position_mm(self) -> float:
        return self._work_position(self.status())


__all__ = ["GrblStage", "GrblStatus", "parse_status", "ERRORS", "ALARMS"]
