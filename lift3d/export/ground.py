"""Where "up" is and what the ground is made of, for maps and the scene graph.

* :func:`resolve_up` — the scene's up axis: the mean up vector of the training cameras (OpenGL camera-to-world
  column 1, as nerfstudio orients scenes), snapped to the nearest signed world axis, or one the user names.
* :func:`floor_class_ids` — the walkable classes: names containing a word of :data:`FLOOR_WORDS`
  (``floor``, ``floor-wood``, ``rug-merged``, ``road``...), or the names/ids the user gives.
* :func:`map_frame` — a rotation taking the output frame to one whose +z is up (identity for z-up scenes).

Examples
--------
>>> import numpy as np
>>> c2w = np.tile(np.eye(4), (3, 1, 1))            # cameras whose up (column 1) is +y
>>> up, why = resolve_up("auto", c2w); up.tolist(), why.split(":")[0]
([0.0, 1.0, 0.0], 'mean up vector of 3 training cameras')
>>> resolve_up("-z", c2w)[0].tolist()
[0.0, 0.0, -1.0]
>>> classes = [{"id": 1, "name": "wall"}, {"id": 2, "name": "floor-wood"}, {"id": 3, "name": "rug-merged"}]
>>> floor_class_ids(classes), floor_class_ids(classes, ["wall"])
([2, 3], [1])
>>> (map_frame(np.array([0.0, 1.0, 0.0])) @ [0.0, 1.0, 0.0]).tolist()
[0.0, 0.0, 1.0]
"""

from __future__ import annotations

import re

import numpy as np

from lift3d.errors import InputError

#: Words that make a class walkable ground (matched against the words of its name).
FLOOR_WORDS = frozenset({
    "floor", "ground", "rug", "carpet", "mat", "road", "sidewalk", "pavement", "parking", "grass", "terrain",
    "dirt", "gravel", "sand", "snow", "path", "playingfield", "field", "platform", "runway", "lawn",
})

_AXES = {"x": 0, "y": 1, "z": 2}


def resolve_up(up: str, c2w: np.ndarray | None = None) -> tuple[np.ndarray, str]:
    """The up axis as a signed unit axis ``[3]``, and why.

    Parameters
    ----------
    up : str
        ``auto`` or one of ``x y z -x -y -z``.
    c2w : np.ndarray, optional
        ``[F, 4, 4]`` OpenGL camera-to-world poses (for ``auto``); without cameras ``auto`` is ``z``.
    """
    text = str(up).strip().lower()
    if text != "auto":
        sign, name = (-1.0, text[1:]) if text.startswith("-") else (1.0, text.lstrip("+"))
        if name not in _AXES:
            raise InputError("--up", f"expected auto, x, y, z, -x, -y or -z, got {up!r}")
        axis = np.zeros(3)
        axis[_AXES[name]] = sign
        return axis, f"--up {text}"
    if c2w is None or len(c2w) == 0:
        return np.array([0.0, 0.0, 1.0]), "no cameras: z"
    mean = np.asarray(c2w, np.float64)[:, :3, 1].mean(0)
    if not np.linalg.norm(mean) > 1e-6:
        return np.array([0.0, 0.0, 1.0]), "camera up vectors cancel out: z"
    k = int(np.argmax(np.abs(mean)))
    axis = np.zeros(3)
    axis[k] = np.sign(mean[k])
    angle = float(np.degrees(np.arccos(np.clip(abs(mean[k]) / np.linalg.norm(mean), -1, 1))))
    name = ("-" if axis[k] < 0 else "") + "xyz"[k]
    return axis, f"mean up vector of {len(c2w)} training cameras: {name} ({angle:.0f} deg from the axis)"


def floor_class_ids(classes, names=()) -> list[int]:
    """Ids of the walkable classes among ``classes`` (``classes.json`` rows or objects with id/name).

    ``names`` (class names or ids, as given to ``--floor-classes``) replaces the default rule; an unknown
    name is an :class:`InputError`.
    """
    rows = [(int(_get(c, "id")), str(_get(c, "name"))) for c in classes]
    if names:
        by_name = {n.lower(): i for i, n in rows}
        ids = {i for i, _ in rows}
        out = []
        for name in names:
            key = str(name).strip()
            if key.lower() in by_name:
                out.append(by_name[key.lower()])
            elif key.isdigit() and int(key) in ids:
                out.append(int(key))
            else:
                raise InputError("--floor-classes", f"unknown class {key!r} (classes: "
                                                    f"{', '.join(n for _, n in rows)})")
        return sorted(set(out))
    return sorted(i for i, n in rows if FLOOR_WORDS & set(re.split(r"[^a-z]+", n.lower())))


def map_frame(up: np.ndarray) -> np.ndarray:
    """``3×3`` rotation R with ``R @ up = +z`` (identity when up is +z; a proper rotation otherwise).

    For a signed axis it permutes axes cyclically (and flips two for a negative axis), so map x and y are
    world axes: a y-up scene maps ``(x, y, z) -> (z, x, y)``; ``-z`` maps to ``(x, -y, -z)``.
    """
    up = np.asarray(up, np.float64)
    k = int(np.argmax(np.abs(up)))
    perm = {0: [1, 2, 0], 1: [2, 0, 1], 2: [0, 1, 2]}[k]  # rows: map x, y, z taken from these world axes
    rot = np.eye(3)[perm]
    if up[k] < 0:
        rot = np.diag([1.0, -1.0, -1.0]) @ rot
    return rot


def _get(obj, key):
    return obj[key] if isinstance(obj, dict) else getattr(obj, key)
