"""A tiny numpy rasteriser for the classic envs' rgb_array frames (no pygame, no display).

Coordinates are pixels, x to the right and y down, with pixel centres at ``i + 0.5``. Each shape
is tested against the pixel centres inside its bounding box only, so a frame costs a few
milliseconds. No antialiasing: frames are for watching a policy, not for print.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

Color = tuple[int, int, int]
Point = tuple[float, float]


class Canvas:
    """An ``(height, width, 3)`` uint8 image to draw filled shapes on."""

    def __init__(self, width: int, height: int, background: Color = (255, 255, 255)):
        self.pixels = np.empty((height, width, 3), np.uint8)
        self.pixels[...] = background

    @property
    def width(self) -> int:
        """Width in pixels."""
        return self.pixels.shape[1]

    @property
    def height(self) -> int:
        """Height in pixels."""
        return self.pixels.shape[0]

    def _window(
        self, low: Point | np.ndarray, high: Point | np.ndarray
    ) -> tuple[slice, slice, np.ndarray, np.ndarray]:
        """Rows/columns covering the box ``low..high`` (two points, or two arrays of ``(x, y)``),
        with their pixel-centre coordinates."""
        x0 = int(np.clip(np.floor(low[0]), 0, self.width))
        x1 = int(np.clip(np.ceil(high[0]) + 1, 0, self.width))
        y0 = int(np.clip(np.floor(low[1]), 0, self.height))
        y1 = int(np.clip(np.ceil(high[1]) + 1, 0, self.height))
        xs = np.arange(x0, x1, dtype=np.float64)[None, :] + 0.5
        ys = np.arange(y0, y1, dtype=np.float64)[:, None] + 0.5
        return slice(y0, y1), slice(x0, x1), xs, ys

    def _paint(self, rows: slice, cols: slice, mask: np.ndarray, color: Color) -> None:
        self.pixels[rows, cols][mask] = color

    def polygon(self, points: Sequence[Point], color: Color) -> None:
        """Fill a convex polygon (either winding)."""
        corners = np.asarray(points, np.float64)
        rows, cols, xs, ys = self._window(corners.min(axis=0), corners.max(axis=0))
        if xs.size == 0 or ys.size == 0:
            return
        edges = np.roll(corners, -1, axis=0) - corners
        # The sign of the cross product says on which side of each edge a pixel lies; inside a
        # convex polygon it is the same for every edge.
        crosses = [
            edge[0] * (ys - corner[1]) - edge[1] * (xs - corner[0])
            for corner, edge in zip(corners, edges, strict=True)
        ]
        inside = np.all([c >= 0 for c in crosses], axis=0) | np.all(
            [c <= 0 for c in crosses], axis=0
        )
        self._paint(rows, cols, inside, color)

    def rectangle(self, left: float, top: float, right: float, bottom: float, color: Color) -> None:
        """Fill the axis-aligned rectangle between ``(left, top)`` and ``(right, bottom)``."""
        self.polygon([(left, top), (right, top), (right, bottom), (left, bottom)], color)

    def circle(self, center: Point, radius: float, color: Color) -> None:
        """Fill the disc of ``radius`` pixels around ``center``."""
        cx, cy = center
        rows, cols, xs, ys = self._window((cx - radius, cy - radius), (cx + radius, cy + radius))
        self._paint(rows, cols, (xs - cx) ** 2 + (ys - cy) ** 2 <= radius**2, color)

    def line(self, start: Point, end: Point, width: float, color: Color) -> None:
        """A segment of the given width with rounded ends."""
        start_arr, end_arr = np.asarray(start, np.float64), np.asarray(end, np.float64)
        half = width / 2.0
        low = np.minimum(start_arr, end_arr) - half
        high = np.maximum(start_arr, end_arr) + half
        rows, cols, xs, ys = self._window(low, high)
        direction = end_arr - start_arr
        length_sq = max(float(direction @ direction), 1e-12)
        along = (
            (xs - start_arr[0]) * direction[0] + (ys - start_arr[1]) * direction[1]
        ) / length_sq
        along = np.clip(along, 0.0, 1.0)
        dx = xs - (start_arr[0] + along * direction[0])
        dy = ys - (start_arr[1] + along * direction[1])
        self._paint(rows, cols, dx**2 + dy**2 <= half**2, color)

    def image(self) -> np.ndarray:
        """A copy of the pixels, ``[height, width, 3]`` uint8."""
        return self.pixels.copy()
