"""Regions of interest drawn by a user: polygons with holes from a file, rasterised on an image, and a
region of the original (unrectified) left image moved onto the rectified one.

Polygon files (pixels of the image they are drawn on, x = column, y = row):
- JSON: a list of [x, y] vertices (one polygon), or an object {"outer": [[x, y], ...], "holes": [[[x,
  y], ...], ...]}, or a list of such objects (several parts);
- CSV (or any other text): one "x,y" vertex per line; a blank line starts the next ring; the first ring
  of a part is its outline, the next ones its holes; a line "part" (alone) starts the next part. Lines
  starting with "#" are comments.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from calib.errors import InputError


@dataclass
class Part:
    """One polygon: outer (N, 2) float64 vertices (x, y) pixels; holes: a list of (M, 2) rings."""

    outer: np.ndarray
    holes: list[np.ndarray]


def _ring(points, path, what: str) -> np.ndarray:
    try:
        ring = np.asarray(points, np.float64)
    except (TypeError, ValueError):
        ring = np.zeros((0, 0))
    if ring.ndim != 2 or ring.shape[1] != 2 or len(ring) < 3 or not np.isfinite(ring).all():
        raise InputError(path, f"{what} is not a list of at least 3 [x, y] vertices")
    return ring


def _from_json(data, path) -> list[Part]:
    if isinstance(data, dict):
        data = [data]
    if isinstance(data, list) and data and not isinstance(data[0], dict):
        return [Part(_ring(data, path, "the polygon"), [])]
    if not isinstance(data, list) or not data:
        raise InputError(path, "expected a list of [x, y] vertices, an object {\"outer\": ..., \"holes\": ...} or a "
                               "list of such objects")
    parts = []
    for k, item in enumerate(data):
        if not isinstance(item, dict) or "outer" not in item:
            raise InputError(path, f"part {k} has no \"outer\" list of vertices")
        holes = item.get("holes", [])
        if not isinstance(holes, list):
            raise InputError(path, f"part {k}: \"holes\" is not a list of rings")
        parts.append(Part(_ring(item["outer"], path, f"part {k}'s outer ring"),
                          [_ring(h, path, f"part {k}'s hole {j}") for j, h in enumerate(holes)]))
    return parts


def _from_text(text: str, path) -> list[Part]:
    parts: list[list[list[tuple[float, float]]]] = [[]]
    ring: list[tuple[float, float]] = []
    for n, line in enumerate(text.splitlines() + [""], 1):
        line = line.strip()
        if line.startswith("#"):
            continue
        if not line or line.lower() == "part":
            if ring:
                parts[-1].append(ring)
                ring = []
            if line and parts[-1]:
                parts.append([])
            continue
        fields = [f for f in line.replace(";", ",").replace("\t", ",").split(",") if f.strip()]
        try:
            x, y = (float(f) for f in fields)
        except ValueError:
            raise InputError(path, f"line {n}: expected 'x,y', got {line!r}") from None
        ring.append((x, y))
    out = [Part(_ring(rings[0], path, f"part {k}'s outline"),
                [_ring(r, path, f"part {k}'s hole {j}") for j, r in enumerate(rings[1:])])
           for k, rings in enumerate(parts) if rings]
    if not out:
        raise InputError(path, "no vertex in the file")
    return out


def read_polygons(path: str | os.PathLike) -> list[Part]:
    """The polygons with holes of a file (module docstring).

    Parameters
    ----------
    path : path
        A JSON or CSV/text polygon file, pixels.

    Returns
    -------
    parts : list of Part
        Outlines and holes, (x, y) pixels. InputError naming the file if it cannot be read or parsed.
    """
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot read the polygon file ({exc.__class__.__name__})") from None
    if text.lstrip().startswith(("[", "{")):
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InputError(path, f"not valid JSON: {exc.msg} at line {exc.lineno}") from None
        return _from_json(data, path)
    return _from_text(text, path)


def polygon_mask(parts: list[Part], width: int, height: int, *, where: str, image: str) -> np.ndarray:
    """(height, width) bool: inside an outline and outside its holes (pixel centres, cv2.fillPoly).

    Parameters
    ----------
    parts : list of Part
        The polygons (`read_polygons`), pixels.
    width, height : int
        The image's size, pixels.
    where : str
        The file or option named in messages.
    image : str
        The image's name in messages.

    Returns
    -------
    mask : (height, width) bool
        InputError naming `where` when a vertex lies outside the image or no pixel is inside.
    """
    mask = np.zeros((height, width), np.uint8)
    for part in parts:
        for ring in [part.outer, *part.holes]:
            bad = ~((ring[:, 0] >= -0.5) & (ring[:, 0] <= width - 0.5) & (ring[:, 1] >= -0.5)
                    & (ring[:, 1] <= height - 0.5))
            if bad.any():
                x, y = ring[np.argmax(bad)]
                raise InputError(where, f"vertex ({x:g}, {y:g}) is outside the {width}x{height} {image}")
        cv2.fillPoly(mask, [np.rint(part.outer).astype(np.int32)], 1)
        for hole in part.holes:
            cv2.fillPoly(mask, [np.rint(hole).astype(np.int32)], 0)
    if not mask.any():
        raise InputError(where, f"the polygon covers no pixel of the {width}x{height} {image}")
    return mask.astype(bool)


def to_rectified(mask: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """A region of the original image moved onto the rectified one: (Hv, Wv) bool, True where the virtual
    pixel samples (its IMM, map_x/map_y real column/row) a pixel of `mask` (nearest pixel) and is valid.

    Parameters
    ----------
    mask : (H, W) bool
        The region in the original image.
    map_x, map_y : (Hv, Wv) float32
        The IMM: the real position each virtual pixel samples.
    valid : (Hv, Wv) bool
        Not blank.

    Returns
    -------
    mask : (Hv, Wv) bool
    """
    out = cv2.remap(mask.astype(np.uint8), map_x.astype(np.float32), map_y.astype(np.float32), cv2.INTER_NEAREST,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out.astype(bool) & valid


def point_to_rectified(x: float, y: float, map_x: np.ndarray, map_y: np.ndarray, valid: np.ndarray
                       ) -> tuple[int, int] | None:
    """The rectified pixel (column, row) that samples the point (x, y) of the original image most closely
    (the IMM's nearest valid virtual pixel), or None when no valid virtual pixel samples within one pixel of
    it (the point is outside the rectified image).

    Parameters
    ----------
    x, y : float
        Column and row in the original image, pixels.
    map_x, map_y : (Hv, Wv) float32
        The IMM: the real position each virtual pixel samples.
    valid : (Hv, Wv) bool
        Not blank.
    """
    d2 = np.where(valid, (map_x - x) ** 2 + (map_y - y) ** 2, np.inf)
    row, col = np.unravel_index(int(np.argmin(d2)), d2.shape)
    return (int(col), int(row)) if d2[row, col] <= 1.0 else None
