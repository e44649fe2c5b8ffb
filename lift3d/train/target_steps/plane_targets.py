"""Pixel targets on the stuff planes, in the order they run: where each stuff pixel's ray first meets a plane
holding its class, walls that reach on past their margin, the other views' labels as a check, segments a plane
surrounds, the upright faces of things standing on the floor, and last their depths as rows of targets.

The pixels are every ``plane_stride``-th row and column of the frames that get targets; each view's pixels and
what the steps made of them are a :class:`~lift3d.train.target_steps.state.ViewTargets` until
:class:`PlaneDepths` turns them into rows (per view: the plane hits, the enclosed segments, the faces).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from lift3d.sfm.planes import ceiling_points, enclosed_segments, label_support, wall_reach
from lift3d.sfm.standing import StandingSettings, standing_faces, stereo_agreement
from lift3d.train.target_steps.state import TargetContext, TargetState, TargetStep, ViewTargets, setting


def _grid(shape: tuple[int, ...], stride: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns ``stride // 2 + k · stride`` of an image of ``shape``, raveled."""
    r, c = np.mgrid[stride // 2:shape[0]:stride, stride // 2:shape[1]:stride]
    return r.ravel(), c.ravel()


@dataclass
class PlaneHits(TargetStep):
    """Where the ray of each stuff pixel first meets a plane (within its extent), kept when that plane holds the
    pixel's class: a ray that meets the floor first cannot see a wall. Records the planes the targets come from:
    ``planes``, ``classes``, ``points_on_planes``, ``median_rms``."""

    name = "plane-hits"

    def apply(self, state: TargetState, context: TargetContext) -> dict[str, Any]:
        planes = state.planes
        if planes is None:
            return {}
        counts = dict(planes=len(planes), classes=[sorted(c) for c in planes.classes],
                      points_on_planes=int(planes.inliers.sum()),
                      median_rms=round(float(np.median(planes.rms)), 4) if len(planes) else None)
        if not len(planes):
            return counts
        held = sorted(set().union(*planes.classes))
        for i in context.targets_for:
            i = int(i)
            sem = context.labels[i]  # targets_for is a subset of the training frames
            r, c = _grid(sem.shape, context.stride)
            cls = sem[r, c]
            keep = np.isin(cls, held)
            r, c, cls = r[keep], c[keep], cls[keep]
            if not len(r):
                continue
            o, d = context.scene.cameras.rays(i, c, r)
            t, k = planes.first_hit(o, d, classes=cls)
            ok = k >= 0
            ok &= planes.holds(k, cls)
            state.views.append(ViewTargets(i, r, c, cls, o, d, t, k, ok))
        return counts


@dataclass
class ReachingWalls(TargetStep):
    """Stuff pixels that met no plane of their class take a wall's plane past its margin where it still reaches:
    inside the scene box, until another plane's extent, a sight line through it, or floor a view sees behind its
    line stops it (a long wall that two views see end-on; :func:`lift3d.sfm.planes.wall_reach`). The box is the
    room's extent. Records ``wall_reach`` (targets)."""

    name = "wall-reach"
    needs = frozenset({"room", "box"})
    enabled: bool = setting("plane_wall_reach")
    box_pad: float = setting("plane_wall_reach_box_pad")
    """The scene box grown by this many plane thresholds bounds the reach."""

    def apply(self, state: TargetState, context: TargetContext) -> dict[str, Any]:
        planes, floor = state.planes, state.floor
        if not state.has_planes() or floor is None or not state.views:
            return {}
        scene, threshold = context.scene, context.threshold
        f, fn, fd = floor
        floor_xyz, _, floor_cams = ceiling_points(scene.cameras, context.frames, context.labels, fn, fd,
                                                  planes.classes[f], stride=context.stride)
        pad = self.box_pad * threshold
        box = np.asarray(scene.scene_box.aabb, np.float64) + [[-pad] * 3, [pad] * 3]
        # the reach takes the planes' geometry only (it finds the cells the views see through over the whole plane
        # itself), so it is the same before or after margin-seen-through
        reach = wall_reach(planes, state.sightlines, (floor_cams, floor_xyz), fn, threshold, box)
        reached = 0
        for view in state.views:
            if view.ok.all():
                continue
            idx = np.flatnonzero(~view.ok)
            rt, rk = reach.first_hit(view.origins[idx], view.directions[idx])
            on = (rt < view.t[idx]) & planes.holds(rk, view.classes[idx])
            view.t[idx[on]], view.plane[idx[on]], view.ok[idx[on]] = rt[on], rk[on], True
            reached += int(on.sum())
        return {"wall_reach": reached}


@dataclass
class LabelSupport(TargetStep):
    """A plane target stays only when at least ``share`` of the other training views that see its point (in their
    image, not behind another plane, label not void) label it a class of its plane: a wardrobe one view's segmenter
    calls wall otherwise gets the wall's depth (:func:`lift3d.sfm.planes.label_support`). Off when ``share`` is 0.
    Records ``refuted_by_other_views``."""

    name = "label-support"
    share: float = setting("plane_label_support")
    """Share of the voting views that must name a class of the plane (0: off)."""
    min_votes: int = setting("plane_label_support_votes")
    """Fewest voting views that can refute a target."""
    tolerance: float = setting("plane_label_support_tolerance")
    """Another plane this many plane thresholds nearer than the point does not hide it."""

    def __post_init__(self) -> None:
        self.enabled = self.enabled and self.share > 0

    def apply(self, state: TargetState, context: TargetContext) -> dict[str, Any]:
        if not state.has_planes() or not state.views:
            return {}
        dropped = 0
        for view in state.views:
            if not view.ok.any():
                continue
            idx = np.flatnonzero(view.ok)
            points = view.origins[idx] + view.t[idx, None] * view.directions[idx]
            support, votes = label_support(context.scene.cameras, context.frames, context.labels, state.planes,
                                           points, view.plane[idx], view.frame,
                                           tolerance=self.tolerance * context.threshold)
            refuted = (votes >= self.min_votes) & (support < self.share * votes)
            view.ok[idx[refuted]] = False
            dropped += int(refuted.sum())
        return {"refuted_by_other_views": dropped}


@dataclass
class EnclosedSegments(TargetStep):
    """Segments of a stuff class that one plane surrounds in a view (most of their one-pixel ring meets it: a window
    whose pattern stereo matched wrongly) take that plane's depth, inside the hull of its points
    (:func:`lift3d.sfm.planes.enclosed_segments`). With ``held``, classes a plane holds too, in the segments whose
    pixels mostly have no target yet (a window in a second wall); pixels with a target keep it. With ``margin``,
    where the scene box is the room (premise ``box``), within the plane's margin too (no sky lies above a wall).
    Records ``enclosed`` (targets)."""

    name = "enclosed-segments"
    enabled: bool = setting("plane_enclosed")
    held: bool = setting("plane_enclosed_held")
    """Classes a plane holds can be enclosed too."""
    margin: bool = setting("plane_enclosed_margin")
    """Within the plane's margin too, where the scene box is the room."""
    ring_share: float = setting("plane_enclosed_ring_share")
    """Share of the ring that must meet the one plane."""
    min_ring: int = setting("plane_enclosed_min_ring")
    """Fewest ring pixels."""
    max_targeted: float = setting("plane_enclosed_max_targeted")
    """A segment with more than this share of its pixels targeted already is left alone."""

    def apply(self, state: TargetState, context: TargetContext) -> dict[str, Any]:
        if not state.has_planes() or not state.views:
            return {}
        planes, cameras = state.planes, context.scene.cameras
        stuff = set(context.scene.stuff_ids)
        # a window in a second wall: the plane holding the window class is the first wall's
        enclosable = sorted(stuff if self.held else stuff - set().union(*planes.classes))
        margin = self.margin and "box" in context.premises
        enclosed = 0
        for view in state.views if enclosable else []:
            sem = context.labels[view.frame]
            targeted = np.zeros(sem.shape, bool)
            targeted[view.rows[view.ok], view.cols[view.ok]] = True
            er, ec, et, ek = enclosed_segments(cameras, view.frame, sem, enclosable, planes, context.stride,
                                               min_share=self.ring_share, min_ring=self.min_ring, targeted=targeted,
                                               max_targeted=self.max_targeted, margin=margin)
            if len(er):
                view.enclosed = (er, ec, et, ek, cameras.rays(view.frame, ec, er)[1])
                enclosed += len(er)
        return {"enclosed": enclosed}


@dataclass
class StandingThings(TargetStep):
    """The pixels of a thing get the depth where their ray first meets an upright face rising from where the views'
    labels put that thing on the floor plane, up to the height the other views' labels leave it, where three
    views' feet line up (a plain cabinet has no texture for stereo; :mod:`lift3d.sfm.standing`). A face is dropped
    when the plane sweep's depths it meets mostly disagree (a plant's leaves spread wider than its pot). Records
    ``standing_faces``, ``standing_faces_refuted`` and ``standing`` (targets)."""

    name = "standing-things"
    needs = frozenset({"room"})
    enabled: bool = setting("plane_standing")
    step: float = setting("plane_standing_step")
    """Spacing of the points up the line above a foot, in plane thresholds."""
    tolerance: float = setting("plane_standing_tolerance")
    """Most a foot may move for one pixel of boundary, in plane thresholds."""
    min_views: int = setting("plane_standing_min_views")
    """Fewest views whose feet make a face."""
    carve_share: float = setting("plane_standing_carve_share")
    """Share of the views that carve a point of a line."""
    carve_views: int = setting("plane_standing_carve_views")
    """Fewest views that carve a point of a line."""
    iterations: int = setting("plane_standing_iterations")
    """RANSAC draws per face."""
    seed: int = setting("plane_standing_seed")
    """Seed of those draws."""
    depth_tolerance: float = setting("plane_standing_depth_tolerance")
    """A plane-sweep depth this many plane thresholds from a face agrees with it."""
    agreement: float = setting("plane_standing_agreement")
    """Share of the depths a face meets that must agree."""
    min_refuting: int = setting("plane_standing_min_refuting")
    """Disagreeing depths a face may always have."""

    def apply(self, state: TargetState, context: TargetContext) -> dict[str, Any]:
        scene, labels, dense = context.scene, context.labels, context.dense
        if not state.has_planes() or state.floor is None or not scene.thing_ids:
            return {}
        f, fn, fd = state.floor
        threshold = context.threshold
        settings = StandingSettings(tolerance=self.tolerance * threshold, min_views=self.min_views,
                                    min_rows=context.plane.boundary_rows, carve_share=self.carve_share,
                                    min_carve_views=self.carve_views, iterations=self.iterations, seed=self.seed)
        faces = standing_faces(scene.cameras, context.frames, labels, fn, fd, state.planes.classes[f],
                               scene.thing_ids, scene.stuff_ids, threshold=threshold, step=self.step * threshold,
                               max_height=state.height(context), settings=settings)
        index = {fr.name: k for k, fr in enumerate(scene.frames)}
        met, agreeing = stereo_agreement(faces, scene.cameras, [index[n] for n in dense.frame_names], labels,
                                         dense.depth, tolerance=self.depth_tolerance * threshold)
        refuted = met - agreeing > np.maximum(self.min_refuting, (1 - self.agreement) * met)
        counts = {"standing_faces": int(len(faces) - refuted.sum()), "standing_faces_refuted": int(refuted.sum())}
        faces = faces.subset(~refuted)
        if not state.views:
            return counts
        standing = 0
        for view in state.views if len(faces) else []:
            sem = labels[view.frame]
            r, c = _grid(sem.shape, context.stride)
            on = np.isin(sem[r, c], faces.classes)
            r, c = r[on], c[on]
            o, d = scene.cameras.rays(view.frame, c, r)
            t, k = faces.first_hit(o, d, sem[r, c])
            hit = k >= 0
            axis = scene.cameras.c2w_opencv[view.frame][:3, 2]
            view.standing = (r[hit], c[hit], t[hit] * (d[hit] @ axis), faces.rms[k[hit]])
            standing += int(hit.sum())
        return {**counts, "standing": standing}


@dataclass
class PlaneDepths(TargetStep):
    """The plane targets as rows: per view, the pixels that met a plane (z-depth along the optical axis, sigma the
    plane's residual, at least ``min_sigma`` plane thresholds), those of segments a plane surrounds, and those on
    things' faces. Records ``targets``."""

    name = "plane-depths"
    min_sigma: float = setting("plane_sigma_floor")
    """Smallest sigma of a target, in plane thresholds."""

    def apply(self, state: TargetState, context: TargetContext) -> dict[str, Any]:
        if not state.has_planes() or not state.views:
            return {}
        planes, cameras = state.planes, context.scene.cameras
        floor_sigma = self.min_sigma * context.threshold
        out = []
        for view in state.views:
            ok = view.ok
            r, c, k, t, d = view.rows[ok], view.cols[ok], view.plane[ok], view.t[ok], view.directions[ok]
            if view.enclosed is not None:
                er, ec, et, ek, ed = view.enclosed
                r, c, t, k, d = np.r_[r, er], np.r_[c, ec], np.r_[t, et], np.r_[k, ek], np.r_[d, ed]
            z = t * (d @ cameras.c2w_opencv[view.frame][:3, 2])
            sigma = np.maximum(planes.rms[k], floor_sigma)
            if view.standing is not None:
                sr, sc, sz, srms = view.standing
                r, c, z, sigma = np.r_[r, sr], np.r_[c, sc], np.r_[z, sz], np.r_[sigma, np.maximum(srms, floor_sigma)]
            n = len(r)
            out.append((np.full(n, view.frame, np.int64), c.astype(np.float32), r.astype(np.float32),
                        z.astype(np.float32), sigma.astype(np.float32), np.ones(n, bool)))
        rows = tuple(np.concatenate(a) for a in zip(*out))
        state.rows.append(rows)
        return {"targets": int(len(rows[0]))}
