"""Categories (classes) of a label space: the one record type, its readers and its default colours.

:class:`Category` is what a scene's ``categories``, an export's ``classes.json`` and a run's class table
hold. :func:`parse_categories` reads a scene's list strictly (every problem is an error);
:func:`as_class_table` / :func:`read_class_table` accept any class table lift3d meets (``classes.json``, a
scene's ``transforms.json``, COCO panoptic JSON) and fill in what is missing. Cheap to import (numpy only).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from lift3d.errors import InputError
from lift3d.utils.colors import hash_colors
from lift3d.utils.files import read_json

#: Offset of the hash colours of classes that name no colour: a family of colours apart from the instance
#: colours of the same numbers (:func:`lift3d.utils.colors.hash_colors`).
UNKNOWN_CLASS_OFFSET = 7919


@dataclass(frozen=True)
class Category:
    """A COCO panoptic category. ``id`` ≥ 1 (0 is void); ``isthing`` separates countable objects (things)
    from amorphous regions (stuff)."""

    id: int
    name: str
    isthing: bool
    color: tuple[int, int, int] = (128, 128, 128)

    def to_json(self) -> dict:
        return {"id": self.id, "name": self.name, "isthing": int(self.isthing), "color": list(self.color)}


def default_category_color(cid: int) -> tuple[int, int, int]:
    """The colour a scene's category gets when it names none (seeded by the id)."""
    rng = np.random.default_rng(cid * 7919)
    return tuple(int(x) for x in rng.integers(40, 256, 3))


def unknown_class_color(cid: int) -> tuple[int, int, int]:
    """The colour of a class a class table lists without one (and pictures give ids missing from it)."""
    return tuple(int(x) for x in hash_colors(np.array([cid]), UNKNOWN_CLASS_OFFSET)[0])


def parse_categories(raw: Any, where: Path, default_color=None) -> list[Category]:
    """Validated categories from parsed JSON: a non-empty list of ``{id, name, isthing[, color]}``.

    Parameters
    ----------
    raw : Any
        The parsed ``categories`` value.
    where : Path
        The file it came from (named in every error).
    default_color : callable, optional
        ``(index, id) -> (r, g, b)`` for a category without ``color``; default a colour seeded by the id.

    Raises
    ------
    InputError
        Not a non-empty list, an entry without an integer ``id`` ≥ 1, a duplicate id, or a bad colour.
    """
    if not isinstance(raw, list) or not raw:
        raise InputError(where, "categories: must be a non-empty list of {id, name, isthing[, color]}")
    out: list[Category] = []
    seen: set[int] = set()
    for k, c in enumerate(raw):
        if not isinstance(c, dict) or "id" not in c:
            raise InputError(where, f"categories[{k}]: needs an 'id'")
        try:
            cid = int(c["id"])
        except (TypeError, ValueError):
            raise InputError(where, f"categories[{k}].id: not an integer ({c['id']!r})") from None
        if cid < 1:
            raise InputError(where, f"categories[{k}].id: must be >= 1 (0 is void)")
        if cid in seen:
            raise InputError(where, f"categories[{k}].id: duplicate id {cid}")
        seen.add(cid)
        color = c.get("color")
        try:
            rgb = tuple(int(x) for x in color[:3]) if color else None
        except (TypeError, ValueError):
            raise InputError(where, f"categories[{k}].color: expected [r, g, b]") from None
        if rgb is None:
            rgb = default_color(k, cid) if default_color is not None else default_category_color(cid)
        out.append(Category(cid, str(c.get("name", f"class_{cid}")), bool(c.get("isthing", 0)), rgb))
    return out


def as_class_table(obj: Any, where: str | Path = "classes") -> list[Category]:
    """Normalise a class table given in any of the forms lift3d meets.

    Parameters
    ----------
    obj : None, sequence or mapping
        ``None`` (no table: ``[]``); a list of :class:`Category`; a list of dicts with ``id``, ``name``,
        ``isthing``, ``color`` (``classes.json`` and COCO ``categories``); a list of objects with those
        attributes; a dict with a ``categories`` or ``classes`` list; or a path to such a JSON file.
        A missing name is ``class_<id>``, a missing colour :func:`unknown_class_color`.
    where : str or Path
        Named in error messages.

    Returns
    -------
    list of Category

    Examples
    --------
    >>> as_class_table([{"id": 4, "name": "chair", "isthing": 1, "color": [1, 2, 3]}])
    [Category(id=4, name='chair', isthing=True, color=(1, 2, 3))]
    >>> as_class_table({"categories": [{"id": 1, "name": "wall"}]})[0].color == unknown_class_color(1)
    True
    """
    if obj is None:
        return []
    if isinstance(obj, (str, Path)):
        return read_class_table(obj)
    if isinstance(obj, Mapping):
        for key in ("categories", "classes"):
            if isinstance(obj.get(key), list):
                return as_class_table(obj[key], where)
        raise InputError(where, "expected a list of classes (or a 'categories' / 'classes' list)")
    out: list[Category] = []
    for k, entry in enumerate(obj):
        if isinstance(entry, Category):
            out.append(entry)
            continue
        get = entry.get if isinstance(entry, Mapping) else (lambda key, d=None, e=entry: getattr(e, key, d))
        try:
            cid = int(get("id"))
        except (TypeError, ValueError):
            raise InputError(where, f"[{k}].id: missing or not an integer") from None
        color = get("color", None)
        if color is None:
            color = unknown_class_color(cid)
        try:
            rgb = tuple(int(x) for x in list(color)[:3])
        except (TypeError, ValueError):
            raise InputError(where, f"[{k}].color: expected [r, g, b], got {color!r}") from None
        if len(rgb) != 3 or not all(0 <= x <= 255 for x in rgb):
            raise InputError(where, f"[{k}].color: expected three integers in 0..255, got {color!r}")
        out.append(Category(cid, str(get("name", None) or f"class_{cid}"), bool(get("isthing", False)), rgb))
    return out


def read_class_table(path: str | Path) -> list[Category]:
    """Read a class table: ``classes.json`` (a list of ``{id, name, isthing, color}``) or any JSON with a
    ``categories`` list (a scene's ``transforms.json``, a COCO panoptic JSON).

    Raises
    ------
    InputError
        The file is missing, not JSON, or not a class table.
    """
    raw = read_json(path, missing="class table not found")
    if not isinstance(raw, (list, dict)):
        raise InputError(path, "expected a list of classes")
    return as_class_table(raw, path)
