"""Colours of lift3d's pictures: stable instance colours, class colours, colourised panoptic maps.

Two rules make pictures comparable across runs, files and frames:

* **An instance id has one colour, everywhere.** :func:`instance_color` hashes the id itself (Fibonacci
  hashing onto the hue circle, saturation and value cycling with the id) so instance 7 is the same colour
  in a point cloud, a mesh, a rendered frame and next week's export, whatever other ids are present. It is
  the formula of ``lift3d render``'s ``instance_vis`` previews, so 2D and 3D pictures agree. Categorical
  colour maps (PyVista's, matplotlib's ``tab20``) re-spread their colours over the ids a picture happens to
  show, so the same object changes colour from one picture to the next; that is what this module avoids.
* **Things are vivid, stuff and void are grey-ish.** Instance colours are saturated (S ≥ 0.65) and bright
  (V ≥ 0.75); instance 0 (stuff, or nothing) is a neutral grey, and :func:`stuff_tint` pulls class colours
  towards that grey so a stuff region still shows its class but never competes with an object.

Class colours come from the class table (``classes.json`` written by ``lift3d export``, or a scene's
``categories``); :func:`load_classes` reads either.

Examples
--------
>>> instance_color([7, 7, 0]).tolist() == [instance_color(7).tolist()[0]] * 2 + [list(INSTANCE_NONE)]
True
>>> classes = [ClassInfo(1, "wall", False, (174, 199, 232)), ClassInfo(6, "table", True, (255, 127, 14))]
>>> semantic_color([6, 1, 0], classes).tolist()
[[255, 127, 14], [174, 199, 232], [60, 60, 60]]
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from lift3d.errors import InputError

__all__ = [
    "ClassInfo",
    "INSTANCE_NONE",
    "VOID_COLOR",
    "instance_color",
    "semantic_color",
    "stuff_tint",
    "panoptic_color",
    "load_classes",
    "as_classes",
    "classes_beside",
    "color_to_float",
]

#: Colour of instance id 0 (stuff, void, "no instance") in instance-coloured pictures: neutral grey.
INSTANCE_NONE = (150, 150, 150)
#: Colour of semantic id 0 (void) and of pixels / points without a label: dark grey.
VOID_COLOR = (60, 60, 60)

# How much of the class colour a stuff region keeps in instance-coloured views (the rest is grey).
_STUFF_TINT = 0.3
# Offset of the hash colours given to class ids missing from the class table (unlike instance colours).
_UNKNOWN_CLASS_OFFSET = 7919


@dataclass(frozen=True)
class ClassInfo:
    """One row of the class table: ``classes.json`` of an export or a scene's ``categories``.

    Attributes
    ----------
    id : int
        Category id (≥ 1; 0 is void).
    name : str
        Display name.
    isthing : bool
        Countable object (has instances) rather than an amorphous region.
    color : tuple of int
        ``(r, g, b)`` in 0..255.
    """

    id: int
    name: str
    isthing: bool
    color: tuple[int, int, int]


# ------------------------------------------------------------------------------------------ hashing
#: 1/φ: Fibonacci hashing of the id onto the hue circle. Consecutive ids (exports number instances 1..K)
#: land far apart in hue, and no id's colour depends on which other ids exist.
_GOLDEN = 0.6180339887498949


def _hsv_to_rgb_u8(h: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectorised HSV (each in [0, 1]) → ``uint8 [..., 3]`` RGB, the arithmetic of :func:`colorsys.hsv_to_rgb`."""
    i = np.floor(h * 6.0)
    f = h * 6.0 - i
    i = i.astype(np.int64) % 6
    p, q, t = v * (1.0 - s), v * (1.0 - s * f), v * (1.0 - s * (1.0 - f))
    r = np.choose(i, [v, q, p, p, t, v])
    g = np.choose(i, [t, v, v, q, p, p])
    b = np.choose(i, [p, p, t, v, v, q])
    return np.clip(np.round(np.stack([r, g, b], -1) * 255.0), 0, 255).astype(np.uint8)


def _hash_colors(ids: np.ndarray, offset: int = 0) -> np.ndarray:
    """Saturated, bright colour of each integer id (≥ 0): hue by Fibonacci hashing, and three saturation and
    two value levels cycling with the id so ids whose hues come close still differ.

    The same formula as the ``instance_vis`` previews of ``lift3d render``
    (:func:`lift3d.render.output.instance_colors`), so an instance has one colour in 2D and 3D pictures.
    """
    k = np.asarray(ids, np.int64) + offset
    hue = (k * _GOLDEN) % 1.0
    sat = 0.65 + 0.35 * ((k * 7) % 3) / 2.0
    val = 0.75 + 0.25 * ((k * 5) % 2)
    return _hsv_to_rgb_u8(hue, sat.astype(np.float64), val.astype(np.float64))


# ------------------------------------------------------------------------------------------ public colours
def instance_color(ids: int | Iterable[int] | np.ndarray) -> np.ndarray:
    """Stable colour of each instance id: ``uint8 [N, 3]`` (``[1, 3]`` for a scalar).

    The colour is a function of the id alone (hue = frac(id / φ), S in {0.65, 0.825, 1}, V in {0.75, 1}),
    so the same id is the same colour in every picture, file and run; consecutive ids get very different
    hues. Ids ≤ 0 (stuff, void, no
    instance) are :data:`INSTANCE_NONE` grey.

    Parameters
    ----------
    ids : int or array_like of int
        Instance ids, any shape; the result is flattened to ``[N, 3]``.

    Returns
    -------
    np.ndarray
        ``uint8 [N, 3]`` RGB.

    Examples
    --------
    >>> c = instance_color([3, 0, 3, 4])
    >>> c.shape, c.dtype, bool((c[0] == c[2]).all()), bool((c[0] == c[3]).all()), c[1].tolist()
    ((4, 3), dtype('uint8'), True, False, [150, 150, 150])
    >>> instance_color(3).tolist() == instance_color(np.array([[3]])).tolist()  # scalar or any shape
    True
    """
    ids = np.asarray(ids, np.int64).reshape(-1)
    out = _hash_colors(ids)
    out[ids <= 0] = INSTANCE_NONE
    return out


def _class_lut(classes: Sequence[ClassInfo]) -> tuple[np.ndarray, np.ndarray]:
    """Sorted class ids and their colours, for ``searchsorted`` look-ups."""
    ids = np.array([c.id for c in classes], np.int64)
    cols = np.array([c.color for c in classes], np.uint8).reshape(-1, 3)
    order = np.argsort(ids)
    return ids[order], cols[order]


def semantic_color(ids: int | Iterable[int] | np.ndarray, classes: Any) -> np.ndarray:
    """Colour of each class id from the class table: ``uint8 [N, 3]``.

    Parameters
    ----------
    ids : int or array_like of int
        Category ids, any shape (flattened). 0 (void) and negative ids are :data:`VOID_COLOR`.
    classes : sequence of ClassInfo, or anything :func:`as_classes` accepts
        The class table. Ids missing from it get a stable hash colour of their own (distinct from the
        instance colours of the same number), so an unexpected class still shows up.

    Returns
    -------
    np.ndarray
        ``uint8 [N, 3]`` RGB.

    Examples
    --------
    >>> table = [{"id": 2, "name": "floor", "isthing": 0, "color": [152, 223, 138]}]
    >>> semantic_color([2, 0], table).tolist()
    [[152, 223, 138], [60, 60, 60]]
    >>> bool((semantic_color([9], table) == semantic_color([9], [])).all())  # unknown ids: stable, table-independent
    True
    """
    ids = np.asarray(ids, np.int64).reshape(-1)
    table = as_classes(classes)
    out = _hash_colors(ids, _UNKNOWN_CLASS_OFFSET)
    if table:
        known_ids, known_cols = _class_lut(table)
        pos = np.clip(np.searchsorted(known_ids, ids), 0, len(known_ids) - 1)
        hit = known_ids[pos] == ids
        out[hit] = known_cols[pos[hit]]
    out[ids <= 0] = VOID_COLOR
    return out


def stuff_tint(colors: np.ndarray, amount: float = _STUFF_TINT) -> np.ndarray:
    """Pull colours towards :data:`INSTANCE_NONE` grey, keeping ``amount`` of the original.

    Used for stuff in instance-coloured views: walls and floor stay distinguishable but grey-ish, so the
    vivid instance colours carry the picture.

    Examples
    --------
    >>> stuff_tint(np.array([[250, 150, 50]], np.uint8), 0.5).tolist()
    [[200, 150, 100]]
    """
    c = np.asarray(colors, np.float64)
    return np.clip(np.round(amount * c + (1.0 - amount) * np.asarray(INSTANCE_NONE, np.float64)), 0, 255).astype(
        np.uint8)


def panoptic_color(semantic: np.ndarray, instance: np.ndarray, classes: Any, *,
                   void_color: Sequence[int] = (0, 0, 0), tint_stuff: bool = False) -> np.ndarray:
    """Colourise panoptic labels: instance colour on things, class colour on stuff, ``void_color`` on void.

    Parameters
    ----------
    semantic : np.ndarray
        Category ids, any shape; 0 = void.
    instance : np.ndarray
        Instance ids of the same shape; > 0 on things (0 on stuff and void).
    classes : sequence of ClassInfo, or anything :func:`as_classes` accepts
        The class table.
    void_color : sequence of int
        RGB of void (default black, the usual background of 2D label maps).
    tint_stuff : bool
        Grey-ish stuff (:func:`stuff_tint`), as in the 3D instance views.

    Returns
    -------
    np.ndarray
        ``uint8 [..., 3]`` with the shape of ``semantic`` plus a colour axis.

    Examples
    --------
    >>> table = [ClassInfo(1, "wall", False, (10, 20, 30)), ClassInfo(3, "chair", True, (200, 0, 0))]
    >>> img = panoptic_color(np.array([[1, 3, 0]]), np.array([[0, 5, 0]]), table)
    >>> img.shape, img[0, 0].tolist(), bool((img[0, 1] == instance_color(5)[0]).all()), img[0, 2].tolist()
    ((1, 3, 3), [10, 20, 30], True, [0, 0, 0])
    """
    sem = np.asarray(semantic, np.int64)
    inst = np.asarray(instance, np.int64)
    if sem.shape != inst.shape:
        raise ValueError(f"semantic {sem.shape} and instance {inst.shape} maps differ in shape")
    flat_sem, flat_inst = sem.reshape(-1), inst.reshape(-1)
    # Colour each distinct id once (label maps hold few ids and many pixels).
    uniq_sem, sem_pos = np.unique(flat_sem, return_inverse=True)
    out = semantic_color(uniq_sem, classes)[sem_pos.reshape(-1)]
    if tint_stuff:
        out = stuff_tint(out)
    thing = (flat_inst > 0) & (flat_sem > 0)
    if thing.any():
        uniq_inst, inst_pos = np.unique(flat_inst[thing], return_inverse=True)
        out[thing] = instance_color(uniq_inst)[inst_pos.reshape(-1)]
    out[flat_sem <= 0] = np.asarray(void_color, np.uint8)
    return out.reshape(sem.shape + (3,))


def color_to_float(rgb: Sequence[int] | np.ndarray) -> tuple[float, ...]:
    """``(r, g, b)`` in 0..255 → floats in [0, 1] (what PyVista and matplotlib take).

    Examples
    --------
    >>> color_to_float((255, 0, 51))
    (1.0, 0.0, 0.2)
    """
    return tuple(float(x) / 255.0 for x in np.asarray(rgb).reshape(-1)[:3])


# ------------------------------------------------------------------------------------------ class tables
def as_classes(obj: Any, where: str | Path = "classes") -> list[ClassInfo]:
    """Normalise a class table given in any of the forms lift3d meets.

    Parameters
    ----------
    obj : None, sequence or mapping
        ``None`` (no table: ``[]``); a list of :class:`ClassInfo`; a list of dicts with ``id``, ``name``,
        ``isthing``, ``color`` (``classes.json`` and COCO ``categories``); a list of objects with those
        attributes (:class:`lift3d.data.scene.Category`); a dict with a ``categories`` or ``classes`` list;
        or a path to such a JSON file.
    where : str or Path
        Named in error messages.

    Returns
    -------
    list of ClassInfo

    Examples
    --------
    >>> as_classes([{"id": 4, "name": "chair", "isthing": 1, "color": [1, 2, 3]}])
    [ClassInfo(id=4, name='chair', isthing=True, color=(1, 2, 3))]
    >>> as_classes({"categories": [{"id": 1, "name": "wall"}]})[0].color == tuple(semantic_color(1, [])[0])
    True
    """
    if obj is None:
        return []
    if isinstance(obj, (str, Path)):
        return load_classes(obj)
    if isinstance(obj, Mapping):
        for key in ("categories", "classes"):
            if isinstance(obj.get(key), list):
                return as_classes(obj[key], where)
        raise InputError(where, "expected a list of classes (or a 'categories' / 'classes' list)")
    out: list[ClassInfo] = []
    for k, entry in enumerate(obj):
        if isinstance(entry, ClassInfo):
            out.append(entry)
            continue
        get = entry.get if isinstance(entry, Mapping) else (lambda key, d=None, e=entry: getattr(e, key, d))
        try:
            cid = int(get("id"))
        except (TypeError, ValueError):
            raise InputError(where, f"[{k}].id: missing or not an integer") from None
        color = get("color", None)
        if color is None:
            color = tuple(int(x) for x in _hash_colors(np.array([cid]), _UNKNOWN_CLASS_OFFSET)[0])
        try:
            rgb = tuple(int(x) for x in list(color)[:3])
        except (TypeError, ValueError):
            raise InputError(where, f"[{k}].color: expected [r, g, b], got {color!r}") from None
        if len(rgb) != 3 or not all(0 <= x <= 255 for x in rgb):
            raise InputError(where, f"[{k}].color: expected three integers in 0..255, got {color!r}")
        out.append(ClassInfo(cid, str(get("name", None) or f"class_{cid}"), bool(get("isthing", False)), rgb))
    return out


def load_classes(path: str | Path) -> list[ClassInfo]:
    """Read a class table: ``classes.json`` (a list of ``{id, name, isthing, color}``) or any JSON with a
    ``categories`` list (a scene's ``transforms.json``, a COCO panoptic JSON).

    Raises
    ------
    InputError
        The file is missing, not JSON, or not a class table.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "class table not found")
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(path, f"not a readable JSON file ({exc})") from exc
    if not isinstance(raw, (list, dict)):
        raise InputError(path, "expected a list of classes")
    return as_classes(raw, path)


def classes_beside(path: str | Path) -> Path | None:
    """The ``classes.json`` that ``lift3d export`` writes beside ``points.ply`` / ``mesh.ply``, if present.

    Examples
    --------
    >>> classes_beside("/nonexistent/points.ply") is None
    True
    """
    candidate = Path(path).with_name("classes.json")
    return candidate if candidate.is_file() else None
