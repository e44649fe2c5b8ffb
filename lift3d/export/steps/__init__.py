"""The export's point steps: what happens to the points after the source draws them, one named step at a time.

:data:`POINT_STEPS` lists them in the order they run. Each is a :class:`~lift3d.export.steps.base.ExportStep`
(a :class:`lift3d.utils.steps.Step`): its settings are its dataclass fields (each one a ``lift3d export`` flag,
``--<step>.<setting>``, see :mod:`lift3d.export.steps.options`), the scene premises it needs
(:mod:`lift3d.model.profiles`; :func:`~lift3d.export.steps.premises.run_premises` says which a run shows), and
one ``apply`` that changes the points and returns what it did, recorded in ``metadata.json`` (``steps.points``).

A new step is a class in one of these modules (or a new module for a new kind of step) and its place in
:data:`POINT_STEPS`; its flags, its record and its documentation in ``lift3d export --help`` follow.

Examples
--------
>>> [cls.name for cls in POINT_STEPS][:5]
['box-fill', 'thing-fill', 'view-surface', 'sensor-surface', 'heads']
>>> sorted(StuffCorners.needs), sorted(BoxFill.needs)
(['room'], ['box'])
"""

from __future__ import annotations

from lift3d.export.steps.base import ExportStep, PointState, StepContext, run_point_steps, step_records
from lift3d.export.steps.fills import BoxFill, ThingFill
from lift3d.export.steps.filters import (ConfidenceFilter, Crop, FrameConversion, OutlierRemoval, SensorSurface,
                                         ViewSurface, VoxelDownsample)
from lift3d.export.steps.instances import FilledJoin, InstanceAssignment, InstanceCleanup, LinkRadius
from lift3d.export.steps.labels import LabelHeads, ViewVote
from lift3d.export.steps.stuff import StuffCorners, StuffOrientation

#: The point steps in the order they run.
POINT_STEPS: tuple[type[ExportStep], ...] = (
    BoxFill, ThingFill, ViewSurface, SensorSurface, LabelHeads, ConfidenceFilter, FrameConversion, Crop,
    OutlierRemoval, VoxelDownsample, LinkRadius, ViewVote, StuffOrientation, StuffCorners, InstanceAssignment,
    FilledJoin, InstanceCleanup,
)

__all__ = ["POINT_STEPS", "ExportStep", "PointState", "StepContext", "run_point_steps", "step_records",
           *(cls.__name__ for cls in POINT_STEPS)]
