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
``categories``); :func:`lift3d.data.categories.read_class_table` reads either.

Examples
--------
>>> instance_color([7, 7, 0]).tolist() == [instance_color(7).tolist()[0]] * 2 + [list(INSTANCE_NONE)]
True
>>> from lift3d.data.categories import Category
>>> classes = [Category(1, "wall", False, (174, 199, 232)), Category(6, "table", True, (255, 127, 14))]
>>> semantic_color([6, 1, 0], classes).tolist()
[[255, 127, 14], [174, 199, 232], [60, 60, 60]]
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from lift3d.data.categories import UNKNOWN_CLASS_OFFSET, Category, as_class_table
from lift3d.utils.colors import hash_colors

__all__ = [
    "INSTANCE_NONE",
    "VOID_COLOR",
    "instance_color",
    "semantic_color",
    "stuff_tint",
    "panoptic_color",
    "classes_beside",
    "color_to_float",
]

#: Colour of instance id 0 (stuff, void, "no instance") in instance-coloured pictures: neutral grey.
INSTANCE_NONE = (150, 150, 150)
#: Colour of semantic id 0 (void) and of pixels / points without a label: dark grey.
VOID_COLOR = (60, 60, 60)

# How much of the class colour a stuff region keeps in instance-coloured views (the rest is grey).
_STUFF_TINT = 0.3


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
    out = hash_colors(ids)
    out[ids <= 0] = INSTANCE_NONE
    return out


def _class_lut(classes: Sequence[Category]) -> tuple[np.ndarray, np.ndarray]:
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
    classes : sequence of Category, or anything :func:`~lift3d.data.categories.as_class_table` accepts
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
    table = as_class_table(classes)
    out = hash_colors(ids, UNKNOWN_CLASS_OFFSET)
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
    classes : sequence of Category, or anything :func:`~lift3d.data.categories.as_class_table` accepts
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
    >>> table = [Category(1, "wall", False, (10, 20, 30)), Category(3, "chair", True, (200, 0, 0))]
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
def classes_beside(path: str | Path) -> Path | None:
    """The ``classes.json`` that ``lift3d export`` writes beside ``points.ply`` / ``mesh.ply``, if present.

    Examples
    --------
    >>> classes_beside("/nonexistent/points.ply") is None
    True
    """
    candidate = Path(path).with_name("classes.json")
    return candidate if candidate.is_file() else None
