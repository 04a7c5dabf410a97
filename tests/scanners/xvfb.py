"""A virtual X screen (Xvfb) for the tests that open a real full-screen window, and reading it back."""

import contextlib
import os
import shutil
import subprocess
import time

import numpy as np
import pytest


@contextlib.contextmanager
def virtual_screen(width: int, height: int):
    """A virtual X screen of width x height pixels, 24-bit; DISPLAY points at it inside the block.
    Skips the test when pygame, python-xlib or Xvfb is missing."""
    pytest.importorskip("pygame")
    pytest.importorskip("Xlib")
    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not installed (./run test installs it)")
    for n in range(91, 120):
        if not os.path.exists(f"/tmp/.X11-unix/X{n}") and not os.path.exists(f"/tmp/.X{n}-lock"):
            break
    proc = subprocess.Popen(["Xvfb", f":{n}", "-screen", "0", f"{width}x{height}x24", "-nolisten", "tcp",
                             "-noreset"],   # no server reset when the last client leaves: the next test connects
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 10
    while not os.path.exists(f"/tmp/.X11-unix/X{n}"):
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            pytest.skip(f"Xvfb could not start on :{n}")
        time.sleep(0.05)
    old = os.environ.get("DISPLAY")
    os.environ["DISPLAY"] = f":{n}"
    try:
        yield f":{n}"
    finally:
        if old is None:
            del os.environ["DISPLAY"]
        else:
            os.environ["DISPLAY"] = old
        proc.terminate()
        proc.wait(timeout=5)


def read_back(display: str) -> np.ndarray:
    """The whole X screen as (H, W, 3) RGB, read through the X server (XGetImage on the root window)."""
    from Xlib import X
    from Xlib import display as xdisplay
    d = xdisplay.Display(display)
    try:
        scr = d.screen()
        w, h = scr.width_in_pixels, scr.height_in_pixels
        raw = scr.root.get_image(0, 0, w, h, X.ZPixmap, 0xFFFFFFFF)
        bgrx = np.frombuffer(raw.data, np.uint8).reshape(h, w, 4)
        return bgrx[:, :, 2::-1]
    finally:
        d.close()
