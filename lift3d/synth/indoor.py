"""The indoor scenes of ``lift3d synth``: a furnished room drawn from the layout's random stream.

What a seed chooses (``docs/synth.md`` lists the ranges):

* the room: a rectangle of 3.5-9 m a side or an L (a rectangle with one corner cut out), 2.4-3.4 m high,
  with 0-3 windows and maybe a rug;
* wall and floor textures, from near-textureless paint to strong patterns (wallpaper stripes, bricks, tiles,
  planks), each with a *texture level* in [0, 1];
* the lighting: a key and a fill light (direction, intensity), a colour temperature of 2700-6500 K and an
  ambient level, scaled to a plausible exposure;
* 6-16 objects from :data:`CATALOGUE`, with sizes from a 2 m sofa down to a 7 cm cup and thin parts
  (chair and stool legs, lamp poles); large pieces stand on the floor (cabinets, shelves, sofas and most
  lamps and plants along the walls, chairs often at a table) and small ones on the tops of tables, cabinets,
  shelves, stools and boxes (a cup on a table).

Floor footprints (bounding circles) never overlap and everything rests on the floor or on its support.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lift3d.data.scene import Category
from lift3d.synth.geometry import (
    Lighting,
    MaterialBank,
    Mesh,
    SceneContent,
    SceneObject,
    box_mesh,
    concat_meshes,
    cylinder_mesh,
    example_mesh,
    fit_on_floor,
    hsv,
    kelvin_rgb,
    lathe_mesh,
    quad_mesh,
    rotation_z,
    sphere_mesh,
    two_tone,
    unit,
)

INDOOR_CATEGORIES = [
    Category(1, "wall", False, (174, 199, 232)),
    Category(2, "floor", False, (152, 223, 138)),
    Category(3, "ceiling", False, (78, 71, 183)),
    Category(4, "rug", False, (255, 187, 120)),
    Category(5, "window", False, (197, 176, 213)),
    Category(6, "table", True, (255, 127, 14)),
    Category(7, "chair", True, (188, 189, 34)),
    Category(8, "cabinet", True, (31, 119, 180)),
    Category(9, "ball", True, (214, 39, 40)),
    Category(10, "lamp", True, (227, 119, 194)),
    Category(11, "plant", True, (44, 160, 44)),
    Category(12, "sculpture", True, (140, 86, 75)),
    Category(13, "toy_plane", True, (23, 190, 207)),
    Category(14, "sofa", True, (82, 84, 163)),
    Category(15, "shelf", True, (148, 103, 189)),
    Category(16, "stool", True, (196, 156, 148)),
    Category(17, "book", True, (247, 182, 210)),
    Category(18, "cup", True, (127, 127, 127)),
    Category(19, "vase", True, (219, 219, 141)),
    Category(20, "figurine", True, (158, 218, 229)),
    Category(21, "box", True, (57, 59, 121)),
]

#: Plausible confusions of the simulated segmenter (same kind: thing -> thing, stuff -> stuff).
INDOOR_CONFUSABLE = {
    1: [5, 3], 2: [4, 1], 3: [1], 4: [2], 5: [1],
    6: [8, 16, 15], 7: [16, 14, 6], 8: [15, 6, 21], 9: [10, 11, 12, 19], 10: [11, 19, 12], 11: [19, 10, 9],
    12: [20, 13, 19], 13: [12, 20, 7], 14: [7, 8], 15: [8, 6], 16: [7, 6], 17: [21, 15], 18: [19, 9],
    19: [18, 11, 12], 20: [12, 13, 19], 21: [8, 17],
}

#: What may stand on the floor and what on a support, with the relative frequency of each class.
FLOOR_WEIGHTS = {
    "table": 1.0, "chair": 1.3, "cabinet": 0.8, "shelf": 0.6, "sofa": 0.5, "stool": 0.5, "lamp": 0.6,
    "plant": 0.7, "sculpture": 0.5, "toy_plane": 0.4, "ball": 0.6, "box": 0.5, "vase": 0.3,
}
SMALL_WEIGHTS = {
    "book": 1.0, "cup": 1.0, "vase": 0.7, "figurine": 0.9, "lamp": 0.4, "toy_plane": 0.4, "ball": 0.4,
    "box": 0.5, "plant": 0.4,
}
#: Floor pieces that usually stand with their back to a wall.
ALONG_WALL = {"cabinet": 0.9, "shelf": 0.95, "sofa": 0.8, "lamp": 0.7, "plant": 0.6}
#: The catalogue of thing classes (a class can come in a floor and a small size).
CATALOGUE = sorted(set(FLOOR_WEIGHTS) | set(SMALL_WEIGHTS))


@dataclass
class Built:
    """A thing built standing on z = 0 around the z axis, front towards +y.

    ``radius`` bounds its floor footprint; ``top`` is ``(half_x, half_y, z)`` of a flat top other things
    may stand on (local frame), or None.
    """

    mesh: Mesh
    radius: float
    top: tuple[float, float, float] | None = None


# --------------------------------------------------------------------------------------------- materials
def _wood(rng, mats: MaterialBank) -> int:
    return mats.add(*two_tone(rng, rng.uniform(0.05, 0.11), rng.uniform(0.35, 0.7), rng.uniform(0.3, 0.7), 0.25),
                    0.5, gain=1.5, stripe=(np.array([1.0, 0.2, 0.0]), 0.45, 1.2))


def _paint(rng, mats: MaterialBank, sat: float = 0.6, val: float = 0.7, spread: float = 0.3) -> int:
    return mats.add(*two_tone(rng, rng.uniform(0, 1), sat, val, spread), rng.uniform(0.45, 0.7), gain=1.3)


# --------------------------------------------------------------------------------------------- catalogue
def _table(rng, mats) -> Built:
    mat = _wood(rng, mats)
    if rng.random() < 0.3:  # round, on a pedestal
        r, h = rng.uniform(0.35, 0.6), rng.uniform(0.5, 0.76)
        th = rng.uniform(0.03, 0.05)
        top = cylinder_mesh(r, th, mat).transformed(np.eye(3), [0, 0, h - th])
        stem = cylinder_mesh(rng.uniform(0.03, 0.06), h - th, mat, segments=12)
        foot = cylinder_mesh(0.6 * r, 0.03, mat)
        return Built(concat_meshes([top, stem, foot]), r, (0.65 * r, 0.65 * r, h))
    w = rng.uniform(0.6, 1.8)
    d, h = rng.uniform(0.5, min(1.0, w)), rng.uniform(0.45, 0.78)
    th, leg = rng.uniform(0.03, 0.06), rng.uniform(0.02, 0.045)
    top = box_mesh([-w / 2, -d / 2, h - th], [w / 2, d / 2, h], mat)
    legs = [box_mesh([sx * (w / 2 - 0.05) - leg, sy * (d / 2 - 0.05) - leg, 0.0],
                     [sx * (w / 2 - 0.05) + leg, sy * (d / 2 - 0.05) + leg, h - th], mat)
            for sx in (-1, 1) for sy in (-1, 1)]
    return Built(concat_meshes([top] + legs), 0.5 * np.hypot(w, d), (w / 2, d / 2, h))


def _chair(rng, mats) -> Built:
    mat = _paint(rng, mats) if rng.random() < 0.5 else _wood(rng, mats)
    s, h = rng.uniform(0.38, 0.5), rng.uniform(0.42, 0.48)
    leg = rng.uniform(0.012, 0.03)
    seat = box_mesh([-s / 2, -s / 2, h - 0.04], [s / 2, s / 2, h], mat)
    back = box_mesh([-s / 2, -s / 2, h], [s / 2, -s / 2 + 0.04, h + rng.uniform(0.35, 0.55)], mat)
    legs = [box_mesh([sx * (s / 2 - leg - 0.01) - leg, sy * (s / 2 - leg - 0.01) - leg, 0.0],
                     [sx * (s / 2 - leg - 0.01) + leg, sy * (s / 2 - leg - 0.01) + leg, h - 0.04], mat)
            for sx in (-1, 1) for sy in (-1, 1)]
    return Built(concat_meshes([seat, back] + legs), s / np.sqrt(2))


def _cabinet(rng, mats) -> Built:
    mat = _wood(rng, mats) if rng.random() < 0.6 else _paint(rng, mats, sat=0.3, val=0.75, spread=0.15)
    w, d, h = rng.uniform(0.4, 1.2), rng.uniform(0.3, 0.6), rng.uniform(0.5, 2.0)
    body = box_mesh([-w / 2, -d / 2, 0.0], [w / 2, d / 2, h], mat)
    top = box_mesh([-w / 2 - 0.02, -d / 2 - 0.02, h], [w / 2 + 0.02, d / 2 + 0.02, h + 0.03], mat)
    return Built(concat_meshes([body, top]), 0.5 * np.hypot(w + 0.04, d + 0.04),
                 (w / 2, d / 2, h + 0.03) if h < 1.3 else None)


def _shelf(rng, mats) -> Built:
    mat = _wood(rng, mats)
    w, d, h = rng.uniform(0.6, 1.2), rng.uniform(0.25, 0.4), rng.uniform(0.8, 2.0)
    t = rng.uniform(0.02, 0.03)
    parts = [box_mesh([-w / 2, -d / 2, 0.0], [-w / 2 + t, d / 2, h], mat),  # sides
             box_mesh([w / 2 - t, -d / 2, 0.0], [w / 2, d / 2, h], mat),
             box_mesh([-w / 2, -d / 2, 0.0], [w / 2, -d / 2 + t, h], mat)]  # back
    n_boards = max(2, int(h / 0.35))
    for k in range(n_boards + 1):  # bottom, shelves and top
        z = k * (h - t) / n_boards
        parts.append(box_mesh([-w / 2, -d / 2, z], [w / 2, d / 2, z + t], mat))
    return Built(concat_meshes(parts), 0.5 * np.hypot(w, d), (w / 2, d / 2, h) if h < 1.3 else None)


def _sofa(rng, mats) -> Built:
    mat = mats.add(*two_tone(rng, rng.uniform(0, 1), rng.uniform(0.2, 0.6), rng.uniform(0.35, 0.7), 0.15),
                   rng.uniform(0.3, 0.5), gain=1.0)
    w, d = rng.uniform(1.4, 2.2), rng.uniform(0.8, 1.0)
    seat, back_h, arm = rng.uniform(0.38, 0.45), rng.uniform(0.75, 0.9), rng.uniform(0.12, 0.2)
    parts = [box_mesh([-w / 2 + arm, -d / 2 + 0.2, 0.05], [w / 2 - arm, d / 2, seat], mat),
             box_mesh([-w / 2, -d / 2, 0.05], [w / 2, -d / 2 + 0.2, back_h], mat),
             box_mesh([-w / 2, -d / 2, 0.05], [-w / 2 + arm, d / 2, seat + 0.2], mat),
             box_mesh([w / 2 - arm, -d / 2, 0.05], [w / 2, d / 2, seat + 0.2], mat)]
    feet = [box_mesh([sx * (w / 2 - 0.06) - 0.025, sy * (d / 2 - 0.06) - 0.025, 0.0],
                     [sx * (w / 2 - 0.06) + 0.025, sy * (d / 2 - 0.06) + 0.025, 0.05], mat)
            for sx in (-1, 1) for sy in (-1, 1)]
    return Built(concat_meshes(parts + feet), 0.5 * np.hypot(w, d))


def _stool(rng, mats) -> Built:
    mat = _wood(rng, mats) if rng.random() < 0.5 else _paint(rng, mats)
    r, h = rng.uniform(0.15, 0.22), rng.uniform(0.45, 0.75)
    leg_r = rng.uniform(0.01, 0.02)
    seat = cylinder_mesh(r, 0.04, mat).transformed(np.eye(3), [0, 0, h - 0.04])
    n_legs = int(rng.integers(3, 5))
    legs = [cylinder_mesh(leg_r, h - 0.04, mat, segments=8).transformed(
        np.eye(3), [0.75 * r * np.cos(2 * np.pi * k / n_legs), 0.75 * r * np.sin(2 * np.pi * k / n_legs), 0.0])
        for k in range(n_legs)]
    return Built(concat_meshes([seat] + legs), r, (0.6 * r, 0.6 * r, h))


def _lamp(rng, mats, small: bool) -> Built:
    mat = _paint(rng, mats, sat=0.3, val=0.5, spread=0.1)
    shade_mat = mats.add(*two_tone(rng, rng.uniform(0.08, 0.16), 0.25, 0.9, 0.1), 0.5, gain=1.0)
    s = rng.uniform(0.22, 0.32) if small else 1.0  # a table lamp is a scaled-down floor lamp
    h = rng.uniform(1.2, 1.8)
    pole = rng.uniform(0.012, 0.03) / max(s, 0.5)
    base_r = rng.uniform(0.12, 0.18)
    shade_r = rng.uniform(0.18, 0.26)
    parts = [cylinder_mesh(base_r, 0.04, mat), cylinder_mesh(pole, h, mat, segments=10),
             lathe_mesh([shade_r, 0.6 * shade_r], [0.0, 0.3], shade_mat).transformed(np.eye(3), [0, 0, h - 0.12])]
    mesh = concat_meshes(parts).transformed(np.eye(3), np.zeros(3), s)
    return Built(mesh, max(base_r, shade_r) * s)


def _plant(rng, mats, small: bool) -> Built:
    pot_mat = mats.add(*two_tone(rng, rng.uniform(0.02, 0.08), 0.5, 0.55, 0.2), 0.5, gain=1.2)
    leaves = mats.add(*two_tone(rng, rng.uniform(0.22, 0.38), 0.65, 0.5, 0.3), 0.45, gain=1.4)
    pot_h = rng.uniform(0.28, 0.36)
    parts = [lathe_mesh([0.13, 0.18], [0.0, pot_h], pot_mat)]
    for k in range(int(rng.integers(2, 5))):
        r = rng.uniform(0.16, 0.26)
        ang = 2 * np.pi * k / 3 + rng.uniform(-0.4, 0.4)
        off = np.array([0.1 * np.cos(ang), 0.1 * np.sin(ang), pot_h + 0.12 + r + 0.12 * k])
        parts.append(sphere_mesh(r, leaves).transformed(np.eye(3), off))
    s = rng.uniform(0.3, 0.45) if small else rng.uniform(0.8, 1.3)
    return Built(concat_meshes(parts).transformed(np.eye(3), np.zeros(3), s), 0.38 * s)


def _sculpture(rng, mats) -> Built:
    mat = _paint(rng, mats)
    which = ["nut", "ant"][int(rng.integers(2))]
    m = fit_on_floor(example_mesh(which, mat), rng.uniform(0.3, 0.8), up_axis=1)
    lo, hi = m.bounds
    return Built(m, 0.5 * np.hypot(hi[0] - lo[0], hi[1] - lo[1]))


def _toy_plane(rng, mats, small: bool) -> Built:
    mat = _paint(rng, mats)
    m = fit_on_floor(example_mesh("airplane", mat), rng.uniform(0.2, 0.4) if small else rng.uniform(0.4, 1.2),
                     up_axis=2)
    lo, hi = m.bounds
    return Built(m, 0.5 * np.hypot(hi[0] - lo[0], hi[1] - lo[1]))


def _ball(rng, mats, small: bool) -> Built:
    r = rng.uniform(0.04, 0.09) if small else rng.uniform(0.1, 0.28)
    return Built(sphere_mesh(r, _paint(rng, mats)).transformed(np.eye(3), [0, 0, r]), r)


def _box(rng, mats, small: bool) -> Built:
    mat = mats.add(*two_tone(rng, rng.uniform(0.06, 0.12), rng.uniform(0.2, 0.5), rng.uniform(0.5, 0.8), 0.1),
                   0.5, gain=1.0) if rng.random() < 0.6 else _paint(rng, mats)
    size = rng.uniform(0.08, 0.25) if small else rng.uniform(0.25, 0.6)
    w, d, h = size * rng.uniform(0.7, 1.3, 3)
    return Built(box_mesh([-w / 2, -d / 2, 0.0], [w / 2, d / 2, h], mat), 0.5 * np.hypot(w, d),
                 (w / 2, d / 2, h) if not small else None)


def _book(rng, mats) -> Built:
    mat = _paint(rng, mats, sat=0.7, val=0.6, spread=0.1)
    length, w, t = rng.uniform(0.15, 0.3), rng.uniform(0.11, 0.22), rng.uniform(0.02, 0.06)
    return Built(box_mesh([-length / 2, -w / 2, 0.0], [length / 2, w / 2, t], mat), 0.5 * np.hypot(length, w))


def _cup(rng, mats) -> Built:
    mat = _paint(rng, mats, sat=0.4, val=0.8, spread=0.1)
    r, h = rng.uniform(0.035, 0.05), rng.uniform(0.07, 0.12)
    body = lathe_mesh([0.8 * r, r, 1.05 * r], [0.0, 0.5 * h, h], mat, segments=16)
    handle = box_mesh([1.0 * r, -0.006, 0.25 * h], [1.0 * r + 0.03, 0.006, 0.8 * h], mat)
    return Built(concat_meshes([body, handle]), r + 0.03)


def _vase(rng, mats, small: bool) -> Built:
    mat = _paint(rng, mats, sat=0.5, val=0.65, spread=0.25)
    if small:
        h, r = rng.uniform(0.18, 0.45), rng.uniform(0.06, 0.13)
    else:
        h, r = rng.uniform(0.5, 0.9), rng.uniform(0.15, 0.25)
    prof = np.array([0.55, 0.9, 1.0, 0.65, 0.42, 0.55]) * r
    heights = np.array([0.0, 0.2, 0.45, 0.75, 0.9, 1.0]) * h
    return Built(lathe_mesh(prof, heights, mat, segments=20), r)


def _figurine(rng, mats) -> Built:
    mat = _paint(rng, mats)
    h = rng.uniform(0.1, 0.35)
    base = cylinder_mesh(0.22 * h, 0.04 * h, mat, segments=16)
    body = lathe_mesh(np.array([0.1, 0.12, 0.08, 0.14, 0.12, 0.04]) * h,
                      np.array([0.04, 0.3, 0.45, 0.62, 0.75, 0.8]) * h, mat, segments=12)
    head = sphere_mesh(0.1 * h, mat, rings=8, segments=12).transformed(np.eye(3), [0, 0, 0.89 * h])
    arm = np.radians(rng.uniform(10, 60))
    arms = []
    for side in (-1, 1):  # thin arms hanging out from the shoulders
        rot = np.array([[np.cos(arm), 0.0, side * np.sin(arm)], [0.0, 1.0, 0.0],
                        [-side * np.sin(arm), 0.0, np.cos(arm)]])
        arms.append(cylinder_mesh(0.025 * h, 0.3 * h, mat, segments=8).transformed(
            rot.T, [side * 0.12 * h, 0.0, 0.42 * h]))
    return Built(concat_meshes([base, body, head] + arms), 0.25 * h)


def build_thing(name: str, rng: np.random.Generator, mats: MaterialBank, small: bool = False) -> Built:
    """One thing of the catalogue (``small``: the size that stands on a table or shelf)."""
    if name == "table":
        return _table(rng, mats)
    if name == "chair":
        return _chair(rng, mats)
    if name == "cabinet":
        return _cabinet(rng, mats)
    if name == "shelf":
        return _shelf(rng, mats)
    if name == "sofa":
        return _sofa(rng, mats)
    if name == "stool":
        return _stool(rng, mats)
    if name == "lamp":
        return _lamp(rng, mats, small)
    if name == "plant":
        return _plant(rng, mats, small)
    if name == "sculpture":
        return _sculpture(rng, mats)
    if name == "toy_plane":
        return _toy_plane(rng, mats, small)
    if name == "ball":
        return _ball(rng, mats, small)
    if name == "box":
        return _box(rng, mats, small)
    if name == "book":
        return _book(rng, mats)
    if name == "cup":
        return _cup(rng, mats)
    if name == "vase":
        return _vase(rng, mats, small)
    if name == "figurine":
        return _figurine(rng, mats)
    raise KeyError(name)


# --------------------------------------------------------------------------------------------- the room
def room_outline(rng: np.random.Generator) -> tuple[np.ndarray, list[tuple[float, float, float, float]], str]:
    """A room's floor outline: ``[K, 2]`` corners counter-clockwise around the origin, the rectangles
    ``(x0, y0, x1, y1)`` that tile it, and its shape (``rectangle`` or ``L``)."""
    for _ in range(100):
        w, d = rng.uniform(3.5, 9.0, 2)
        if max(w, d) / min(w, d) <= 2.2:
            break
    x0, x1, y0, y1 = -w / 2, w / 2, -d / 2, d / 2
    if min(w, d) < 5.0 or rng.random() >= 0.35:
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]), [(x0, y0, x1, y1)], "rectangle"
    cw, cd = w * rng.uniform(0.3, 0.45), d * rng.uniform(0.3, 0.45)
    # The top-right corner cut out, then mirrored to a random corner (a mirror reverses the winding).
    poly = np.array([[x0, y0], [x1, y0], [x1, y1 - cd], [x1 - cw, y1 - cd], [x1 - cw, y1], [x0, y1]])
    rects = [(x0, y0, x1, y1 - cd), (x0, y1 - cd, x1 - cw, y1)]
    sx, sy = (1.0 if rng.random() < 0.5 else -1.0), (1.0 if rng.random() < 0.5 else -1.0)
    poly = poly * [sx, sy]
    if sx * sy < 0:
        poly = poly[::-1]
    rects = [(min(a * sx, c * sx), min(b * sy, e * sy), max(a * sx, c * sx), max(b * sy, e * sy))
             for a, b, c, e in rects]
    return poly, rects, "L"


def polygon_area(poly: np.ndarray) -> float:
    """Area of a simple polygon ``[K, 2]`` (shoelace formula)."""
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def inside_polygon(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """``[N]`` bool: which of ``points`` ``[N, 2]`` lie inside ``poly`` ``[K, 2]`` (even-odd rule)."""
    pts = np.atleast_2d(points)
    inside = np.zeros(len(pts), bool)
    for (xa, ya), (xb, yb) in zip(poly, np.roll(poly, -1, axis=0)):
        crosses = (ya > pts[:, 1]) != (yb > pts[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            x_at = xa + (pts[:, 1] - ya) * (xb - xa) / (yb - ya)
        inside ^= crosses & (pts[:, 0] < x_at)
    return inside


def distance_to_outline(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """``[N]`` distance from ``points`` ``[N, 2]`` to the nearest edge of ``poly``."""
    pts = np.atleast_2d(points)
    best = np.full(len(pts), np.inf)
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):
        ab = b - a
        t = np.clip(((pts - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(pts - (a + t[:, None] * ab), axis=1))
    return best


def _wall_texture(rng, mats: MaterialBank) -> tuple[int, dict]:
    level = float(rng.uniform(0, 1))
    hue = rng.uniform(0.0, 0.17) if rng.random() < 0.7 else rng.uniform(0, 1)
    c0, c1 = two_tone(rng, hue, rng.uniform(0.05, 0.35), rng.uniform(0.65, 0.9), 0.02 + 0.3 * level)
    style = "plain" if level < 0.25 else ("blotchy" if level < 0.7 else ["stripes", "bricks"][int(rng.integers(2))])
    kw: dict = {}
    if style == "stripes":  # wallpaper: vertical stripes, in world x and y so every wall shows them
        kw["stripe"] = (np.array([1.0, 1.0, 0.0]), rng.uniform(0.25, 0.5), 1.5)
    elif style == "bricks":
        kw["grid"] = (np.array([1.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), rng.uniform(0.25, 0.4), 0.35,
                      hsv(hue, 0.1, 0.95))
    mat = mats.add(c0, c1, rng.uniform(0.8, 1.6), gain=0.3 + 1.5 * level, **kw)
    return mat, {"style": style, "level": round(level, 3)}


def _floor_texture(rng, mats: MaterialBank) -> tuple[int, dict]:
    level = float(rng.uniform(0, 1))
    style = ["wood", "tiles", "carpet", "concrete"][int(rng.integers(4))]
    spread = 0.02 + 0.35 * level
    if style == "wood":
        c0, c1 = two_tone(rng, rng.uniform(0.05, 0.1), 0.55, 0.55, spread)
        mat = mats.add(c0, c1, 0.9, gain=0.4 + 1.2 * level, flat_z=True,
                       stripe=(np.array([1.0, 0.0, 0.0]), rng.uniform(0.35, 0.55), 1.6))
    elif style == "tiles":
        c0, c1 = two_tone(rng, rng.uniform(0, 1), rng.uniform(0.0, 0.3), rng.uniform(0.55, 0.85), spread)
        mat = mats.add(c0, c1, 1.2, gain=0.3 + 1.0 * level, flat_z=True,
                       grid=(np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), rng.uniform(0.3, 0.6),
                             0.1 + 0.4 * level, hsv(0.1, 0.05, 0.9)))
    elif style == "carpet":
        c0, c1 = two_tone(rng, rng.uniform(0, 1), rng.uniform(0.2, 0.6), rng.uniform(0.35, 0.6), spread)
        mat = mats.add(c0, c1, 0.5, gain=0.3 + 1.2 * level, flat_z=True)
    else:
        c0, c1 = two_tone(rng, 0.1, 0.05, rng.uniform(0.5, 0.7), spread)
        mat = mats.add(c0, c1, 1.5, gain=0.3 + 0.8 * level, flat_z=True)
    return mat, {"style": style, "level": round(level, 3)}


def room_lighting(rng: np.random.Generator) -> tuple[Lighting, dict]:
    """A key and a fill light of one colour temperature plus ambient light, scaled to an exposure."""
    kelvin = float(rng.uniform(2700, 6500))
    tint = kelvin_rgb(kelvin)
    ambient, key, fill = rng.uniform(0.25, 0.55), rng.uniform(0.3, 0.65), rng.uniform(0.05, 0.3)
    hemisphere = rng.uniform(0.0, 0.15)
    # Auto-exposure, roughly: a wall half-lit by the key and fill lights comes out at the same brightness.
    exposure = rng.uniform(0.9, 1.15) / (ambient + 0.6 * (key + fill) + 0.5 * hemisphere)
    az, el = rng.uniform(0, 2 * np.pi), np.radians(rng.uniform(25, 70))
    az_f, el_f = az + np.pi + rng.uniform(-0.6, 0.6), np.radians(rng.uniform(15, 45))
    dirs = np.array([[np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)],
                     [np.cos(az_f) * np.cos(el_f), np.sin(az_f) * np.cos(el_f), np.sin(el_f)]])
    light = Lighting(ambient * exposure * tint, hemisphere * exposure, dirs,
                     np.stack([key * exposure * tint, fill * exposure * tint]))
    desc = {"kelvin": round(kelvin), "ambient": round(float(ambient * exposure), 3),
            "key": round(float(key * exposure), 3), "fill": round(float(fill * exposure), 3),
            "key_direction": np.round(dirs[0], 3).tolist()}
    return light, desc


# --------------------------------------------------------------------------------------------- placement
def _place_on_floor(rng, radius: float, poly: np.ndarray, circles: list[tuple[np.ndarray, float]],
                    along_wall: bool, gap: float = 0.1, tries: int = 300) -> tuple[np.ndarray, float] | None:
    """A free floor position (bounding circles ``gap`` apart, inside the room) and a yaw, or None."""
    lo, hi = poly.min(0), poly.max(0)
    edges = [(a, b) for a, b in zip(poly, np.roll(poly, -1, axis=0))]
    lengths = np.array([np.linalg.norm(b - a) for a, b in edges])
    for _ in range(tries):
        if along_wall:  # back to a wall (the front, +y, faces into the room)
            k = int(rng.choice(len(edges), p=lengths / lengths.sum()))
            a, b = edges[k]
            along = unit(b - a)
            inward = np.array([-along[1], along[0]])  # counter-clockwise outline: the interior is on the left
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


def _place_next_to(rng, radius: float, anchor: tuple[np.ndarray, float], poly, circles,
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
class _Support:
    index: int  # into objects
    centre: np.ndarray
    yaw: float
    top: tuple[float, float, float]
    circles: list


def _place_on_support(rng, radius: float, supports: list[_Support], tries: int = 30):
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


# --------------------------------------------------------------------------------------------- build
def build_indoor(rng: np.random.Generator) -> SceneContent:
    """A furnished room (see the module docstring): stuff (walls, floor, ceiling, windows, maybe a rug) and
    6-16 things of the catalogue.

    Parameters
    ----------
    rng : np.random.Generator
        The layout's random stream (the same stream gives the same room).
    """
    mats = MaterialBank(rng)
    poly, rects, shape = room_outline(rng)
    height = float(rng.uniform(2.4, 3.4))
    lo, hi = poly.min(0), poly.max(0)
    area = polygon_area(poly)
    objects: list[SceneObject] = []

    # ---- stuff: walls on the outline's edges, extended past convex corners so no ray slips through a crack
    pad = 0.05
    wall_mat, wall_desc = _wall_texture(rng, mats)
    floor_mat, floor_desc = _floor_texture(rng, mats)
    ceil_mat = mats.add(hsv(0.12, 0.05, 0.92), hsv(0.12, 0.08, 0.84), 1.5, gain=0.8)
    n = len(poly)
    turn = [(poly[k] - poly[k - 1], poly[(k + 1) % n] - poly[k]) for k in range(n)]
    convex = [float(a[0] * b[1] - a[1] * b[0]) > 0 for a, b in turn]  # a left turn on a counter-clockwise outline
    walls, edges = [], []
    for k in range(n):
        a, b = poly[k], poly[(k + 1) % n]
        d = unit(b - a)
        a2 = a - d * pad * convex[k]
        b2 = b + d * pad * convex[(k + 1) % n]
        walls.append(quad_mesh([a2[0], a2[1], -pad], [*(b2 - a2), 0.0], [0, 0, height + 2 * pad], wall_mat))
        edges.append((a, b))
    objects.append(SceneObject(1, 1, concat_meshes(walls), "wall"))
    floors = [quad_mesh([x0 - pad, y0 - pad, 0.0], [x1 - x0 + 2 * pad, 0, 0], [0, y1 - y0 + 2 * pad, 0], floor_mat)
              for x0, y0, x1, y1 in rects]
    ceilings = [quad_mesh([x0 - pad, y0 - pad, height], [x1 - x0 + 2 * pad, 0, 0], [0, y1 - y0 + 2 * pad, 0],
                          ceil_mat) for x0, y0, x1, y1 in rects]
    objects.append(SceneObject(2, 2, concat_meshes(floors), "floor"))
    objects.append(SceneObject(3, 3, concat_meshes(ceilings), "ceiling"))

    has_rug = bool(rng.random() < 0.75)
    if has_rug:  # inside the largest rectangle of the outline
        x0, y0, x1, y1 = max(rects, key=lambda r: (r[2] - r[0]) * (r[3] - r[1]))
        rw, rd = rng.uniform(1.2, 0.65 * (x1 - x0)), rng.uniform(1.0, 0.65 * (y1 - y0))
        rc = np.array([(x0 + x1) / 2, (y0 + y1) / 2]) + rng.uniform(-0.15, 0.15, 2) * [x1 - x0 - rw, y1 - y0 - rd]
        rug_mat = mats.add(*two_tone(rng, rng.uniform(0.55, 1.0), 0.55, 0.6, 0.3), 0.7, gain=2.0, flat_z=True,
                           grid=(np.array([1.0, 1.0, 0]), np.array([1.0, -1.0, 0]), 0.6, 0.35, hsv(0.13, 0.3, 0.9)))
        objects.append(SceneObject(4, 4, quad_mesh([rc[0] - rw / 2, rc[1] - rd / 2, 0.006], [rw, 0, 0], [0, rd, 0],
                                                   rug_mat), "rug"))
    win_mat = mats.add(hsv(0.58, 0.35, 0.95), hsv(0.55, 0.5, 0.8), 1.0, gain=1.0,
                       grid=(np.array([1.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), 0.7, 0.3, (0.95, 0.95, 0.95)))
    windows = []
    long_edges = [k for k, (a, b) in enumerate(edges) if np.linalg.norm(b - a) >= 1.8]
    n_windows = min(int(rng.integers(0, 4)), len(long_edges))
    for k in rng.choice(long_edges, size=n_windows, replace=False) if n_windows else []:
        a, b = edges[int(k)]
        length, d = np.linalg.norm(b - a), unit(b - a)
        ww = rng.uniform(0.8, min(1.8, length - 0.8))
        wh = rng.uniform(0.8, min(1.4, height - 1.2))
        wz = rng.uniform(0.7, height - wh - 0.3)
        start = a + d * rng.uniform(0.4, length - 0.4 - ww) + np.array([-d[1], d[0]]) * 0.01
        windows.append(quad_mesh([start[0], start[1], wz], [*(d * ww), 0.0], [0, 0, wh], win_mat))
    if windows:
        objects.append(SceneObject(5, 5, concat_meshes(windows), "window"))

    # ---- things: how many, which, and where
    cat_of = {c.name: c.id for c in INDOOR_CATEGORIES}
    n_max = int(np.clip(6 + area / 3.5, 6, 16))
    n_things = int(np.clip(round(rng.uniform(0.5, 1.0) * n_max), 6, 16))
    n_small = int(rng.binomial(n_things, rng.uniform(0.2, 0.45)))
    n_floor = n_things - n_small

    def draw(weights: dict, k: int) -> list[str]:
        names = sorted(weights)
        p = np.array([weights[x] for x in names])
        return [names[i] for i in rng.choice(len(names), size=k, p=p / p.sum())] if k > 0 else []

    first = ["table", "cabinet", "shelf"][int(rng.choice(3, p=[0.6, 0.2, 0.2]))]  # something to put things on
    floor_names = [first] + draw(FLOOR_WEIGHTS, n_floor - 1)
    small_names = draw(SMALL_WEIGHTS, n_small)
    # Big furniture first (it needs the most room), chairs after the tables they may stand at.
    order = {"sofa": 0, "table": 1, "shelf": 2, "cabinet": 3}
    floor_names.sort(key=lambda x: order.get(x, 4))

    circles: list[tuple[np.ndarray, float]] = []
    tables: list[tuple[np.ndarray, float]] = []
    supports: list[_Support] = []
    objects_desc = []
    next_id = 1001
    counts: dict[str, int] = {}
    footprint_budget = 0.4 * area  # leave room to walk

    def add(name: str, built: Built, centre3: np.ndarray, yaw: float, rests_on: int) -> SceneObject:
        nonlocal next_id
        mesh = built.mesh.transformed(rotation_z(yaw), centre3)
        k = counts.get(name, 0)
        counts[name] = k + 1
        obj = SceneObject(next_id, cat_of[name], mesh, f"{name}_{k}", rests_on=rests_on)
        objects.append(obj)
        b = mesh.bounds
        objects_desc.append({"id": next_id, "class": name, "size_m": np.round(b[1] - b[0], 3).tolist(),
                             "on": "floor" if rests_on == 0 else rests_on})
        next_id += 1
        return obj

    used = 0.0
    for name in floor_names:
        built = build_thing(name, rng, mats)
        if used + np.pi * built.radius**2 > footprint_budget:
            continue
        placed = None
        if name == "chair" and tables and rng.random() < 0.7:
            placed = _place_next_to(rng, built.radius, tables[int(rng.integers(len(tables)))], poly, circles)
        if placed is None:
            placed = _place_on_floor(rng, built.radius, poly, circles,
                                     along_wall=rng.random() < ALONG_WALL.get(name, 0.0))
        if placed is None:
            continue  # no room left: drop it
        centre, yaw = placed
        circles.append((centre, built.radius))
        used += np.pi * built.radius**2
        add(name, built, np.array([centre[0], centre[1], 0.0]), yaw, 0)
        if name == "table":
            tables.append((centre, built.radius))
        if built.top is not None:
            supports.append(_Support(len(objects) - 1, centre, yaw, built.top, []))

    def place_small(name: str) -> bool:
        built = build_thing(name, rng, mats, small=True)
        spot = _place_on_support(rng, built.radius, supports)
        if spot is not None:
            s, pos, yaw = spot
            add(name, built, pos, yaw, objects[s.index].segment_id)
            return True
        placed = _place_on_floor(rng, built.radius, poly, circles, along_wall=False)
        if placed is None:
            return False
        centre, yaw = placed
        circles.append((centre, built.radius))
        add(name, built, np.array([centre[0], centre[1], 0.0]), yaw, 0)
        return True

    for name in small_names:
        place_small(name)
    for _ in range(20):  # at least 6 things, whatever was dropped
        if next_id - 1001 >= 6:
            break
        place_small(draw(SMALL_WEIGHTS, 1)[0])
    if next_id - 1001 < 6:
        raise RuntimeError(f"could only place {next_id - 1001} objects in the room (need 6)")

    lighting, light_desc = room_lighting(rng)
    aabb = np.array([[lo[0], lo[1], 0.0], [hi[0], hi[1], height]])
    description = {
        "room": {"shape": shape, "size_m": np.round([hi[0] - lo[0], hi[1] - lo[1], height], 3).tolist(),
                 "floor_area_m2": round(area, 2), "outline": np.round(poly, 3).tolist(),
                 "windows": len(windows), "rug": has_rug},
        "wall_texture": wall_desc, "floor_texture": floor_desc, "lighting": light_desc,
        "objects": objects_desc,
    }
    return SceneContent(
        kind="indoor", categories=list(INDOOR_CATEGORIES), objects=objects, materials=mats, lighting=lighting,
        confusable=INDOOR_CONFUSABLE, scene_box_type="bounded", aabb=aabb, depth_unit_scale_factor=1e-3,
        room_polygon=poly, description=description,
    )
