"""Cluttered rooms (``--clutter dense``): 30-40 things, the hard cases for lifting small and thin things.

On top of the room's own things (drawn as without clutter, so the room, its furniture and its lighting stay
those of ``--clutter none``), from the clutter's own random stream:

* a **table set**: a dining table with four chairs around it (two if four do not fit);
* **rows of one class side by side**, 1-6 cm apart: 3-4 balls (always), and two of: 2-4 boxes, 2-3 stools,
  2-3 books lying on the floor, 2-3 figurines on thin legs;
* **thin and flat things on the floor**: 1-2 toy planes lying flat (wings 0.35-0.45 m across, 1 % of that
  thick at the tips), 1-2 mats (0.8-2 cm thick), a figurine on thin legs (0.22-0.35 m, legs 5-8 mm), a floor
  lamp (its stand);
* **on tables and other tops**: a row of three cups, 2-3 small figurines on thin legs in a row, books, a
  small toy plane, a vase, a table lamp;
* then more small things on the floor and on tops until the room holds its drawn total of 32-40.

Floor things never overlap: their footprints (the convex hull of the mesh seen from above) are at least
1 cm apart (3 cm between groups) and inside the room, clear of inner walls and doorways, with most groups
against the walls and, after the table set, a 0.6 m disc at the most open point of the room kept free for
the cameras; small
things stand inside their support's top without overlapping each other. Every added thing can be seen from
eye height (1.5 m) at two of six points spread over the free floor, and stays so as more things come, so the
cameras, which then turn to the things they see least (``cameras.cover_things``), can find it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from lift3d.data.scene import Category
from lift3d.synth.catalogue import (
    Built,
    build_thing,
    dining_table,
    flat_toy_plane,
    floor_ball,
    legged_figurine,
    mat_thing,
)
from lift3d.synth.geometry import MaterialBank, SceneObject, rotation_z, unit
from lift3d.synth.placement import Support
from lift3d.synth.polygons import convex_gap, convex_hull, distance_to_outline, inside_polygon, polygon_area

#: Things a cluttered room holds in all (its own and the clutter's): drawn from this range.
TOTAL_THINGS = (32, 40)
#: Floor footprints cover at most this share of the floor (the rest is for walking and the cameras).
FLOOR_SHARE = 0.55
#: The cameras' free floor (at least this far from walls and footprints) must stay in one piece: a new thing
#: may cut off at most :data:`CUT_OFF_M2` of it from the rest.
CAMERA_CLEARANCE = 0.5
CUT_OFF_M2 = 0.3


@dataclass
class ClutterRoom:
    """The room as the clutter sees it.

    ``add(name, built, centre3, yaw, rests_on, group)`` adds a thing to the scene (``indoor.build_indoor``'s),
    ``objects`` is the scene's objects so far and ``supports`` the tops small things may stand on.
    """

    region: np.ndarray
    walls: list
    keepouts: list
    ceiling_at: Callable[[np.ndarray], np.ndarray]
    objects: list[SceneObject]
    supports: list[Support]
    add: Callable[..., SceneObject]
    area: float
    categories: list[Category]


def _disc(centre: np.ndarray, radius: float) -> np.ndarray:
    ang = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    return centre + radius / np.cos(np.pi / 12) * np.column_stack([np.cos(ang), np.sin(ang)])


class _Floor:
    """The floor's footprints and the tests a new one must pass."""

    def __init__(self, room: ClutterRoom):
        self.room = room
        things = {c.id for c in room.categories if c.isthing}
        self.hulls = [convex_hull(o.mesh.vertices[:, :2]) for o in room.objects
                      if o.category_id in things and o.rests_on == 0]
        self.covered = sum(polygon_area(h) for h in self.hulls)
        self.blocked = [_disc(c, r) for c, r in room.keepouts]
        #: (index in the scene's objects, vertices) of the things added so far (each must stay in sight)
        self.tracked: list[tuple[int, np.ndarray]] = []
        # The floor at 10 cm, for keeping the cameras' free floor in one piece.
        lo, hi = room.region.min(0), room.region.max(0)
        self.res = 0.1
        self.origin = lo - 0.2
        size = np.ceil((hi + 0.2 - self.origin) / self.res).astype(int) + 1
        self.raster = np.zeros((int(size[1]), int(size[0])), np.uint8)
        cv2.fillPoly(self.raster, [self._px(room.region)], 1, shift=4)
        for disc in self.blocked:
            cv2.fillConvexPoly(self.raster, self._px(disc), 0, shift=4)
        self.cut_off = self._cut_off([])
        self.viewpoints = self._open_points()[1]

    def _open_points(self) -> tuple[np.ndarray, np.ndarray]:
        """The free floor's most open point, and eye-height viewpoints: that point, then up to five free points
        each farthest from those chosen."""
        region = self.room.region
        lo, hi = region.min(0), region.max(0)
        grid = np.stack(np.meshgrid(np.linspace(lo[0], hi[0], 40), np.linspace(lo[1], hi[1], 40)), -1).reshape(-1, 2)
        grid = grid[inside_polygon(grid, region)]
        clear = distance_to_outline(grid, region)
        for h in self.hulls + self.blocked:
            clear = np.minimum(clear, np.where(inside_polygon(grid, h), 0.0, distance_to_outline(grid, h)))
        chosen = [int(np.argmax(clear))]
        far = np.linalg.norm(grid - grid[chosen[0]], axis=1)
        far[clear < 0.6] = -1.0
        for _ in range(5):
            if far.max() <= 0.5:
                break
            chosen.append(int(np.argmax(far)))
            far = np.minimum(far, np.linalg.norm(grid - grid[chosen[-1]], axis=1))
        return grid[chosen[0]], np.column_stack([grid[chosen], np.full(len(chosen), 1.5)])

    def reserve_camera_spot(self) -> None:
        """Keep a 0.6 m disc at the most open point of the floor free for the cameras (after the big pieces)."""
        spot, self.viewpoints = self._open_points()
        self.blocked.append(_disc(spot, 0.6))

    def _px(self, xy: np.ndarray) -> np.ndarray:
        return np.round((xy - self.origin) / self.res * 16).astype(np.int32)

    def _cut_off(self, new: list[np.ndarray]) -> float:
        """Area (m²) of the cameras' free floor outside its largest piece, with the footprints ``new`` added."""
        free = self.raster.copy()
        for h in self.hulls + new:
            cv2.fillConvexPoly(free, self._px(h), 0, shift=4)
        ok = (cv2.distanceTransform(free, cv2.DIST_L2, 5) * self.res >= CAMERA_CLEARANCE).astype(np.uint8)
        n, lab = cv2.connectedComponents(ok, connectivity=8)
        if n <= 1:
            return 0.0
        sizes = np.bincount(lab.ravel())[1:]
        return float(sizes.sum() - sizes.max()) * self.res**2

    def free_spots(self, clearance: float) -> np.ndarray:
        """``[N, 2]`` floor points (10 cm apart) at least ``clearance`` from walls, footprints and keep-outs."""
        free = self.raster.copy()
        for h in self.hulls + self.blocked:
            cv2.fillConvexPoly(free, self._px(h), 0, shift=4)
        rows, cols = np.nonzero(cv2.distanceTransform(free, cv2.DIST_L2, 5) * self.res >= clearance)
        return self.origin + np.column_stack([cols, rows]) * self.res

    def keeps_floor_whole(self, new: list[np.ndarray]) -> bool:
        """Whether adding the footprints ``new`` leaves the cameras' free floor in one piece (as much as before)."""
        return self._cut_off(new) <= self.cut_off + CUT_OFF_M2

    def in_sight(self, new: list[tuple[np.ndarray, np.ndarray]]) -> bool:
        """Whether the things ``new`` (vertices, triangles), once added, can each be seen (two of their sample
        points with nothing else in front) from two of the viewpoints, and hide none of the things added before."""
        import open3d as o3d  # here, not at module level: Open3D takes seconds to import

        scene = o3d.t.geometry.RaycastingScene()
        for o in self.room.objects:
            scene.add_triangles(o3d.core.Tensor(o.mesh.vertices.astype(np.float32)),
                                o3d.core.Tensor(o.mesh.triangles.astype(np.uint32)))
        first_new = len(self.room.objects)
        for v, t in new:
            scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(t.astype(np.uint32)))
        targets = [(first_new + k, v) for k, (v, _) in enumerate(new)] + list(self.tracked)
        for geometry, vertices in targets:
            idx = np.unique(np.linspace(0, len(vertices) - 1, min(16, len(vertices))).astype(int))
            pts = np.vstack([vertices[idx], vertices.mean(0)])
            seen = 0
            for eye in self.viewpoints:
                d = pts - eye
                dist = np.linalg.norm(d, axis=1)
                rays = np.concatenate([np.repeat(eye[None], len(pts), axis=0), d / dist[:, None]], axis=1)
                ans = scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))
                hit = (ans["geometry_ids"].numpy() == geometry) | (ans["t_hit"].numpy() >= dist - 0.01)
                seen += hit.sum() >= 2
                if seen >= min(2, len(self.viewpoints)):
                    break
            else:
                return False
        return True

    def fits(self, hull: np.ndarray, gap: float, extra: list[np.ndarray] = ()) -> bool:
        region = self.room.region
        if not inside_polygon(hull, region).all() or distance_to_outline(hull, region).min() < 0.02:
            return False
        if inside_polygon(region, hull).any():
            return False
        if any(convex_gap(hull, b) <= 0.0 for b in self.blocked):
            return False
        if any(convex_gap(hull, h) < gap for h in self.hulls):
            return False
        return all(convex_gap(hull, h) > 0.005 for h in extra)

    def budget(self, hulls: list[np.ndarray]) -> bool:
        return self.covered + sum(polygon_area(h) for h in hulls) <= FLOOR_SHARE * self.room.area


def _world_hull(local: np.ndarray, centre: np.ndarray, yaw: float) -> np.ndarray:
    return local @ rotation_z(yaw)[:2, :2].T + centre


def add_clutter(rng: np.random.Generator, mats: MaterialBank, room: ClutterRoom) -> dict:
    """Fill ``room`` with the cluttered room's things (module docstring); returns what was added
    (``lift3d_synth.scene.clutter``).

    Parameters
    ----------
    rng : np.random.Generator
        The clutter's random stream.
    mats : MaterialBank
        The scene's materials (drawing from ``rng`` while the clutter is added).
    room : ClutterRoom
        The room and the scene's ``add``.
    """
    floor = _Floor(room)
    things = {c.id for c in room.categories if c.isthing}
    target = int(rng.integers(TOTAL_THINGS[0], TOTAL_THINGS[1] + 1))
    groups: list[dict] = []

    def count() -> int:
        return sum(o.category_id in things for o in room.objects)

    edges = [(a, b) for a, b in room.walls if np.linalg.norm(b - a) > 0.3] or list(room.walls)
    lengths = np.array([np.linalg.norm(b - a) for a, b in edges])

    def frame(along_wall: bool, length: float, depth: float, spots: np.ndarray | None = None
              ) -> tuple[np.ndarray, float]:
        """A group's centre and yaw: its local +x along a wall and +y into the room, or anywhere (one of
        ``spots`` when given)."""
        if along_wall:
            p = lengths / lengths.sum()
            k = int(rng.choice(len(edges), p=p))
            a, b = edges[k]
            along = unit(b - a)
            inward = np.array([-along[1], along[0]])
            half = min(length / 2 + 0.05, lengths[k] / 2)
            t = rng.uniform(half, max(half, lengths[k] - half))
            return a + along * t + inward * (depth / 2 + 0.04), float(np.arctan2(along[1], along[0]))
        lo, hi = room.region.min(0), room.region.max(0)
        centre = rng.uniform(lo, hi) if spots is None or not len(spots) else \
            spots[int(rng.integers(len(spots)))] + rng.uniform(-0.05, 0.05, 2)
        if rng.random() < 0.7:  # square to a wall, as furniture mostly is
            a, b = edges[int(rng.choice(len(edges), p=lengths / lengths.sum()))]
            return centre, float(np.arctan2(*(b - a)[::-1]) + np.pi / 2 * rng.integers(4))
        return centre, float(rng.uniform(0, 2 * np.pi))

    def place_group(name: str, members: list[tuple[str, Built, np.ndarray, float]], along_wall: float,
                    gap: float = 0.03, tries: int = 150) -> bool:
        """Place ``members`` (class, thing, local position, local yaw) as one group, or nothing."""
        local_hulls = [convex_hull(b.mesh.vertices[:, :2]) @ rotation_z(y)[:2, :2].T + xy for _, b, xy, y in members]
        pts = np.concatenate(local_hulls)
        length, depth = float(np.ptp(pts[:, 0])), float(np.ptp(pts[:, 1]))
        mid = (pts.min(0) + pts.max(0)) / 2
        # Free placements start from floor points with room for the group's shorter side.
        spots = floor.free_spots(min(length, depth) / 2 + gap) if along_wall < 1.0 else None
        for _ in range(tries):
            centre, yaw = frame(bool(rng.random() < along_wall), length, depth, spots)
            hulls = [_world_hull(h - mid, centre, yaw) for h in local_hulls]
            if not floor.budget(hulls):
                return False
            if not all(floor.fits(h, gap, hulls[:k]) for k, h in enumerate(hulls)):
                continue
            placed = []
            for cls, built, xy, y in members:
                c = centre + rotation_z(yaw)[:2, :2] @ (xy - mid)
                placed.append((built.mesh.vertices @ rotation_z(yaw + y).T + np.array([c[0], c[1], 0.0]),
                               built.mesh.triangles))
            if not all(np.all(v[:, 2] < room.ceiling_at(v[:, :2]) - 0.05) for v, _ in placed):
                continue
            if not floor.keeps_floor_whole(hulls) or not floor.in_sight(placed):
                continue
            for (cls, built, xy, y), h in zip(members, hulls):
                c = centre + rotation_z(yaw)[:2, :2] @ (xy - mid)
                obj = room.add(cls, built, np.array([c[0], c[1], 0.0]), yaw + y, 0, name)
                floor.tracked.append((len(room.objects) - 1, obj.mesh.vertices))
                floor.hulls.append(h)
                floor.covered += polygon_area(h)
                if built.top is not None:
                    room.supports.append(Support(len(room.objects) - 1, c, yaw + y, built.top, []))
            floor.cut_off = floor._cut_off([])
            groups.append({"group": name, "class": members[0][0], "n": len(members), "on": "floor"})
            return True
        return False

    def row(cls: str, builts: list[Built], spacing: tuple[float, float]) -> list[tuple[str, Built, np.ndarray, float]]:
        """Things side by side along local x, ``spacing`` metres apart (footprint to footprint)."""
        widths = [float(np.ptp(b.mesh.vertices[:, 0])) for b in builts]
        x, out = 0.0, []
        for b, w in zip(builts, widths):
            out.append((cls, b, np.array([x + w / 2, 0.0]), 0.0))
            x += w + rng.uniform(*spacing)
        return out

    # ---- a table set: a dining table and four chairs around it (two when four do not fit)
    table = dining_table(rng, mats)
    hx, hy = table.top[0], table.top[1]
    chairs = [build_thing("chair", rng, mats) for _ in range(4)]
    seats = [float(np.ptp(c.mesh.vertices[:, 0])) for c in chairs]
    g = rng.uniform(0.04, 0.1)
    if 2 * hx >= 1.3:  # two chairs on each long side
        spots = [(np.array([sx * hx / 2, sy * (hy + g + s / 2)]), 0.0 if sy < 0 else np.pi)
                 for (sx, sy), s in zip([(-1, -1), (1, -1), (-1, 1), (1, 1)], seats)]
    else:  # one on each side
        spots = [(np.array([0.0, -(hy + g + seats[0] / 2)]), 0.0), (np.array([0.0, hy + g + seats[1] / 2]), np.pi),
                 (np.array([hx + g + seats[2] / 2, 0.0]), np.pi / 2),
                 (np.array([-(hx + g + seats[3] / 2), 0.0]), -np.pi / 2)]
    members = [("table", table, np.zeros(2), 0.0)] + [("chair", c, xy, y) for c, (xy, y) in zip(chairs, spots)]
    if not place_group("table_set", members, along_wall=0.0, tries=300):
        # Two chairs facing each other across the table.
        two = [members[1], members[4]] if 2 * hx >= 1.3 else [members[1], members[2]]
        place_group("table_set", members[:1] + two, along_wall=0.0, tries=300)

    floor.reserve_camera_spot()

    # ---- rows of one class side by side
    r = rng.uniform(0.1, 0.17)
    balls = [floor_ball(rng, mats, r * rng.uniform(0.9, 1.1)) for _ in range(int(rng.integers(3, 5)))]
    place_group("row_of_balls", row("ball", balls, (0.01, 0.06)), along_wall=0.6)
    kinds = ["box", "stool", "book", "figurine"]
    for k in rng.permutation(len(kinds))[:2]:
        kind = kinds[int(k)]
        if kind == "box":
            builts = [build_thing("box", rng, mats) for _ in range(int(rng.integers(2, 5)))]
        elif kind == "stool":
            builts = [build_thing("stool", rng, mats) for _ in range(int(rng.integers(2, 4)))]
        elif kind == "book":
            builts = [build_thing("book", rng, mats, small=True) for _ in range(int(rng.integers(2, 4)))]
        else:
            h = rng.uniform(0.25, 0.35)
            builts = [legged_figurine(rng, mats, h * rng.uniform(0.9, 1.1)) for _ in range(int(rng.integers(2, 4)))]
        place_group(f"row_of_{kind}{'es' if kind == 'box' else 's'}", row(kind, builts, (0.01, 0.06)), along_wall=0.7)

    # ---- thin and flat things on the floor
    singles = [("toy_plane", flat_toy_plane(rng, mats)) for _ in range(int(rng.integers(1, 3)))]
    singles += [("mat", mat_thing(rng, mats)) for _ in range(int(rng.integers(1, 3)))]
    singles += [("figurine", legged_figurine(rng, mats)), ("lamp", build_thing("lamp", rng, mats))]
    for cls, built in singles:
        place_group(f"{cls}_on_the_floor", [(cls, built, np.zeros(2), 0.0)],
                    along_wall=0.9 if cls == "lamp" else 0.5, gap=0.05)

    # ---- on tables and other tops
    def on_top(name: str, cls: str, builts: list[Built], as_row: bool) -> bool:
        """Things on one support's top (side by side along its longer side with ``as_row``), or nothing."""
        radii = [b.radius for b in builts]
        order = [room.supports[k] for k in rng.permutation(len(room.supports))]
        for s in order:
            hx, hy, z = s.top
            axis = 0 if hx >= hy else 1
            for _ in range(30):
                if as_row:
                    span = sum(2 * r for r in radii) + 0.02 * (len(radii) - 1)
                    half_long, half_short = (hx, hy) if axis == 0 else (hy, hx)
                    if span > 2 * half_long - 0.02 or max(radii) > half_short - 0.01:
                        break
                    start = rng.uniform(-half_long + 0.01, half_long - 0.01 - span)
                    across = rng.uniform(-half_short + max(radii), half_short - max(radii))
                    local, x = [], start
                    for r in radii:
                        p = np.array([x + r, across])
                        local.append(p if axis == 0 else p[::-1])
                        x += 2 * r + 0.02
                else:
                    r = radii[0]
                    if min(hx, hy) < r + 0.01:
                        break
                    local = [rng.uniform([-hx + r, -hy + r], [hx - r, hy - r])]
                if all(np.linalg.norm(p - q) > r + rq + 0.02 for p, r in zip(local, radii) for q, rq in s.circles):
                    poses = []
                    for p, b in zip(local, builts):
                        world = s.centre + rotation_z(s.yaw)[:2, :2] @ p
                        poses.append((np.array([world[0], world[1], s.top[2]]), s.yaw + rng.uniform(0, 2 * np.pi)))
                    if not floor.in_sight([(b.mesh.vertices @ rotation_z(y).T + c, b.mesh.triangles)
                                           for b, (c, y) in zip(builts, poses)]):
                        continue
                    rest_on = room.objects[s.index].segment_id
                    for p, r, b, (c, y) in zip(local, radii, builts, poses):
                        s.circles.append((p, r))
                        obj = room.add(cls, b, c, y, rest_on, name)
                        floor.tracked.append((len(room.objects) - 1, obj.mesh.vertices))
                    groups.append({"group": name, "class": cls, "n": len(builts), "on": int(rest_on)})
                    return True
        return False

    if not any(min(s.top[0], s.top[1]) >= 0.15 for s in room.supports):  # something to put things on
        for _ in range(6):
            cabinet = build_thing("cabinet", rng, mats)
            if cabinet.top is not None and place_group("cabinet", [("cabinet", cabinet, np.zeros(2), 0.0)], 1.0):
                break
    on_top("row_of_cups", "cup", [build_thing("cup", rng, mats) for _ in range(3)], as_row=True)
    h = rng.uniform(0.18, 0.28)
    on_top("row_of_figurines", "figurine", [legged_figurine(rng, mats, h * rng.uniform(0.9, 1.1))
                                            for _ in range(int(rng.integers(2, 4)))], as_row=True)
    for cls in ("book", "book", "toy_plane", "vase", "lamp"):
        built = flat_toy_plane(rng, mats, rng.uniform(0.2, 0.3)) if cls == "toy_plane" \
            else build_thing(cls, rng, mats, small=True)
        on_top(f"{cls}_on_a_top", cls, [built], as_row=False)

    # ---- more small things on the floor and on tops until the room holds its total
    fill = ["ball", "box", "book", "figurine", "toy_plane", "cup", "vase"]
    failures = 0
    while count() < target and failures < 40:
        cls = fill[int(rng.integers(len(fill)))]
        if cls == "figurine":
            built = legged_figurine(rng, mats, rng.uniform(0.15, 0.3))
        elif cls == "toy_plane":
            built = flat_toy_plane(rng, mats, rng.uniform(0.2, 0.45))
        else:
            built = build_thing(cls, rng, mats, small=True)
        if cls in ("cup", "vase") or rng.random() < 0.5:
            ok = on_top(f"{cls}_on_a_top", cls, [built], as_row=False)
        else:
            ok = place_group(f"{cls}_on_the_floor", [(cls, built, np.zeros(2), 0.0)], along_wall=0.6, gap=0.03,
                             tries=60)
        failures += not ok
    return {"level": "dense", "target": target, "things": count(), "groups": groups}
