"""Which scene premises (:mod:`lift3d.model.profiles`) a run shows, and so which export steps may run."""

from __future__ import annotations

from lift3d.model.profiles import PROFILES, premises_of
from lift3d.model.run import LoadedRun

#: What the export assumed of every bounded scene before runs recorded their profile: a room in its box.
BOUNDED_BEFORE_PROFILES = PROFILES["manhattan-room"]


def run_premises(loaded: LoadedRun, profile: str = "auto") -> tuple[frozenset[str], str]:
    """The premises the export may rely on for ``loaded``'s scene, and why.

    ``profile`` other than ``auto`` decides (``lift3d export --profile``). Otherwise the run's own profile does, as
    training recorded it in ``config.yml`` (``scene.profile.premises``). A run from before that shows, as the export
    then assumed, every premise when its field is bounded (the box-face fill, the thing fill and the corner step
    ran on every bounded scene) and none when it is unbounded.

    Examples
    --------
    >>> from types import SimpleNamespace as NS
    >>> run = NS(cfg=NS(scene={}), model=NS(bounded=True))
    >>> sorted(run_premises(run)[0]), sorted(run_premises(run, "room")[0])
    (['box', 'manhattan', 'room'], ['room'])
    >>> run_premises(NS(cfg=NS(scene={"profile": {"premises": ["room"]}}), model=NS(bounded=True)))
    (frozenset({'room'}), "the run's profile (config.yml: scene.profile.premises)")
    """
    if profile != "auto":
        return premises_of(profile), f"--profile {profile}"
    recorded = ((getattr(loaded.cfg, "scene", None) or {}).get("profile") or {}).get("premises")
    if recorded is not None:
        return frozenset(str(p) for p in recorded), "the run's profile (config.yml: scene.profile.premises)"
    if loaded.model.bounded:
        return BOUNDED_BEFORE_PROFILES, "a run without a recorded profile, bounded: a room in its box (the rule " \
                                        "before profiles)"
    return frozenset(), "a run without a recorded profile, unbounded: no premise (the rule before profiles)"
