"""Labels at the points: the field's heads, then the training views' vote on stuff classes."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lift3d.export.steps.base import ExportStep, PointState, StepContext
from lift3d.export.views import VOTE_MAX_POINTS, VOTE_MIN_VIEWS, VOTE_REL_TOLERANCE, VOTE_SHARE, VoteRules, \
    vote_stuff_labels
from lift3d.export.visibility import train_frames


@dataclass
class LabelHeads(ExportStep):
    """The field's semantic and instance heads (and the colour head, unless the source has colours) label every
    point, once per point in chunks: class = argmax over the categories, instance channel = argmax over the
    instance channels on thing classes, confidence = the chosen class's probability."""

    name = "heads"
    switchable = False

    def apply(self, state: PointState, context: StepContext) -> dict:
        p = state.points
        labels = context.loaded.model.query_labels(p.xyz.astype(np.float32), p.dirs, progress=context.progress)
        state.points = replace(p, rgb=labels.rgb if p.rgb is None else p.rgb, semantic=labels.semantic,
                               channel=labels.channel, confidence=labels.confidence, dirs=None,
                               field_semantic=labels.semantic.copy(), field_channel=labels.channel.copy())
        return {"labelled": len(p)}


@dataclass
class ViewVote(ExportStep):
    """A point whose training views agree, in their 2D labels, that it is a stuff class takes that class (a chair's
    label does not spread onto the floor around its legs; :func:`lift3d.export.views.vote_stuff_labels`). Views
    without a depth map are rendered for the visibility test."""

    name = "view-vote"
    flags = {"enabled": "--no-view-vote"}
    needs_points = True
    tolerance_links: float = 0.25
    """A view sees a point within this many of the source's link radii (half a field grid cell) of the view's depth
    there, plus ``rel_tolerance`` of that depth."""
    rel_tolerance: float = VOTE_REL_TOLERANCE
    """… plus this share of the view's depth."""
    min_views: int = VOTE_MIN_VIEWS
    """Fewest views that must see and label a point before their vote can change its class."""
    share: float = VOTE_SHARE
    """Share of those votes the winning class needs."""
    max_points: int = VOTE_MAX_POINTS
    """The vote is taken on at most this many points; the rest follow their nearest."""

    def apply(self, state: PointState, context: StepContext) -> dict:
        p, loaded = state.points, context.loaded
        rules = VoteRules(min_views=self.min_views, share=self.share, rel_tolerance=self.rel_tolerance,
                          max_points=self.max_points)
        semantic, channel, info = vote_stuff_labels(
            context.world(p), p.semantic, p.channel, loaded, context.scene, train_frames(context.scene),
            abs_tolerance=self.tolerance_links * context.grid_link / float(loaded.norm.scale),
            depth_cache=context.view_depth_cache, rules=rules)
        state.points = replace(p, semantic=semantic, channel=channel)
        return info
