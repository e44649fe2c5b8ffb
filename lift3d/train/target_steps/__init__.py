"""The training's depth targets as an ordered list of named steps (:class:`lift3d.utils.steps.Step`).

Each step has its settings as dataclass fields (each an ``image_depth.*`` setting: a ``--image_depth.*`` flag),
the scene premises it assumes in ``needs`` (:data:`lift3d.model.profiles.PREMISES`) and one ``apply(state,
context)`` that changes the shared :class:`TargetState` and returns the counts ``config.yml`` records.
:func:`target_steps` gives the steps of a source in the order they run (docs/sfm.md, "Training with it"):

* ``sparse``: :class:`SparseObservations`;
* ``dense``: that and :class:`PlaneSweepDepths`;
* ``planes``: :class:`SparseObservations`, then the stuff planes and their rules (:mod:`.plane_rules`:
  :class:`FitPlanes`, :class:`FloorBoundary`, :class:`CornerCutters`, :class:`FloorLineWalls`,
  :class:`SquareWalls`, :class:`CeilingBoundary`, :class:`MarginSeenThrough`), the pixel targets on them
  (:mod:`.plane_targets`: :class:`PlaneHits`, :class:`ReachingWalls`, :class:`LabelSupport`,
  :class:`EnclosedSegments`, :class:`StandingThings`, :class:`PlaneDepths`), and :class:`PlaneSweepOnThings`.

A new step is a :class:`TargetStep` subclass in the module of its kind, its settings named with
:func:`~lift3d.train.target_steps.state.setting` after new :class:`~lift3d.model.config.ImageDepthConfig`
fields, and its place in :data:`PIPELINES`.
"""

from __future__ import annotations

from lift3d.model.config import ImageDepthConfig
from lift3d.train.target_steps.plane_rules import (CeilingBoundary, CornerCutters, FitPlanes, FloorBoundary,
                                                   FloorLineWalls, MarginSeenThrough, SquareWalls)
from lift3d.train.target_steps.plane_targets import (EnclosedSegments, LabelSupport, PlaneDepths, PlaneHits,
                                                     ReachingWalls, StandingThings)
from lift3d.train.target_steps.sources import PlaneSweepDepths, PlaneSweepOnThings, SparseObservations
from lift3d.train.target_steps.state import PlaneSettings, TargetContext, TargetState, TargetStep, ViewTargets

#: Source -> its steps, in the order they run.
PIPELINES: dict[str, tuple[type[TargetStep], ...]] = {
    "sparse": (SparseObservations,),
    "dense": (SparseObservations, PlaneSweepDepths),
    "planes": (SparseObservations, FitPlanes, FloorBoundary, CornerCutters, FloorLineWalls, SquareWalls,
               CeilingBoundary, MarginSeenThrough, PlaneHits, ReachingWalls, LabelSupport, EnclosedSegments,
               StandingThings, PlaneDepths, PlaneSweepOnThings),
}


def target_steps(source: str, cfg: ImageDepthConfig) -> list[TargetStep]:
    """The steps of ``source`` (``sparse``, ``dense`` or ``planes``) in order, with their settings from ``cfg``."""
    return [step.from_config(cfg) for step in PIPELINES[source]]


__all__ = ["PIPELINES", "target_steps", "TargetStep", "TargetState", "TargetContext", "ViewTargets", "PlaneSettings",
           "SparseObservations", "PlaneSweepDepths", "PlaneSweepOnThings", "FitPlanes", "FloorBoundary",
           "CornerCutters", "FloorLineWalls", "SquareWalls", "CeilingBoundary", "MarginSeenThrough", "PlaneHits",
           "ReachingWalls", "LabelSupport", "EnclosedSegments", "StandingThings", "PlaneDepths"]
