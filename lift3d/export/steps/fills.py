"""The two fills: the training views' rendered surface where the isosurface has a hole (:mod:`lift3d.export.fills`).

They run on the ``surface`` source's points before the heads label them, so the filled points are labelled with
the rest in one pass.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lift3d.export.fills import BOX_FILL_MARGIN, FillRules, box_face_fill, thing_surface_fill
from lift3d.export.points import LabelledPoints
from lift3d.export.steps.base import ExportStep, PointState, StepContext


@dataclass
class _Fill(ExportStep):
    gap_links: float = 1.0
    """A rendered point fills a hole only this many instance link radii (two isosurface voxels each) or more from
    every isosurface point."""
    spacings: float = FillRules.spacings
    """… and more than this many point spacings; the kept points are thinned to one per point spacing."""
    smooth: float = FillRules.smooth
    """A rendered depth counts when it agrees with its 3 × 3 median to within this share (not an edge)."""

    def skip(self, state: PointState, context: StepContext) -> str | None:
        return None if context.source == "surface" else f"the {context.source} source: the surface source only"

    def _add(self, state: PointState, x: np.ndarray, dirs: np.ndarray, filled: bool) -> None:
        state.points = state.points.append(LabelledPoints(x, filled=np.full(len(x), filled), dirs=dirs))


@dataclass
class BoxFill(_Fill):
    """Where the isosurface has a hole next to the scene box (a wall or ceiling the box hugs), the training views'
    rendered surface fills it (:func:`lift3d.export.fills.box_face_fill`)."""

    name = "box-fill"
    needs = frozenset({"box"})
    flags = {"enabled": "--no-box-fill"}
    why_needed = ("rays end at the scene box whatever the density, so a wall, floor or ceiling on the box's face "
                  "may have no isosurface; a box that is not the room has no surface on its faces to fill in")
    margin: float = BOX_FILL_MARGIN
    """Rendered surface within this share of the box's diagonal of a face of the box fills holes."""

    def apply(self, state: PointState, context: StepContext) -> dict:
        x, dirs, info = box_face_fill(context.loaded, context.scene, state.points.xyz, context.cameras,
                                      cache=context.view_depth_cache, margin=self.margin,
                                      min_gap=self.gap_links * context.grid_link,
                                      rules=FillRules(spacings=self.spacings, smooth=self.smooth))
        self._add(state, x, dirs, False)
        return info


@dataclass
class ThingFill(_Fill):
    """Where the isosurface has no point on a thing that the training views without a depth map render (and label
    that thing), their rendered surface fills it (:func:`lift3d.export.fills.thing_surface_fill`); the filled
    points join the instance they border (``filled-join``)."""

    name = "thing-fill"
    needs = frozenset({"room"})
    flags = {"enabled": "--no-thing-fill"}
    why_needed = ("measured in rooms; on streets it cost point mIoU (outdoor seeds 0 and 2: -0.02 to -0.05) and "
                  "objects found (a filled patch joined a neighbouring car), and took 50-60 s more")
    gap_links: float = 0.5
    """A rendered point fills a hole only this many instance link radii or more from every isosurface point: half
    the box fill's, so a thing's holes narrower than the link radius are filled too (nine tuning runs: point mIoU
    +0.011 on average over the full gap, F-score -0.002)."""

    def apply(self, state: PointState, context: StepContext) -> dict:
        x, dirs, info = thing_surface_fill(context.loaded, context.scene, state.points.xyz, context.cameras,
                                           cache=context.view_depth_cache, min_gap=self.gap_links * context.grid_link,
                                           rules=FillRules(spacings=self.spacings, smooth=self.smooth))
        self._add(state, x, dirs, True)
        return info
