"""The rooms of ``lift3d synth``: outline, walls, floor, ceiling, windows and rug (the stuff), by shape.

``--room-shape`` (``build_indoor(room_shape=...)``) chooses among:

* ``auto`` — what the seed gives, as before this option existed (a rectangle, or one seed in three of the rooms
  at least 5 m wide an L), so existing seeds give the same bytes; ``box`` and ``l`` force one of the two
  (``box`` on a seed whose ``auto`` room is a rectangle is that same room);
* ``polygon`` — 5-8 walls at angles that are not right angles (each corner at least 8° from 90°), convex or
  with one reflex corner, turned so that no wall is within 6° of the x or y axis;
* ``hexagon`` — a regular hexagon (walls at 120°), turned likewise;
* ``sloped`` — box walls under a plane ceiling that falls from 2.9-3.6 m at one wall to 2.2-2.6 m at the
  opposite one (an attic); the walls' tops follow it;
* ``vaulted`` — box walls under a barrel vault: springing at 2.4-2.9 m, rising 0.35 m to 0.4 of the span;
* ``round`` — a cylindrical room (radius 2.3-3.8 m) or a rectangle with one wall bowed outwards;
* ``open`` — two rooms joined by a wide doorway (1.4-2.4 m wide, 2.05-2.35 m high), or a room with one wall
  missing onto a larger, higher, dark space.

Every shape keeps the stuff classes (``wall``, ``floor``, ``ceiling``, ``window``, ``rug``) and textures; windows
go on straight walls only. A :class:`Room` also says where things may stand (``place_region``, the walls to
stand against, floor areas to keep free) and, for the new shapes, what camera planning needs (``spec``:
the ceiling height above every point, the cameras' region, inner walls).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from lift3d.synth.geometry import (
    MaterialBank,
    Mesh,
    RoomSpec,
    SceneObject,
    box_mesh,
    concat_meshes,
    hsv,
    make_mesh,
    quad_mesh,
    two_tone,
    unit,
)
from lift3d.synth.polygons import (
    distance_to_outline,
    inside_polygon,
    interior_angles,
    polygon_area,
    polygon_triangles,
    signed_area,
)

#: ``--room-shape`` choices; ``auto`` is the seed's rectangle or L.
ROOM_SHAPES = ("auto", "box", "l", "polygon", "hexagon", "sloped", "vaulted", "round", "open")
#: Shapes built by the original generator (the others are :func:`build_room`'s).
LEGACY_SHAPES = ("auto", "box", "l")
#: Walls reach this far beyond convex corners, below the floor and above the ceiling, so no ray slips through
#: a crack.
PAD = 0.05
#: Cameras stay at least this far (metres) from the walls, floor and ceiling of the new shapes.
ROOM_CLEARANCE = 0.5


# --------------------------------------------------------------------------------------------- ceilings
@dataclass
class Ceiling:
    """The ceiling's height above every floor point.

    ``kind`` is ``flat`` (``height``), ``plane`` (rising from ``low`` at the wall ``s = s_low`` to ``high``
    at ``s = s_high``, ``s = direction . xy``), ``vault`` (a circular arc across the span: ``z = z_axis +
    sqrt(radius² - u²)`` with ``u = across . xy - u_centre``, springing at ``spring`` on the side walls) or
    ``regions`` (flat, one height per floor polygon).
    """

    kind: str
    height: float = 0.0
    low: float = 0.0
    high: float = 0.0
    direction: np.ndarray | None = None
    s_low: float = 0.0
    s_high: float = 1.0
    across: np.ndarray | None = None
    u_centre: float = 0.0
    half_span: float = 1.0
    spring: float = 0.0
    rise: float = 0.0
    regions: list[tuple[np.ndarray, float]] = field(default_factory=list)

    @property
    def radius(self) -> float:
        return (self.half_span**2 + self.rise**2) / (2 * self.rise)

    @property
    def curved(self) -> bool:
        return self.kind == "vault"

    def at(self, xy: np.ndarray) -> np.ndarray:
        """``[N]`` ceiling height (metres) above the points ``xy`` ``[N, 2]``."""
        xy = np.atleast_2d(np.asarray(xy, np.float64))
        if self.kind == "flat":
            return np.full(len(xy), self.height)
        if self.kind == "plane":
            s = xy @ self.direction
            return self.low + (self.high - self.low) * (s - self.s_low) / (self.s_high - self.s_low)
        if self.kind == "vault":
            u = xy @ self.across - self.u_centre
            r = self.radius
            return self.spring + self.rise - r + np.sqrt(np.maximum(r**2 - u**2, 0.0))
        out = np.full(len(xy), self.regions[-1][1])
        for poly, h in reversed(self.regions):
            out[inside_polygon(xy, poly)] = h
        return out

    @property
    def top(self) -> float:
        """The highest point of the ceiling."""
        if self.kind == "flat":
            return self.height
        if self.kind == "plane":
            return max(self.low, self.high)
        if self.kind == "vault":
            return self.spring + self.rise
        return max(h for _, h in self.regions)

    def to_json(self) -> dict:
        r = lambda x: round(float(x), 4)  # noqa: E731
        if self.kind == "flat":
            return {"type": "flat", "height_m": r(self.height)}
        if self.kind == "plane":
            # z = a x + b y + c
            k = (self.high - self.low) / (self.s_high - self.s_low)
            a, b = k * self.direction
            c = self.low - k * self.s_low
            return {"type": "plane", "low_m": r(self.low), "high_m": r(self.high),
                    "rising_towards": [r(v) for v in self.direction], "z_equals_ax_by_c": [r(a), r(b), r(c)]}
        if self.kind == "vault":
            return {"type": "barrel_vault", "springline_m": r(self.spring), "crown_m": r(self.spring + self.rise),
                    "radius_m": r(self.radius), "across": [r(v) for v in self.across], "crown_at": r(self.u_centre),
                    "span_m": r(2 * self.half_span),
                    "rule": "z = crown - radius + sqrt(radius^2 - (across . xy - crown_at)^2)"}
        return {"type": "flat_regions", "regions": [{"outline": np.round(p, 3).tolist(), "height_m": r(h)}
                                                    for p, h in self.regions]}


# --------------------------------------------------------------------------------------------- the room
@dataclass
class Room:
    """A room's stuff and what placing things and cameras in it needs.

    Attributes
    ----------
    outline : np.ndarray
        ``[K, 2]`` floor outline, counter-clockwise; the walls stand on its edges.
    stuff : list of SceneObject
        Walls, floor, ceiling, maybe a rug and windows.
    ceiling : Ceiling
        Its height above every point.
    place_region : np.ndarray
        ``[P, 2]`` polygon things stand in (the outline, or the lit room of an open plan).
    wall_edges : list of (a, b), optional
        Walls furniture may stand against, counter-clockwise (the room on their left); None: the
        outline's edges (the original generator's rule).
    keepouts : list of (centre, radius)
        Floor discs nothing may stand on (inner walls, the way through a doorway).
    extra_regions : list of (polygon, wall_edges, count)
        Further floor areas with a few things of their own (the dark space of an open plan).
    description : dict
        ``lift3d_synth.scene.room``.
    spec : RoomSpec, optional
        For camera planning (None for the original shapes: their cameras stay as they were).
    """

    outline: np.ndarray
    stuff: list[SceneObject]
    ceiling: Ceiling
    place_region: np.ndarray
    description: dict
    wall_edges: list | None = None
    keepouts: list = field(default_factory=list)
    extra_regions: list = field(default_factory=list)
    spec: RoomSpec | None = None
    wall_desc: dict = field(default_factory=dict)
    floor_desc: dict = field(default_factory=dict)

    @property
    def aabb(self) -> np.ndarray:
        lo, hi = self.outline.min(0), self.outline.max(0)
        return np.array([[lo[0], lo[1], 0.0], [hi[0], hi[1], self.ceiling.top]])


# --------------------------------------------------------------------------------------------- textures
def wall_texture(rng, mats: MaterialBank) -> tuple[int, dict]:
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


def floor_texture(rng, mats: MaterialBank) -> tuple[int, dict]:
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



# --------------------------------------------------------------------------------------------- the original shapes
def room_outline(rng: np.random.Generator, force: str | None = None
                 ) -> tuple[np.ndarray, list[tuple[float, float, float, float]], str]:
    """A room's floor outline: ``[K, 2]`` corners counter-clockwise around the origin, the rectangles
    ``(x0, y0, x1, y1)`` that tile it, and its shape (``rectangle`` or ``L``; ``force`` one of them)."""
    for _ in range(100):
        w, d = rng.uniform(3.5, 9.0, 2)
        if max(w, d) / min(w, d) <= 2.2 and (force != "L" or min(w, d) >= 5.0):
            break
    x0, x1, y0, y1 = -w / 2, w / 2, -d / 2, d / 2
    # Drawn as before this option existed, so a forced shape on a seed that gives it anyway is that same room.
    rectangle = min(w, d) < 5.0 or rng.random() >= 0.35
    if force == "rectangle" or (force is None and rectangle):
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


def legacy_room(rng: np.random.Generator, mats: MaterialBank, force: str | None = None) -> Room:
    """The original generator's room (``--room-shape auto``; ``box``, ``l`` force its shape): a rectangle or
    an L, 2.4-3.4 m high, 0-3 windows, a rug in three rooms of four. Draws exactly what it drew before the
    other shapes existed."""
    poly, rects, shape = room_outline(rng, force)
    height = float(rng.uniform(2.4, 3.4))
    lo, hi = poly.min(0), poly.max(0)
    area = polygon_area(poly)
    objects: list[SceneObject] = []

    # ---- stuff: walls on the outline's edges, extended past convex corners so no ray slips through a crack
    pad = PAD
    pad = 0.05
    wall_mat, wall_desc = wall_texture(rng, mats)
    floor_mat, floor_desc = floor_texture(rng, mats)
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

    desc = {"shape": shape, "size_m": np.round([hi[0] - lo[0], hi[1] - lo[1], height], 3).tolist(),
            "floor_area_m2": round(area, 2), "outline": np.round(poly, 3).tolist(),
            "windows": len(windows), "rug": has_rug}
    return Room(poly, objects, Ceiling("flat", height=height), poly, desc, wall_desc=wall_desc, floor_desc=floor_desc)


# --------------------------------------------------------------------------------------------- the new shapes
def _edge_inward(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = unit(b - a)
    return np.array([-d[1], d[0]])  # counter-clockwise outline: the interior is on the left


def _convex_corners(poly: np.ndarray) -> list[bool]:
    n = len(poly)
    turn = [(poly[k] - poly[k - 1], poly[(k + 1) % n] - poly[k]) for k in range(n)]
    return [float(a[0] * b[1] - a[1] * b[0]) > 0 for a, b in turn]  # a left turn on a counter-clockwise outline


def _strip(xy: np.ndarray, bottom: np.ndarray, top: np.ndarray, material: int, smooth: bool) -> Mesh:
    """A vertical band through the floor points ``xy`` ``[n, 2]`` from ``bottom`` to ``top`` ``[n]``."""
    n = len(xy)
    verts = np.concatenate([np.column_stack([xy, bottom]), np.column_stack([xy, top])])
    tris = [t for i in range(n - 1) for t in ((i, i + 1, n + i + 1), (i, n + i + 1, n + i))]
    return make_mesh(verts, tris, material, smooth=smooth)


def _flat_polygon(poly: np.ndarray, z: np.ndarray, material: int) -> Mesh:
    """The polygon ``poly`` ``[K, 2]`` at heights ``z`` ``[K]`` (a floor, or a plane ceiling's corners)."""
    return make_mesh(np.column_stack([poly, z]), polygon_triangles(poly), material, smooth=False)


def _walls(outline: np.ndarray, curved: np.ndarray, ceiling: Ceiling, mat_of_edge: list[int]) -> Mesh:
    """Walls on the outline's edges from below the floor to above the ceiling (their tops follow it),
    straight edges extended past convex corners; consecutive ``curved`` edges form one smooth-shaded wall."""
    n = len(outline)
    convex = _convex_corners(outline)
    # Runs of edges: a straight edge alone, or a maximal sequence of curved edges.
    if curved.all():
        runs = [list(range(n)) + [0]]
        closed = True
    else:
        closed = False
        start = next(k for k in range(n) if not curved[k] or not curved[k - 1])
        runs, k = [], start
        while len(runs) == 0 or k != start:
            run = [k]
            if curved[k]:
                while curved[(run[-1] + 1) % n] and (run[-1] + 1) % n != start:
                    run.append((run[-1] + 1) % n)
            runs.append(run + [(run[-1] + 1) % n])  # vertex indices: the run's edges' starts and its end
            k = (run[-1] + 1) % n
    parts = []
    for run in runs:
        pts = outline[run].copy()
        edges = list(zip(run[:-1], run[1:]))
        inward = np.array([_edge_inward(outline[a], outline[b]) for a, b in edges])
        if not closed:  # extend past convex corners
            pts[0] -= unit(pts[1] - pts[0]) * PAD * convex[run[0]]
            pts[-1] += unit(pts[-1] - pts[-2]) * PAD * convex[run[-1]]
        smooth = bool(curved[run[0]])
        if not smooth and ceiling.curved:  # a straight wall under a vault: sample its arched top
            t = np.linspace(0.0, 1.0, 33)[:, None]
            pts = pts[0] + t * (pts[1] - pts[0])
            nudge = np.repeat(inward[:1], len(pts), axis=0)
        else:
            nudge = np.concatenate([inward[:1], (inward[:-1] + inward[1:]) / 2, inward[-1:]]) if len(inward) > 1 \
                else np.repeat(inward, 2, axis=0)
        top = ceiling.at(pts + 0.01 * nudge) + PAD
        parts.append(_strip(pts, np.full(len(pts), -PAD), top, mat_of_edge[run[0]], smooth))
    return concat_meshes(parts)


def _ceiling_mesh(ceiling: Ceiling, outline: np.ndarray, material: int | list[int]) -> Mesh:
    if ceiling.kind in ("flat", "plane"):
        return _flat_polygon(outline, ceiling.at(outline), material)
    if ceiling.kind == "regions":
        mats = material if isinstance(material, list) else [material] * len(ceiling.regions)
        return concat_meshes([_flat_polygon(p, np.full(len(p), h), m) for (p, h), m in zip(ceiling.regions, mats)])
    # A barrel vault: a grid across the span and along the axis, past the walls by PAD, smooth-shaded.
    along = np.array([-ceiling.across[1], ceiling.across[0]])
    s = outline @ along
    u = np.linspace(-ceiling.half_span - PAD, ceiling.half_span + PAD, 49)
    v = np.array([s.min() - PAD, s.max() + PAD])
    uu, vv = np.meshgrid(u, v)  # rows: along
    xy = (uu.ravel() + ceiling.u_centre)[:, None] * ceiling.across + vv.ravel()[:, None] * along
    verts = np.column_stack([xy, ceiling.at(xy)])
    m = len(u)
    tris = [t for i in range(m - 1) for t in ((i, i + 1, m + i + 1), (i, m + i + 1, m + i))]
    return make_mesh(verts, tris, material, smooth=True)


def _off_axes(rng: np.random.Generator, poly: np.ndarray, margin_deg: float = 6.0) -> tuple[np.ndarray, float]:
    """``poly`` turned about the origin by a random angle after which no edge is within ``margin_deg`` of the
    x or y axis."""
    edges = np.roll(poly, -1, axis=0) - poly
    ang = np.degrees(np.arctan2(edges[:, 1], edges[:, 0]))
    for _ in range(200):
        turn = float(rng.uniform(0.0, 360.0))
        off = (ang + turn) % 90.0
        if np.all((off >= margin_deg) & (off <= 90.0 - margin_deg)):
            break
    c, s = np.cos(np.radians(turn)), np.sin(np.radians(turn))
    return poly @ np.array([[c, s], [-s, c]]), turn


def _centred(poly: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``poly`` moved so its bounding box is centred on the origin, and the move."""
    shift = -(poly.min(0) + poly.max(0)) / 2
    return poly + shift, shift


def polygon_outline(rng: np.random.Generator) -> tuple[np.ndarray, dict]:
    """5-8 walls, 16-50 m², every corner 60-170° (at least 8° from a right angle), walls at least 1.5 m long;
    in two rooms of five one reflex corner (190-250°); turned off the axes."""
    reflex = bool(rng.random() < 0.4)  # decided first: a reflex outline passes the checks less often
    for _ in range(2000):
        k = int(rng.integers(5, 9))
        ang = 2 * np.pi * (np.arange(k) + rng.uniform(-0.3, 0.3, k)) / k
        rad = rng.uniform(0.85, 1.15, k)
        if reflex:
            rad[int(rng.integers(k))] *= rng.uniform(0.45, 0.65)
        poly = np.column_stack([rad * np.cos(ang), rad * np.sin(ang)])
        if signed_area(poly) <= 0:
            continue
        poly *= np.sqrt(rng.uniform(16.0, 50.0) / polygon_area(poly))
        angles = interior_angles(poly)
        convex = angles < 180.0
        lengths = np.linalg.norm(np.roll(poly, -1, axis=0) - poly, axis=1)
        ok = (np.all((angles[convex] >= 60) & (angles[convex] <= 170) & (np.abs(angles[convex] - 90) >= 8))
              and int((~convex).sum()) == int(reflex) and np.all(angles[~convex] <= 250)
              and np.all(angles[~convex] >= 190) and lengths.min() >= 1.5 and np.ptp(poly, axis=0).max() <= 11.0)
        if ok:
            break
    poly, turn = _off_axes(rng, poly)
    poly, _ = _centred(poly)
    return poly, {"n_walls": len(poly), "reflex_corners": int((interior_angles(poly) > 180).sum()),
                  "rotation_deg": round(turn, 2), "corner_angles_deg": np.round(interior_angles(poly), 1).tolist()}


def hexagon_outline(rng: np.random.Generator) -> tuple[np.ndarray, dict]:
    """A regular hexagon of side 2.3-4 m (14-42 m²), turned off the axes."""
    side = float(rng.uniform(2.3, 4.0))
    ang = np.radians(60.0 * np.arange(6))
    poly, turn = _off_axes(rng, side * np.column_stack([np.cos(ang), np.sin(ang)]))
    poly, _ = _centred(poly)
    return poly, {"side_m": round(side, 3), "rotation_deg": round(turn, 2)}


def _rectangle(rng: np.random.Generator, lo: float, hi: float, aspect: float) -> tuple[float, float]:
    for _ in range(100):
        w, d = rng.uniform(lo, hi, 2)
        if max(w, d) / min(w, d) <= aspect:
            break
    return float(w), float(d)


def _box(w: float, d: float) -> np.ndarray:
    return np.array([[-w / 2, -d / 2], [w / 2, -d / 2], [w / 2, d / 2], [-w / 2, d / 2]])


def _circle_arc(centre: np.ndarray, radius: float, a0: float, a1: float, n: int) -> np.ndarray:
    t = np.linspace(a0, a1, n + 1)
    return centre + radius * np.column_stack([np.cos(t), np.sin(t)])


def _clean(poly: np.ndarray) -> np.ndarray:
    """Drop repeated corners, then corners on a straight line."""
    pts = [p for k, p in enumerate(poly) if np.linalg.norm(p - poly[k - 1]) > 1e-9]
    changed = True
    while changed:
        changed = False
        for k in range(len(pts)):
            a, b, c = pts[k - 1], pts[k], pts[(k + 1) % len(pts)]
            if abs(float((b - a)[0] * (c - b)[1] - (b - a)[1] * (c - b)[0])) < 1e-9:
                pts.pop(k)
                changed = True
                break
    return np.array(pts)


def _rotate90(points: np.ndarray, quarter: int) -> np.ndarray:
    c, s = [(1, 0), (0, 1), (-1, 0), (0, -1)][quarter % 4]
    return np.asarray(points, np.float64) @ np.array([[c, s], [-s, c]], np.float64)


def _box_2d(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])


@dataclass
class _Plan:
    """What a shape builder decides before meshing."""

    outline: np.ndarray
    ceiling: Ceiling
    curved: np.ndarray  # [K] bool per edge
    params: dict
    place_region: np.ndarray | None = None
    wall_edges: list | None = None
    window_edges: list | None = None  # edge indices windows may go on (default: every straight edge)
    dark_edges: list = field(default_factory=list)  # edges of the dark space (own material)
    floors: list = field(default_factory=list)  # (polygon, dark) pieces (default: the outline)
    inner_boxes: list = field(default_factory=list)  # (lo3, hi3) wall pieces inside the outline
    keepouts: list = field(default_factory=list)
    extra_regions: list = field(default_factory=list)
    camera_region: np.ndarray | None = None
    camera_top: Callable | None = None
    obstacles: list = field(default_factory=list)


def _plan_polygon(rng) -> _Plan:
    poly, params = polygon_outline(rng)
    return _Plan(poly, Ceiling("flat", height=float(rng.uniform(2.5, 3.4))), np.zeros(len(poly), bool), params)


def _plan_hexagon(rng) -> _Plan:
    poly, params = hexagon_outline(rng)
    return _Plan(poly, Ceiling("flat", height=float(rng.uniform(2.5, 3.4))), np.zeros(len(poly), bool), params)


def _plan_sloped(rng) -> _Plan:
    w, d = _rectangle(rng, 3.5, 8.0, 2.0)
    poly = _box(w, d)
    direction = [np.array([1.0, 0.0]), np.array([0.0, 1.0]), np.array([-1.0, 0.0]), np.array([0.0, -1.0])][
        int(rng.integers(4))]
    low = float(rng.uniform(2.2, 2.6))
    high = float(rng.uniform(max(low + 0.6, 2.9), 3.6))
    s = poly @ direction
    ceiling = Ceiling("plane", low=low, high=high, direction=direction, s_low=float(s.min()), s_high=float(s.max()))
    slope = np.degrees(np.arctan2(high - low, s.max() - s.min()))
    return _Plan(poly, ceiling, np.zeros(4, bool), {"slope_deg": round(float(slope), 2)})


def _plan_vaulted(rng) -> _Plan:
    w, d = _rectangle(rng, 3.5, 8.0, 2.2)
    poly = _box(w, d)
    # The vault spans the shorter side in three rooms of four.
    across_x = (w <= d) == (rng.random() < 0.75)
    across = np.array([1.0, 0.0]) if across_x else np.array([0.0, 1.0])
    span = w if across_x else d
    spring = float(rng.uniform(2.4, 2.9))
    rise = float(rng.uniform(0.35, 0.4 * span))
    ceiling = Ceiling("vault", across=across, u_centre=0.0, half_span=span / 2, spring=spring, rise=rise)
    return _Plan(poly, ceiling, np.zeros(4, bool), {})


def _plan_round(rng) -> _Plan:
    height = Ceiling("flat", height=float(rng.uniform(2.5, 3.3)))
    if rng.random() < 0.5:  # a cylinder
        r = float(rng.uniform(2.3, 3.8))
        poly = _circle_arc(np.zeros(2), r, 0.0, 2 * np.pi, 72)[:-1]
        return _Plan(poly, height, np.ones(len(poly), bool),
                     {"variant": "cylinder", "centre": [0.0, 0.0], "radius_m": round(r, 4)})
    # A rectangle with one wall bowed outwards along a circular arc through its two corners.
    w, d = _rectangle(rng, 3.5, 7.0, 2.0)
    side = int(rng.integers(4))
    box = _box(w, d)
    box = np.roll(box, -((side + 1) % 4), axis=0)  # the bowed wall runs from box[3] to box[0]
    a, b = box[3], box[0]
    chord = float(np.linalg.norm(b - a))
    sag = float(rng.uniform(0.5, min(1.6, 0.4 * chord)))
    radius = (chord**2 / 4 + sag**2) / (2 * sag)
    outward = -_edge_inward(a, b)
    centre = (a + b) / 2 - outward * (radius - sag)
    a0 = np.arctan2(*(a - centre)[::-1])
    a1 = np.arctan2(*(b - centre)[::-1])
    if a1 < a0:  # counter-clockwise from a to b around the centre
        a1 += 2 * np.pi
    assert a1 - a0 < np.pi  # the short arc: it bows outwards
    arc = _circle_arc(centre, radius, a0, a1, 32)
    poly = np.concatenate([box[:3], arc[:-1]])  # the arc runs from box[3] back to box[0] = poly[0]
    curved = np.zeros(len(poly), bool)
    curved[3:] = True  # edges arc[k] -> arc[k + 1], the last one closing onto poly[0]
    poly, shift = _centred(poly)
    return _Plan(poly, height, curved, {"variant": "curved_wall", "centre": np.round(centre + shift, 4).tolist(),
                                        "radius_m": round(radius, 4), "bulge_m": round(sag, 4),
                                        "chord_m": round(chord, 4), "bulges_towards": np.round(outward, 4).tolist()})


def _plan_open(rng) -> _Plan:
    """Two rooms side by side along x = 0 (A on the left, B on the right), then turned by a multiple of 90°
    and centred."""
    t = 0.12  # inner wall thickness
    if rng.random() < 0.5:  # --- two rooms joined by a wide doorway
        wa, da = _rectangle(rng, 3.3, 5.5, 1.8)
        wb, lb = float(rng.uniform(3.0, 5.5)), float(rng.uniform(3.0, 6.0))
        yb0 = float(rng.uniform(2.4 - lb, da - 2.4))
        if abs(yb0) < 0.3:
            yb0 = 0.0
        if abs(yb0 + lb - da) < 0.3:
            lb = da - yb0
        yb1 = yb0 + lb
        s0, s1 = max(0.0, yb0), min(da, yb1)
        door_w = float(rng.uniform(1.4, min(2.4, s1 - s0 - 0.6)))
        dy0 = float(rng.uniform(s0 + 0.3, s1 - 0.3 - door_w))
        dy1 = dy0 + door_w
        height = float(rng.uniform(2.5, 3.2))
        door_h = float(rng.uniform(2.05, min(2.35, height - 0.25)))
        outline = _clean(np.array([[-wa, 0.0], [0.0, 0.0], [0.0, yb0], [wb, yb0], [wb, yb1], [0.0, yb1], [0.0, da],
                                   [-wa, da]]))
        quarter = int(rng.integers(4))
        rot = lambda p: _rotate90(p, quarter)  # noqa: E731
        outline = rot(outline)
        outline, shift = _centred(outline)
        move = lambda p: rot(p) + shift  # noqa: E731
        boxes2d = [(np.array([-t / 2, s0]), np.array([t / 2, dy0]), -PAD), (np.array([-t / 2, dy1]),
                                                                             np.array([t / 2, s1]), -PAD),
                   (np.array([-t / 2, dy0]), np.array([t / 2, dy1]), door_h)]
        inner = []
        for lo2, hi2, z0 in boxes2d:
            c = move(_box_2d(lo2, hi2))
            inner.append((np.array([*c.min(0), z0]), np.array([*c.max(0), height + PAD])))
        door_a, door_b = move(np.array([[0.0, dy0], [0.0, dy1]]))
        door_mid = (door_a + door_b) / 2
        normal = _edge_inward(door_a, door_b)
        # Nothing stands in the way through the door (a disc across it and one on each side).
        keepouts = [(door_mid + k * 0.75 * normal, door_w / 2 + 0.25) for k in (-1, 0, 1)]
        for lo3, hi3 in inner[:2]:  # the stubs, as discs every 10 cm
            a2, b2 = lo3[:2], hi3[:2]
            steps = max(2, int(np.ceil(np.linalg.norm(b2 - a2) / 0.1)) + 1)
            keepouts += [(a2 + (b2 - a2) * k / (steps - 1), t / 2 + 0.02) for k in range(steps)]

        def camera_top(xy: np.ndarray) -> np.ndarray:
            top = np.full(len(np.atleast_2d(xy)), height - 0.6)
            near = distance_to_outline(np.atleast_2d(xy), np.array([door_a, door_b])) < 0.7
            top[near] = door_h - 0.6
            return top

        obstacles = [_box_2d(lo3[:2], hi3[:2]) for lo3, hi3 in inner[:2]]
        params = {"variant": "doorway", "doorway": {"from": np.round(door_a, 4).tolist(),
                                                    "to": np.round(door_b, 4).tolist(), "width_m": round(door_w, 4),
                                                    "height_m": round(door_h, 4)},
                  "rooms": [np.round(move(_box_2d(np.array([-wa, 0.0]), np.array([0.0, da]))), 4).tolist(),
                            np.round(move(_box_2d(np.array([0.0, yb0]), np.array([wb, yb1]))), 4).tolist()],
                  "inner_walls": [{"box": [np.round(lo3, 4).tolist(), np.round(hi3, 4).tolist()]}
                                  for lo3, hi3 in inner]}
        return _Plan(outline, Ceiling("flat", height=height), np.zeros(len(outline), bool), params,
                     inner_boxes=inner, keepouts=keepouts, camera_top=camera_top, obstacles=obstacles)
    # --- a room open on one side onto a larger, higher, dark space
    wa, da = _rectangle(rng, 3.5, 6.0, 1.6)
    wb = float(rng.uniform(4.0, 8.0))
    e0, e1 = rng.uniform(0.6, 2.5, 2)
    ha = float(rng.uniform(2.4, 3.0))
    hb = ha + float(rng.uniform(0.4, 1.5))
    beam = 0.25  # a beam over the opening, hanging this far below the room's ceiling
    outline = np.array([[-wa, 0.0], [0.0, 0.0], [0.0, -e0], [wb, -e0], [wb, da + e1], [0.0, da + e1], [0.0, da],
                        [-wa, da]])
    quarter = int(rng.integers(4))
    outline = _rotate90(outline, quarter)
    outline, shift = _centred(outline)
    move = lambda p: _rotate90(p, quarter) + shift  # noqa: E731
    room_a = move(_box_2d(np.array([-wa, 0.0]), np.array([0.0, da])))
    space_b = move(_box_2d(np.array([0.0, -e0]), np.array([wb, da + e1])))
    room_a = room_a if signed_area(room_a) > 0 else room_a[::-1]
    space_b = space_b if signed_area(space_b) > 0 else space_b[::-1]
    c = move(_box_2d(np.array([-t / 2, 0.0]), np.array([t / 2, da])))
    inner = [(np.array([*c.min(0), ha - beam]), np.array([*c.max(0), hb + PAD]))]
    open_a, open_b = move(np.array([[0.0, 0.0], [0.0, da]]))
    # Edges of the outline in the dark space: those not on room A's three walls.
    edges = list(zip(outline, np.roll(outline, -1, axis=0)))
    on_a = [bool(np.all(inside_polygon(((a + b) / 2 + 0.02 * _edge_inward(a, b))[None], room_a))) for a, b in edges]
    dark = [k for k, a_side in enumerate(on_a) if not a_side]
    a_walls = [edges[k] for k, a_side in enumerate(on_a) if a_side]
    b_walls = [edges[k] for k in dark]

    def camera_top(xy: np.ndarray) -> np.ndarray:
        xy = np.atleast_2d(xy)
        top = np.full(len(xy), ha - 0.6)
        top[distance_to_outline(xy, np.array([open_a, open_b])) < 0.7] = ha - beam - 0.6
        return top

    params = {"variant": "dark_space", "room": np.round(room_a, 4).tolist(),
              "dark_space": np.round(space_b, 4).tolist(),
              "opening": {"from": np.round(open_a, 4).tolist(), "to": np.round(open_b, 4).tolist(),
                          "beam_bottom_m": round(ha - beam, 4)},
              "inner_walls": [{"box": [np.round(inner[0][0], 4).tolist(), np.round(inner[0][1], 4).tolist()]}]}
    return _Plan(outline, Ceiling("regions", regions=[(room_a, ha), (space_b, hb)]), np.zeros(len(outline), bool),
                 params, place_region=room_a, wall_edges=a_walls,
                 window_edges=[k for k in range(len(edges)) if on_a[k]],
                 dark_edges=dark, floors=[(room_a, False), (space_b, True)], inner_boxes=inner,
                 extra_regions=[(space_b, b_walls, int(rng.integers(1, 4)))], camera_region=room_a,
                 camera_top=camera_top)


_PLANNERS = {"polygon": _plan_polygon, "hexagon": _plan_hexagon, "sloped": _plan_sloped, "vaulted": _plan_vaulted,
             "round": _plan_round, "open": _plan_open}


def _rug(rng, mats: MaterialBank, region: np.ndarray, keepouts: list, wall_dirs: np.ndarray) -> SceneObject | None:
    """A rug inside ``region``, parallel to one of its walls, clear of the keep-out discs."""
    for _ in range(200):
        rw, rd = rng.uniform(1.2, 2.8), rng.uniform(1.0, 2.0)
        u = wall_dirs[int(rng.integers(len(wall_dirs)))]
        v = np.array([-u[1], u[0]])
        c = rng.uniform(region.min(0), region.max(0))
        corners = c + np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) @ np.stack([u * rw / 2, v * rd / 2])
        edge_pts = np.concatenate([a + (b - a) * np.linspace(0, 1, 12)[:, None]
                                   for a, b in zip(corners, np.roll(corners, -1, axis=0))])
        if not inside_polygon(edge_pts, region).all() or distance_to_outline(edge_pts, region).min() < 0.15:
            continue
        if inside_polygon(region, corners).any():
            continue
        if any(np.linalg.norm(edge_pts - p, axis=1).min() < r or inside_polygon(p[None], corners)[0]
               for p, r in keepouts):
            continue
        rug_mat = mats.add(*two_tone(rng, rng.uniform(0.55, 1.0), 0.55, 0.6, 0.3), 0.7, gain=2.0, flat_z=True,
                           grid=(np.array([*u, 0.0]) + np.array([*v, 0.0]), np.array([*u, 0.0]) - np.array([*v, 0.0]),
                                 0.6, 0.35, hsv(0.13, 0.3, 0.9)))
        o = corners[0]
        return SceneObject(4, 4, quad_mesh([o[0], o[1], 0.006], [*(u * rw), 0.0], [*(v * rd), 0.0], rug_mat), "rug")
    return None


def build_room(rng: np.random.Generator, mats: MaterialBank, shape: str) -> Room:
    """A room of one of the new shapes (module docstring), with its textures, windows on straight walls and
    maybe a rug; ``Room.spec`` tells camera planning the ceiling, the cameras' region and inner walls."""
    plan = _PLANNERS[shape](rng)
    outline, ceiling = plan.outline, plan.ceiling
    wall_mat, wall_desc = wall_texture(rng, mats)
    floor_mat, floor_desc = floor_texture(rng, mats)
    ceil_mat = mats.add(hsv(0.12, 0.05, 0.92), hsv(0.12, 0.08, 0.84), 1.5, gain=0.8)
    n = len(outline)
    objects: list[SceneObject] = []
    dark_wall = dark_floor = dark_ceiling = None
    if plan.dark_edges or any(dark for _, dark in plan.floors):
        hue = rng.uniform(0.0, 1.0)
        dark_wall = mats.add(*two_tone(rng, hue, 0.2, rng.uniform(0.14, 0.22), 0.06), 1.5, gain=0.8)
        dark_floor = mats.add(*two_tone(rng, hue, 0.15, rng.uniform(0.1, 0.18), 0.05), 1.2, gain=0.8, flat_z=True)
        dark_ceiling = mats.add(*two_tone(rng, hue, 0.1, rng.uniform(0.1, 0.16), 0.04), 1.5, gain=0.8)
    mat_of_edge = [dark_wall if k in plan.dark_edges else wall_mat for k in range(n)]
    walls = [_walls(outline, plan.curved, ceiling, mat_of_edge)]
    walls += [box_mesh(lo, hi, wall_mat) for lo, hi in plan.inner_boxes]
    objects.append(SceneObject(1, 1, concat_meshes(walls), "wall"))
    floors = plan.floors or [(outline, False)]
    floor_meshes = [_flat_polygon(p, np.zeros(len(p)), dark_floor if dark else floor_mat) for p, dark in floors]
    objects.append(SceneObject(2, 2, concat_meshes(floor_meshes), "floor"))
    ceil_mats = [dark_ceiling if dark else ceil_mat for _, dark in floors] if ceiling.kind == "regions" else ceil_mat
    objects.append(SceneObject(3, 3, _ceiling_mesh(ceiling, outline, ceil_mats), "ceiling"))

    region = plan.place_region if plan.place_region is not None else outline
    edges = list(zip(outline, np.roll(outline, -1, axis=0)))
    wall_edges = plan.wall_edges if plan.wall_edges is not None else edges
    has_rug = bool(rng.random() < 0.75)
    rug = None
    if has_rug:
        dirs = np.array([unit(b - a) for a, b in wall_edges if np.linalg.norm(b - a) > 0.5] or
                        [unit(b - a) for a, b in wall_edges])
        rug = _rug(rng, mats, region, plan.keepouts, dirs)
        if rug is not None:
            objects.append(rug)
    win_mat = mats.add(hsv(0.58, 0.35, 0.95), hsv(0.55, 0.5, 0.8), 1.0, gain=1.0,
                       grid=(np.array([1.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), 0.7, 0.3, (0.95, 0.95, 0.95)))
    allowed = plan.window_edges if plan.window_edges is not None else range(n)
    long_edges = [k for k in allowed if not plan.curved[k] and np.linalg.norm(edges[k][1] - edges[k][0]) >= 1.8]
    n_windows = min(int(rng.integers(0, 4)), len(long_edges))
    windows = []
    for k in rng.choice(long_edges, size=n_windows, replace=False) if n_windows else []:
        a, b = edges[int(k)]
        length, d = np.linalg.norm(b - a), unit(b - a)
        inward = _edge_inward(a, b)
        wall_top = float(min(ceiling.at(np.stack([a, b]) + 0.01 * inward)))
        ww = rng.uniform(0.8, min(1.8, length - 0.8))
        wh = rng.uniform(0.8, min(1.4, wall_top - 1.2))
        wz = rng.uniform(0.7, wall_top - wh - 0.3)
        start = a + d * rng.uniform(0.4, length - 0.4 - ww) + inward * 0.01
        windows.append(quad_mesh([start[0], start[1], wz], [*(d * ww), 0.0], [0, 0, wh], win_mat))
    if windows:
        objects.append(SceneObject(5, 5, concat_meshes(windows), "window"))

    lo, hi = outline.min(0), outline.max(0)
    desc = {"shape": shape, "size_m": np.round([hi[0] - lo[0], hi[1] - lo[1], ceiling.top], 3).tolist(),
            "floor_area_m2": round(polygon_area(outline), 2), "outline": np.round(outline, 4).tolist(),
            "windows": len(windows), "rug": rug is not None, **plan.params, "ceiling": ceiling.to_json(),
            "curved_walls": [int(k) for k in np.flatnonzero(plan.curved)]}
    camera_region = plan.camera_region if plan.camera_region is not None else outline
    camera_top = plan.camera_top or (lambda xy: ceiling.at(xy) - 0.6)
    spec = RoomSpec(ceiling_at=ceiling.at, camera_region=camera_region, camera_top=camera_top,
                    obstacles=list(plan.obstacles), clearance=ROOM_CLEARANCE)
    return Room(outline, objects, ceiling, region, desc, wall_edges=plan.wall_edges, keepouts=plan.keepouts,
                extra_regions=plan.extra_regions, spec=spec, wall_desc=wall_desc, floor_desc=floor_desc)
