"""The outdoor scenes of ``lift3d synth``: an unbounded street drawn from the layout's random stream.

A road along +y with grass strips, raised sidewalks and façades on both sides (and one across the far end,
520 m away), parked cars and vans, trees, streetlights, traffic signs and pedestrians; sky where nothing is
hit. A seed chooses the street's width, the grass and sidewalk widths, the buildings' heights, widths, colours
and window grids, how densely cars are parked, the spacing of trees and streetlights and the number of signs
and pedestrians (``docs/synth.md`` lists the ranges).
"""

from __future__ import annotations

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
    hsv,
    lathe_mesh,
    quad_mesh,
    rotation_z,
    sphere_mesh,
    two_tone,
    unit,
)

OUTDOOR_CATEGORIES = [
    Category(1, "road", False, (128, 64, 128)),
    Category(2, "sidewalk", False, (244, 35, 232)),
    Category(3, "building", False, (70, 70, 70)),
    Category(4, "terrain", False, (152, 251, 152)),
    Category(5, "sky", False, (70, 130, 180)),
    Category(6, "car", True, (0, 0, 142)),
    Category(7, "van", True, (0, 60, 100)),
    Category(8, "pedestrian", True, (220, 20, 60)),
    Category(9, "tree", True, (107, 142, 35)),
    Category(10, "streetlight", True, (250, 170, 30)),
    Category(11, "sign", True, (220, 220, 0)),
]

#: Plausible confusions of the simulated segmenter (same kind).
OUTDOOR_CONFUSABLE = {
    1: [2], 2: [1, 4], 3: [5], 4: [2], 5: [3],
    6: [7], 7: [6], 8: [10], 9: [10], 10: [9, 8, 11], 11: [10],
}

#: Where the street begins and ends along y (metres); the cameras move near y = 0.
STREET_START, STREET_END = -40.0, 520.0


def _car(rng, body_mat: int, glass_mat: int, tyre_mat: int, van: bool) -> Mesh:
    """A car (body + glass cabin) or a van (tall body + windscreen) on four wheels, along +y, on z = 0."""
    length = rng.uniform(4.6, 5.4) if van else rng.uniform(3.9, 4.6)
    width = rng.uniform(1.9, 2.1) if van else rng.uniform(1.7, 1.85)
    body_h = rng.uniform(1.5, 1.8) if van else rng.uniform(0.65, 0.8)
    parts = [box_mesh([-width / 2, -length / 2, 0.3], [width / 2, length / 2, 0.3 + body_h], body_mat)]
    if van:
        parts.append(box_mesh([-width / 2 + 0.05, length / 2 - 1.2, 0.9], [width / 2 - 0.05, length / 2 + 0.02,
                                                                            0.3 + body_h - 0.15], glass_mat))
    else:
        cab_l = length * rng.uniform(0.45, 0.55)
        y0 = -length / 2 + length * rng.uniform(0.2, 0.3)
        parts.append(box_mesh([-width / 2 + 0.1, y0, 0.3 + body_h], [width / 2 - 0.1, y0 + cab_l, 0.3 + body_h + 0.55],
                              glass_mat))
    rot_x = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # wheel axis along x
    for sx in (-1, 1):
        for sy in (-1, 1):
            # The rotated cylinder spans x in [0, 0.24]: shift it so the tyre is centred under the body's edge.
            wheel = cylinder_mesh(0.34, 0.24, tyre_mat, segments=16).transformed(
                rot_x, [sx * (width / 2 - 0.1) - 0.12, sy * (length / 2 - 0.8), 0.34])
            parts.append(wheel)
    return concat_meshes(parts)


def _sign(rng, pole_mat: int, plate_mat: int) -> Mesh:
    """A traffic sign: a thin pole with a round or square plate facing the road (-x in local axes)."""
    h = rng.uniform(2.0, 2.8)
    r = rng.uniform(0.025, 0.045)
    size = rng.uniform(0.4, 0.75)
    pole = cylinder_mesh(r, h, pole_mat, segments=8)
    if rng.random() < 0.5:
        rot = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # disc facing x
        plate = cylinder_mesh(size / 2, 0.02, plate_mat, segments=20).transformed(rot, [-r - 0.03, 0.0, h - size / 2])
    else:
        plate = box_mesh([-r - 0.03, -size / 2, h - size], [-r - 0.01, size / 2, h], plate_mat)
    return concat_meshes([pole, plate])


def build_outdoor(rng: np.random.Generator) -> SceneContent:
    """An unbounded street along +y (see the module docstring).

    Parameters
    ----------
    rng : np.random.Generator
        The layout's random stream.
    """
    mats = MaterialBank(rng)
    objects: list[SceneObject] = []
    length = STREET_END - STREET_START
    road_half = float(rng.uniform(3.0, 6.0))
    grass_w = 0.0 if rng.random() < 0.25 else float(rng.uniform(0.6, 2.0))
    grass_end = road_half + grass_w
    sidewalk_end = grass_end + float(rng.uniform(1.8, 4.0))

    road_mat = mats.add((0.36, 0.36, 0.38), (0.27, 0.27, 0.29), 3.0, gain=rng.uniform(0.6, 1.4), flat_z=True)
    objects.append(SceneObject(1, 1, quad_mesh([-road_half - 0.05, STREET_START, 0.0], [2 * road_half + 0.1, 0, 0],
                                               [0, length, 0], road_mat), "road"))
    walk_mat = mats.add(*two_tone(rng, 0.08, 0.06, rng.uniform(0.5, 0.7), 0.1), 2.0, gain=1.0, flat_z=True,
                        grid=(np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), rng.uniform(1.0, 2.0), 0.25,
                              (0.75, 0.73, 0.7)))
    grass_mat = mats.add((0.33, 0.52, 0.2), (0.22, 0.4, 0.14), 1.5, gain=1.4, flat_z=True)
    walks, grass = [], []
    for side in (-1, 1):
        # Raised by 12 cm: the kerb is a box side visible from the road.
        if grass_w > 0:
            lo_g = min(side * road_half, side * grass_end)
            grass.append(box_mesh([lo_g, STREET_START, -0.5], [lo_g + grass_w, STREET_END, 0.12], grass_mat))
        lo_w = min(side * grass_end, side * sidewalk_end)
        walks.append(box_mesh([lo_w, STREET_START, -0.5], [lo_w + sidewalk_end - grass_end, STREET_END, 0.12],
                              walk_mat))
    objects.append(SceneObject(2, 2, concat_meshes(walks), "sidewalk"))
    if grass:
        objects.append(SceneObject(4, 4, concat_meshes(grass), "terrain"))

    # ---- façades: boxes of random width and height on both sides, and one across the far end of the street.
    h_lo = float(rng.uniform(5.0, 10.0))
    h_hi = h_lo + float(rng.uniform(4.0, 18.0))
    w_lo = float(rng.uniform(8.0, 14.0))
    window_period = float(rng.uniform(2.5, 4.0))
    palette = rng.choice([0.05, 0.08, 0.1, 0.55, 0.0, 0.3], size=3, replace=False)
    buildings = []
    for side in (-1, 1):
        y = STREET_START
        while y < STREET_END:
            w = rng.uniform(w_lo, w_lo + 12.0)
            h = rng.uniform(h_lo, h_hi)
            d = rng.uniform(10.0, 16.0)
            c0, c1 = two_tone(rng, float(rng.choice(palette)), rng.uniform(0.1, 0.35), rng.uniform(0.5, 0.8), 0.12)
            mat = mats.add(c0, c1, 4.0, gain=1.0,
                           grid=(np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]),
                                 window_period * rng.uniform(0.9, 1.1), rng.uniform(0.3, 0.6), hsv(0.58, 0.25, 0.35)))
            x_in = side * (sidewalk_end + rng.uniform(0.0, 0.6))
            lo = [min(x_in, x_in + side * d), y, -0.5]
            hi = [max(x_in, x_in + side * d), min(y + w, STREET_END), h]
            buildings.append(box_mesh(lo, hi, mat))
            y += w + (rng.uniform(2.0, 6.0) if rng.random() < 0.3 else 0.0)
    end_mat = mats.add((0.7, 0.62, 0.55), (0.6, 0.52, 0.47), 6.0, gain=1.0,
                       grid=(np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), 3.5, 0.5, hsv(0.58, 0.25, 0.35)))
    buildings.append(box_mesh([-70.0, STREET_END, -0.5], [70.0, STREET_END + 12.0, 40.0], end_mat))
    objects.append(SceneObject(3, 3, concat_meshes(buildings), "building"))

    # ---- things.
    cat_of = {c.name: c.id for c in OUTDOOR_CATEGORIES}
    next_id = 1001
    tyre = mats.add((0.08, 0.08, 0.08), (0.14, 0.14, 0.14), 0.5, gain=1.0)
    glass = mats.add((0.2, 0.25, 0.3), (0.35, 0.4, 0.45), 1.5, gain=1.0)
    counts: dict[str, int] = {}

    def add(name: str, mesh: Mesh) -> None:
        nonlocal next_id
        objects.append(SceneObject(next_id, cat_of[name], mesh, f"{name}_{next_id - 1000}"))
        counts[name] = counts.get(name, 0) + 1
        next_id += 1

    # Parked cars along both kerbs, more densely near the start of the street so they are seen up close.
    p_near, p_far = float(rng.uniform(0.4, 0.9)), float(rng.uniform(0.2, 0.6))
    van_share = float(rng.uniform(0.1, 0.4))
    for side in (-1, 1):
        y = STREET_START + 30 + rng.uniform(0, 4)
        while y < 200.0:
            if rng.random() < (p_near if y < 60 else p_far):
                van = rng.random() < van_share
                body = mats.add(*two_tone(rng, rng.uniform(0, 1), rng.uniform(0.2, 0.8), rng.uniform(0.4, 0.85), 0.15),
                                1.2, gain=1.0)
                mesh = _car(rng, body, glass, tyre, van)
                x = side * (road_half - 1.15)
                add("van" if van else "car", mesh.transformed(rotation_z(rng.uniform(-0.04, 0.04)), [x, y + 2.5, 0.0]))
                y += (5.6 if van else 5.0) + rng.uniform(0.3, 1.5)
            else:
                y += rng.uniform(4.0, 9.0)
    # Trees on the grass strips (on the sidewalk's edge without grass), streetlights between them, signs and
    # pedestrians on the sidewalks.
    trunk_mat = mats.add((0.35, 0.25, 0.16), (0.25, 0.17, 0.1), 0.6, gain=1.0)
    pole_mat = mats.add((0.45, 0.47, 0.5), (0.35, 0.37, 0.4), 1.0, gain=1.0)
    tree_spacing = None if rng.random() < 0.15 else float(rng.uniform(9.0, 20.0))
    light_spacing = float(rng.uniform(18.0, 35.0))
    tree_x = (road_half + grass_end) / 2 if grass_w > 0 else grass_end + 0.5
    for side in (-1, 1):
        occupied = []  # (x, y) and radius along this side: nothing overlaps
        if tree_spacing is not None:
            for y in np.arange(STREET_START + 35 + rng.uniform(0, 5), 320.0, tree_spacing):
                y = y + rng.uniform(-1.5, 1.5)
                crown = mats.add(*two_tone(rng, rng.uniform(0.22, 0.33), 0.6, 0.45, 0.2), 0.7, gain=1.0)
                h = rng.uniform(2.2, 3.0)
                r = rng.uniform(1.2, 2.0)
                tree = concat_meshes([cylinder_mesh(rng.uniform(0.1, 0.18), h + 0.5, trunk_mat, segments=12),
                                      sphere_mesh(r, crown).transformed(np.eye(3), [0, 0, h + r * 0.8])])
                add("tree", tree.transformed(np.eye(3), [side * tree_x, y, 0.12]))
                occupied.append((np.array([side * tree_x, y]), r))
        for y in np.arange(STREET_START + 38 + rng.uniform(0, 8), 320.0, light_spacing):
            pos = np.array([side * (grass_end + 0.4), y])
            if any(np.linalg.norm(pos - q) < r + 0.3 for q, r in occupied):
                continue  # no pole grows through a crown
            h = rng.uniform(6.0, 7.0)
            arm = box_mesh([0.0, -0.08, h - 0.15], [1.6, 0.08, h], pole_mat)
            head = box_mesh([1.2, -0.22, h - 0.3], [1.9, 0.22, h - 0.1], pole_mat)
            light = concat_meshes([cylinder_mesh(0.15, h, pole_mat, segments=12), arm, head])
            yaw = 0.0 if side < 0 else np.pi  # the arm reaches over the road
            add("streetlight", light.transformed(rotation_z(yaw), [pos[0], pos[1], 0.12]))
            occupied.append((pos, 0.3))
        for _ in range(int(rng.integers(1, 6))):
            pos = np.array([side * (grass_end + 0.35), rng.uniform(4.0, 60.0)])
            if any(np.linalg.norm(pos - q) < r + 0.6 for q, r in occupied):
                continue
            plate = mats.add(*two_tone(rng, float(rng.choice([0.0, 0.6, 0.15])), 0.8, 0.8, 0.05), 0.5, gain=1.0)
            yaw = 0.0 if side > 0 else np.pi  # the plate faces the road
            add("sign", _sign(rng, pole_mat, plate).transformed(rotation_z(yaw), [pos[0], pos[1], 0.12]))
            occupied.append((pos, 0.3))
        for _ in range(int(rng.integers(2, 10))):
            for _try in range(50):
                pos = np.array([side * rng.uniform(grass_end + 0.8, sidewalk_end - 0.4), rng.uniform(5.0, 90.0)])
                if all(np.linalg.norm(pos - q) > r + 0.5 for q, r in occupied):
                    break
            else:
                continue
            occupied.append((pos, 0.25))
            cloth = mats.add(*two_tone(rng, rng.uniform(0, 1), 0.6, 0.6, 0.3), 0.6, gain=1.2)
            skin = mats.add(*two_tone(rng, 0.07, 0.45, 0.75, 0.1), 0.5, gain=1.0)
            height = rng.uniform(1.55, 1.9)
            body = lathe_mesh([0.16, 0.22, 0.2, 0.12], [0.0, 0.9, height - 0.3, height - 0.22], cloth, segments=12)
            head = sphere_mesh(0.12, skin, rings=8, segments=12).transformed(np.eye(3), [0, 0, height - 0.12])
            add("pedestrian", concat_meshes([body, head]).transformed(np.eye(3), [pos[0], pos[1], 0.12]))
    sun = unit([0.45, 0.75, 0.48])
    lighting = Lighting(np.full(3, 0.45), 0.12, np.array([sun, unit([-0.5, -0.3, 0.3])]),
                        np.array([[0.55] * 3, [0.12] * 3]))
    description = {
        "street": {"road_half_width_m": round(road_half, 3), "grass_width_m": round(grass_w, 3),
                   "sidewalk_end_m": round(sidewalk_end, 3), "grass_end_m": round(grass_end, 3),
                   "building_height_m": [round(h_lo, 2), round(h_hi, 2)],
                   "window_period_m": round(window_period, 2), "parking_density": [round(p_near, 3), round(p_far, 3)],
                   "tree_spacing_m": None if tree_spacing is None else round(tree_spacing, 2),
                   "streetlight_spacing_m": round(light_spacing, 2)},
        "object_counts": dict(sorted(counts.items())),
    }
    return SceneContent(
        kind="outdoor", categories=list(OUTDOOR_CATEGORIES), objects=objects, materials=mats, lighting=lighting,
        confusable=OUTDOOR_CONFUSABLE, scene_box_type="unbounded",
        aabb=np.array([[-sidewalk_end - 16, STREET_START, -0.5], [sidewalk_end + 16, STREET_END + 12, 40.0]]),
        sky_category=cat_of["sky"], depth_unit_scale_factor=1e-2, description=description,
    )
