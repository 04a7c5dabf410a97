"""Sequence files streamed (a row of `stereodic bench dic`): the peak memory of reading every frame of a
20,000-frame file (`calib.sequences`, as `stereodic dic` and `dic2d` read it) - a Photron .mraw (8-bit),
a lossless video (FFV1 in AVI) and a multi-page TIFF of 128x96 frames - against the same process
reading its first frame only: the difference is what streaming costs, bounded by a few frames whatever
the file's length. Each read runs in its own process (`run_isolated`: whole-process peak RSS)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from stereodic.bench import Figure, run_isolated

GOAL_EXTRA_BYTES = 64 * 2 ** 20
WIDTH, HEIGHT = 128, 96


def _frames(n: int):
    rng = np.random.default_rng(0)
    base = rng.integers(0, 256, (HEIGHT, WIDTH), dtype=np.uint8)
    for k in range(n):
        yield np.roll(base, k % WIDTH, axis=1)


def _write(folder: Path, n: int) -> dict[str, Path]:
    import cv2
    import tifffile
    files = {"mraw": folder / "seq.cih", "avi": folder / "seq.avi", "tif": folder / "seq.tif"}
    with open(folder / "seq.mraw", "wb") as f:
        for img in _frames(n):
            f.write(img.tobytes())
    (folder / "seq.cih").write_text(f"Record Rate(fps) : 1000\nTotal Frame : {n}\nStart Frame : 0\n"
                                    f"Image Width : {WIDTH}\nImage Height : {HEIGHT}\nColor Type : Mono\n"
                                    f"Color Bit : 8\nFile Format : MRaw\n")
    video = cv2.VideoWriter(str(files["avi"]), cv2.VideoWriter_fourcc(*"FFV1"), 1000, (WIDTH, HEIGHT), isColor=False)
    for img in _frames(n):
        video.write(img)
    video.release()
    with tifffile.TiffWriter(files["tif"], bigtiff=True) as tif:
        for img in _frames(n):
            tif.write(img, photometric="minisblack", contiguous=False)
    return files


def _read(path: str, every: bool) -> int:
    """Read the file's frames (all, or the first only) as the DIC commands do; returns a checksum."""
    from calib.image_files import expand
    from calib.imageio import read_gray
    refs = expand(path)
    total = 0
    for ref in refs if every else refs[:1]:
        total += int(read_gray(ref)[0, 0])
    return total + len(refs)


def figures(quick: bool = False) -> list[Figure]:
    n = 2000 if quick else 20000
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        files = _write(Path(tmp), n)
        for kind, path in files.items():
            _, one, _ = run_isolated(_read, str(path), False)
            seconds, peak, _ = run_isolated(_read, str(path), True)
            extra = peak - one
            out.append(Figure("dic", f"{n:,}-frame {kind} ({WIDTH}x{HEIGHT}, 8-bit) read frame by frame: peak "
                              f"memory beyond one frame's read ({n / seconds:.0f} frames/s)", extra / 2 ** 20, "MiB",
                              goal=f"<= {GOAL_EXTRA_BYTES / 2 ** 20:.0f}", ok=extra <= GOAL_EXTRA_BYTES))
    return out
