"""Sequence files written by their formats' documented layouts (independently of the readers under
test): a Phantom .cine (CINEFILEHEADER, BITMAPINFOHEADER, SETUP with its Length, a TIME64 tagged block,
image pointers, annotated images stored bottom-up) and a Photron .mraw with its .cih header."""

from __future__ import annotations

import struct

import numpy as np

SETUP_LENGTH = 400      # our SETUP's length: the tagged blocks follow it


def write_cine(path, frames: np.ndarray, times_s: np.ndarray) -> None:
    """frames (N, H, W) uint8 or uint16; times_s (N,) seconds since 1970."""
    n, h, w = frames.shape
    bits = 16 if frames.dtype == np.uint16 else 8
    off_bmp, off_setup = 44, 84
    tagged = struct.pack("<IHH", 8 + 8 * n, 1002, 0) + b"".join(
        struct.pack("<II", int(round((t % 1) * 2 ** 32)) & 0xFFFFFFFF, int(t)) for t in times_s)
    off_ptrs = off_setup + SETUP_LENGTH + len(tagged)
    annotation = 8 + 12                                  # size field, 12 bytes of text, image size field
    first = off_ptrs + 8 * n
    size = w * h * bits // 8
    pointers = [first + k * (annotation + size) for k in range(n)]
    head = struct.pack("<2sHHHiIiIIIIII", b"CI", 44, 0, 1, 0, n, 0, n, off_bmp, off_setup, off_ptrs, 0, 0)
    bmp = struct.pack("<IiiHHIIiiII", 40, w, h, 1, bits, 0, size, 0, 0, 0, 0)
    setup = bytearray(SETUP_LENGTH)
    setup[140:144] = struct.pack("<2sH", b"ST", SETUP_LENGTH)
    with open(path, "wb") as f:
        f.write(head + bmp + bytes(setup) + tagged + np.asarray(pointers, "<i8").tobytes())
        for img in frames:
            f.write(struct.pack("<I", annotation) + b"frame-notes." + struct.pack("<I", size))
            f.write(np.ascontiguousarray(img[::-1]).astype("<u2" if bits == 16 else "u1").tobytes())


def write_mraw(stem, frames: np.ndarray, *, bits: int, fps: float, start: int = 0) -> None:
    """stem.mraw and stem.cih of frames (N, H, W), 8, 12 (packed) or 16 bits."""
    n, h, w = frames.shape
    with open(f"{stem}.mraw", "wb") as f:
        for img in frames:
            if bits == 8:
                f.write(img.astype("u1").tobytes())
            elif bits == 16:
                f.write(img.astype("<u2").tobytes())
            else:
                p = img.astype(np.uint16).reshape(-1, 2)
                b = np.stack([p[:, 0] >> 4, ((p[:, 0] & 15) << 4) | (p[:, 1] >> 8), p[:, 1] & 255], 1)
                f.write(b.astype("u1").tobytes())
    info = {"Record Rate(fps)": f"{fps:g}", "Total Frame": n, "Start Frame": start, "Image Width": w,
            "Image Height": h, "Color Type": "Mono", "Color Bit": bits, "File Format": "MRaw",
            "EffectiveBit Depth": min(bits, 12), "EffectiveBit Side": "Lower"}
    with open(f"{stem}.cih", "w") as f:
        f.write("#Camera Information Header\n" + "".join(f"{k} : {v}\n" for k, v in info.items()))
