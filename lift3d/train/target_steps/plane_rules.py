"""The stuff planes and the rules that shape them, in the order they run (docs/sfm.md, "Stuff planes").

:class:`FitPlanes` fits planes to the sparse points and the plane-sweep depths; each rule after it changes
``state.planes`` (and so the floor); :class:`MarginSeenThrough` closes the planes' margins where the views see
through them. A rule that assumes a room (a floor below the cameras, walls around them, a ceiling above) or
walls at right angles says so in ``needs``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from lift3d.data.scene import Scene
from lift3d.data.stereo import DenseDepth
from lift3d.sfm.planes import (FitSettings, NewWalls, StuffPlanes, add_walls, ceiling_boundary_points, ceiling_plane,
                               ceiling_points, contradicted, corner_cutters, correct_walls, fit_planes,
                               floor_boundary_points, floor_line, floor_line_classes, floor_line_walls,
                               most_walls_hold, point_classes, square_walls, wall_classes, wall_directions)
from lift3d.train.target_steps.state import TargetContext, TargetState, TargetStep, setting


@dataclass
class FitPlanes(TargetStep):
    """Planes of the stuff classes fitted to the sparse points (each with its observations' majority class) and the
    plane-sweep depths (each with its pixel's class): walls get 1–2 sparse points per 1000 pixels but a few percent
    dense coverage. Points are thinned to one per ``voxel`` cell and class, so a textured corner that the plane
    sweep covers densely does not outvote a wall; every observation is a sight line for the fit's free-space
    test (:func:`lift3d.sfm.planes.fit_planes`). Records ``stuff_points`` (thinned) and ``sightlines``."""

    name = "fit-planes"
    min_points: int = setting("plane_min_points")
    """Fewest points (after thinning) that make a plane."""
    min_share: float = setting("plane_min_share")
    """A plane also needs this share of the stuff points (after thinning)."""
    voxel: float = setting("plane_voxel")
    """Cell of the thinning, as a share of the diagonal (0 keeps every point)."""
    margin: float = setting("plane_margin")
    """How far a plane reaches beyond its points' hull, as a share of the diagonal."""
    min_support: int = setting("plane_min_support")
    """Plane-sweep depths fewer source views confirmed are not fitted."""
    max_size: int = setting("plane_fit_max_size")
    """The plane-sweep depths are taken on a grid of at most this many pixels along a view's longer side (0: every
    pixel)."""
    point_share: float = setting("plane_fit_point_share")
    """A point takes its observations' majority class when this share of them agree."""
    max_planes: int = setting("plane_fit_max_planes")
    """Most planes."""
    iterations: int = setting("plane_fit_iterations")
    """RANSAC draws per plane."""
    candidates: int = setting("plane_fit_candidates")
    """RANSAC planes scored against the sight lines per plane found."""
    max_crossing_share: float = setting("plane_fit_max_crossing_share")
    """Most sight lines crossing a plane, as a share of those ending on it."""
    class_share: float = setting("plane_fit_class_share")
    """A plane holds every class with this share of its inliers."""
    class_cover: float = setting("plane_fit_class_cover")
    """A plane also holds every class of which it has this share of the points."""
    max_sightlines: int = setting("plane_fit_max_sightlines")
    """Most sight lines in the free-space test (an even random draw when there are more; 0 = all)."""
    seed: int = setting("plane_fit_seed")
    """Seed of RANSAC's draws (and of the sight lines' draw)."""

    def apply(self, state: TargetState, context: TargetContext) -> dict[str, Any]:
        scene, sparse, labels = context.scene, context.sparse, context.labels
        stuff = scene.stuff_ids
        if not stuff:
            return {"planes": 0}
        obs_class = np.zeros(len(sparse.obs_frame), np.int64)
        for i, sem in labels.items():
            k = np.flatnonzero(sparse.obs_frame == i)
            h, w = sem.shape
            col = np.clip(np.floor(sparse.obs_uv[k, 0]).astype(np.int64), 0, w - 1)
            row = np.clip(np.floor(sparse.obs_uv[k, 1]).astype(np.int64), 0, h - 1)
            obs_class[k] = sem[row, col]
        xyz = [sparse.xyz]
        cls = [point_classes(sparse.obs_point, obs_class, len(sparse), min_share=self.point_share)]
        cams, seen_xyz = [scene.cameras.centers[sparse.obs_frame]], [sparse.xyz[sparse.obs_point]]
        p, c, o = dense_points(scene, context.dense, labels, self.min_support, max_size=self.max_size)
        xyz.append(p), cls.append(c), cams.append(o), seen_xyz.append(p)
        xyz, cls = np.concatenate(xyz), np.concatenate(cls).astype(np.int64)
        state.points, state.classes = self.thin(xyz, cls, context.diag)
        state.sightlines = self.drawn(np.concatenate(cams), np.concatenate(seen_xyz))
        n_stuff = int(np.isin(state.classes, stuff).sum())
        # from the stereo points alone: the boundary points of later steps would raise it and lose the walls few
        # views see
        state.min_points = max(self.min_points, int(self.min_share * n_stuff))
        state.up, state.fit = context.up, self
        state.planes = self.fit_planes(state, context)
        return {"stuff_points": n_stuff, "sightlines": int(len(state.sightlines[0]))}

    def drawn(self, cams: np.ndarray, seen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The sight lines ``(cameras [N, 3], seen points [N, 3])``, at most ``max_sightlines`` of them (an even
        random draw, in their order)."""
        if 0 < self.max_sightlines < len(cams):
            keep = np.sort(np.random.default_rng(self.seed).choice(len(cams), self.max_sightlines, replace=False))
            cams, seen = cams[keep], seen[keep]
        return cams, seen

    def thin(self, xyz: np.ndarray, cls: np.ndarray, diag: float) -> tuple[np.ndarray, np.ndarray]:
        """One point per ``voxel`` cell and class, the first in order."""
        if self.voxel > 0 and len(xyz):
            key = np.c_[np.floor(xyz / (self.voxel * diag)).astype(np.int64), cls]
            first = np.unique(key, axis=0, return_index=True)[1]
            xyz, cls = xyz[first], cls[first]
        return xyz, cls

    def refit_with(self, state: TargetState, context: TargetContext, points: tuple[np.ndarray, ...]) -> None:
        """Fits ``state.planes`` again with more ``points``: ``(xyz [N, 3], classes [N], cameras [N, 3])``, thinned
        into ``state.points`` (the thinned points stay: one per cell and class already, first in order), each a
        sight line from its camera."""
        xyz, cls, cams = points
        state.points, state.classes = self.thin(np.r_[state.points, xyz], np.r_[state.classes, cls], context.diag)
        state.sightlines = (np.r_[state.sightlines[0], cams], np.r_[state.sightlines[1], xyz])
        state.planes = self.fit_planes(state, context)

    def fit_planes(self, state: TargetState, context: TargetContext) -> StuffPlanes:
        """Planes of ``state.points`` (already thinned), tested against ``state.sightlines``."""
        search = FitSettings(max_planes=self.max_planes, iterations=self.iterations, min_class_share=self.class_share,
                             min_class_cover=self.class_cover, candidates=self.candidates,
                             max_crossing_share=self.max_crossing_share)
        return fit_planes(state.points, state.classes, context.scene.stuff_ids, threshold=context.threshold,
                          min_points=state.min_points, margin=self.margin * context.diag, up=context.up,
                          sightlines=state.sightlines, seed=self.seed, settings=search,
                          up_tolerance_deg=context.up_tolerance_deg)


@dataclass
class FloorBoundary(TargetStep):
    """Wall points from where the labels put a wall directly on the floor: the ray through that boundary meets
    the floor plane at the wall's foot, and the wall rises vertically from there (no texture needed;
    :func:`lift3d.sfm.planes.floor_boundary_points`). The planes are fitted again with them. Records
    ``floor_boundary_points``, the classes below the line (``floor_line_floors``) and those the floor plane holds
    but that count as a wall's (``floor_line_walls_on_floor_plane``: :func:`lift3d.sfm.planes.floor_line_classes`).
    """

    name = "floor-boundary"
    needs = frozenset({"room"})
    enabled: bool = setting("plane_floor_boundary")
    step: float = setting("plane_floor_boundary_step")
    """Spacing of the points up a wall, in plane thresholds."""
    tolerance: float = setting("plane_floor_boundary_tolerance")
    """Most a foot may move for one pixel of boundary, in plane thresholds."""

    def apply(self, state: TargetState, context: TargetContext) -> dict[str, Any]:
        if not state.has_planes() or state.floor is None:
            return {}
        planes, (f, n, d) = state.planes, state.floor
        floors, walls = floor_line_classes(planes, f, n, context.scene.stuff_ids)
        threshold = context.threshold
        foot, foot_cls, foot_cam = floor_boundary_points(
            context.scene.cameras, context.frames, context.labels, n, d, floors, walls,
            step=self.step * threshold, max_height=state.height(context), tolerance=self.tolerance * threshold,
            min_rows=context.plane.boundary_rows)
        if len(foot):
            state.fit.refit_with(state, context, (foot, foot_cls, foot_cam))
        return {"floor_boundary_points": int(len(foot)), "floor_line_floors": floors,
                "floor_line_walls_on_floor_plane": sorted(set(walls) & set(planes.classes[f]))}


@dataclass
class CornerCutters(TargetStep):
    """Drops a wall that cuts across the corner of two other walls and is made of their ends' points (a stray
    cluster between them can make it the largest plane; :func:`lift3d.sfm.planes.corner_cutters`). Only in a room
    whose walls meet at right angles is every such plane false: a wall between two walls that are not parallel
    is then no wall. Records ``corner_cutters_dropped``."""

    name = "corner-cutters"
    needs = frozenset({"room", "manhattan"})
    enabled: bool = setting("plane_corner_cutters")
    near: float = setting("plane_corner_cutters_near")
    """A wall's points this many plane thresholds from another wall are at its end."""
    end_share: float = setting("plane_corner_cutters_end_share")
    """Share of a wall's points each end must have."""
    ends_share: float = setting("plane_corner_cutters_ends_share")
    """Share of a wall's points both ends must have."""

    def apply(self, state: TargetState, context: TargetContext) -> dict[str, Any]:
        if not state.has_planes():
            return {}
        up = state.floor[1] if state.floor is not None else context.up
        eye = context.scene.cameras.centers[context.frames].mean(0)
        cut = corner_cutters(state.planes, state.points, state.classes, context.threshold, up, eye, near=self.near,
                             min_end_share=self.end_share, min_ends_share=self.ends_share)
        state.planes = state.planes.subset(~cut)
        return {"corner_cutters_dropped": int(cut.sum())}


@dataclass
class FloorLineWalls(TargetStep):
    """Far plain walls: where many views' wall-on-floor boundaries agree in pixels on a wall no plane has yet, in the
    room's two wall directions (:func:`lift3d.sfm.planes.floor_line_walls`, added by
    :func:`lift3d.sfm.planes.add_walls`). With ``correct``, walls found by stereo first move to where the
    boundaries put them when they clearly disagree (:func:`lift3d.sfm.planes.correct_walls`). Records
    ``floor_line_walls``, ``floor_line_moved`` and ``floor_line_observations``."""

    name = "floor-line-walls"
    needs = frozenset({"room", "manhattan"})
    enabled: bool = setting("plane_floor_line_walls")
    correct: bool = setting("plane_floor_line_correct")
    """Move stereo walls to where the boundaries put them first."""
    line_pixels: float = setting("plane_line_pixels")
    """Rows a view's boundary may be off a wall's foot and still count for it."""
    min_views: int = setting("plane_floor_line_min_views")
    """Fewest views supporting a wall."""
    view_share: float = setting("plane_floor_line_view_share")
    """Share of a view's columns that must support a wall."""
    max_walls: int = setting("plane_floor_line_max_walls")
    """Most walls found per direction."""
    crossing_share: float = setting("plane_floor_line_crossing_share")
    """Most sight lines crossing a wall found, as a share of those ending on it."""
    class_share: float = setting("plane_floor_line_class_share")
    """A wall found holds the classes of this share of its points."""
    gap: float = setting("plane_floor_line_gap")
    """A wall found ends at a gap in its feet of this many plane thresholds."""
    settle: bool = setting("plane_floor_line_settle")
    """A wall found moves onto the stereo points in front of it first."""
    past_edge: bool = setting("plane_floor_line_past_edge")
    """A wall found rises past the top of a view's image while the view labels it wall."""
    correct_reach: float = setting("plane_floor_line_correct_reach")
    """Most a wall moves, in plane thresholds."""
    correct_gain: float = setting("plane_floor_line_correct_gain")
    """How many times more support a wall needs where it moves to."""
    correct_crossing_share: float = setting("plane_floor_line_correct_crossing_share")
    """Most sight lines crossing a moved wall, as a share of those ending on it."""

    def apply(self, state: TargetState, context: TargetContext) -> dict[str, Any]:
        if not state.has_planes() or state.floor is None:
            return {}
        planes, (f, n, d) = state.planes, state.floor
        scene, threshold = context.scene, context.threshold
        height = state.height(context)
        directions = wall_directions(planes, n, agree_deg=context.plane.directions_agree_deg)
        if directions is None:
            return {"floor_line_walls": 0, "floor_line_moved": 0, "floor_line_observations": 0}
        upright = wall_classes(planes, f, n, scene.stuff_ids)
        line = floor_line(scene.cameras, context.frames, context.labels, n, d,
                          sorted(set(planes.classes[f]) - set(upright)), upright, min_rows=context.plane.boundary_rows)
        moved = 0
        if self.correct:
            planes, moved = correct_walls(line, directions, planes, threshold, pixel_tolerance=self.line_pixels,
                                          min_views=self.min_views, view_share=self.view_share,
                                          reach=self.correct_reach, min_gain=self.correct_gain,
                                          sightlines=state.sightlines, max_crossing_share=self.correct_crossing_share)
        found = floor_line_walls(line, directions, planes, threshold, pixel_tolerance=self.line_pixels,
                                 min_views=self.min_views, view_share=self.view_share, max_walls=self.max_walls)
        how = NewWalls(max_crossing_share=self.crossing_share, min_class_share=self.class_share,
                       gap=self.gap * threshold, settle=self.settle, past_edge=self.past_edge)
        planes, kept = add_walls(planes, scene.cameras, context.labels, line, found, n, height, threshold,
                                 state.sightlines, how)
        state.planes = planes
        return {"floor_line_walls": kept, "floor_line_moved": moved, "floor_line_observations": int(len(line))}


@dataclass
class SquareWalls(TargetStep):
    """Walls within a few degrees of the room's two wall directions (their mean normal modulo a right angle) turn
    onto them about the middle of their points, while their points still fit (stereo turns a plain wall by 1–4°;
    :func:`lift3d.sfm.planes.square_walls`). Records ``walls_squared``."""

    name = "square-walls"
    needs = frozenset({"room", "manhattan"})
    enabled: bool = setting("plane_square_walls")
    max_turn_deg: float = setting("plane_square_walls_max_turn_deg")
    """Walls within this many degrees of a direction turn onto it."""
    min_kept: float = setting("plane_square_walls_min_kept")
    """Share of a wall's points that must stay on it."""

    def apply(self, state: TargetState, context: TargetContext) -> dict[str, Any]:
        if not state.has_planes():
            return {}
        up = state.floor[1] if state.floor is not None else context.up
        directions = wall_directions(state.planes, up, agree_deg=context.plane.directions_agree_deg)
        if directions is None:
            return {}
        state.planes, turned = square_walls(state.planes, directions, state.points, context.threshold,
                                            max_turn_deg=self.max_turn_deg, min_kept=self.min_kept)
        return {"walls_squared": turned}


@dataclass
class CeilingBoundary(TargetStep):
    """A ceiling plane where the labels' ceiling-on-wall boundaries meet the walls' planes
    (:func:`lift3d.sfm.planes.ceiling_boundary_points`), over the points where the ceiling pixels' rays meet it: a
    level plane when the boundary points agree on one height above the cameras
    (:func:`lift3d.sfm.planes.level_ceiling_height`); with ``slope``, one tilted plane through them instead when it
    qualifies (:func:`lift3d.sfm.planes.ceiling_plane`: an attic's ceiling meets its walls at different
    heights). With ``extend``, first every level plane above the cameras that stereo found for a ceiling class
    reaches over every pixel of that class. Walls from stereo alone are enough: this does not need the floor line.
    Records ``ceiling_boundary_points``, ``ceiling_height``, ``ceiling_slope_degrees`` (of a tilted ceiling),
    ``ceiling_contradicted`` and ``ceiling_extended``."""

    name = "ceiling-boundary"
    needs = frozenset({"room"})
    enabled: bool = setting("plane_ceiling_boundary")
    extend: bool = setting("plane_ceiling_extend")
    """Grow textured ceilings over their class's pixels first."""
    slope: bool = setting("plane_ceiling_slope")
    """A tilted plane where the boundary points do not agree on one height."""
    crossing_share: float = setting("plane_ceiling_crossing_share")
    """Most sight lines crossing a ceiling plane, as a share of those ending on it."""
    wall_share: float = setting("plane_ceiling_wall_share")
    """A class this share of the walls hold is a wall's, not a ceiling's."""

    def apply(self, state: TargetState, context: TargetContext) -> dict[str, Any]:
        if not state.has_planes() or state.floor is None:
            return {}
        planes, (_, n, d) = state.planes, state.floor  # the floor as it is before any ceiling is added
        stuff, threshold = context.scene.stuff_ids, context.threshold
        # Stuff no level plane holds (a ceiling with enough texture has its plane from stereo already) and fewer
        # than half the walls: the points along a wall's top edge that the labels call ceiling can make one wall's
        # plane hold the ceiling class (tuning room 7). Each class on its own, so that a window above a wall cannot
        # pull a ceiling's height.
        found: dict[str, Any] = {"ceiling_boundary_points": 0, "ceiling_height": None, "ceiling_contradicted": 0}
        vertical = planes.vertical(n)
        if self.extend:
            planes, found["ceiling_extended"] = self.extended(planes, n, d, state, context)
            vertical = planes.vertical(n)
        cams = context.scene.cameras.centers[np.asarray(context.frames, np.int64)]
        for c in [c for c in stuff if not any(c in k for k, v in zip(planes.classes, vertical) if not v)
                  and not most_walls_hold(planes, vertical, c, self.wall_share)]:
            points, eyes = ceiling_boundary_points(context.scene.cameras, context.frames, context.labels, planes, n,
                                                   [c], min_rows=context.plane.boundary_rows)
            found["ceiling_boundary_points"] += len(points)
            plane, top = ceiling_plane(points, eyes, cams, n, d, threshold, state.min_points, slope=self.slope)
            if plane is None:
                continue
            grown = self.plane_over_pixels(planes, plane, c, state, context)
            if grown is None:
                found["ceiling_contradicted"] += 1
                continue
            planes = grown
            if top is not None:
                found["ceiling_height"] = round(top, 4)
            else:
                found["ceiling_slope_degrees"] = round(float(np.degrees(np.arccos(np.clip(plane[0] @ n, -1, 1)))), 2)
        state.planes = planes
        return found

    def extended(self, planes: StuffPlanes, n: np.ndarray, d: float, state: TargetState,
                 context: TargetContext) -> tuple[StuffPlanes, int]:
        """The planes with each level plane above the cameras that stereo found for a ceiling class reaching over
        every pixel the labels give that class, and how many classes got that.

        A textured ceiling gets its level plane from the stereo points, but only over the few it matched: on a
        tuning room, 141 points of an 8 × 8 m ceiling with a repeating grid, and 70 % of the ceiling's GT points
        were out of the export's reach (its pixels got no target, and the field left the ceiling half
        transparent). The rays of the pixels of that class meet the plane where the ceiling is, as for a plain
        ceiling, and those points become one more plane at the same place holding the class. A class that
        ``wall_share`` of the walls hold is not a ceiling's; a plane that more sight lines cross than end on over
        that reach is not added."""
        vertical = planes.vertical(n)
        eye = float(np.median(context.scene.cameras.centers[np.asarray(context.frames, np.int64)] @ n + d))
        count = 0
        for k in np.flatnonzero(~vertical):
            if float(planes.origin[k] @ n + d) <= eye:
                continue
            for c in sorted(int(c) for c in planes.classes[k] if c in context.scene.stuff_ids):
                if most_walls_hold(planes, vertical, c, self.wall_share):
                    continue
                grown = self.plane_over_pixels(planes, (planes.normal[k], float(planes.offset[k])), c, state,
                                               context)
                if grown is not None:
                    count += len(grown) > len(planes)
                    planes = grown
        return planes, count

    def plane_over_pixels(self, planes: StuffPlanes, plane: tuple[np.ndarray, float], class_id: int,
                          state: TargetState, context: TargetContext) -> StuffPlanes | None:
        """The planes and one more, ``plane = (normal, offset)``, over the points where the rays of the pixels the
        labels call ``class_id`` meet it (:func:`lift3d.sfm.planes.ceiling_points`), holding that class; None when
        the views see through it there."""
        normal, offset = plane
        xyz, cls, _ = ceiling_points(context.scene.cameras, context.frames, context.labels, normal, offset, [class_id],
                                     stride=context.stride)
        # The views see through a level plane at a window's sill, to the wall above it: a test room's window, cut
        # by the top of every view that shows its sill, made a level plane at 1.67 m in a room 3.2 m high, which
        # 30 × as many sight lines cross as end on. A real ceiling's share is what stray points above it make:
        # 0–0.21 on tuning rooms 6–10, so the share allowed is 1 (more crossing it than ending on it). Fewer than
        # three points, or points along a line, count as contradicted too.
        if contradicted(state.sightlines, normal, offset, xyz, context.threshold,
                        max_crossing_share=self.crossing_share):
            return None
        return planes.with_plane(normal, offset, xyz, cls, context.threshold)


@dataclass
class MarginSeenThrough(TargetStep):
    """A plane's margin no longer reaches where sight lines to points beyond the plane pass through it
    (:meth:`lift3d.sfm.planes.StuffPlanes.with_seen_through`): the inner wall of an L-shaped room whose other inner
    wall has no plane does not reach into the other wing."""

    name = "margin-seen-through"
    enabled: bool = setting("plane_margin_seen_through")
    cell: float = setting("plane_margin_seen_through_cell")
    """Cells of the margin a sight line takes away, in plane thresholds."""

    def apply(self, state: TargetState, context: TargetContext) -> dict[str, Any]:
        if state.has_planes():
            state.planes = state.planes.with_seen_through(*state.sightlines, context.threshold,
                                                          cell=self.cell * context.threshold)
        return {}


def dense_points(scene: Scene, dense: DenseDepth, labels: dict[int, np.ndarray], min_support: int, *,
                 max_size: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The plane sweep's depths as world points ``[N, 3]``, their pixels' classes ``[N]`` and their cameras'
    centres ``[N, 3]``, leaving out depths fewer than ``min_support`` source views confirmed (when recorded).
    With ``max_size`` > 0 a view's depths are taken at every k-th pixel of each row and column (the centre one
    of each k × k block), k the smallest stride that leaves at most ``max_size`` pixels along its longer side."""
    index = {f.name: k for k, f in enumerate(scene.frames)}
    supports = dense.support if dense.support is not None else [None] * len(dense)
    xyz, cls, cams = [np.zeros((0, 3))], [np.zeros(0, np.int64)], [np.zeros((0, 3))]
    for name, depth, support in zip(dense.frame_names, dense.depth, supports):
        i = index[name]
        depth = np.asarray(depth)
        use = depth > 0
        if support is not None:
            use &= np.asarray(support) >= min_support
        stride = max(1, -(-max(depth.shape) // max_size)) if max_size > 0 else 1
        if stride > 1:
            grid = np.zeros_like(use)
            grid[stride // 2::stride, stride // 2::stride] = True
            use &= grid
        r, c = np.nonzero(use)
        if not len(r):
            continue
        o, d = scene.cameras.rays(i, c, r)
        xyz.append(o + d * (depth[r, c] / (d @ scene.cameras.c2w_opencv[i][:3, 2]))[:, None])
        cls.append(labels[i][r, c].astype(np.int64)), cams.append(o)
    return np.concatenate(xyz), np.concatenate(cls), np.concatenate(cams)
