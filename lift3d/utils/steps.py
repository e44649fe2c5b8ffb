"""Named processing steps run in order, each saying whether it ran, why, and what it did.

The training's depth-target sources and the export's post-steps are lists of steps. A step is a small class:
its settings (a dataclass, every threshold named), the scene *premises* it assumes (a room around the
cameras, walls at right angles...), and one :meth:`Step.apply` that changes a shared state and returns the
counts worth recording. :func:`run_steps` runs a list of them against the premises the scene shows (its
profile, :mod:`lift3d.model.profiles`) and returns one :class:`StepRecord` per step, ran or not, for
``config.yml`` and ``metadata.json``.

Examples
--------
>>> from dataclasses import dataclass
>>> @dataclass
... class Doubled(Step):
...     name = "doubled"
...     def apply(self, state, context):
...         state["x"] *= 2
...         return {"x": state["x"]}
>>> @dataclass
... class Squared(Step):
...     name = "squared"
...     needs = frozenset({"room"})
...     def apply(self, state, context):
...         state["x"] **= 2
...         return {}
>>> state = {"x": 3}
>>> records = run_steps([Doubled(), Squared()], state, None, premises={"object"})
>>> state["x"], [(r.name, r.ran, r.why) for r in records]
(6, [('doubled', True, 'on'), ('squared', False, 'premise not shown: room')])
>>> records[0].to_json()["counts"]
{'x': 6}
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, ClassVar, Iterable


@dataclass
class StepRecord:
    """What one step did (or why it did not run)."""

    name: str
    ran: bool
    why: str
    seconds: float = 0.0
    counts: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"name": self.name, "ran": self.ran, "why": self.why}
        if self.ran:
            out["seconds"] = round(self.seconds, 3)
            out["counts"] = self.counts
        return out


@dataclass
class Step:
    """One named step. Subclasses are dataclasses whose fields are the step's settings.

    Class attributes
    ----------------
    name : str
        Kebab-case name, as ``config.yml``, ``metadata.json`` and the flags spell it.
    needs : frozenset of str
        Scene premises the step assumes (:data:`lift3d.model.profiles.PREMISES`); it is skipped, with the
        reason recorded, when the scene does not show one of them.
    """

    name: ClassVar[str] = "step"
    needs: ClassVar[frozenset[str]] = frozenset()
    enabled: bool = True

    def apply(self, state: Any, context: Any) -> dict[str, Any]:
        """Change ``state`` in place; return the counts worth recording (JSON-safe)."""
        raise NotImplementedError


def run_steps(steps: Iterable[Step], state: Any, context: Any, premises: Iterable[str]) -> list[StepRecord]:
    """Run ``steps`` in order on ``state``; a step runs when enabled and every premise it needs is shown.

    Parameters
    ----------
    steps : iterable of Step
    state : any
        What the steps change (the export's points, the training's planes and targets).
    context : any
        What the steps read (scene, run, settings shared by all steps).
    premises : iterable of str
        The premises the scene shows (its profile's).

    Returns
    -------
    list of StepRecord
        One per step, in order.
    """
    shown = set(premises)
    records = []
    for step in steps:
        if not step.enabled:
            records.append(StepRecord(step.name, False, "off"))
            continue
        missing = sorted(set(step.needs) - shown)
        if missing:
            records.append(StepRecord(step.name, False, "premise not shown: " + ", ".join(missing)))
            continue
        t0 = time.perf_counter()
        counts = step.apply(state, context) or {}
        records.append(StepRecord(step.name, True, "on", time.perf_counter() - t0, dict(counts)))
    return records
