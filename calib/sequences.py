"""Image sequences in one file: videos (MP4, AVI, MOV, MKV), multi-page TIFF stacks, Phantom .cine and
Photron .mraw (with its .cih header), read frame by frame with each frame's timestamp.

A frame of such a file is named by a frame reference, a path `FILE::K` (frame K, from 0) or
`FILE::K:left` / `FILE::K:right` (the left or right half of a side-by-side stereo stream), which
`calib.imageio.read_gray` and `image_size` accept like an image file; `expand_sequence` (used by
`calib.image_files.expand`: a pattern that names such a file, or `FILE:left` / `FILE:right`) gives
every frame's reference. Files stay open in a small cache (`open_sequence`) and only the frame asked
for is read, so a 20,000-frame file streams in the memory of a few frames.

The readers follow the formats' documented layouts:
- video: OpenCV's FFmpeg decoder; colour frames to luminance; timestamps K / the stream's frame rate.
- multi-page TIFF: tifffile, page by page (8 or 16 bits); no timestamps.
- Phantom .cine (Vision Research's "cine file format"): CINEFILEHEADER (44 bytes: "CI", header size,
  compression, version, first movie image, total image count, first image number, image count, offsets
  of the BITMAPINFOHEADER, the SETUP and the image pointers, trigger time), BITMAPINFOHEADER (40 bytes:
  width, height - positive: rows stored bottom-up -, bit count 8 or 16, compression 0), SETUP (its
  `Length` at byte 142 of it), then tagged blocks up to the image pointers (block size u32, type u16,
  reserved u16; type 1002: one TIME64 per image, fractions u32 / 2^32 then seconds u32 since 1970), then
  ImageCount int64 pointers; each image: annotation size u32 (the annotation block's length, from the
  pointer), ..., image size u32 (the block's last 4 bytes), then the pixels (little-endian, 16-bit
  values as the camera's RealBPP bits). Uncompressed grey cines only (packed 10/12-bit cines: an
  InputError saying so).
- Photron .mraw with its .cih text header ("Key : Value" lines: Image Width, Image Height, Total Frame,
  Start Frame, Record Rate(fps), Color Bit 8, 12 or 16, Color Type Mono, File Format MRaw): frames one
  after the other, 8-bit, 16-bit little-endian, or 12-bit packed (3 bytes = 2 pixels: p0 = b0 << 4 |
  b1 >> 4, p1 = (b1 & 15) << 8 | b2); timestamps (Start Frame + K) / Record Rate.
"""

from __future__ import annotations

import functools
import os
import re
import struct
import warnings
from pathlib import Path

import numpy as np

from calib.errors import InputError

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".m4v")
SEQUENCE_SUFFIXES = VIDEO_SUFFIXES + (".cine", ".cih", ".mraw", ".tif", ".tiff")
_REF = re.compile(r"^(?P<file>.+)::(?P<k>\d+)(?::(?P<half>left|right))?$")
_HALF = re.compile(r"^(?P<file>.+):(?P<half>left|right)$")


def parse_frame_ref(path: str | os.PathLike) -> tuple[Path, int, str | None] | None:
    """(file, frame index, half or None) of a frame reference `FILE::K[:left|right]`, else None."""
    m = _REF.match(os.fspath(path))
    return None if m is None else (Path(m["file"]), int(m["k"]), m["half"])


def frame_ref(path: str | os.PathLike, k: int, half: str | None = None) -> Path:
    """The reference of frame k (and half) of a sequence file."""
    return Path(f"{os.fspath(path)}::{k}" + (f":{half}" if half else ""))


class _Video:
    def __init__(self, path: Path):
        import cv2
        self.path = path
        self.cap = cv2.VideoCapture(str(path))
        ok, img = self.cap.read() if self.cap.isOpened() else (False, None)
        if not ok:
            raise InputError(path, "cannot be decoded as a video (damaged, or a codec OpenCV's FFmpeg lacks)")
        self.count = int(self.cap.get(cv2.CAP_PROP_FRAME_COUNT))
        fps = self.cap.get(cv2.CAP_PROP_FPS)
        self.size = (img.shape[1], img.shape[0])
        self.times_s = np.arange(self.count) / fps if fps > 0 else None
        self._next, self._first = 1, self._gray(img)

    @staticmethod
    def _gray(img):
        import cv2
        return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img

    def frame(self, k: int) -> np.ndarray:
        import cv2
        if k == 0 and self._first is not None:
            return self._first
        if k != self._next:
            self.cap.set(cv2.CAP_PROP_POS_FRAMES, k)
        ok, img = self.cap.read()
        if not ok:
            raise InputError(frame_ref(self.path, k), "cannot be decoded (the video ends early or is damaged)")
        self._next = k + 1
        return self._gray(img)


class _Tiff:
    def __init__(self, path: Path):
        import tifffile
        try:
            self.tif = tifffile.TiffFile(path)
            pages = self.tif.pages
            self.count = len(pages)
            first = pages[0]
        except Exception:
            raise InputError(path, "not a readable TIFF stack") from None
        self.path = path
        self.size = (first.imagewidth, first.imagelength)
        self.times_s = None

    def frame(self, k: int) -> np.ndarray:
        try:
            img = self.tif.pages[k].asarray()
        except Exception:
            raise InputError(frame_ref(self.path, k), "cannot be read (the TIFF page is damaged)") from None
        if img.ndim == 3:                               # colour: contiguous (h, w, c) or planar (c, h, w)
            planar = img.shape[1:] == (self.size[1], self.size[0])
            img = (img[:3].mean(0) if planar else img[..., :3].mean(-1)).round().astype(img.dtype)
        if img.shape != (self.size[1], self.size[0]):
            raise InputError(frame_ref(self.path, k), f"page is {img.shape[1]}x{img.shape[0]}, the stack's first "
                                                      f"{self.size[0]}x{self.size[1]}")
        if img.dtype not in (np.uint8, np.uint16):
            raise InputError(frame_ref(self.path, k), f"pixel type {img.dtype} is not supported (8 or 16 bits)")
        return img


class _Cine:
    def __init__(self, path: Path):
        self.path = path
        with open(path, "rb") as f:
            head = f.read(44)
            if len(head) < 44 or head[:2] != b"CI":
                raise InputError(path, "is not a Phantom cine file (no 'CI' header)")
            (_, _, compression, _, _, _, _, count, off_bmp, off_setup, off_ptrs, _, _) = struct.unpack(
                "<2sHHHiIiIIIIII", head)
            f.seek(off_bmp)
            bmp = f.read(40)
            f.seek(off_setup + 142)
            setup_length = struct.unpack("<H", f.read(2))[0]
            if len(bmp) < 40:
                raise InputError(path, "is cut short (no bitmap header)")
            _, width, height, _, bits, bi_compression, _, _, _, _, _ = struct.unpack("<IiiHHIIiiII", bmp)
            if compression != 0 or bi_compression != 0 or bits not in (8, 16):
                raise InputError(path, f"holds {bits}-bit images of compression {compression}/{bi_compression}: "
                                       f"only uncompressed 8- or 16-bit grey cines are read")
            self.times_s = None
            pos = off_setup + setup_length
            while pos + 8 <= off_ptrs:                       # the tagged blocks
                f.seek(pos)
                size, kind, _ = struct.unpack("<IHH", f.read(8))
                if size < 8:
                    break
                if kind == 1002:
                    t = np.frombuffer(f.read(8 * count), "<u4").reshape(-1, 2)
                    if len(t) == count:
                        self.times_s = t[:, 1] + t[:, 0] / 2.0 ** 32
                pos += size
            f.seek(off_ptrs)
            raw = f.read(8 * count)
        if len(raw) < 8 * count:
            raise InputError(path, "is cut short (its image pointers)")
        self.pointers = np.frombuffer(raw, "<i8")
        self.count, self.size = count, (width, abs(height))
        self.bottom_up = height > 0
        self.dtype = np.dtype("<u2" if bits == 16 else "u1")

    def frame(self, k: int) -> np.ndarray:
        w, h = self.size
        with open(self.path, "rb") as f:
            f.seek(int(self.pointers[k]))
            annotation = struct.unpack("<I", f.read(4))[0]
            f.seek(int(self.pointers[k]) + annotation)
            data = f.read(w * h * self.dtype.itemsize)
        if len(data) < w * h * self.dtype.itemsize:
            raise InputError(frame_ref(self.path, k), "is cut short")
        img = np.frombuffer(data, self.dtype).reshape(h, w)
        return (img[::-1] if self.bottom_up else img).astype(self.dtype.newbyteorder("="))


def _cih(path: Path) -> dict[str, str]:
    info = {}
    try:
        text = path.read_text(errors="replace")
    except OSError as exc:
        raise InputError(path, f"cannot be read ({exc.strerror})") from None
    for line in text.splitlines():
        key, sep, value = line.partition(" : ")
        if sep:
            info[key.strip()] = value.strip()
    return info


class _Mraw:
    def __init__(self, path: Path):
        cih, mraw = path.with_suffix(".cih"), path.with_suffix(".mraw")
        if not cih.is_file():
            raise InputError(cih, "is missing: a Photron .mraw needs its .cih header beside it")
        if not mraw.is_file():
            raise InputError(mraw, "is missing: the .cih header's images")
        info = _cih(cih)
        try:
            w, h, n = (int(info[k]) for k in ("Image Width", "Image Height", "Total Frame"))
            bits = int(info["Color Bit"])
            rate = float(info.get("Record Rate(fps)", "0"))
            start = int(info.get("Start Frame", "0"))
        except (KeyError, ValueError) as exc:
            raise InputError(cih, f"lacks a readable {exc} (a .cih header: Image Width, Image Height, Total "
                                  f"Frame, Color Bit)") from None
        if info.get("File Format", "MRaw").lower() != "mraw" or bits not in (8, 12, 16) \
                or info.get("Color Type", "Mono").lower() != "mono":
            raise InputError(cih, f"describes {info.get('File Format')} {info.get('Color Type')} {bits}-bit "
                                  f"images: only monochrome MRaw of 8, 12 or 16 bits is read")
        self.path, self.mraw, self.bits = path, mraw, bits
        self.frame_bytes = w * h * bits // 8
        if mraw.stat().st_size < n * self.frame_bytes:
            raise InputError(mraw, f"is cut short: {mraw.stat().st_size} bytes for {n} frames of {w}x{h} at "
                                   f"{bits} bits")
        self.count, self.size = n, (w, h)
        self.times_s = (start + np.arange(n)) / rate if rate > 0 else None

    def frame(self, k: int) -> np.ndarray:
        w, h = self.size
        with open(self.mraw, "rb") as f:
            f.seek(k * self.frame_bytes)
            data = np.frombuffer(f.read(self.frame_bytes), np.uint8)
        if self.bits == 8:
            return data.reshape(h, w).copy()
        if self.bits == 16:
            return data.view("<u2").reshape(h, w).astype(np.uint16)
        b = data.reshape(-1, 3).astype(np.uint16)
        out = np.empty((len(b), 2), np.uint16)
        out[:, 0] = (b[:, 0] << 4) | (b[:, 1] >> 4)
        out[:, 1] = ((b[:, 1] & 15) << 8) | b[:, 2]
        return out.reshape(h, w)


Reader = "_Video | _Tiff | _Cine | _Mraw"   # one open sequence file: count, size, times_s, frame(k)


def _tiff_pages(path: Path) -> int:
    import tifffile
    try:
        with tifffile.TiffFile(path) as tif:
            return len(tif.pages)
    except Exception:
        return 0


def is_sequence(path: str | os.PathLike) -> bool:
    """Whether `path` is a sequence file: a video, .cine, .cih/.mraw, or a TIFF of more than one page."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in SEQUENCE_SUFFIXES or not path.is_file():
        return False
    return suffix not in (".tif", ".tiff") or _tiff_pages(path) > 1


@functools.lru_cache(maxsize=4)
def _open(path: str, stamp: tuple) -> Reader:
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in VIDEO_SUFFIXES:
        return _Video(p)
    if suffix in (".tif", ".tiff"):
        return _Tiff(p)
    if suffix == ".cine":
        return _Cine(p)
    return _Mraw(p)


def open_sequence(path: str | os.PathLike) -> Reader:
    """The open reader of a sequence file (module docstring), kept open while it is used: `count`,
    `size` (width, height), `times_s` (seconds, or None) and `frame(k)` (2-D uint8 or uint16).
    InputError naming the file when it is missing or cannot be read."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "is missing" if not path.exists() else "is not a file")
    st = path.stat()
    if st.st_size == 0:
        raise InputError(path, "is empty")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return _open(str(path), (st.st_mtime_ns, st.st_size))


def expand_sequence(path: str | os.PathLike) -> list[Path] | None:
    """Every frame's reference of a sequence file, or of `FILE:left` / `FILE:right` (the halves of a
    side-by-side stream); None when `path` names no sequence file."""
    text = os.fspath(path)
    half = None
    m = _HALF.match(text)
    if m and not Path(text).exists():
        text, half = m["file"], m["half"]
    if not is_sequence(text):
        return None
    reader = open_sequence(text)
    if reader.count < 1:
        raise InputError(text, "holds no frame")
    return [frame_ref(text, k, half) for k in range(reader.count)]


def _check_index(ref, reader: Reader, k: int) -> None:
    if not 0 <= k < reader.count:
        raise InputError(ref, f"frame {k} does not exist: the file holds frames 0 to {reader.count - 1}")


def read_frame(ref: str | os.PathLike) -> np.ndarray:
    """The frame a reference names (module docstring), 2-D uint8 or uint16; InputError naming it when it
    cannot be read."""
    file, k, half = parse_frame_ref(ref)
    reader = open_sequence(file)
    _check_index(ref, reader, k)
    img = reader.frame(k)
    if half is not None:
        w = img.shape[1] // 2
        img = img[:, :w] if half == "left" else img[:, w:2 * w]
    return np.ascontiguousarray(img)


def frame_size(ref: str | os.PathLike) -> tuple[int, int]:
    """(width, height) of the frame a reference names, from the file's header."""
    file, k, half = parse_frame_ref(ref)
    reader = open_sequence(file)
    _check_index(ref, reader, k)
    w, h = reader.size
    return (w // 2, h) if half else (w, h)


def frame_times(refs: list) -> list[float] | None:
    """The timestamps (seconds) of frame references, or None unless every one is a frame of a file that
    records them."""
    out = []
    for ref in refs:
        parsed = parse_frame_ref(ref)
        if parsed is None:
            return None
        times = open_sequence(parsed[0]).times_s
        if times is None:
            return None
        out.append(float(times[parsed[1]]))
    return out
