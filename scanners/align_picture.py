"""The alignment aid's fused picture: what the camera sees, laid onto the display where it sees it, with
the expected and the captured crosshair (the seed's "image fusion of an expected crosshair and the
captured crosshair, displayed on the LCD dynamically").

Drawn in display pixels, at the display's own size, for the pattern display itself:
- background: the camera's picture of the screen (the fringes' mean), warped into display coordinates
  through the measured homography, so the camera's field shows where it lies on the screen;
- cyan, the expected crosshair and field: lines along the display's rows and columns through the foot of
  the perpendicular from the camera's projection centre, a circle of the tolerance around it (the
  distance times tan(tolerance)), and the outline the camera's field would have if it were square;
- green (within the tolerance) or orange (not), the captured crosshair and field: the display points
  the image's central row and column and its border see, and a ring where its line of sight meets the
  screen. Turning the camera moves the ring onto the cyan centre and the orange outline onto the cyan;
- an inset magnifying the two centres (so that the tolerance circle is large) with an arrow: the way
  the captured centre must move (the way to turn the camera);
- the readout as text, beside the camera's field.
"""

from __future__ import annotations

import cv2
import numpy as np

from calib.alignment import display_points, square_points

EXPECTED = (0, 210, 255)
WITHIN = (70, 230, 70)
OUTSIDE = (255, 140, 0)
TEXT = (235, 235, 235)
SHIFT = 4                                    # cv2 drawing with 1/16-pixel coordinates
ONE = 1 << SHIFT


def _pts(p: np.ndarray) -> np.ndarray:
    p = p[np.isfinite(p).all(axis=-1)]
    return np.rint(p * ONE).astype(np.int32).reshape(-1, 1, 2)


def _border(width: int, height: int, n: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """u, v of points around the image border, in order."""
    s = np.linspace(0, 1, n, endpoint=False)
    w, h = width - 1, height - 1
    u = np.concatenate([s * w, np.full(n, w), (1 - s) * w, np.zeros(n)])
    v = np.concatenate([np.zeros(n), s * h, np.full(n, h), (1 - s) * h])
    return u, v


def _camera_layer(canvas: np.ndarray, mean: np.ndarray, valid: np.ndarray, homography: np.ndarray) -> None:
    """Lay the camera's picture (dimmed, grey 40..190) into the canvas where the camera sees the display."""
    h, w = canvas.shape[:2]
    ref = mean[valid][::17] if valid.any() else mean.ravel()
    lo, hi = np.percentile(ref, [1, 99]) if ref.size else (0.0, 1.0)
    grey = cv2.convertScaleAbs(mean, alpha=150 / max(hi - lo, 1e-6), beta=40 - 150 * lo / max(hi - lo, 1e-6))
    grey = np.clip(grey, 40, 190)
    grey[~valid] = 0
    warped = cv2.warpPerspective(grey, homography, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                 borderValue=0)
    np.copyto(canvas, warped[:, :, None], where=(warped >= 20)[:, :, None])


def _wrap(lines: list[tuple[str, tuple]], width: int, size: float, thick: int) -> list[tuple[str, tuple]]:
    """Lines broken at spaces so that each fits `width` pixels (continuations indented)."""
    out = []
    for text, colour in lines:
        words, line = text.split(" "), ""
        for word in words:
            trial = f"{line} {word}" if line else word
            if line and cv2.getTextSize(trial, cv2.FONT_HERSHEY_SIMPLEX, size, thick)[0][0] > width:
                out.append((line, colour))
                line = "   " + word
            else:
                line = trial
        out.append((line, colour))
    return out


def _text_block(canvas: np.ndarray, lines: list[tuple[str, tuple]], origin: tuple[int, int], width: int,
                scale: float) -> int:
    """Draw the lines, wrapped to `width` pixels, on a darkened box at `origin`; returns its height."""
    font, size, thick = cv2.FONT_HERSHEY_SIMPLEX, 0.75 * scale, max(1, round(2 * scale))
    step = round(30 * scale)
    lines = _wrap(lines, width - step, size, thick)
    x0, y0 = origin
    height = step * len(lines) + step // 2
    box = canvas[y0:y0 + height, x0:x0 + width]
    box[:] = (box * 0.25).astype(np.uint8)
    for i, (text, colour) in enumerate(lines):
        cv2.putText(canvas, text, (x0 + step // 2, y0 + step * (i + 1)), font, size, colour, thick, cv2.LINE_AA)
    return height


def _cross(canvas, centre, arm, angle_rad, colour, thick) -> None:
    for d in (np.array([np.cos(angle_rad), np.sin(angle_rad)]), np.array([-np.sin(angle_rad), np.cos(angle_rad)])):
        cv2.line(canvas, tuple(_pts(centre - arm * d)[0, 0]), tuple(_pts(centre + arm * d)[0, 0]), colour, thick,
                 cv2.LINE_AA, SHIFT)


def _inset(canvas: np.ndarray, offset_px: np.ndarray, roll_deg: float, tolerance_px: float, tolerance_deg: float,
           colour: tuple, corner: tuple[int, int], side: int, status: str, scale: float) -> None:
    """The two centres magnified: the expected crosshair in the middle, the captured one at the offset
    times the zoom, the tolerance circle at the same zoom, an arrow the way the captured centre must
    move. The zoom puts the tolerance circle at a fifth of the inset, or less when the captured centre
    would fall outside; the captured crosshair's roll is magnified too (a roll of the tolerance shows
    as 10 degrees, at most 45)."""
    x0, y0 = corner
    panel = canvas[y0:y0 + side, x0:x0 + side]
    panel[:] = (panel * 0.2).astype(np.uint8)
    cv2.rectangle(canvas, (x0, y0), (x0 + side - 1, y0 + side - 1), TEXT, 1)
    font, thick = cv2.FONT_HERSHEY_SIMPLEX, max(1, round(2 * scale))
    head = round(44 * scale)
    cv2.putText(canvas, status, (x0 + round(12 * scale), y0 + round(32 * scale)), font, 0.9 * scale, colour, thick,
                cv2.LINE_AA)
    c = np.array([x0 + side / 2, y0 + (side + head) / 2])
    room = (side - head) / 2 - 12 * scale
    gain = min(0.4 * room / max(tolerance_px, 1e-9), 0.5 * room / max(np.linalg.norm(offset_px), 1e-9))
    _cross(canvas, c, room, 0.0, EXPECTED, thick)
    cv2.circle(canvas, tuple(_pts(c)[0, 0]), round(tolerance_px * gain * ONE), EXPECTED, thick, cv2.LINE_AA, SHIFT)
    p = c + offset_px * gain
    turn = min(10 / tolerance_deg, 45 / max(abs(roll_deg), 1e-9))
    _cross(canvas, p, 0.45 * room, np.radians(roll_deg * turn), colour, thick)
    cv2.circle(canvas, tuple(_pts(p)[0, 0]), round(0.06 * room * ONE), colour, thick, cv2.LINE_AA, SHIFT)
    gap = np.linalg.norm(c - p)
    if gap > 0.15 * room:
        tip = p + (c - p) * (1 - 0.06 * room / gap)
        cv2.arrowedLine(canvas, tuple(_pts(p)[0, 0]), tuple(_pts(tip)[0, 0]), colour, thick, cv2.LINE_AA, SHIFT,
                        min(0.5, 0.15 * room / gap))
    caption = (x0 + round(12 * scale), y0 + side - round(12 * scale))
    cv2.putText(canvas, f"zoom x{gain:.1f}, roll x{turn:.0f}", caption, font, 0.6 * scale, TEXT,
                max(1, round(1.5 * scale)), cv2.LINE_AA)


def fused_picture(size: tuple[int, int], measurement, pitch_mm, tolerance_deg: float,
                  lines: list[tuple[str, tuple]]) -> np.ndarray:
    """The fused picture, (height, width, 3) uint8 RGB at the display's `size` = (width, height).

    measurement: a `scanners.align.Measurement` (decoded map, homography, camera model, pose, reading);
    pitch_mm: the display's pixel pitch; tolerance_deg: the squareness tolerance; lines: the readout,
    (text, RGB colour) pairs, drawn beside the camera's field (where there is most room) with the inset
    below them.
    """
    w, h = size
    scale = h / 1080
    canvas = np.full((h, w, 3), 48, np.uint8)
    m, rd = measurement, measurement.reading
    _camera_layer(canvas, m.display_map.mean, m.display_map.valid, m.homography)
    model, fit = m.model, m.fit
    within = rd.square_within(tolerance_deg)
    colour = WITHIN if within else OUTSIDE
    thin, thick = max(2, round(2 * scale)), max(3, round(4 * scale))
    tol_px = rd.distance_mm * np.tan(np.radians(tolerance_deg)) / pitch_mm[0]
    foot = rd.foot_px
    _cross(canvas, foot, 2.0 * max(w, h), 0.0, EXPECTED, thin)
    cv2.circle(canvas, tuple(_pts(foot)[0, 0]), round(tol_px * ONE), EXPECTED, thin, cv2.LINE_AA, SHIFT)
    bu, bv = _border(model.width, model.height)
    cv2.polylines(canvas, [_pts(square_points(model, fit, bu, bv, pitch_mm))], True, EXPECTED, thin, cv2.LINE_AA,
                  SHIFT)
    field = display_points(model, fit, bu, bv, pitch_mm)
    cv2.polylines(canvas, [_pts(field)], True, colour, thick, cv2.LINE_AA, SHIFT)
    s = np.linspace(0, 1, 65)
    for u, v in ((s * (model.width - 1), np.full_like(s, (model.height - 1) / 2)),
                 (np.full_like(s, (model.width - 1) / 2), s * (model.height - 1))):
        cv2.polylines(canvas, [_pts(display_points(model, fit, u, v, pitch_mm))], False, colour, thick,
                      cv2.LINE_AA, SHIFT)
    cv2.circle(canvas, tuple(_pts(rd.line_of_sight_px)[0, 0]), round(max(tol_px, 6 * scale) * ONE), colour, thick,
               cv2.LINE_AA, SHIFT)
    margin = round(20 * scale)
    seen = field[np.isfinite(field).all(axis=1)]
    left, right = (np.clip([seen[:, 0].min(), seen[:, 0].max()], 0, w) if len(seen) else (w / 2, w / 2))
    room_left, room_right = left - 2 * margin, w - right - 2 * margin
    width = int(max(room_left, room_right, 0.28 * w))
    x0 = margin if room_left >= room_right else w - margin - width
    used = _text_block(canvas, lines, (x0, margin), width, scale)
    side = int(min(0.4 * h, width, h - used - 3 * margin))
    if side < 0.2 * h:                                   # no room under the text: the other side's bottom
        side = int(0.3 * h)
        x0 = w - margin - side if x0 == margin else margin
    _inset(canvas, rd.line_of_sight_px - foot, rd.roll_deg, tol_px, tolerance_deg, colour,
           (x0, h - margin - side), side, "SQUARE" if within else "NOT SQUARE", scale)
    return canvas


def message_picture(size: tuple[int, int], lines: list[tuple[str, tuple]]) -> np.ndarray:
    """A plain picture with a few lines of text (when there is nothing to fuse)."""
    canvas = np.full((size[1], size[0], 3), 48, np.uint8)
    margin = round(20 * size[1] / 1080)
    _text_block(canvas, lines, (margin, margin), size[0] - 2 * margin, size[1] / 1080)
    return canvas


__all__ = ["fused_picture", "message_picture"]
