"""Showing patterns: full screen on a chosen monitor, one display pixel per image pixel.

A `Screen` shows 8-bit images of exactly its own size, grey patterns or colour pictures (the alignment
aid's readout), and returns only once the image is on the glass and has settled (the LCD's response
time and the camera's pipeline latency: `settle_s`). `pressed` returns the keys pressed on it since the
last call (a full-screen window has the keyboard: Esc or q to stop, s to measure the stage again).

- `PygameScreen` (`--display screen[:N]`): SDL2 through pygame, borderless full screen on monitor N at
  the monitor's own resolution, so there is no scaling; SDL applies no colour management; the mouse
  cursor is hidden; with vsync the flip waits for the vertical blank before the settle delay starts.
  Why pygame rather than Qt (PySide6): one self-contained wheel (about 14 MB, SDL2 inside) instead of
  a 100-300 MB Qt stack with its own platform plugins and system libraries; SDL puts a window of the
  monitor's native size on an explicit display index without Qt's device-pixel-ratio scaling to undo;
  the blit of an RGB buffer is pixel for pixel; and vsync is one flag. pygame is imported only when a
  screen is opened, so headless machines import this module freely.
- `FileScreen` (`--display file:DIR?size=WxH`): headless; each shown image is written to DIR as
  00000.png, 00001.png, ... (for a dry run, or for another program that puts them on a screen).
- `SimScreen` (`--display sim`): the simulated LCD of `scanners.sim`; it only holds the image shown, for
  the simulated camera to render (a colour picture as the grey a monochrome display would show: its
  Rec. 601 luma).
"""

from __future__ import annotations

import os
import time
from abc import ABC, abstractmethod
from pathlib import Path
from urllib.parse import parse_qsl, urlsplit

import numpy as np

from calib.errors import InputError
from calib.imageio import write_gray, write_rgb
from scanners.errors import HardwareError


class Screen(ABC):
    """A display device showing uint8 images of exactly `size` = (width, height) pixels: grey (H, W) or
    colour (H, W, 3) RGB."""

    size: tuple[int, int]
    pitch_mm: tuple[float, float] | None = None   # known for simulated screens; real ones: say it
    serial = 0                                     # counts the images shown

    def show(self, image: np.ndarray) -> None:
        """Put `image` ((height, width) or (height, width, 3) RGB, uint8) on the screen and wait until it
        is settled."""
        w, h = self.size
        if image.shape[:2] != (h, w) or image.shape[2:] not in ((), (3,)) or image.dtype != np.uint8:
            raise ValueError(f"pattern is {image.dtype} {image.shape[1::-1]}, the screen needs uint8 {w}x{h}")
        self._show(image)
        self.serial += 1

    @abstractmethod
    def _show(self, image: np.ndarray) -> None:
        ...

    def pressed(self) -> list[str]:
        """Names of the keys pressed on the screen since the last call ("escape", "q", "s", ...; "quit"
        when its window was closed). Screens without a keyboard return []."""
        return []

    def close(self) -> None:
        """Release the screen."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class FileScreen(Screen):
    """Writes every image shown to `folder` as NNNNN.png, numbered from the files already there."""

    def __init__(self, folder: str | os.PathLike, size: tuple[int, int]):
        self.folder = Path(folder)
        self.size = size
        self._next = len(list(self.folder.glob("[0-9][0-9][0-9][0-9][0-9].png"))) if self.folder.is_dir() else 0

    def _show(self, image: np.ndarray) -> None:
        (write_gray if image.ndim == 2 else write_rgb)(self.folder / f"{self._next:05d}.png", image)
        self._next += 1


class SimScreen(Screen):
    """The simulated LCD (`scanners.sim.display.SimDisplay`): holds the image shown for a SimulatedCamera."""

    def __init__(self, sim_display=None):
        from scanners.sim.display import SimDisplay
        self.sim = sim_display or SimDisplay()
        self.size = (self.sim.width_px, self.sim.height_px)
        self.pitch_mm = tuple(self.sim.pitch_mm)
        self.image: np.ndarray | None = None

    def _show(self, image: np.ndarray) -> None:
        if image.ndim == 3:
            image = np.rint(image @ np.array([0.299, 0.587, 0.114])).astype(np.uint8)
        self.image = image.copy()


class PygameScreen(Screen):
    """Full screen on monitor `monitor` (0-based, SDL's display index) at its native resolution."""

    def __init__(self, monitor: int = 0, settle_s: float = 0.15, vsync: bool = False):
        os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
        os.environ.setdefault("SDL_VIDEO_MINIMIZE_ON_FOCUS_LOSS", "0")   # stay up when the user clicks elsewhere
        os.environ.setdefault("SDL_WINDOWS_DPI_AWARENESS", "permonitorv2")  # no Windows DPI scaling
        try:
            import pygame
        except ImportError:
            raise HardwareError("showing patterns on a screen needs pygame (pip install pygame)") from None
        self._pg = pygame
        try:
            pygame.display.init()
            if pygame.display.get_driver() in ("offscreen", "dummy", "evdev"):   # SDL fell back: nothing shows
                raise HardwareError(f"screen:{monitor}: no monitor to show patterns on (SDL video driver "
                                    f"{pygame.display.get_driver()!r}; is DISPLAY set?)")
            sizes = pygame.display.get_desktop_sizes()
            if not 0 <= monitor < len(sizes):
                raise HardwareError(f"screen:{monitor}: there are {len(sizes)} monitor(s), numbered from 0")
            self.size = tuple(sizes[monitor])
            flags = pygame.FULLSCREEN | pygame.NOFRAME
            if vsync:  # SDL's vsync needs a renderer: SCALED at the native size is 1:1
                flags |= pygame.SCALED
            self._surface = pygame.display.set_mode(self.size, flags, display=monitor, vsync=int(vsync))
            got = self._surface.get_size()
            if got != self.size:
                raise HardwareError(f"screen:{monitor}: got a {got[0]}x{got[1]} window on a {self.size[0]}x"
                                    f"{self.size[1]} monitor (desktop scaling?); patterns must be 1:1")
            pygame.display.set_caption("stereodic patterns")
            pygame.mouse.set_visible(False)
        except pygame.error as exc:
            pygame.display.quit()
            raise HardwareError(f"screen:{monitor}: cannot open a full-screen window ({exc})") from None
        except BaseException:
            pygame.display.quit()
            raise
        self.monitor, self.settle_s = monitor, settle_s
        self._keys: list[str] = []

    def _show(self, image: np.ndarray) -> None:
        pg = self._pg
        try:
            rgb = np.repeat(image[:, :, None], 3, axis=2) if image.ndim == 2 else np.ascontiguousarray(image)
            self._surface.blit(pg.image.frombuffer(rgb.tobytes(), self.size, "RGB"), (0, 0))
            pg.display.flip()
            self._collect()  # keep the window responsive for the window manager
        except pg.error as exc:
            raise HardwareError(f"screen:{self.monitor}: {exc}") from None
        time.sleep(self.settle_s)

    def _collect(self) -> None:
        pg = self._pg
        for event in pg.event.get():
            if event.type == pg.QUIT:
                self._keys.append("quit")
            elif event.type == pg.KEYDOWN:
                self._keys.append(pg.key.name(event.key))

    def pressed(self) -> list[str]:
        try:
            self._collect()
        except self._pg.error as exc:
            raise HardwareError(f"screen:{self.monitor}: {exc}") from None
        keys, self._keys = self._keys, []
        return keys

    def close(self) -> None:
        self._pg.display.quit()


def open_screen(spec: str, settle_s: float = 0.15, vsync: bool = False) -> Screen:
    """A screen from a `--display` value: `screen[:N]`, `file:DIR?size=WxH` or `sim`."""
    if spec == "sim":
        return SimScreen()
    if spec == "screen" or spec.startswith("screen:"):
        n = spec.partition(":")[2] or "0"
        if not n.isdigit():
            raise InputError("--display", f"expected screen:N with N a monitor number, got {spec!r}")
        return PygameScreen(int(n), settle_s, vsync)
    if spec.startswith("file:"):
        parts = urlsplit(spec)
        options = dict(parse_qsl(parts.query))
        folder = parts.netloc + parts.path
        try:
            w, h = (int(v) for v in options.get("size", "").lower().split("x"))
        except ValueError:
            raise InputError("--display", f"{spec!r}: give the pattern size, file:DIR?size=1920x1080") from None
        if not folder or w <= 0 or h <= 0:
            raise InputError("--display", f"{spec!r}: expected file:DIR?size=WIDTHxHEIGHT")
        return FileScreen(folder, (w, h))
    raise InputError("--display", f"unknown display {spec!r} (screen[:N], file:DIR?size=WxH or sim)")


__all__ = ["Screen", "FileScreen", "SimScreen", "PygameScreen", "open_screen"]
