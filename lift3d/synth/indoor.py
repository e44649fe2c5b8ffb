"""The indoor scenes of ``lift3d synth``: a furnished room drawn from the layout's random stream.

What a seed chooses (``docs/synth.md`` lists the ranges):

* the room (:mod:`lift3d.synth.rooms`): by default a rectangle of 3.5-9 m a side or an L (a rectangle with
  one corner cut out), 2.4-3.4 m high, with 0-3 windows and maybe a rug; ``room_shape`` asks for a polygon,
  a hexagon, a sloped or vaulted ceiling, a round room or an open plan instead;
* wall and floor textures, from near-textureless paint to strong patterns (wallpaper stripes, bricks, tiles,
  planks), each with a *texture level* in [0, 1];
* the lighting: a key and a fill light (direction, intensity), a colour temperature of 2700-6500 K and an
  ambient level, scaled to a plausible exposure;
* 6-16 objects from :data:`CATALOGUE` (:mod:`lift3d.synth.catalogue`), with sizes from a 2 m sofa down to a
  7 cm cup and thin parts (chair and stool legs, lamp poles); large pieces stand on the floor (cabinets,
  shelves, sofas and most lamps and plants along the walls, chairs often at a table) and small ones on the
  tops of tables, cabinets, shelves, stools and boxes (a cup on a table); ``clutter="dense"`` adds a
  cluttered room's worth more (:mod:`lift3d.synth.clutter`), from its own random stream.

Floor footprints (bounding circles) never overlap and everything rests on the floor or on its support.
"""

from __future__ import annotations

import numpy as np

from lift3d.synth.catalogue import (  # noqa: F401  (re-exported: the catalogue's home before it had its own)
    ALONG_WALL,
    CATALOGUE,
    FLOOR_WEIGHTS,
    INDOOR_CATEGORIES,
    INDOOR_CONFUSABLE,
    SMALL_WEIGHTS,
    Built,
    build_thing,
    indoor_categories,
)
from lift3d.synth.clutter import ClutterRoom, add_clutter
from lift3d.synth.geometry import Lighting, MaterialBank, RoomSpec, SceneContent, SceneObject, kelvin_rgb, rotation_z
from lift3d.synth.placement import Support, place_next_to, place_on_floor, place_on_support
from lift3d.synth.polygons import distance_to_outline, inside_polygon, polygon_area  # noqa: F401  (re-exported)
from lift3d.synth.rooms import (  # noqa: F401  (room_outline re-exported)
    LEGACY_SHAPES,
    ROOM_CLEARANCE,
    ROOM_SHAPES,
    build_room,
    legacy_room,
    room_outline,
)

#: ``--clutter`` choices: ``auto`` lets the seed pick ``none`` or ``dense`` (``lift3d.synth.make``).
CLUTTER_LEVELS = ("none", "auto", "dense")
#: Floor things of an open plan's dark space.
DARK_SPACE_THINGS = ("cabinet", "box", "shelf", "plant", "ball", "sofa", "chair")


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




# --------------------------------------------------------------------------------------------- build
def build_indoor(rng: np.random.Generator, room_shape: str = "auto", clutter: str = "none",
                 clutter_rng: np.random.Generator | None = None) -> SceneContent:
    """A furnished room (see the module docstring): stuff (walls, floor, ceiling, windows, maybe a rug) and
    6-16 things of the catalogue, 30-40 with ``clutter="dense"``.

    Parameters
    ----------
    rng : np.random.Generator
        The layout's random stream (the same stream gives the same room).
    room_shape : str
        One of :data:`ROOM_SHAPES` (``lift3d.synth.rooms``); ``auto`` is the original rectangle or L.
    clutter : {"none", "dense"}
        ``dense`` adds the cluttered room's things (``lift3d.synth.clutter``) to the room's own.
    clutter_rng : np.random.Generator, optional
        The clutter's random stream (needed with ``dense``); it draws the added things, so the room, its
        own things and the lighting are those of ``clutter="none"``.
    """
    if room_shape not in ROOM_SHAPES:
        raise ValueError(f"room_shape {room_shape!r} is not one of {', '.join(ROOM_SHAPES)}")
    if clutter not in ("none", "dense"):
        raise ValueError(f"clutter {clutter!r} is not 'none' or 'dense'")
    mats = MaterialBank(rng)
    legacy = room_shape in LEGACY_SHAPES
    room = legacy_room(rng, mats, {"auto": None, "box": "rectangle", "l": "L"}[room_shape]) if legacy \
        else build_room(rng, mats, room_shape)
    poly = room.place_region
    area = polygon_area(poly)
    objects: list[SceneObject] = list(room.stuff)
    walls = None if legacy else (room.wall_edges or list(zip(room.outline, np.roll(room.outline, -1, axis=0))))
    categories, confusable = indoor_categories(clutter == "dense")

    def fits_under_ceiling(built: Built, centre3: np.ndarray, yaw: float) -> bool:
        if legacy:
            return True  # the original rooms' ceiling is above everything in the catalogue
        v = built.mesh.vertices @ rotation_z(yaw).T + centre3
        return bool(np.all(v[:, 2] < room.ceiling.at(v[:, :2]) - 0.05))

    # ---- things: how many, which, and where
    cat_of = {c.name: c.id for c in categories}
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

    circles: list[tuple[np.ndarray, float]] = list(room.keepouts)  # inner walls, doorways: nothing stands there
    tables: list[tuple[np.ndarray, float]] = []
    supports: list[Support] = []
    objects_desc = []
    next_id = 1001
    counts: dict[str, int] = {}
    footprint_budget = 0.4 * area  # leave room to walk

    def add(name: str, built: Built, centre3: np.ndarray, yaw: float, rests_on: int,
            group: str | None = None) -> SceneObject:
        nonlocal next_id
        mesh = built.mesh.transformed(rotation_z(yaw), centre3)
        k = counts.get(name, 0)
        counts[name] = k + 1
        obj = SceneObject(next_id, cat_of[name], mesh, f"{name}_{k}", rests_on=rests_on, thin=built.thin,
                          yaw=float(yaw))
        objects.append(obj)
        b = mesh.bounds
        objects_desc.append({"id": next_id, "class": name, "size_m": np.round(b[1] - b[0], 3).tolist(),
                             "on": "floor" if rests_on == 0 else rests_on})
        if group is not None:
            objects_desc[-1]["group"] = group
        next_id += 1
        return obj

    used = 0.0
    for name in floor_names:
        built = build_thing(name, rng, mats)
        if used + np.pi * built.radius**2 > footprint_budget:
            continue
        placed = None
        if name == "chair" and tables and rng.random() < 0.7:
            placed = place_next_to(rng, built.radius, tables[int(rng.integers(len(tables)))], poly, circles)
        if placed is None:
            placed = place_on_floor(rng, built.radius, poly, circles,
                                    along_wall=rng.random() < ALONG_WALL.get(name, 0.0), walls=walls)
        if placed is None:
            continue  # no room left: drop it
        centre, yaw = placed
        if not fits_under_ceiling(built, np.array([centre[0], centre[1], 0.0]), yaw):
            continue
        circles.append((centre, built.radius))
        used += np.pi * built.radius**2
        add(name, built, np.array([centre[0], centre[1], 0.0]), yaw, 0)
        if name == "table":
            tables.append((centre, built.radius))
        if built.top is not None:
            supports.append(Support(len(objects) - 1, centre, yaw, built.top, []))

    def place_small(name: str) -> bool:
        built = build_thing(name, rng, mats, small=True)
        spot = place_on_support(rng, built.radius, supports)
        if spot is not None:
            s, pos, yaw = spot
            add(name, built, pos, yaw, objects[s.index].segment_id)
            return True
        placed = place_on_floor(rng, built.radius, poly, circles, along_wall=False, walls=walls)
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

    for region, region_walls, count in room.extra_regions:  # an open plan's dark space: a few things of its own
        for _ in range(count):
            name = DARK_SPACE_THINGS[int(rng.integers(len(DARK_SPACE_THINGS)))]
            built = build_thing(name, rng, mats)
            placed = place_on_floor(rng, built.radius, region, circles, along_wall=True, walls=region_walls)
            if placed is not None and fits_under_ceiling(built, np.array([*placed[0], 0.0]), placed[1]):
                circles.append((placed[0], built.radius))
                add(name, built, np.array([placed[0][0], placed[0][1], 0.0]), placed[1], 0)

    clutter_desc = None
    if clutter == "dense":
        layout_rng = mats.rng
        mats.rng = clutter_rng  # the clutter's materials come from its own stream, so the lighting is unchanged
        clutter_desc = add_clutter(clutter_rng, mats, ClutterRoom(
            region=poly, walls=walls or list(zip(poly, np.roll(poly, -1, axis=0))), keepouts=list(room.keepouts),
            ceiling_at=room.ceiling.at, objects=objects, supports=supports, add=add, area=area,
            categories=categories))
        mats.rng = layout_rng

    lighting, light_desc = room_lighting(rng)
    description = {
        "room": room.description,
        "wall_texture": room.wall_desc, "floor_texture": room.floor_desc, "lighting": light_desc,
        "objects": objects_desc,
    }
    if clutter_desc is not None:
        description["clutter"] = clutter_desc
    spec = room.spec
    if clutter == "dense":
        if spec is None:
            height = room.ceiling.top
            spec = RoomSpec(ceiling_at=room.ceiling.at, camera_region=room.outline,
                            camera_top=lambda xy: np.full(len(np.atleast_2d(xy)), height - 0.6),
                            clearance=ROOM_CLEARANCE)
        spec.cover_things = True
    return SceneContent(
        kind="indoor", categories=categories, objects=objects, materials=mats, lighting=lighting,
        confusable=confusable, scene_box_type="bounded", aabb=room.aabb, depth_unit_scale_factor=1e-3,
        room_polygon=room.outline, description=description, room=spec,
    )
