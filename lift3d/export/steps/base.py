"""What every point step of the export shares: the step class, the points it changes, what it reads, and the loop.

A point step (:class:`ExportStep`) is a :class:`lift3d.utils.steps.Step`: a dataclass whose fields are its settings,
each documented by the string under it (that text is its ``--help``), the scene premises it ``needs``, and one
``apply(state, context)`` that changes ``state.points`` and returns the counts worth recording. The export runs
them in order with :func:`run_point_steps`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np

from lift3d.data.scene import Scene
from lift3d.export.frames import to_frame, world_from_normalized
from lift3d.export.points import LabelledPoints, OrientedBox
from lift3d.model.run import LoadedRun
from lift3d.utils.steps import Step, StepRecord, run_steps


@dataclass
class PointState:
    """What the steps change: the points, and what earlier steps decided that later ones honour."""

    points: LabelledPoints
    """The points (normalised coordinates until ``frame-conversion``; unlabelled until ``heads``)."""
    link_radius: float | None = None
    """Instance link radius in the points' units (``link-radius``)."""
    crop: OrientedBox | None = None
    """The crop box (``crop``): points added later stay inside it."""
    voxel_size: float = 0.0
    """The voxel size (``voxel-downsample``): points added later keep one per voxel."""


@dataclass
class StepContext:
    """What the steps read: the run, its scene and what the point source measured."""

    loaded: LoadedRun
    scene: Scene
    source: str
    """The point source that drew the points (``surface``, ``tsdf``, ``rays``)."""
    grid_link: float
    """The source's instance link radius in normalised units (two isosurface voxels for ``surface``)."""
    cameras: Any = None
    """``surface`` source: the training cameras in normalised coordinates."""
    view_depth_cache: dict = field(default_factory=dict)
    """Renders of the training views without a depth map, shared by the fills and the vote (and the mesh)."""
    progress: bool = False

    @property
    def transform(self) -> np.ndarray:
        """``4×4`` world ← normalised."""
        return world_from_normalized(self.loaded.norm)

    def world(self, points: LabelledPoints) -> np.ndarray:
        """``[N, 3]`` the points in the cameras' world frame, whatever frame they are in."""
        return points.xyz if points.frame == "world" else to_frame(points.xyz, self.transform, "world")

    def with_field_labels(self, points: LabelledPoints) -> LabelledPoints:
        """``points`` with ``field_semantic`` / ``field_channel`` the field's own labels at their positions (for points
        a step made or moved after the heads ran; unchanged when the heads have not run yet)."""
        if points.field_semantic is None or not len(points):
            return points
        x = self.loaded.norm.to_normalized(self.world(points)).astype(np.float32)
        labels = self.loaded.model.query_labels(x)
        return replace(points, field_semantic=labels.semantic, field_channel=labels.channel)

    def to_output(self, length: float, points: LabelledPoints) -> float:
        """A length in normalised units, in the units of the points' frame."""
        return length * (1.0 if points.frame == "normalized" else 1.0 / float(self.loaded.norm.scale))


@dataclass
class ExportStep(Step):
    """A point step of the export (see the module docstring).

    Class attributes, besides :class:`~lift3d.utils.steps.Step`'s ``name`` and ``needs``
    -------------------------------------------------------------------------------------
    switchable : bool
        The step can be turned off (``--<name>.enabled false``); steps the others build on cannot.
    flags : dict
        Setting → the flag ``lift3d export`` had for it before the steps had flags of their own
        (``--voxel-size``; a bool's ``--no-…`` / ``--…`` sets it False / True). Its Python keyword is the flag's
        name without dashes and ``no-`` (``voxel_size``, ``complete_corners``).
    why_needed : str
        Why the step needs its premises (docs/export.md).
    needs_points : bool
        The step has nothing to do without points (it is skipped, saying so).
    """

    switchable: ClassVar[bool] = True
    flags: ClassVar[dict[str, str]] = {}
    why_needed: ClassVar[str] = ""
    needs_points: ClassVar[bool] = False

    def skip(self, state: PointState, context: StepContext) -> str | None:
        """Why the step does nothing on these points with these settings (None: it runs)."""
        return "no points" if self.needs_points and not len(state.points) else None

    def check(self) -> None:
        """Raise :class:`lift3d.errors.InputError` (naming the flag) for a setting out of range."""

    def settings(self) -> dict[str, Any]:
        """The settings as JSON values (tuples as lists, other objects as text)."""
        out = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, tuple):
                value = list(value)
            elif value is not None and not isinstance(value, (bool, int, float, str, list)):
                value = str(value)
            out[f.name] = value
        return out


def run_point_steps(steps: list[ExportStep], state: PointState, context: StepContext,
                    premises: frozenset[str]) -> list[StepRecord]:
    """Run ``steps`` in order (:func:`lift3d.utils.steps.run_steps`), skipping with the reason a step that is on and
    whose premises the scene shows but that has nothing to do here (:meth:`ExportStep.skip`). Each record that ran
    counts the points after it (``points_after``)."""
    records = []
    for step in steps:
        why = step.enabled and not (step.needs - premises) and step.skip(state, context)
        if why:
            records.append(StepRecord(step.name, False, why))
            continue
        record, = run_steps([step], state, context, premises)
        if record.ran:
            record.counts["points_after"] = len(state.points)
        records.append(record)
    return records


def step_records(steps: list[ExportStep], records: list[StepRecord]) -> list[dict[str, Any]]:
    """The records for ``metadata.json``: each with the premises its step needs and its settings."""
    return [{**r.to_json(), "needs": sorted(s.needs), "settings": s.settings()} for s, r in zip(steps, records)]
