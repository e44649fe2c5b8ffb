"""The things of ``lift3d synth``'s rooms: the indoor classes, their plausible confusions and one builder per
class (``docs/synth.md`` has the catalogue's sizes).

Every builder draws its sizes and material from the layout's random stream and returns a :class:`Built`:
the mesh standing on z = 0 around the z axis, front towards +y, the radius of its floor footprint, the flat
top other things may stand on, and the thickness of its thinnest part (legs, poles, wings, handles).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lift3d.data.scene import Category
from lift3d.synth.geometry import (
    MaterialBank,
    Mesh,
    box_mesh,
    concat_meshes,
    cylinder_mesh,
    example_mesh,
    fit_on_floor,
    lathe_mesh,
    make_mesh,
    sphere_mesh,
    two_tone,
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

#: Classes only cluttered rooms (``--clutter dense``) hold, ids after the ones above so those never change.
#: Other rooms list only :data:`INDOOR_CATEGORIES`, so their files (and the label space a run trains) stay
#: as they were.
CLUTTER_CATEGORIES = [
    Category(22, "mat", True, (255, 152, 150)),
]
#: :data:`INDOOR_CONFUSABLE` with the cluttered rooms' classes.
CLUTTER_CONFUSABLE = {**INDOOR_CONFUSABLE, 17: [21, 15, 22], 21: [8, 17, 22], 22: [17, 21]}


def indoor_categories(clutter: bool) -> tuple[list[Category], dict[int, list[int]]]:
    """The classes of an indoor scene and their plausible confusions (``clutter``: with the cluttered
    rooms' classes)."""
    if clutter:
        return INDOOR_CATEGORIES + CLUTTER_CATEGORIES, CLUTTER_CONFUSABLE
    return list(INDOOR_CATEGORIES), INDOOR_CONFUSABLE


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
    may stand on (local frame), or None; ``thin`` is the thickness (metres) of its thinnest part (a leg's,
    a pole's or a wing's), None when it has no part thinner than its body.
    """

    mesh: Mesh
    radius: float
    top: tuple[float, float, float] | None = None
    thin: float | None = None


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
        stem_r = rng.uniform(0.03, 0.06)
        stem = cylinder_mesh(stem_r, h - th, mat, segments=12)
        foot = cylinder_mesh(0.6 * r, 0.03, mat)
        return Built(concat_meshes([top, stem, foot]), r, (0.65 * r, 0.65 * r, h), thin=2 * stem_r)
    w = rng.uniform(0.6, 1.8)
    d, h = rng.uniform(0.5, min(1.0, w)), rng.uniform(0.45, 0.78)
    th, leg = rng.uniform(0.03, 0.06), rng.uniform(0.02, 0.045)
    top = box_mesh([-w / 2, -d / 2, h - th], [w / 2, d / 2, h], mat)
    legs = [box_mesh([sx * (w / 2 - 0.05) - leg, sy * (d / 2 - 0.05) - leg, 0.0],
                     [sx * (w / 2 - 0.05) + leg, sy * (d / 2 - 0.05) + leg, h - th], mat)
            for sx in (-1, 1) for sy in (-1, 1)]
    return Built(concat_meshes([top] + legs), 0.5 * np.hypot(w, d), (w / 2, d / 2, h), thin=2 * leg)


def _chair(rng, mats) -> Built:
    mat = _paint(rng, mats) if rng.random() < 0.5 else _wood(rng, mats)
    s, h = rng.uniform(0.38, 0.5), rng.uniform(0.42, 0.48)
    leg = rng.uniform(0.012, 0.03)
    seat = box_mesh([-s / 2, -s / 2, h - 0.04], [s / 2, s / 2, h], mat)
    back = box_mesh([-s / 2, -s / 2, h], [s / 2, -s / 2 + 0.04, h + rng.uniform(0.35, 0.55)], mat)
    legs = [box_mesh([sx * (s / 2 - leg - 0.01) - leg, sy * (s / 2 - leg - 0.01) - leg, 0.0],
                     [sx * (s / 2 - leg - 0.01) + leg, sy * (s / 2 - leg - 0.01) + leg, h - 0.04], mat)
            for sx in (-1, 1) for sy in (-1, 1)]
    return Built(concat_meshes([seat, back] + legs), s / np.sqrt(2), thin=2 * leg)


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
    return Built(concat_meshes(parts), 0.5 * np.hypot(w, d), (w / 2, d / 2, h) if h < 1.3 else None, thin=t)


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
    return Built(concat_meshes([seat] + legs), r, (0.6 * r, 0.6 * r, h), thin=2 * leg_r)


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
    return Built(mesh, max(base_r, shade_r) * s, thin=2 * pole * s)


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
    # The ant's legs are 1-3 % of its size across; the nut has no thin part.
    thin = 0.02 * (hi[0] - lo[0]) if which == "ant" else None
    return Built(m, 0.5 * np.hypot(hi[0] - lo[0], hi[1] - lo[1]), thin=thin)


def _toy_plane(rng, mats, small: bool) -> Built:
    mat = _paint(rng, mats)
    m = fit_on_floor(example_mesh("airplane", mat), rng.uniform(0.2, 0.4) if small else rng.uniform(0.4, 1.2),
                     up_axis=2)
    return _plane_built(m)


def _plane_built(m: Mesh) -> Built:
    lo, hi = m.bounds
    # The wing tips are about 1 % of the span thick.
    return Built(m, 0.5 * np.hypot(hi[0] - lo[0], hi[1] - lo[1]), thin=0.01 * (hi[0] - lo[0]))


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
    return Built(concat_meshes([body, handle]), r + 0.03, thin=0.012)


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
    return Built(concat_meshes([base, body, head] + arms), 0.25 * h, thin=0.05 * h)


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



# --------------------------------------------------------------------------------------------- clutter
# Builders only cluttered rooms use (lift3d.synth.clutter): sizes chosen for the hard cases, thin or flat.
def dining_table(rng, mats) -> Built:
    """A rectangular dining table 1.1-1.7 x 0.7-0.95 m, 0.72-0.78 m high, on four legs 3-5 cm thick."""
    mat = _wood(rng, mats)
    w, d, h = rng.uniform(1.1, 1.7), rng.uniform(0.7, 0.95), rng.uniform(0.72, 0.78)
    th, leg = rng.uniform(0.03, 0.045), rng.uniform(0.015, 0.025)
    top = box_mesh([-w / 2, -d / 2, h - th], [w / 2, d / 2, h], mat)
    legs = [box_mesh([sx * (w / 2 - 0.06) - leg, sy * (d / 2 - 0.06) - leg, 0.0],
                     [sx * (w / 2 - 0.06) + leg, sy * (d / 2 - 0.06) + leg, h - th], mat)
            for sx in (-1, 1) for sy in (-1, 1)]
    return Built(concat_meshes([top] + legs), 0.5 * np.hypot(w, d), (w / 2, d / 2, h), thin=2 * leg)


def legged_figurine(rng, mats, height: float | None = None) -> Built:
    """A figurine on thin legs, no base: a person on two legs or an animal on four, 0.22-0.35 m (or
    ``height``), legs 1.6-2.4 % of its height across (5-8 mm at 0.3 m) and thin arms or a neck."""
    mat = _paint(rng, mats)
    h = rng.uniform(0.22, 0.35) if height is None else height
    leg_r = rng.uniform(0.008, 0.012) * h
    if rng.random() < 0.5:  # a person: two legs, a body, a head and two thin arms
        leg_h = 0.45 * h
        legs = [cylinder_mesh(leg_r, leg_h, mat, segments=8).transformed(np.eye(3), [side * 0.05 * h, 0.0, 0.0])
                for side in (-1, 1)]
        body = lathe_mesh(np.array([0.09, 0.1, 0.07, 0.03]) * h, np.array([0.43, 0.6, 0.77, 0.8]) * h, mat,
                          segments=12)
        head = sphere_mesh(0.08 * h, mat, rings=8, segments=12).transformed(np.eye(3), [0, 0, 0.89 * h])
        arm = np.radians(rng.uniform(15, 50))
        arms = []
        for side in (-1, 1):
            rot = np.array([[np.cos(arm), 0.0, side * np.sin(arm)], [0.0, 1.0, 0.0],
                            [-side * np.sin(arm), 0.0, np.cos(arm)]])
            arms.append(cylinder_mesh(0.7 * leg_r, 0.28 * h, mat, segments=8).transformed(
                rot.T, [side * 0.09 * h, 0.0, 0.5 * h]))
        mesh = concat_meshes(legs + [body, head] + arms)
        thinnest = 1.4 * leg_r  # the arms
    else:  # an animal: a long body on four legs, a thin neck and a head
        length = rng.uniform(0.9, 1.2) * h
        leg_h = 0.5 * h
        unit_sphere = sphere_mesh(1.0, mat, rings=8, segments=12)
        body = make_mesh(unit_sphere.vertices * [0.5 * length, 0.14 * h, 0.12 * h] + [0.0, 0.0, leg_h + 0.08 * h],
                         unit_sphere.triangles, mat, smooth=True)
        legs = [cylinder_mesh(leg_r, leg_h + 0.02 * h, mat, segments=8).transformed(
            np.eye(3), [sx * 0.35 * length, sy * 0.07 * h, 0.0]) for sx in (-1, 1) for sy in (-1, 1)]
        tilt = np.radians(35)
        rot = np.array([[np.cos(tilt), 0.0, np.sin(tilt)], [0.0, 1.0, 0.0], [-np.sin(tilt), 0.0, np.cos(tilt)]])
        neck = cylinder_mesh(1.3 * leg_r, 0.3 * h, mat, segments=8).transformed(
            rot, [0.45 * length, 0.0, leg_h + 0.1 * h])
        head = sphere_mesh(0.08 * h, mat, rings=8, segments=12).transformed(
            np.eye(3), [0.45 * length + 0.3 * h * np.sin(tilt), 0.0, leg_h + 0.1 * h + 0.3 * h * np.cos(tilt)])
        mesh = concat_meshes([body, neck, head] + legs)
        thinnest = 2 * leg_r
    lo, hi = mesh.bounds
    centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    mesh = mesh.transformed(np.eye(3), -centre)
    lo, hi = mesh.bounds
    return Built(mesh, 0.5 * float(np.hypot(hi[0] - lo[0], hi[1] - lo[1])), thin=thinnest)


def flat_toy_plane(rng, mats, span: float | None = None) -> Built:
    """The toy plane lying flat on its belly, wings 0.35-0.45 m across (or ``span``), 1 % of that thick at
    the tips."""
    mat = _paint(rng, mats)
    return _plane_built(fit_on_floor(example_mesh("airplane", mat), rng.uniform(0.35, 0.45) if span is None else span,
                                     up_axis=2))


def mat_thing(rng, mats) -> Built:
    """A mat lying on the floor (a doormat, a yoga or play mat): 0.5-1.2 x 0.35-0.7 m, 0.8-2 cm thick."""
    m = mats.add(*two_tone(rng, rng.uniform(0, 1), rng.uniform(0.3, 0.7), rng.uniform(0.35, 0.7), 0.2), 0.4,
                 gain=1.5, stripe=(np.array([1.0, 0.0, 0.0]), rng.uniform(0.08, 0.2), 1.2))
    w, d, t = rng.uniform(0.5, 1.2), rng.uniform(0.35, 0.7), rng.uniform(0.008, 0.02)
    return Built(box_mesh([-w / 2, -d / 2, 0.0], [w / 2, d / 2, t], m), 0.5 * float(np.hypot(w, d)))


def floor_ball(rng, mats, radius: float) -> Built:
    """A ball of ``radius`` metres resting on z = 0."""
    return Built(sphere_mesh(radius, _paint(rng, mats)).transformed(np.eye(3), [0, 0, radius]), radius)
