"""Scene profiles: which kind of scene this is, and so which priors may run.

A prior that assumes something about the scene (a room around the cameras, walls at right angles, a room
that fills its box) runs only where the scene shows it. Each assumption is a *premise*; a profile is the set
of premises a kind of scene shows; each step of the training's depth targets and of the export names the
premises it needs (:class:`lift3d.utils.steps.Step`). The training picks the profile from what the scene
shows and writes the evidence and the reason to ``config.yml``; ``--profile`` overrides it.

Examples
--------
>>> sorted(PROFILES["manhattan-room"])
['box', 'manhattan', 'room']
>>> premises_of("room")
frozenset({'room'})
>>> premises_of("street")
Traceback (most recent call last):
...
lift3d.errors.InputError: --profile: unknown profile 'street' (auto, manhattan-room, room, open, outdoor, object)
"""

from __future__ import annotations

from lift3d.errors import InputError

#: What each premise means (the steps that need it are listed in docs/presets.md).
PREMISES = {
    "room": "the cameras stand inside a room: a level floor below them, upright walls around them, a level "
            "ceiling above when the views show one; stuff classes lie on planes",
    "manhattan": "the walls run along two directions at right angles",
    "box": "the scene box is the room: its walls, floor and ceiling lie on the box's faces",
}

#: Profile name -> the premises that kind of scene shows.
PROFILES: dict[str, frozenset[str]] = {
    "manhattan-room": frozenset({"room", "manhattan", "box"}),
    "room": frozenset({"room"}),
    "open": frozenset(),
    "outdoor": frozenset(),
    "object": frozenset(),
}

#: ``--profile`` choices.
CHOICES = ("auto",) + tuple(PROFILES)


def premises_of(profile: str) -> frozenset[str]:
    """The premises of ``profile`` (an :class:`InputError` naming ``--profile`` when unknown)."""
    if profile not in PROFILES:
        raise InputError("--profile", f"unknown profile {profile!r} ({', '.join(CHOICES)})")
    return PROFILES[profile]
