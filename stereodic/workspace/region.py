"""The specimen's region of interest, drawn in the ORIGINAL left reference image and handed to `stereodic
dic` as its `--mask` in the LEFT RECTIFIED image.

A region is a list of polygons (rectangles are polygons of four corners), each either a part of the
region or a hole cut out of it, in the original left image's pixels (x = column, y = row, integer
coordinates at pixel centres). `original_mask` fills them (parts, then holes cleared); `rectified_mask`
carries that mask through the rig's left IMM (each rectified pixel takes the value of the original pixel
it samples), so that the region drawn on the camera's own image is where `dic` correlates.

`automatic_region` finds the speckled specimen from the speckle's predicted displacement noise
(`stereodic.dic.speckle_quality`: where a subset's predicted random error is low, the image has the
texture of a speckle pattern; plain background, shadow and saturated areas do not): the largest connected
area whose prediction is within a factor of the median's, as one polygon (its outline, simplified).
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass

import cv2
import numpy as np

from calib.errors import InputError

HOLE_COLOUR = "#ff3030"     # a drawn shape in this colour is a hole
PART_COLOUR = "#30ff30"


@dataclass
class Polygon:
    """One polygon of a region: (N, 2) float64 vertices (x, y) in the original left image, pixels; `hole`:
    cut out of the region rather than added to it."""

    points: np.ndarray
    hole: bool = False


def original_mask(polygons: list[Polygon], size: tuple[int, int]) -> np.ndarray:
    """(H, W) bool mask of the region in the original image of `size` (width, height): the parts filled,
    then the holes cleared (module docstring)."""
    w, h = size
    mask = np.zeros((h, w), np.uint8)
    for hole in (False, True):
        for p in polygons:
            if p.hole == hole:
                cv2.fillPoly(mask, [np.round(p.points).astype(np.int32).reshape(-1, 1, 2)], 0 if hole else 1)
    return mask.astype(bool)


def rectified_mask(mask: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(Hv, Wv) bool: the original-image `mask` seen in the rectified image whose pixels sample the original
    at (map_x, map_y) (the rig's left IMM; False where `valid` is False or the sample leaves the image)."""
    h, w = mask.shape
    col = np.round(map_x).astype(np.int64)
    row = np.round(map_y).astype(np.int64)
    inside = valid & (col >= 0) & (col < w) & (row >= 0) & (row < h)
    out = np.zeros(map_x.shape, bool)
    out[inside] = mask[row[inside], col[inside]]
    return out


def automatic_region(noise_map_px: np.ndarray, *, factor: float = 2.0) -> list[Polygon]:
    """The speckled specimen's region (module docstring) from the map of predicted displacement noise
    (pixels, NaN where a subset does not fit): one polygon, or none where nothing is textured."""
    finite = np.isfinite(noise_map_px)
    if not finite.any():
        return []
    good = (finite & (noise_map_px <= factor * np.median(noise_map_px[finite]))).astype(np.uint8)
    good = cv2.morphologyEx(good, cv2.MORPH_OPEN, np.ones((5, 5), np.uint8))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(good)
    if n < 2:
        return []
    biggest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    contours, _ = cv2.findContours((labels == biggest).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    outline = max(contours, key=cv2.contourArea)
    outline = cv2.approxPolyDP(outline, 0.01 * cv2.arcLength(outline, True), True)
    return [Polygon(outline.reshape(-1, 2).astype(np.float64))]


def to_json(polygons: list[Polygon]) -> list[dict]:
    """The region as JSON data: [{"points": [[x, y], ...], "hole": bool}, ...]."""
    return [{"points": p.points.tolist(), "hole": bool(p.hole)} for p in polygons]


def from_json(data, where: str | os.PathLike = "region") -> list[Polygon]:
    """The region of `to_json`'s data (or its JSON text); InputError naming `where` when a polygon has
    fewer than three vertices or its numbers are not pairs."""
    if isinstance(data, str):
        data = json.loads(data)
    out = []
    for i, item in enumerate(data or []):
        try:
            pts = np.asarray(item["points"], np.float64).reshape(-1, 2)
        except (KeyError, TypeError, ValueError):
            raise InputError(where, f"polygon {i} is not a list of [x, y] pairs") from None
        if len(pts) < 3 or not np.isfinite(pts).all():
            raise InputError(where, f"polygon {i} needs at least three finite vertices, has {len(pts)}")
        out.append(Polygon(pts, bool(item.get("hole", False))))
    return out


def shape_polygon(shape: dict) -> Polygon:
    """The polygon of a plotly shape (a rectangle, or a path "M x,y L x,y ... Z"); a hole when drawn in
    HOLE_COLOUR."""
    hole = (shape.get("line") or {}).get("color") == HOLE_COLOUR
    if shape.get("type") == "rect":
        x0, y0, x1, y1 = (float(shape[k]) for k in ("x0", "y0", "x1", "y1"))
        return Polygon(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]), hole)
    numbers = [float(v) for v in re.findall(r"-?\d+(?:\.\d+)?(?:[eE]-?\d+)?", shape.get("path", ""))]
    return Polygon(np.array(numbers).reshape(-1, 2), hole)


def polygon_shape(p: Polygon) -> dict:
    path = "M" + "L".join(f"{x:.1f},{y:.1f}" for x, y in p.points) + "Z"
    colour = HOLE_COLOUR if p.hole else PART_COLOUR
    return dict(type="path", path=path, line=dict(color=colour, width=2), fillcolor=colour, opacity=0.25,
                editable=True, layer="above")
