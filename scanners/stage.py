"""Motorised linear stages: one interface (`Stage`), the serial link and the base of the serial drivers,
and the manual stage. The drivers (`stage_zaber`, `stage_grbl`) build on it; `stage_url.open_stage`
chooses one from a stage URL.

Positions are in millimetres along the stage axis, in the stage's own coordinates (0 at its home
position unless the controller says otherwise); the acquisition records them as the frames' `z_mm`.
"""

from __future__ import annotations

import sys
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass

import serial

from scanners.errors import HardwareError

try:  # POSIX ports raise termios.error (not an OSError) when the far end of a pty is gone
    from termios import error as _TermiosError
except ImportError:  # Windows
    _TermiosError = OSError
IO_ERRORS = (serial.SerialException, OSError, _TermiosError)


class Stage(ABC):
    """A linear stage. Positions in mm along its axis."""

    name: str = "stage"
    emulator = None  # the StageEmulator behind an `emulated:` stage (its true position drives simulations)

    @abstractmethod
    def home(self) -> None:
        """Find the reference position and wait until the stage is still."""

    @abstractmethod
    def move_to(self, z_mm: float) -> float:
        """Move to the absolute position z_mm, wait until still and return the position it reports."""

    @abstractmethod
    def position_mm(self) -> float:
        """The position the controller reports."""

    def close(self) -> None:
        """Release the port (and stop an emulator)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# ------------------------------------------------------------------------------------------ link

class SerialLink:
    """Text lines over a pyserial port: a serial device, a pty or any pyserial URL (`socket://...`).

    Every I/O failure becomes a `HardwareError` naming the stage; a read that times out returns None.
    """

    def __init__(self, port: str, baudrate: int, name: str):
        self.name = name
        self.port_name = port
        try:
            self.port = serial.serial_for_url(port, baudrate=baudrate, timeout=0.02, write_timeout=2.0)
        except (*IO_ERRORS, ValueError) as exc:
            raise HardwareError(f"{name}: cannot open the port ({exc})") from None
        self._buf = bytearray()

    def send(self, data: bytes) -> None:
        try:
            self.port.write(data)
            self.port.flush()
        except IO_ERRORS as exc:
            raise HardwareError(f"{self.name}: lost the connection ({exc})") from None

    def read_line(self, timeout_s: float) -> str | None:
        """The next line (without its CR/LF), or None if none is complete within timeout_s."""
        deadline = time.monotonic() + timeout_s
        while True:
            nl = self._buf.find(b"\n")
            if nl >= 0:
                line = bytes(self._buf[:nl]).rstrip(b"\r")
                del self._buf[:nl + 1]
                return line.decode("ascii", errors="replace")
            if time.monotonic() >= deadline:
                return None
            try:
                chunk = self.port.read(max(1, self.port.in_waiting))
            except IO_ERRORS as exc:
                raise HardwareError(f"{self.name}: lost the connection ({exc})") from None
            self._buf += chunk

    def discard_input(self) -> None:
        """Forget unread input (stale replies before a retry)."""
        self._buf.clear()
        try:
            self.port.reset_input_buffer()
        except IO_ERRORS as exc:
            raise HardwareError(f"{self.name}: lost the connection ({exc})") from None

    def close(self) -> None:
        try:
            self.port.close()
        except IO_ERRORS:
            pass


@dataclass(frozen=True)
class LinkOptions:
    """Options common to the serial drivers (see the module docstring)."""

    timeout_s: float = 1.0
    retries: int = 2
    move_timeout_s: float = 120.0
    home: str = "auto"
    tolerance_um: float = 1.0
    poll_s: float = 0.01


class SerialStage(Stage):
    """A stage driven over a `SerialLink`; closing it also stops the emulator behind it, if any."""

    def __init__(self, link: SerialLink, options: LinkOptions):
        self.link = link
        self.options = options
        self.name = link.name

    def _check_arrival(self, target_mm: float, reported_mm: float) -> float:
        if abs(reported_mm - target_mm) * 1000 > self.options.tolerance_um:
            raise HardwareError(f"{self.name}: stopped at {reported_mm:.4f} mm instead of {target_mm:.4f} mm")
        return reported_mm

    def close(self) -> None:
        self.link.close()
        if self.emulator is not None:
            self.emulator.close()


# ------------------------------------------------------------------------------------------ manual

class ManualStage(Stage):
    """No motor: asks the user (on stderr, answer on stdin) to move the stage and trusts the answer."""

    name = "manual stage"

    def __init__(self, ask=input):
        self._ask = ask
        self._z: float | None = None

    def home(self) -> None:
        pass

    def move_to(self, z_mm: float) -> float:
        if self._z != z_mm:
            print(f"Move the stage to z = {z_mm:g} mm, then press Enter.", file=sys.stderr)
            try:
                self._ask("")
            except EOFError:
                raise HardwareError("manual stage: no answer on standard input") from None
            self._z = z_mm
        return z_mm

    def position_mm(self) -> float:
        if self._z is None:
            raise HardwareError("manual stage: position unknown until the first move")
        return self._z


__all__ = ["Stage", "SerialStage", "SerialLink", "LinkOptions", "ManualStage", "IO_ERRORS"]
