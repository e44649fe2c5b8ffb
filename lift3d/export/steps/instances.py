"""Instances: the link radius they connect over, their ids, the filled patches joining their objects, and the
clean-up (:mod:`lift3d.export.instances`, :mod:`lift3d.export.cleanup`)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from lift3d.errors import InputError
from lift3d.export.cleanup import MERGE_MIN_SHARE, CleanupRules, class_segments, clean_instances
from lift3d.export.instances import assign_instances, join_filled_instances
from lift3d.export.points import default_crumb_points, typical_spacing
from lift3d.export.steps.base import ExportStep, PointState, StepContext
from lift3d.export.visibility import train_frames

#: Instances whose points' mean class probability is lower fold into their surroundings. A thing the field
#: learned from a spurious 2D segment in one or two views (a chair painted on a wall) keeps the wall in its
#: class distribution: on tuning scene 100 such instances had a mean class probability of 0.61-0.66, every
#: instance on a real object 0.78-0.93.
MIN_INSTANCE_CONFIDENCE = 0.7
#: Instances need the majority of their visible points on one 2D thing segment in this many of the clean-up's
#: voting views (:func:`lift3d.export.cleanup.clean_instances`). One: on tuning scene 5, asking for two or three
#: folded real objects that few views see (a toy plane on the floor in 1 of 1 voting view, a ball in 2 of 5).
MIN_SUPPORT_VIEWS = 1
#: Voting views that must confirm an instance's class for it to keep that class when it would fold into another
#: (:class:`lift3d.export.cleanup.CleanupRules`). Two, not one: one view is what a spurious 2D segment gives. On
#: the cluttered tuning room 100 (sensor depth) two and three kept the same instances; on tuning room 100 with
#: view-correlated labels two kept no spurious one (docs/export.md).
KEEP_CONFIRMED_VIEWS = 2


@dataclass
class LinkRadius(ExportStep):
    """The instance link radius, in output units: points of one instance connect across gaps of about two field grid
    cells (the source's radius), ``spacings`` point spacings (sparse clouds) or one voxel, whichever is largest. The
    steps after it measure their distances in it; ``metadata.json`` has it as
    ``thresholds.points.instance_link_radius``."""

    name = "link-radius"
    switchable = False
    spacings: float = 1.5
    """Point spacings (median nearest-neighbour distances) the radius spans at least."""

    def apply(self, state: PointState, context: StepContext) -> dict:
        p = state.points
        grid = context.to_output(context.grid_link, p)
        spacing = typical_spacing(p.xyz)
        state.link_radius = link = max(grid, self.spacings * spacing, state.voxel_size)
        p.thresholds["instance_link_radius"] = float(link)
        return {"link_radius": float(link), "grid": float(grid), "spacing": float(spacing)}


@dataclass
class InstanceAssignment(ExportStep):
    """Instance ids: connected components of one (class, instance channel) within the link radius; components under
    ``min_points`` take their surroundings' labels (dropped when isolated); ids contiguous ``1..K`` by size then
    position (:func:`lift3d.export.instances.assign_instances`)."""

    name = "instances"
    switchable = False
    flags = {"min_points": "--min-points"}
    min_points: int = 0
    """Instance fragments under this many points take their surroundings' label (0 = keep all)."""

    def check(self) -> None:
        if int(self.min_points) < 0:
            raise InputError("--min-points", f"must be >= 0, got {self.min_points}")

    def apply(self, state: PointState, context: StepContext) -> dict:
        p = state.points
        assignment = assign_instances(p.xyz, p.semantic, p.channel, link_radius=state.link_radius,
                                      min_points=int(self.min_points))
        state.points = replace(p, semantic=assignment.semantic, instance=assignment.instance).take(assignment.keep)
        return assignment.stats


@dataclass
class FilledJoin(ExportStep):
    """Instances made mostly of filled points (``thing-fill``) join the nearest other instance of their class and
    instance channel within reach (:func:`lift3d.export.instances.join_filled_instances`)."""

    name = "filled-join"
    radius_links: float = 3.0
    """Reach in instance link radii: a filled patch lies at least one link radius from the isosurface it completes,
    three reach it."""
    same_channel: bool = True
    """Join only an instance of the same instance channel: the field tells objects apart where its isosurface does
    not reach them (a whole object mostly filled keeps its own id instead of joining its neighbour)."""

    def skip(self, state: PointState, context: StepContext) -> str | None:
        return None if state.points.filled is not None and state.points.filled.any() else "no filled points"

    def apply(self, state: PointState, context: StepContext) -> dict:
        p = state.points
        instance, joined = join_filled_instances(p.xyz, p.semantic, p.instance, p.filled,
                                                 radius=self.radius_links * state.link_radius,
                                                 channel=p.channel if self.same_channel else None)
        state.points = replace(p, instance=instance)
        return {"joined": joined}


@dataclass
class InstanceCleanup(ExportStep):
    """One instance per object, no crumbs (:mod:`lift3d.export.cleanup`): fragments that one 2D segment covers in
    the training views merge; crumbs, instances the 2D labels never confirm as a thing and unsure instances fold
    into their neighbour (dropped when isolated)."""

    name = "instance-cleanup"
    flags = {"merge": "--no-merge-fragments", "crumb_points": "--crumb-points",
             "min_confidence": "--min-instance-confidence", "min_support_views": "--min-support-views"}
    merge: bool = True
    """Merge instances of one class that one 2D pseudo-label segment covers in the training views seeing both."""
    crumb_points: int | None = None
    """Instances under this many points fold into their neighbour (default: the points of a patch one link radius on
    a side, from the cloud's density; 0 = keep all)."""
    min_confidence: float = MIN_INSTANCE_CONFIDENCE
    """Instances whose points' mean class probability is below this fold into their surroundings (0 = keep all)."""
    min_support_views: int = MIN_SUPPORT_VIEWS
    """Instances that the 2D labels confirm as a thing in fewer training views fold into their surroundings
    (0 = keep all)."""
    max_views: int = CleanupRules.max_views
    """Voting views, evenly spread over the training views."""
    min_share: float = field(default=MERGE_MIN_SHARE)
    """Share of the views seeing two same-class instances in which one 2D segment must hold both to merge them."""
    min_views: int = CleanupRules.min_views
    """Fewest views that must see both for them to merge."""
    keep_confirmed_views: int = KEEP_CONFIRMED_VIEWS
    """An instance to fold (crumb, unconfirmed or unsure) that the 2D labels confirm as its own class in at least
    this many voting views keeps its class: it folds only into its own class, else stays an instance (0 = off)."""

    def check(self) -> None:
        if self.crumb_points is not None and self.crumb_points < 0:
            raise InputError("--crumb-points", f"must be >= 0, got {self.crumb_points}")
        if not 0.0 <= self.min_confidence <= 1.0:
            raise InputError("--min-instance-confidence", f"must be in [0, 1], got {self.min_confidence}")
        if int(self.keep_confirmed_views) < 0:
            raise InputError("--instance-cleanup.keep-confirmed-views", f"must be >= 0, got {self.keep_confirmed_views}")
        if int(self.min_support_views) < 0:
            raise InputError("--min-support-views", f"must be >= 0, got {self.min_support_views}")

    def apply(self, state: PointState, context: StepContext) -> dict:
        p, scene, link = state.points, context.scene, state.link_radius
        crumbs = default_crumb_points(link, typical_spacing(p.xyz)) if self.crumb_points is None \
            else int(self.crumb_points)
        rules = CleanupRules(merge=self.merge, max_views=self.max_views, min_share=self.min_share,
                             min_views=self.min_views, min_support_views=int(self.min_support_views),
                             min_confidence=float(self.min_confidence),
                             keep_confirmed_views=int(self.keep_confirmed_views))
        semantic, instance, kept, info = clean_instances(
            p.xyz, context.world(p), p.semantic, p.instance, cameras=scene.cameras, frames=train_frames(scene),
            segments_of=lambda f: _segments(scene, f), link_radius=link, crumb_points=crumbs,
            rules=rules, confidence=p.confidence)
        state.points = replace(p, semantic=semantic, instance=instance).take(kept)
        return info


def _segments(scene, frame: int):
    """Frame ``frame``'s 2D thing segments, with their class in the id (:func:`class_segments`)."""
    labels = scene.pseudo_labels(frame)
    return class_segments(labels.semantic, labels.instance)
