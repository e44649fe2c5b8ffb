"""Camera paths of ``lift3d synth``: ``orbit``, ``walk`` and ``handheld``, out of the geometry.

Indoors the paths are planned on a :class:`FloorPlan`, the room's floor rasterised at 5 cm with every
floor-standing object's footprint (the convex hull of its vertices seen from above) marked as an obstacle:

* ``orbit`` — views circling the room's middle at 0.9-2.2 m, each looking at an object or across the room
  (the original synthetic capture);
* ``walk`` — a walk-through at eye height: 4-7 waypoints spread over the free floor, joined by shortest
  paths that keep away from furniture and walls, smoothed, and sampled evenly by arc length. The camera looks
  ahead along the path and around (a slow yaw sweep of ±25-60°), tilted down at the furniture;
* ``handheld`` — a walk that also passes close to furniture (some waypoints right beside an object, where the
  camera turns to look at it), lower and bobbing, with hand-held jitter: smooth drift of a few centimetres and
  degrees plus a small per-frame shake, and roll.

Outdoors ``walk`` drives (or walks) down the middle of the street with a gentle weave and ``handheld`` adds
looking around and jitter; ``orbit`` needs a room.

Every camera ends at least :data:`MIN_CLEARANCE` from any surface: after planning, a camera closer than that
is pushed straight away from the nearest surface point (Open3D distance queries).

Rooms with a :class:`~lift3d.synth.geometry.RoomSpec` (the shapes beyond the original rectangle and L, and
cluttered rooms) are planned on the spec's camera region with its inner walls as obstacles, under the ceiling
height above each point rather than the room's top, and keep their cameras at least ``spec.clearance``
(0.5 m) from the walls, floor and ceiling — ``orbit`` and ``walk`` cameras from everything; in cluttered rooms
some views then turn to the things seen in too few views (:func:`cover_things`). Rooms without one keep the
original planning, draw for draw.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import sparse
from scipy.ndimage import gaussian_filter1d
from scipy.sparse.csgraph import dijkstra

from dataclasses import replace

from lift3d.data.cameras import look_at
from lift3d.synth.geometry import RayCaster, SceneContent

#: Camera path names (``auto`` picks one per seed).
PATHS = ("orbit", "walk", "handheld")
#: Paths each scene kind supports (``auto`` chooses among them).
PATHS_OF_KIND = {"indoor": ("orbit", "walk", "handheld"), "outdoor": ("walk", "handheld")}
#: No camera is closer than this (metres) to any surface.
MIN_CLEARANCE = 0.25


# --------------------------------------------------------------------------------------------- floor plan
class FloorPlan:
    """The room's free floor on a grid: ``clearance`` is the distance (metres) from a cell to the nearest wall
    or floor-standing object's footprint (0 outside the room and inside footprints).

    Parameters
    ----------
    content : SceneContent
        An indoor scene (needs ``room_polygon``).
    resolution : float
        Cell size in metres.
    """

    def __init__(self, content: SceneContent, resolution: float = 0.05):
        poly = content.room_polygon
        if poly is None:
            raise ValueError("FloorPlan needs a room outline (indoor scenes)")
        spec = content.room
        if spec is not None:
            poly = spec.camera_region
        self.res = float(resolution)
        self.origin = poly.min(0) - 2 * self.res
        size = np.ceil((poly.max(0) + 2 * self.res - self.origin) / self.res).astype(int) + 1
        self.shape = (int(size[1]), int(size[0]))  # rows = y, columns = x
        free = np.zeros(self.shape, np.uint8)
        # fillPoly with 4 fractional bits: outlines and hulls land on the grid to 1/16 of a cell.
        cv2.fillPoly(free, [np.round(self.to_pixel(poly) * 16).astype(np.int32)], 1, shift=4)
        #: distance (metres) to the walls alone (None: the original rooms, where ``clearance`` is all there is)
        self.wall_clearance = None
        if spec is not None:
            for ob in spec.obstacles:  # inner walls
                cv2.fillConvexPoly(free, np.round(self.to_pixel(ob) * 16).astype(np.int32), 0, shift=4)
            self.wall_clearance = cv2.distanceTransform(free, cv2.DIST_L2, 5).astype(np.float64) * self.res
        for obj in content.floor_things:
            hull = cv2.convexHull(self.to_pixel(obj.mesh.vertices[:, :2]).astype(np.float32))
            cv2.fillConvexPoly(free, np.round(hull[:, 0] * 16).astype(np.int32), 0, shift=4)
        self.clearance = cv2.distanceTransform(free, cv2.DIST_L2, 5).astype(np.float64) * self.res
        self.wall_margin = spec.clearance if spec is not None else 0.0

    def to_pixel(self, xy: np.ndarray) -> np.ndarray:
        """World ``(x, y)`` → continuous ``(column, row)``."""
        return (np.asarray(xy, np.float64) - self.origin) / self.res

    def to_world(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Cell indices → world ``[N, 2]`` cell centres."""
        return self.origin + np.column_stack([cols, rows]).astype(np.float64) * self.res

    def clearance_at(self, xy: np.ndarray, walls_only: bool = False) -> np.ndarray:
        """``[N]`` clearance at world points (nearest cell; 0 off the grid); ``walls_only``: from the walls
        alone (rooms with a spec)."""
        grid = self.wall_clearance if walls_only else self.clearance
        px = np.round(self.to_pixel(np.atleast_2d(xy))).astype(int)
        ok = (px[:, 0] >= 0) & (px[:, 0] < self.shape[1]) & (px[:, 1] >= 0) & (px[:, 1] < self.shape[0])
        out = np.zeros(len(px))
        out[ok] = grid[px[ok, 1], px[ok, 0]]
        return out

    def walkable(self, min_clearance: float) -> np.ndarray:
        """``bool`` grid: the largest connected area of cells at least ``min_clearance`` from obstacles,
        relaxing the clearance (down to 0.3 m) when no cell has that much; in rooms with a spec also at least
        its clearance (plus a cell) from the walls, whatever the relaxing."""
        for c in (min_clearance, 0.4, 0.35, 0.3):
            if c > min_clearance:
                continue
            mask = (self.clearance >= c).astype(np.uint8)
            if self.wall_clearance is not None:
                mask &= (self.wall_clearance >= self.wall_margin + self.res).astype(np.uint8)
            n, lab = cv2.connectedComponents(mask, connectivity=8)
            if n > 1:
                sizes = np.bincount(lab.ravel())[1:]
                return lab == 1 + int(np.argmax(sizes))
        raise RuntimeError("no free floor for cameras in the room")


def _shortest_route(plan: FloorPlan, mask: np.ndarray, stops: list[tuple[int, int]]) -> np.ndarray:
    """World ``[M, 2]`` polyline through ``stops`` (cells of ``mask``) along grid shortest paths that prefer
    clearance (each step costs its length times ``1 + 0.3 / clearance``)."""
    rows, cols = np.nonzero(mask)
    index = -np.ones(mask.shape, np.int64)
    index[rows, cols] = np.arange(len(rows))
    cost = 1.0 + 0.3 / np.maximum(plan.clearance[rows, cols], 0.05)
    src, dst, w = [], [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        r2, c2 = rows + dr, cols + dc
        ok = (r2 >= 0) & (r2 < mask.shape[0]) & (c2 >= 0) & (c2 < mask.shape[1])
        ok[ok] &= mask[r2[ok], c2[ok]]
        a, b = np.flatnonzero(ok), index[r2[ok], c2[ok]]
        src.append(a)
        dst.append(b)
        w.append(np.hypot(dr, dc) * 0.5 * (cost[a] + cost[b]))
    n = len(rows)
    graph = sparse.coo_matrix((np.concatenate(w), (np.concatenate(src), np.concatenate(dst))), shape=(n, n)).tocsr()
    cells = []
    for (ra, ca), (rb, cb) in zip(stops[:-1], stops[1:]):
        a, b = index[ra, ca], index[rb, cb]
        _, pred = dijkstra(graph, directed=False, indices=int(a), return_predecessors=True)
        seq = [b]
        while seq[-1] != a and pred[seq[-1]] >= 0:
            seq.append(pred[seq[-1]])
        cells.extend(seq[::-1][1:] if cells else seq[::-1])
    cells = np.asarray(cells)
    return plan.to_world(rows[cells], cols[cells])


def _resample(poly: np.ndarray, spacing: float) -> np.ndarray:
    """``poly`` ``[M, D]`` resampled at equal arc-length ``spacing``."""
    seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0:
        return poly[:1]
    t = np.linspace(0.0, s[-1], max(2, int(np.ceil(s[-1] / spacing)) + 1))
    return np.column_stack([np.interp(t, s, poly[:, k]) for k in range(poly.shape[1])])


def _smooth_noise(rng: np.random.Generator, n: int, sigma: float, width: float, dims: int = 1) -> np.ndarray:
    """``[n, dims]`` temporally smooth noise: white noise filtered by a Gaussian of ``width`` frames, scaled
    to standard deviation ``sigma``."""
    x = rng.normal(size=(n + 8 * int(np.ceil(width)) + 2, dims))
    if width > 0:
        x = gaussian_filter1d(x, width, axis=0, mode="wrap")
    x = x[: n]
    return x / max(float(x.std()), 1e-9) * sigma


def _c2w(eye: np.ndarray, yaw: float, pitch: float, roll: float = 0.0) -> np.ndarray:
    fwd = np.array([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)])
    c2w = look_at(eye, eye + fwd)
    if roll:
        c, s = np.cos(roll), np.sin(roll)
        c2w[:3, :3] = c2w[:3, :3] @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return c2w


# --------------------------------------------------------------------------------------------- indoor
def orbit_path(content: SceneContent, plan: FloorPlan, n_views: int, rng: np.random.Generator) -> np.ndarray:
    """``[n, 4, 4]`` OpenGL camera-to-world matrices circling the room's middle at varied heights, each
    looking at an object or across the room."""
    spec = content.room
    mask = plan.walkable(0.45 if spec is None else max(0.45, spec.clearance))
    rows, cols = np.nonzero(mask)
    free = plan.to_world(rows, cols)
    centre = free.mean(0)
    half = 0.5 * (free.max(0) - free.min(0))
    height = content.aabb[1, 2]
    things = content.things
    c2ws = []
    for k in range(n_views):
        base = 2 * np.pi * k / n_views + rng.uniform(-0.15, 0.15)
        goal = centre + rng.uniform(0.55, 0.85) * half * np.array([np.cos(base), np.sin(base)])
        xy = free[np.argmin(np.linalg.norm(free - goal, axis=1))] + rng.uniform(-0.5, 0.5, 2) * plan.res
        top = min(2.2, height - 0.4) if spec is None else max(0.95, min(2.2, float(spec.camera_top(xy[None])[0])))
        eye = np.array([xy[0], xy[1], rng.uniform(0.9, top)])
        if rng.random() < 0.5 and things:
            lo, hi = things[int(rng.integers(len(things)))].mesh.bounds
            target = (lo + hi) / 2
        else:
            t = centre + rng.uniform(-0.3, 0.3, 2) * half
            target = np.array([t[0], t[1], rng.uniform(0.2, 0.9)])
        if np.linalg.norm((target - eye)[:2]) < 1.0:  # too close to frame it: look across the room instead
            t = centre - 0.5 * (eye[:2] - centre)
            target = np.array([t[0], t[1], 0.5])
        c2ws.append(look_at(eye, target))
    return np.stack(c2ws)


def walk_path(content: SceneContent, plan: FloorPlan, n_views: int, rng: np.random.Generator,
              handheld: bool = False) -> np.ndarray:
    """``[n, 4, 4]`` camera-to-world matrices of a walk-through (``handheld``: close passes and jitter)."""
    spec = content.room
    mask = plan.walkable(0.3 if handheld else (0.45 if spec is None else max(0.45, spec.clearance)))
    rows, cols = np.nonzero(mask)
    free = plan.to_world(rows, cols)
    clear = plan.clearance[rows, cols]
    # Waypoints spread over the free floor: each new one is a random cell among the far ones from those chosen.
    n_way = int(rng.integers(5, 10) if handheld else rng.integers(4, 8))
    chosen = [int(rng.integers(len(free)))]
    dmin = np.linalg.norm(free - free[chosen[0]], axis=1)
    for _ in range(n_way - 1):
        far = np.flatnonzero(dmin >= 0.6 * dmin.max())
        k = int(far[rng.integers(len(far))])
        chosen.append(k)
        dmin = np.minimum(dmin, np.linalg.norm(free - free[k], axis=1))
    things = content.floor_things
    if handheld and things:
        # Some waypoints right beside a piece of furniture: the free cell nearest to it.
        for j in range(1, n_way, 3):
            lo, hi = things[int(rng.integers(len(things)))].mesh.bounds
            goal = (lo[:2] + hi[:2]) / 2
            near = np.flatnonzero(clear < 0.4) if np.any(clear < 0.4) else np.arange(len(free))
            chosen[j] = int(near[np.argmin(np.linalg.norm(free[near] - goal, axis=1))])
    # Visit them in nearest-neighbour order from the first.
    order = [chosen[0]]
    rest = chosen[1:]
    while rest:
        d = [np.linalg.norm(free[r] - free[order[-1]]) for r in rest]
        order.append(rest.pop(int(np.argmin(d))))
    route = _shortest_route(plan, mask, [(int(rows[k]), int(cols[k])) for k in order])
    dense = _resample(route, 0.05)
    smooth = gaussian_filter1d(dense, 6.0, axis=0, mode="nearest")  # ~30 cm: round the grid's corners
    keep = plan.clearance_at(smooth) >= MIN_CLEARANCE + 0.05
    if spec is not None:  # smoothing must not take the path nearer the walls than the plan allows
        keep &= plan.clearance_at(smooth, walls_only=True) >= spec.clearance + plan.res
    dense = np.where(keep[:, None], smooth, dense)
    seg = np.linalg.norm(np.diff(dense, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    t = (np.arange(n_views) + 0.5) / n_views * s[-1]
    xy = np.column_stack([np.interp(t, s, dense[:, 0]), np.interp(t, s, dense[:, 1])])
    ahead = np.column_stack([np.interp(np.minimum(t + 0.4, s[-1]), s, dense[:, 0]),
                             np.interp(np.minimum(t + 0.4, s[-1]), s, dense[:, 1])]) - \
        np.column_stack([np.interp(np.maximum(t - 0.4, 0), s, dense[:, 0]),
                         np.interp(np.maximum(t - 0.4, 0), s, dense[:, 1])])
    heading = np.unwrap(np.arctan2(ahead[:, 1], ahead[:, 0]))
    u = t / max(s[-1], 1e-9)
    sweep = np.radians(rng.uniform(25, 60)) * np.sin(2 * np.pi * rng.uniform(1.0, 3.0) * u + rng.uniform(0, 2 * np.pi))
    yaw = heading + sweep
    pitch = -np.radians(rng.uniform(10, 25)) + np.radians(6) * np.sin(2 * np.pi * rng.uniform(0.5, 2.0) * u)
    ceiling = content.aabb[1, 2]
    if handheld:
        z = rng.uniform(1.2, 1.6) + _smooth_noise(rng, n_views, 0.08, 4.0)[:, 0]
    else:
        z = rng.uniform(1.45, 1.7) + 0.02 * np.sin(2 * np.pi * t / 0.7)  # a step every ~70 cm
    z = np.clip(z, 0.5, ceiling - 0.35) if spec is None else np.clip(z, 0.6, spec.camera_top(xy))
    yaw, pitch = _glance_at_things(content, xy, z, yaw, pitch, plan.clearance_at(xy) if handheld else None)
    if handheld:
        xy = xy + _smooth_noise(rng, n_views, 0.04, 2.0, dims=2) + rng.normal(0, 0.01, (n_views, 2))
        yaw = yaw + np.radians(_smooth_noise(rng, n_views, 4.0, 2.0)[:, 0] + rng.normal(0, 0.7, n_views))
        pitch = pitch + np.radians(_smooth_noise(rng, n_views, 3.0, 2.0)[:, 0] + rng.normal(0, 0.7, n_views))
        roll = np.radians(_smooth_noise(rng, n_views, 3.0, 3.0)[:, 0] + rng.normal(0, 0.7, n_views))
    else:
        roll = np.zeros(n_views)
    return np.stack([_c2w(np.array([xy[k, 0], xy[k, 1], z[k]]), yaw[k], pitch[k], roll[k]) for k in range(n_views)])


def _glance_at_things(content: SceneContent, xy: np.ndarray, z: np.ndarray, yaw: np.ndarray, pitch: np.ndarray,
                      clearance: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Turn each view (``yaw``, ``pitch`` in radians) most of the way towards the thing nearest to its line of
    sight (within 75° and 0.6-6 m), as a person walking through a room looks at what is in it; with
    ``clearance`` (hand-held), a view beside a piece of furniture turns fully to it. Smoothed over time."""
    things = content.things
    if not things:
        return yaw, pitch
    centres = np.array([o.mesh.bounds.mean(axis=0) for o in things])
    yaw, pitch = yaw.copy(), pitch.copy()
    for k in range(len(yaw)):
        dv = centres[:, :2] - xy[k]
        dist = np.linalg.norm(dv, axis=1)
        diff = (np.arctan2(dv[:, 1], dv[:, 0]) - yaw[k] + np.pi) % (2 * np.pi) - np.pi
        ok = (dist > 0.6) & (dist < 6.0) & (np.abs(diff) < np.radians(75))
        w = 0.7
        if clearance is not None and clearance[k] < 0.6:  # right beside furniture: look at the nearest thing
            j = int(np.argmin(dist))
            w = float(np.clip((0.6 - clearance[k]) / 0.25, 0.7, 1.0))
        elif ok.any():
            j = int(np.flatnonzero(ok)[np.argmin(np.abs(diff[ok]) * (1.0 + 0.2 * dist[ok]))])
        else:
            continue
        yaw[k] += w * diff[j]
        down = np.arctan2(centres[j, 2] - z[k], max(dist[j], 0.3))
        pitch[k] = (1 - w) * pitch[k] + w * np.clip(down, np.radians(-60), np.radians(20))
    return gaussian_filter1d(yaw, 1.0, mode="nearest"), gaussian_filter1d(pitch, 1.0, mode="nearest")


# --------------------------------------------------------------------------------------------- outdoor
def street_path(content: SceneContent, n_views: int, rng: np.random.Generator, handheld: bool = False) -> np.ndarray:
    """``[n, 4, 4]`` camera-to-world matrices moving forward (+y) down the street at eye height with a gentle
    lateral weave and small yaw/pitch changes (so views are not all collinear); ``handheld`` walks more
    slowly, looks around and jitters."""
    street = content.description["street"]
    # Parked cars' inner sides are ~2.1 m in from the kerb: keep the weave clear of them.
    limit = max(0.2, street["road_half_width_m"] - 2.1 - 0.6)
    length = rng.uniform(4.0, 8.0) if handheld else rng.uniform(5.0, 10.0)
    centre = rng.uniform(-0.3, 0.3) * limit
    amp = rng.uniform(0.3, 1.0) * min(0.5, limit - abs(centre))
    phase = rng.uniform(0, 2 * np.pi)
    s = np.arange(n_views) / max(n_views - 1, 1)
    x = centre + amp * np.sin(2 * np.pi * s + phase)
    y = length * s
    z = 1.6 + 0.08 * np.sin(4 * np.pi * s + phase)
    yaw = np.radians(8.0) * np.sin(2 * np.pi * 1.5 * s + phase) + np.radians(rng.uniform(-1.5, 1.5, n_views))
    pitch = np.radians(1.0 + rng.uniform(-1.5, 1.5, n_views))  # horizon a little below the image centre
    roll = np.zeros(n_views)
    if handheld:
        z = rng.uniform(1.4, 1.7) + _smooth_noise(rng, n_views, 0.05, 3.0)[:, 0]
        yaw += np.radians(rng.uniform(15, 35)) * np.sin(2 * np.pi * rng.uniform(1.0, 2.5) * s + rng.uniform(0, 6.3))
        yaw += np.radians(_smooth_noise(rng, n_views, 3.0, 2.0)[:, 0])
        pitch += np.radians(_smooth_noise(rng, n_views, 2.0, 2.0)[:, 0] + rng.normal(0, 0.5, n_views))
        roll = np.radians(_smooth_noise(rng, n_views, 2.5, 3.0)[:, 0] + rng.normal(0, 0.5, n_views))
        x = x + _smooth_noise(rng, n_views, 0.04, 2.0)[:, 0]
    # yaw 0 looks down +y: heading pi/2 in the x-y plane
    return np.stack([_c2w(np.array([x[k], y[k], z[k]]), np.pi / 2 - yaw[k], pitch[k], roll[k])
                     for k in range(n_views)])


# --------------------------------------------------------------------------------------------- all
def keep_clear(c2w: np.ndarray, caster: RayCaster, min_clearance: float = MIN_CLEARANCE,
               iterations: int = 10) -> np.ndarray:
    """Push every camera centre closer than ``min_clearance`` to a surface straight away from its nearest
    surface point (rotations unchanged).

    Raises
    ------
    RuntimeError
        When some camera is still too close after ``iterations`` pushes (a planning bug).
    """
    c2w = c2w.copy()
    centres = c2w[:, :3, 3].copy()
    for _ in range(iterations):
        d = caster.distance(centres)
        bad = np.flatnonzero(d < min_clearance)
        if not len(bad):
            break
        near = caster.closest_points(centres[bad])
        away = centres[bad] - near
        away /= np.maximum(np.linalg.norm(away, axis=1, keepdims=True), 1e-9)
        centres[bad] = near + away * (min_clearance + 0.02)
    d = caster.distance(centres)
    if np.any(d < min_clearance - 1e-3):
        raise RuntimeError(f"camera {int(np.argmin(d))} is {d.min():.3f} m from a surface after pushing")
    c2w[:, :3, 3] = centres
    return c2w


def keep_clear_of_room(c2w: np.ndarray, caster: RayCaster, room_caster: RayCaster, min_clearance: float,
                       room_clearance: float, iterations: int = 20) -> np.ndarray:
    """:func:`keep_clear` for rooms with a spec: every camera at least ``room_clearance`` from the room's
    surfaces (``room_caster``: walls, floor, ceiling, windows, rug) and ``min_clearance`` from everything.

    Raises
    ------
    RuntimeError
        When some camera is still too close after ``iterations`` pushes (a planning bug).
    """
    c2w = c2w.copy()
    centres = c2w[:, :3, 3].copy()
    for _ in range(iterations):
        # Both pushes at once, so a camera in a corner between the room and a thing does not swing back and forth.
        move = np.zeros_like(centres)
        for cast, clear in ((room_caster, room_clearance), (caster, min_clearance)):
            short = clear - cast.distance(centres)
            idx = np.flatnonzero(short > 0)
            if len(idx):
                away = centres[idx] - cast.closest_points(centres[idx])
                away /= np.maximum(np.linalg.norm(away, axis=1, keepdims=True), 1e-9)
                move[idx] += away * (short[idx, None] + 0.02)
        if not move.any():
            break
        centres += move
    d_room, d_any = room_caster.distance(centres), caster.distance(centres)
    if np.any(d_room < room_clearance - 1e-3) or np.any(d_any < min_clearance - 1e-3):
        k = int(np.argmin(np.minimum(d_room - room_clearance, d_any - min_clearance)))
        raise RuntimeError(f"camera {k} is {d_room[k]:.3f} m from the room and {d_any[k]:.3f} m from anything "
                           "after pushing")
    c2w[:, :3, 3] = centres
    return c2w


def _thing_samples(content: SceneContent, per_thing: int = 24) -> list[np.ndarray]:
    """Up to ``per_thing`` vertices spread over each thing's mesh, and its vertices' mean."""
    out = []
    for o in content.things:
        v = o.mesh.vertices
        idx = np.unique(np.linspace(0, len(v) - 1, min(per_thing, len(v))).astype(int))
        out.append(np.vstack([v[idx], v.mean(0)]))
    return out


def things_in_view(c2w: np.ndarray, content: SceneContent, caster: RayCaster, hfov_deg: float, aspect: float,
                   samples: list[np.ndarray] | None = None, min_points: int = 2) -> np.ndarray:
    """``[V, T]`` bool: which things each view sees — at least ``min_points`` of its sample points inside the
    image (a 5 % margin) with nothing in front of them."""
    samples = _thing_samples(content) if samples is None else samples
    ids = np.array([o.segment_id for o in content.things])
    owner = np.concatenate([np.full(len(p), k) for k, p in enumerate(samples)])
    pts = np.concatenate(samples)
    tan_x = np.tan(np.radians(hfov_deg) / 2) * 0.95
    tan_y = tan_x / aspect
    out = np.zeros((len(c2w), len(samples)), bool)
    for k, m in enumerate(c2w):
        eye = m[:3, 3]
        local = (pts - eye) @ m[:3, :3]  # camera axes: x right, y up, looking down -z
        depth = -local[:, 2]
        inside = np.flatnonzero((depth > 0.1) & (np.abs(local[:, 0]) < tan_x * depth) &
                                (np.abs(local[:, 1]) < tan_y * depth))
        if not len(inside):
            continue
        d = pts[inside] - eye
        dist = np.linalg.norm(d, axis=1)
        hits = caster.cast(np.repeat(eye[None], len(inside), axis=0), d / dist[:, None])
        seen = (hits.segment == ids[owner[inside]]) | (hits.t >= dist - 0.01)
        out[k] = np.bincount(owner[inside][seen], minlength=len(samples)) >= min_points
    return out


def cover_things(c2w: np.ndarray, content: SceneContent, caster: RayCaster, hfov_deg: float, aspect: float,
                 min_views: int) -> np.ndarray:
    """Turn views (rotation only, keeping their positions) towards the things seen in fewer than
    ``min_views`` views, least seen first: each time the view that sees that thing best from where it stands
    (nearest, with a clear line of sight) among those whose turn costs no other thing its last needed view.
    Things no view can see stay as they are."""
    things = content.things
    if not things:
        return c2w
    c2w = c2w.copy()
    samples = _thing_samples(content)
    vis = things_in_view(c2w, content, caster, hfov_deg, aspect, samples)
    centres = np.array([p[:-1].mean(0) for p in samples])
    hopeless: set[int] = set()
    for _ in range(4 * len(c2w)):
        count = vis.sum(0)
        need = [int(t) for t in np.argsort(count, kind="stable") if count[t] < min_views and int(t) not in hopeless]
        if not need:
            break
        t = need[0]
        eyes = c2w[:, :3, 3]
        dist = np.linalg.norm(centres[t] - eyes, axis=1)
        best = None
        for k in np.argsort(dist, kind="stable"):
            if vis[k, t] or not 0.5 < dist[k] < 6.0:
                continue
            turned = look_at(eyes[k], centres[t])
            new = things_in_view(turned[None], content, caster, hfov_deg, aspect, samples)[0]
            if not new[t]:
                continue
            lost = vis[k] & ~new
            if np.any(count[lost] <= min_views):
                continue
            best = (k, turned, new)
            break
        if best is None:
            hopeless.add(t)
            continue
        k, turned, new = best
        c2w[k] = turned
        vis[k] = new
    return c2w


def camera_path(content: SceneContent, caster: RayCaster, name: str, n_views: int,
                rng: np.random.Generator, fov: tuple[float, float] | None = None) -> np.ndarray:
    """``[n, 4, 4]`` OpenGL camera-to-world matrices of path ``name`` (one of :data:`PATHS`), every camera at
    least :data:`MIN_CLEARANCE` from any surface (in rooms with a spec at least its clearance from the room,
    and ``orbit`` and ``walk`` cameras from everything).

    ``fov`` is ``(horizontal field of view in degrees, width / height)``: in cluttered rooms views turn to
    the things seen in fewer than ``clip(round(n / 15), 1, 4)`` views (:func:`cover_things`).
    """
    if name not in PATHS_OF_KIND[content.kind]:
        raise ValueError(f"camera path {name!r} is not available for {content.kind} scenes")
    if content.kind == "outdoor":
        c2w = street_path(content, n_views, rng, handheld=name == "handheld")
    else:
        plan = FloorPlan(content)
        if name == "orbit":
            c2w = orbit_path(content, plan, n_views, rng)
        else:
            c2w = walk_path(content, plan, n_views, rng, handheld=name == "handheld")
    spec = content.room
    if spec is None:
        return keep_clear(c2w, caster)
    cats = {c.id: c for c in content.categories}
    room_caster = RayCaster(replace(content, objects=[o for o in content.objects if not cats[o.category_id].isthing]))
    c2w = keep_clear_of_room(c2w, caster, room_caster, MIN_CLEARANCE if name == "handheld" else spec.clearance,
                             spec.clearance)
    if spec.cover_things and fov is not None:
        c2w = cover_things(c2w, content, caster, fov[0], fov[1], int(np.clip(round(n_views / 15), 1, 4)))
    return c2w
