"""The steps' settings from outside: ``lift3d export`` flags made from the dataclass fields, and Python keywords.

Every setting of every step is a flag ``--<step>.<setting>`` (``--stuff-corners.plane-threshold 0.006``,
``--view-vote.enabled false``), its help the text under the field. The flags ``lift3d export`` had before the
steps had flags of their own (:attr:`ExportStep.flags <lift3d.export.steps.base.ExportStep.flags>`:
``--voxel-size``, ``--no-complete-corners``, ``--obb-center`` ...) set the same settings, and their names without
dashes are Python keywords of :func:`configure_steps` (``voxel_size=0.05``, ``complete_corners=False``).
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import textwrap
import types
import typing
from typing import Any

from lift3d.export.steps import POINT_STEPS
from lift3d.export.steps.base import ExportStep
from lift3d.model.config import field_docs

#: The Python keyword of :class:`~lift3d.export.steps.filters.Crop`'s ready box (``obb=``), which has no flag.
BOX_KEYWORD = "obb"


def step_docs(cls: type) -> dict[str, str]:
    """The text under each setting of a step class, its base classes' settings included."""
    docs: dict[str, str] = {}
    for base in reversed(cls.__mro__):
        if dataclasses.is_dataclass(base):
            docs.update(field_docs(base))
    docs.setdefault("enabled", "Run the step (where the scene shows its premises).")
    return docs


def _settings(cls: type[ExportStep]):
    """(field, its type without None) of each setting of ``cls`` that has a flag."""
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if f.metadata.get("flag") is False or (f.name == "enabled" and not cls.switchable):
            continue
        tp = hints[f.name]
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if typing.get_origin(tp) in (typing.Union, types.UnionType) and len(args) == 1:
            tp = args[0]
        yield f, tp


def keyword(flag: str) -> str:
    """The Python keyword of a flag: ``--no-complete-corners`` → ``complete_corners``, ``--voxel-size`` →
    ``voxel_size``.

    >>> keyword("--no-complete-corners"), keyword("--obb-center")
    ('complete_corners', 'obb_center')
    """
    return flag.removeprefix("--").removeprefix("no-").replace("-", "_")


def plain(text: str) -> str:
    """Docstring text as ``--help`` shows it: one line, without reStructuredText roles and literals.

    >>> plain("fills it (:func:`lift3d.export.fills.box_face_fill`; ``filled-join``)")
    'fills it (lift3d.export.fills.box_face_fill; filled-join)'
    """
    text = re.sub(r":[a-z]+:`~?([^`]+)`", r"\1", " ".join(text.split()))
    return text.replace("``", "")


def _bool(text: str) -> bool:
    if text.lower() in ("1", "true", "yes", "on"):
        return True
    if text.lower() in ("0", "false", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")


def add_step_flags(parser: argparse.ArgumentParser) -> None:
    """One argument group per step, with a flag per setting (and the step's older flags); the values land in
    ``args`` as ``step:<step>.<setting>`` (:func:`steps_from_args`)."""
    for cls in POINT_STEPS:
        step = cls()
        docs = step_docs(cls)
        needs = f" Needs: {', '.join(sorted(cls.needs))}." if cls.needs else ""
        about = textwrap.fill(plain(cls.__doc__ or "") + needs, width=98)
        group = parser.add_argument_group(f"step {cls.name}", about)
        for f, tp in _settings(cls):
            dest = f"step:{cls.name}.{f.name}"
            generic = f"--{cls.name}.{f.name.replace('_', '-')}"
            default = getattr(step, f.name)
            kwargs: dict[str, Any] = {"dest": dest, "default": argparse.SUPPRESS}
            if tp is bool:
                kwargs.update(type=_bool, metavar="{true,false}")
            elif typing.get_origin(tp) is tuple:
                kwargs.update(type=float, nargs=len(typing.get_args(tp)), metavar="V")
            else:
                kwargs.update(type=tp, metavar=tp.__name__.upper())
            if "choices" in f.metadata:
                kwargs.update(choices=f.metadata["choices"], metavar=None)
            shown = " ".join(map(str, default)) if isinstance(default, tuple) else \
                str(default).lower() if isinstance(default, bool) else default
            text = plain(docs.get(f.name, "")) + ("" if default is None else f" (default: {shown})")
            group.add_argument(generic, help=text.replace("%", "%%"), **kwargs)
            old = cls.flags.get(f.name)
            if old is None:
                continue
            if tp is bool:
                value = not old.startswith("--no-")
                group.add_argument(old, dest=dest, action="store_const", const=value, default=argparse.SUPPRESS,
                                   help=f"the same as {generic} {str(value).lower()}")
            else:
                group.add_argument(old, help=f"the same as {generic}", **kwargs)


def steps_from_args(args: argparse.Namespace) -> list[ExportStep]:
    """The steps with the settings the flags of :func:`add_step_flags` gave (the rest at their defaults)."""
    given: dict[str, dict[str, Any]] = {}
    for key, value in vars(args).items():
        if key.startswith("step:"):
            name, setting = key[5:].split(".", 1)
            given.setdefault(name, {})[setting] = tuple(value) if isinstance(value, list) else value
    return configure_steps(given)


def configure_steps(settings: dict[str, dict[str, Any]] | None = None, steps: list[ExportStep] | None = None,
                    **keywords: Any) -> list[ExportStep]:
    """``steps`` (default: every step of :data:`POINT_STEPS` at its defaults) with new settings.

    Parameters
    ----------
    settings : dict, optional
        Step name → {setting: value}.
    steps : list of ExportStep, optional
    **keywords
        Settings by the Python keyword of their older flag (:func:`keyword`: ``voxel_size=0.05``,
        ``complete_corners=False``, ``min_support_views=0``) and ``obb=`` (a crop box).

    Examples
    --------
    >>> steps = configure_steps({"stuff-corners": {"min_angle": 45.0}}, voxel_size=0.05, view_vote=False)
    >>> [(s.name, s.enabled) for s in steps if s.name in ("view-vote", "voxel-downsample")]
    [('voxel-downsample', True), ('view-vote', False)]
    >>> next(s for s in steps if s.name == "stuff-corners").min_angle
    45.0
    """
    steps = list(steps) if steps is not None else [cls() for cls in POINT_STEPS]
    by_name = {s.name: i for i, s in enumerate(steps)}
    changes: dict[str, dict[str, Any]] = {name: dict(values) for name, values in (settings or {}).items()}
    known = keyword_settings()
    for key, value in keywords.items():
        if key not in known:
            raise TypeError(f"unknown export setting {key!r} (known: {', '.join(sorted(known))})")
        name, setting = known[key]
        changes.setdefault(name, {})[setting] = value
    for name, values in changes.items():
        if name not in by_name:
            raise TypeError(f"unknown export step {name!r} (known: {', '.join(by_name)})")
        step = steps[by_name[name]]
        names = {f.name for f in dataclasses.fields(step)}
        unknown = sorted(set(values) - names)
        if unknown:
            raise TypeError(f"step {name}: unknown setting(s) {', '.join(unknown)} (known: {', '.join(sorted(names))})")
        steps[by_name[name]] = dataclasses.replace(step, **values)
    return steps


def keyword_settings() -> dict[str, tuple[str, str]]:
    """Python keyword → (step name, setting): the older flags' names, and ``obb``."""
    out = {keyword(flag): (cls.name, setting) for cls in POINT_STEPS for setting, flag in cls.flags.items()}
    out[BOX_KEYWORD] = ("crop", "box")
    return out
