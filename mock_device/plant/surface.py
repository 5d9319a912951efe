"""The plate surface: height z(x, y) in machine Z and where there is metal under the torch."""

import math
from collections.abc import Sequence

from .scenario import KerfSpec, PlateSpec, VoidSpec

__all__ = ["GAP_KERF", "GAP_METAL", "GAP_WIDE", "PlateSurface", "distance_to_segment_mm"]

#: ``PlateSurface.gap_kind`` results: metal under the tip, a narrow gap (old kerf or a void
#: narrower than the arc-loss width), a wide gap (a wide void or off the plate).
GAP_METAL = 0
GAP_KERF = 1
GAP_WIDE = 2


def distance_to_segment_mm(
    point: tuple[float, float], start: tuple[float, float], end: tuple[float, float]
) -> float:
    """Euclidean distance in mm from ``point`` to the segment ``start``-``end`` (x, y pairs)."""
    x_mm, y_mm = point
    x0_mm, y0_mm = start
    x1_mm, y1_mm = end
    dx = x1_mm - x0_mm
    dy = y1_mm - y0_mm
    len2 = dx * dx + dy * dy
    if len2 == 0.0:
        return math.hypot(x_mm - x0_mm, y_mm - y0_mm)
    u = ((x_mm - x0_mm) * dx + (y_mm - y0_mm) * dy) / len2
    u = 0.0 if u < 0.0 else (1.0 if u > 1.0 else u)
    return math.hypot(x_mm - (x0_mm + u * dx), y_mm - (y0_mm + u * dy))


class PlateSurface:
    """Height and metal map of the plate.

    ``z = top + tilt_x·x/1000 + tilt_y·y/1000 + Σ A·sin(k·(x cos φ + y sin φ) + phase)``,
    tilt about the machine origin. There is metal over the plate rectangle
    (0..size_x, 0..size_y) except inside voids and within half a kerf width of an old kerf.
    """

    __slots__ = (
        "_kerfs",
        "_tilt_x",
        "_tilt_y",
        "_top",
        "_voids",
        "_waves",
        "size_x_mm",
        "size_y_mm",
    )

    def __init__(
        self,
        plate: PlateSpec,
        kerfs: Sequence[KerfSpec] = (),
        voids: Sequence[VoidSpec] = (),
        *,
        default_kerf_width_mm: float = 1.5,
        wide_void_mm: float = 6.0,
    ) -> None:
        self._top = plate.top_mm
        self._tilt_x = plate.tilt_x_mm_per_m / 1000.0
        self._tilt_y = plate.tilt_y_mm_per_m / 1000.0
        self.size_x_mm = plate.size_x_mm
        self.size_y_mm = plate.size_y_mm
        self._waves: tuple[tuple[float, float, float, float], ...] = tuple(
            (
                w.amplitude_mm,
                2.0 * math.pi * math.cos(math.radians(w.direction_deg)) / w.wavelength_mm,
                2.0 * math.pi * math.sin(math.radians(w.direction_deg)) / w.wavelength_mm,
                math.radians(w.phase_deg),
            )
            for w in plate.waves
            if w.amplitude_mm > 0.0
        )
        kerf_rows: list[tuple[float, ...]] = []
        for k in kerfs:
            half = 0.5 * (k.width_mm if k.width_mm is not None else default_kerf_width_mm)
            dx = k.x1_mm - k.x0_mm
            dy = k.y1_mm - k.y0_mm
            kerf_rows.append(
                (
                    min(k.x0_mm, k.x1_mm) - half,
                    max(k.x0_mm, k.x1_mm) + half,
                    min(k.y0_mm, k.y1_mm) - half,
                    max(k.y0_mm, k.y1_mm) + half,
                    k.x0_mm,
                    k.y0_mm,
                    dx,
                    dy,
                    dx * dx + dy * dy,
                    half * half,
                )
            )
        self._kerfs = tuple(kerf_rows)
        self._voids = tuple(
            (
                v.x_min_mm,
                v.x_max_mm,
                v.y_min_mm,
                v.y_max_mm,
                GAP_WIDE
                if min(v.x_max_mm - v.x_min_mm, v.y_max_mm - v.y_min_mm) >= wide_void_mm
                else GAP_KERF,
            )
            for v in voids
        )

    def height_mm(self, x_mm: float, y_mm: float) -> float:
        """Surface height in machine Z at (x, y)."""
        z = self._top + self._tilt_x * x_mm + self._tilt_y * y_mm
        for amp, kx, ky, phase in self._waves:
            z += amp * math.sin(kx * x_mm + ky * y_mm + phase)
        return z

    def gradient(self, x_mm: float, y_mm: float) -> tuple[float, float]:
        """(dz/dx, dz/dy) of the surface at (x, y), dimensionless (mm per mm)."""
        gx = self._tilt_x
        gy = self._tilt_y
        for amp, kx, ky, phase in self._waves:
            c = amp * math.cos(kx * x_mm + ky * y_mm + phase)
            gx += c * kx
            gy += c * ky
        return gx, gy

    def gap_kind(self, x_mm: float, y_mm: float) -> int:
        """``GAP_METAL``, ``GAP_KERF`` (narrow gap) or ``GAP_WIDE`` under the point."""
        if not (0.0 <= x_mm <= self.size_x_mm and 0.0 <= y_mm <= self.size_y_mm):
            return GAP_WIDE
        for x_lo, x_hi, y_lo, y_hi, kind in self._voids:
            if x_lo <= x_mm <= x_hi and y_lo <= y_mm <= y_hi:
                return kind
        for x_lo, x_hi, y_lo, y_hi, x0, y0, dx, dy, len2, half2 in self._kerfs:
            if x_mm < x_lo or x_mm > x_hi or y_mm < y_lo or y_mm > y_hi:
                continue
            px = x_mm - x0
            py = y_mm - y0
            u = (px * dx + py * dy) / len2 if len2 > 0.0 else 0.0
            u = 0.0 if u < 0.0 else (1.0 if u > 1.0 else u)
            ex = px - u * dx
            ey = py - u * dy
            if ex * ex + ey * ey <= half2:
                return GAP_KERF
        return GAP_METAL

    def is_metal(self, x_mm: float, y_mm: float) -> bool:
        """True when there is plate metal under (x, y): not a void, not an old kerf."""
        return self.gap_kind(x_mm, y_mm) == GAP_METAL

    def distance_to_nearest_kerf_mm(self, x_mm: float, y_mm: float) -> float:
        """Distance from (x, y) to the centre line of the nearest old kerf (inf if none)."""
        best = math.inf
        for row in self._kerfs:
            x0, y0, dx, dy = row[4], row[5], row[6], row[7]
            best = min(best, distance_to_segment_mm((x_mm, y_mm), (x0, y0), (x0 + dx, y0 + dy)))
        return best
