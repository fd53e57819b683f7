"""The arena of the authors' release: walls, obstacle blocks, zones and spawn area.

Every number is ``spec/simulator.md`` §2, read from the release's scene. Unity's
ground plane (x, z) maps to our (x, y) unchanged; angles are counter-clockwise from +x.
"""

from __future__ import annotations

import math

import numpy as np

HALF = 4000.0
"""Centre line of the perimeter walls: x, y = ±4000 (§2)."""
SEGMENT_LENGTH = 200.0
SEGMENT_THICKNESS = 40.0
"""Every wall, perimeter or obstacle, is a chain of 200 x 40 box segments (§2)."""
SPAWN_HALF = 2000.0
"""Robots and targets are placed uniformly in [-2000, 2000]², without rejection (§3)."""
TARGET_SIZE = 20.0
"""A target is a 20-unit cube (§2)."""

ZONE_CENTRES = ((2800.0, 2800.0), (-2800.0, 2800.0), (-2800.0, -2800.0), (2812.0, -2800.0))
"""Zone of colour 1..4 (red, green, yellow, blue); zone 4's centre is offset to x = 2812 in
the release's scene (§2)."""
ZONE_OUTER = 1000.0
"""A carried target counts when its cube enters this square around its zone's centre (§4.5)."""
ZONE_INNER = 800.0
"""A carrier places when its zone detector enters this square (§4.5)."""

OBSTACLES: tuple[tuple[float, float, float], ...] = (
    (2873.4, 815.9, 125.0), (-870.8, 101.1, 81.5), (-841.2, 298.9, 81.5),
    (-833.7, 2078.5, 102.9), (-878.3, 2273.5, 102.9), (3102.6, 488.1, 125.0),
    (2988.0, 652.0, 125.0), (1187.5, -2640.5, 26.0), (-115.7, -1367.7, 26.0),
    (64.0, -1280.0, 26.0), (243.7, -1192.3, 26.0), (828.0, -2816.0, 26.0),
    (1007.7, -2728.3, 26.0), (-2379.7, 488.5, 26.0), (-2200.0, 576.3, 26.0),
    (-2020.3, 664.0, 26.0), (1464.5, -499.5, 26.0), (1644.3, -411.7, 26.0),
    (1824.0, -324.0, 26.0), (-3120.8, -1228.8, 116.4), (-3032.0, -1408.0, 116.4),
    (-2943.2, -1587.2, 116.4), (1480.5, 2252.5, 26.0), (1660.3, 2340.3, 26.0),
    (1840.0, 2428.0, 26.0), (-2364.0, 2032.0, 26.0), (-2184.3, 2119.7, 26.0),
    (-2004.5, 2207.5, 26.0), (2500.0, -680.0, 146.6), (2667.0, -790.1, 146.6),
    (2834.0, -900.1, 146.6), (-1027.0, -2279.9, 146.6), (-860.0, -2389.9, 146.6),
    (-693.0, -2500.0, 146.6), (-2236.0, -1256.0, 146.6), (-2069.0, -1366.1, 146.6),
    (-1902.0, -1476.1, 146.6), (-8.0, 1259.5, 179.0), (192.0, 1256.0, 179.0),
    (998.2, 432.3, 112.9), (1076.0, 248.0, 112.9), (1153.8, 63.7, 112.9),
    (-3328.3, -2396.0, 90.0), (-3324.0, -2596.0, 90.0), (-3319.7, -2796.0, 90.0),
    (-3320.5, -2968.1, 90.0), (-3316.3, -3168.0, 90.0),
)  # fmt: skip
"""The 47 obstacle segments: centre (x, y) and the angle of the long axis in degrees (§2)."""


Segment = tuple[float, float, float, float]
"""A wall segment: centre x, y, the angle of its long axis in degrees, its length."""


def perimeter(scale: float = 1.0) -> list[Segment]:
    """The perimeter segments: at scale 1, 40 a wall centred at -3900, -3700, …, 3900 along it
    (§2). A scaled arena keeps as many 200-long segments as fit, stretched to close the wall."""
    half = HALF * scale
    count = max(1, round(2 * half / SEGMENT_LENGTH))
    length = 2 * half / count
    out: list[Segment] = []
    for k in range(count):
        c = -half + length * (k + 0.5)
        out += [(c, half, 0.0, length), (c, -half, 0.0, length)]
        out += [(half, c, 90.0, length), (-half, c, 90.0, length)]
    return out


def segments(obstacles: bool, scale: float = 1.0) -> list[Segment]:
    """Every wall segment of an arena, perimeter first; obstacle centres scale with the arena,
    their size does not."""
    blocks = [(x * scale, y * scale, a, SEGMENT_LENGTH) for x, y, a in OBSTACLES]
    return perimeter(scale) + (blocks if obstacles else [])


def corners(
    x: float, y: float, angle_deg: float, length: float = SEGMENT_LENGTH
) -> list[tuple[float, float]]:
    """The four corners of the segment centred at (x, y) with its long axis at ``angle_deg``."""
    a = math.radians(angle_deg)
    ux, uy = math.cos(a) * length / 2, math.sin(a) * length / 2
    vx, vy = -math.sin(a) * SEGMENT_THICKNESS / 2, math.cos(a) * SEGMENT_THICKNESS / 2
    return [(x + sx * ux + tx * vx, y + sx * uy + tx * vy) for sx, tx in SQUARE]


SQUARE = ((-1, -1), (1, -1), (1, 1), (-1, 1))


def zone_centres(scale: float = 1.0) -> np.ndarray:
    return np.array(ZONE_CENTRES) * scale
