"""The obstacle layout: 47 static wall blocks, on or off as a group, as in the release.

The release's block positions are not published in a form we can read, so this is our own
fixed layout with the same count: a dashed ring of 32 blocks just outside the spawn area, which
robots must thread to reach the zones, and 15 blocks scattered inside it. Every trial uses the
same layout; targets and robots are never placed inside a block.
"""

from __future__ import annotations

from .scenario import Arena

Box = tuple[float, float, float, float]
"""x0, y0, x1, y1."""

LENGTH, THICKNESS = 300.0, 60.0


def _block(x: float, y: float, horizontal: bool) -> Box:
    hx, hy = (LENGTH / 2, THICKNESS / 2) if horizontal else (THICKNESS / 2, LENGTH / 2)
    return (x - hx, y - hy, x + hx, y + hy)


def layout(arena: Arena) -> list[Box]:
    s = arena.spawn_half
    ring = s + 250.0
    along = [s * f for f in (-0.875, -0.625, -0.375, -0.125, 0.125, 0.375, 0.625, 0.875)]
    blocks = [_block(a, side * ring, True) for side in (-1, 1) for a in along]
    blocks += [_block(side * ring, a, False) for side in (-1, 1) for a in along]
    inner = [
        _block(s * fx, s * fy, (ix + iy) % 2 == 0)
        for iy, fy in enumerate((-0.5, 0.0, 0.5))
        for ix, fx in enumerate((-0.8, -0.4, 0.0, 0.4, 0.8))
    ]
    return blocks + inner
