"""Stuff surfaces: labels that follow the surface's orientation, and corners completed where stuff planes meet
(:mod:`lift3d.export.stuff`)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lift3d.export.steps.base import ExportStep, PointState, StepContext
from lift3d.export.stuff import CORNER_FIT_POINTS, CORNER_MIN_ANGLE, CORNER_MIN_PLANE_SHARE, ORIENTATION_POINTS, \
    complete_stuff_corners, orient_stuff_labels
from lift3d.export.visibility import train_frames
from lift3d.sfm.mvs import plane_fit_up

#: Inlier distance of the planes :func:`lift3d.export.stuff.complete_stuff_corners` fits, as a share of the scene
#: box's diagonal (4 cm in a 10 m room). 0.2 % and 0.8 % gave point mIoU within 0.005 of it on each tuning run,
#: neither better on all.
CORNER_PLANE_THRESHOLD = 0.004


@dataclass
class StuffOrientation(ExportStep):
    """A stuff point whose surface faces the way a neighbouring stuff class faces, and not the way its own class
    does, takes that class (ceiling is not wall where the two meet; :func:`lift3d.export.stuff.orient_stuff_labels`)."""

    name = "stuff-orientation"
    flags = {"enabled": "--no-orient-stuff"}
    radius_links: float = 2.0
    """Another stuff class within this many instance link radii may take a point: about the width over which the
    label grid's cells blur an edge between two surfaces."""
    cone_degrees: float = 30.0
    """Two surface axes agree when they are less than this apart."""
    own_share: float = 0.1
    """A point moves when under this share of its class's points agree with its axis …"""
    other_share: float = 0.6
    """… and over this share of the other class's points do."""
    max_curvature: float = 0.05
    """Only points whose neighbourhood is this planar move."""
    min_class_points: int = 50
    """Stuff classes with fewer points are left alone and are no target."""
    max_points: int = ORIENTATION_POINTS
    """Orientations are measured on at most this many stuff points; the others follow their nearest."""

    def apply(self, state: PointState, context: StepContext) -> dict:
        p = state.points
        semantic, info = orient_stuff_labels(p.xyz, p.semantic, context.scene.stuff_ids,
                                             radius=self.radius_links * state.link_radius,
                                             cone_degrees=self.cone_degrees, own_share=self.own_share,
                                             other_share=self.other_share, max_curvature=self.max_curvature,
                                             min_class_points=self.min_class_points, max_points=self.max_points)
        state.points = replace(p, semantic=semantic)
        return info


@dataclass
class StuffCorners(ExportStep):
    """Stuff points near two stuff planes that meet (a wall and the ceiling, two walls) are replaced by their
    projections onto each, which take the plane's class: the isosurface's rounded edge becomes two surfaces that
    meet (:func:`lift3d.export.stuff.complete_stuff_corners`). The projections stay in the crop box and keep one
    point per voxel."""

    name = "stuff-corners"
    needs = frozenset({"room"})
    needs_points = True
    flags = {"enabled": "--no-complete-corners"}
    why_needed = ("it fits level and upright planes to the stuff classes (up from the training cameras) and makes "
                  "their meeting edges sharp: walls, floor and ceiling of a room; a street's stuff is not planes "
                  "that meet at edges")
    radius_links: float = 2.0
    """A stuff point within this many instance link radii of two planes that meet is a corner point: the width over
    which the isosurface rounds an edge."""
    plane_threshold: float = CORNER_PLANE_THRESHOLD
    """Inlier distance of the fitted planes, as a share of the scene box's diagonal (4 cm in a 10 m room)."""
    min_plane_share: float = CORNER_MIN_PLANE_SHARE
    """A plane takes part when it holds this share of the fitted points (or half of one of its classes' points)."""
    min_angle: float = CORNER_MIN_ANGLE
    """Two planes make a corner when they meet at this angle or more (degrees)."""
    max_points: int = CORNER_FIT_POINTS
    """Planes are fitted to at most this many stuff points."""

    def apply(self, state: PointState, context: StepContext) -> dict:
        p, loaded, scene = state.points, context.loaded, context.scene
        n_before = len(p)
        lo, hi = np.asarray(loaded.norm.aabb_world, np.float64)
        diag = float(np.linalg.norm(hi - lo)) * (float(loaded.norm.scale) if p.frame == "normalized" else 1.0)
        up, up_tolerance = plane_fit_up(scene.cameras[np.asarray(train_frames(scene))])  # as the training's fit
        keep, source, new_xyz, new_semantic, info = complete_stuff_corners(
            p.xyz, p.semantic, scene.stuff_ids, radius=self.radius_links * state.link_radius,
            threshold=self.plane_threshold * diag, up=up, up_tolerance_deg=up_tolerance,
            min_plane_share=self.min_plane_share,
            min_angle=self.min_angle, max_points=self.max_points)
        if len(source):
            # the projections carry their point's colour, instance channel and confidence; the field's own labels
            # (field_semantic, field_channel) are the field's at the projections, as everywhere else
            moved = replace(p.take(source), xyz=new_xyz.astype(p.xyz.dtype),
                            semantic=new_semantic.astype(p.semantic.dtype))
            p = p.take(keep).append(context.with_field_labels(moved))
        # The projections honour the crop box and the voxel size: none outside the box, one point per voxel.
        keep = state.crop.contains(p.xyz) if state.crop is not None else np.ones(len(p), bool)
        if state.voxel_size > 0:
            first = np.zeros(len(p), bool)
            first[np.unique(np.floor(p.xyz / state.voxel_size).astype(np.int64), axis=0, return_index=True)[1]] = True
            keep &= first
        state.points = p if keep.all() else p.take(keep)
        return {**info, "points_before": int(n_before)}
