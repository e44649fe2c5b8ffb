"""Where the things of ``lift3d synth``'s rooms go: free floor spots (bounding circles apart, inside the room,
maybe with the back to a wall), a spot beside another thing (a chair at a table), and a spot on a support's
top (a cup on a table)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lift3d.synth.geometry import rotation_z, unit
from lift3d.synth.polygons import distance_to_outline, inside_polygon


def place_on_floor(rng, radius: float, poly: np.ndarray, circles: list[tuple[np.ndarray, float]],
                   along_wall: bool, gap: float = 0.1, tries: int = 300,
                   walls: list | None = None) -> tuple[np.ndarray, float] | None:
    """A free floor position (bounding circles ``gap`` apart, inside the room) and a yaw, or None.

    ``walls`` (counter-clockwise edges ``(a, b)``) are what ``along_wall`` things stand against, a short piece
    of a curved wall at its middle; None: the edges of ``poly`` (the original rooms' rule, drawn as before).
    """
    lo, hi = poly.min(0), poly.max(0)
    edges = [(a, b) for a, b in zip(poly, np.roll(poly, -1, axis=0))] if walls is None else walls
    lengths = np.array([np.linalg.norm(b - a) for a, b in edges])
    for _ in range(tries):
        if along_wall:  # back to a wall (the front, +y, faces into the room)
            k = int(rng.choice(len(edges), p=lengths / lengths.sum()))
            a, b = edges[k]
            along = unit(b - a)
            inward = np.array([-along[1], along[0]])  # counter-clockwise outline: the interior is on the left
            if walls is not None and lengths[k] < 2 * radius + 0.1:
                t = lengths[k] / 2  # a piece of a curved wall: its middle, so the circle touches the curve there
            else:
                t = rng.uniform(radius + 0.05, max(radius + 0.05, lengths[k] - radius - 0.05))
            c = a + along * t + inward * (radius + 0.03)
            yaw = float(np.arctan2(inward[1], inward[0]) - np.pi / 2)
        else:
            c = rng.uniform(lo, hi)
            yaw = float(rng.uniform(0, 2 * np.pi))
        if not inside_polygon(c[None], poly)[0] or distance_to_outline(c[None], poly)[0] < radius + 0.02:
            continue
        if all(np.linalg.norm(c - p) > radius + r + gap for p, r in circles):
            return c, yaw
    return None


def place_next_to(rng, radius: float, anchor: tuple[np.ndarray, float], poly, circles,
                  tries: int = 40) -> tuple[np.ndarray, float] | None:
    """A position beside ``anchor`` (centre, radius), facing it (a chair at a table)."""
    centre, r_anchor = anchor
    for _ in range(tries):
        ang = rng.uniform(0, 2 * np.pi)
        c = centre + (r_anchor + radius + rng.uniform(0.0, 0.1)) * np.array([np.cos(ang), np.sin(ang)])
        if not inside_polygon(c[None], poly)[0] or distance_to_outline(c[None], poly)[0] < radius + 0.02:
            continue
        if all(np.linalg.norm(c - p) > radius + r + 0.05 for p, r in circles if p is not centre):
            towards = centre - c
            return c, float(np.arctan2(towards[1], towards[0]) - np.pi / 2)
    return None


@dataclass
class Support:
    """A flat top small things stand on: ``top`` is ``(half_x, half_y, z)`` in the frame of the thing at
    ``centre`` turned by ``yaw``; ``circles`` the footprints already on it (local)."""

    index: int  # into objects
    centre: np.ndarray
    yaw: float
    top: tuple[float, float, float]
    circles: list


def place_on_support(rng, radius: float, supports: list[Support], tries: int = 30):
    """A support, a world position on its top and a yaw for a small thing of footprint ``radius``, or None."""
    fits = [s for s in supports if min(s.top[0], s.top[1]) >= radius + 0.01]
    for s in [fits[k] for k in rng.permutation(len(fits))]:
        hx, hy, z = s.top
        for _ in range(tries):
            local = rng.uniform([-hx + radius, -hy + radius], [hx - radius, hy - radius])
            if all(np.linalg.norm(local - p) > radius + r + 0.02 for p, r in s.circles):
                s.circles.append((local, radius))
                world = s.centre + rotation_z(s.yaw)[:2, :2] @ local
                return s, np.array([world[0], world[1], z]), float(rng.uniform(0, 2 * np.pi))
    return None
