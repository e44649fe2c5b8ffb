"""Which kind of scene this is, from what the scene shows: the profile that decides which priors may run.

The profiles and their premises are :mod:`lift3d.model.profiles`. The evidence, all of it recorded in
``config.yml`` under ``scene.profile``:

* ``bounded``: the scene space (:func:`lift3d.model.normalization.infer_normalization`); unbounded is
  ``outdoor``.
* ``outdoor_label_share``: the share of the training pseudo-labels' pixels whose class name is an outdoor
  word (:data:`OUTDOOR_WORDS`: sky, road, terrain...); more than :data:`OUTDOOR_SHARE` is ``outdoor``.
* ``cameras_inside``: the share of cameras inside the box of the content's middle 90 % (per axis). A capture
  around an object has its cameras outside what it looks at (and their optical axes meet ahead of them:
  ``axes_meet_ahead``): ``object``.
* planes of the content points (RANSAC, level or upright about the cameras' up): ``floor`` (a level plane
  below the cameras holding at least :data:`MIN_PLANE_SHARE` of the points), ``walls`` (upright planes, each
  that share, reaching above the cameras), ``ceiling``. A floor and two walls make a ``room``.
* ``manhattan``: the share of the walls' points on walls within :data:`MANHATTAN_DEG` of two directions at
  right angles; at least :data:`MANHATTAN_SHARE` with two walls or more makes it a ``manhattan-room``.
* ``box_faces``: with a ``scene_box``, the share of the floor's and walls' points within
  :data:`BOX_FACE_TOLERANCE` of the box's diagonal of one of its faces: at least :data:`BOX_SHARE` is the
  ``box`` premise (the scene box is the room: rays may stop at it, its faces may be filled).

``--profile NAME`` overrides the choice (the evidence is still recorded); ``box`` then still needs a
``scene_box``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lift3d.data.scene import Scene
from lift3d.model.normalization import ContentPoints, SceneNormalization, optical_axes_focus
from lift3d.model.profiles import PROFILES, premises_of

#: Class-name words of outdoor scenes (matched against the words of a class name).
OUTDOOR_WORDS = frozenset({"sky", "road", "street", "sidewalk", "pavement", "terrain", "vegetation", "grass",
                           "parking", "railroad", "bridge", "mountain"})
#: More than this share of the labels' pixels of outdoor classes makes the scene ``outdoor``.
OUTDOOR_SHARE = 0.05
#: A plane counts (floor, wall, ceiling) when it holds at least this share of the content points.
MIN_PLANE_SHARE = 0.03
#: Inlier distance of the planes, as a share of the content's diagonal.
PLANE_THRESHOLD = 0.01
#: Walls within this many degrees of two directions at right angles are Manhattan walls.
MANHATTAN_DEG = 5.0
#: Share of the walls' points on Manhattan walls that makes the room a Manhattan room.
MANHATTAN_SHARE = 0.9
#: A point within this share of the box's diagonal of a face of the scene box lies on it.
BOX_FACE_TOLERANCE = 0.02
#: Share of the floor's and walls' points on the box's faces that makes the box the room.
BOX_SHARE = 0.5
#: Fewer cameras inside the content than this share, with optical axes that meet ahead: an object capture.
INSIDE_SHARE = 0.5
#: Content points used (a random sample, seeded).
MAX_POINTS = 50_000


@dataclass
class ProfileChoice:
    """The profile, its premises, the evidence and the reason (``config.yml``'s ``scene.profile``)."""

    name: str
    premises: list[str]
    why: str
    evidence: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "premises": list(self.premises), "why": self.why, "evidence": self.evidence}


def outdoor_label_share(scene: Scene, frames: np.ndarray, max_frames: int = 20) -> float:
    """Share of the pseudo-labels' labelled pixels (up to ``max_frames`` frames) of classes whose name has an
    outdoor word."""
    outdoor = [c.id for c in scene.categories if OUTDOOR_WORDS & set(re.split(r"[^a-z]+", c.name.lower()))]
    if not outdoor or not len(frames) or not scene.has_pseudo_labels:
        return 0.0
    pick = np.asarray(frames)[np.linspace(0, len(frames) - 1, min(len(frames), max_frames)).round().astype(int)]
    hit = total = 0
    for i in np.unique(pick):
        sem = scene.pseudo_labels(int(i)).semantic
        hit += int(np.isin(sem, outdoor).sum())
        total += int((sem > 0).sum())
    return hit / total if total else 0.0


def _cameras_up(scene: Scene) -> np.ndarray:
    up = scene.cameras.c2w[:, :3, 1].mean(0)  # OpenGL camera y = image up
    n = np.linalg.norm(up)
    return up / n if n > 1e-6 else np.array([0.0, 0.0, 1.0])


def plane_evidence(xyz: np.ndarray, cams: np.ndarray, up: np.ndarray, box: np.ndarray | None) -> dict[str, Any]:
    """Floor, walls and ceiling of the content points ``[N, 3]`` around the cameras ``[F, 3]`` (see the module
    docstring), with the Manhattan share and, given a box ``[2, 3]``, the share of their points on its faces.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> floor = np.c_[rng.uniform(-3, 3, (600, 2)), np.zeros(600)]
    >>> walls = [np.c_[np.full(300, x), rng.uniform(-3, 3, 300), rng.uniform(0, 2.5, 300)] for x in (-3, 3)]
    >>> walls += [np.c_[rng.uniform(-3, 3, 300), np.full(300, y), rng.uniform(0, 2.5, 300)] for y in (-3, 3)]
    >>> cams = np.c_[rng.uniform(-1, 1, (10, 2)), np.full(10, 1.5)]
    >>> e = plane_evidence(np.concatenate([floor] + walls), cams, np.array([0, 0, 1.0]),
    ...                    np.array([[-3, -3, 0], [3, 3, 2.5]]))
    >>> e["floor"], e["walls"], e["ceiling"], round(e["manhattan"], 2), round(e["box_faces"], 2)
    (True, 4, False, 1.0, 1.0)
    """
    # here, not at module level: keeps `import lift3d.train` cheap (lift3d.sfm loads OpenCV)
    from lift3d.sfm.planes import fit_planes

    diag = float(np.linalg.norm(np.ptp(xyz, axis=0)))
    threshold = PLANE_THRESHOLD * diag
    min_points = max(20, int(MIN_PLANE_SHARE * len(xyz)))
    planes = fit_planes(xyz, np.ones(len(xyz), np.int64), [1], threshold=threshold, min_points=min_points, up=up)
    eye = float(np.median(cams @ up))
    out: dict[str, Any] = {"floor": False, "walls": 0, "ceiling": False, "manhattan": 0.0, "box_faces": None,
                           "planes": len(planes)}
    structural, wall_normals, wall_counts = [], [], []
    for k in range(len(planes)):
        n, d = planes.normal[k], float(planes.offset[k])
        on = np.abs(xyz @ n + d) <= threshold
        if on.sum() < min_points:
            continue
        pts = xyz[on]
        height = pts @ up
        if abs(n @ up) > math.cos(math.radians(10)):  # level
            if np.median(height) < eye:
                out["floor"] = True
            else:
                out["ceiling"] = True
            structural.append(pts)
        elif abs(n @ up) < math.sin(math.radians(10)) and np.percentile(height, 98) > eye:  # upright, above the eye
            out["walls"] += 1
            horizontal = n - (n @ up) * up
            wall_normals.append(horizontal / np.linalg.norm(horizontal))
            wall_counts.append(len(pts))
            structural.append(pts)
    if len(wall_normals) >= 2:
        out["manhattan"] = _manhattan_share(np.asarray(wall_normals), np.asarray(wall_counts, float), up)
    if box is not None and structural:
        pts = np.concatenate(structural)
        tol = BOX_FACE_TOLERANCE * float(np.linalg.norm(box[1] - box[0]))
        on_face = np.any(np.abs(pts[:, :, None] - box.T[None]) <= tol, axis=(1, 2))
        out["box_faces"] = float(on_face.mean())
    return out


def _manhattan_share(normals: np.ndarray, counts: np.ndarray, up: np.ndarray) -> float:
    """Share of the walls' points (``counts``) on walls within :data:`MANHATTAN_DEG` of the two directions at
    right angles that hold the most (the walls' directions modulo 90°, tried at each wall)."""
    side = np.cross(up, normals[0])
    side /= np.linalg.norm(side)
    angles = np.degrees(np.arctan2(normals @ side, normals @ normals[0])) % 90.0
    best = 0.0
    for a in angles:
        off = np.abs((angles - a + 45.0) % 90.0 - 45.0)
        best = max(best, float(counts[off <= MANHATTAN_DEG].sum() / counts.sum()))
    return best


def choose_profile(scene: Scene, norm: SceneNormalization, content: ContentPoints | None,
                   override: str = "auto") -> ProfileChoice:
    """The scene's profile from its evidence (module docstring), or ``override``.

    Parameters
    ----------
    scene : Scene
    norm : SceneNormalization
        The scene space (bounded or not, the box).
    content : ContentPoints or None
        Where the surfaces are (depth maps or triangulated points); without any, only the labels and the
        camera layout speak.
    override : str
        ``auto`` or a profile name (``--profile``).
    """
    train = scene.split("train")
    cams = scene.cameras.centers[train]
    up = _cameras_up(scene)
    ev: dict[str, Any] = {"bounded": bool(norm.bounded), "outdoor_label_share": round(outdoor_label_share(scene, train), 4)}
    _, ahead = optical_axes_focus(scene)
    ev["axes_meet_ahead"] = round(ahead, 3)
    xyz = None
    if content is not None and len(content.xyz):
        xyz = np.asarray(content.xyz, np.float64)
        if len(xyz) > MAX_POINTS:
            xyz = xyz[np.random.default_rng(0).choice(len(xyz), MAX_POINTS, replace=False)]
        lo, hi = np.percentile(xyz, [5, 95], axis=0)
        ev["cameras_inside"] = round(float(np.mean(np.all((cams >= lo) & (cams <= hi), axis=1))), 3)
        box = np.asarray(scene.scene_box.aabb, float) if scene.scene_box is not None else None
        ev.update(plane_evidence(xyz, cams, up, box))
        ev["content"] = content.source
    name, why = _decide(ev)
    if override != "auto":
        premises_of(override)  # an unknown name is one line naming --profile
        name, why = override, f"--profile {override} (the evidence said {name}: {why})"
    premises = set(PROFILES[name])
    if "box" in premises and not (ev.get("box_faces") is not None and ev["box_faces"] >= BOX_SHARE):
        premises.discard("box")
        why += ("; no box premise: " + ("no scene_box" if scene.scene_box is None else
                                          f"{ev.get('box_faces') or 0:.0%} of the floor's and walls' points on the "
                                          f"scene box's faces (< {BOX_SHARE:.0%})"))
    return ProfileChoice(name, sorted(premises), why, ev)


def _decide(ev: dict[str, Any]) -> tuple[str, str]:
    if not ev["bounded"]:
        return "outdoor", "unbounded space (the content reaches far beyond the cameras)"
    if ev["outdoor_label_share"] > OUTDOOR_SHARE:
        return "outdoor", f"{ev['outdoor_label_share']:.0%} of the labels' pixels are outdoor classes (sky, road...)"
    if "cameras_inside" not in ev:
        return "open", "no depth maps or triangulated points to say what the scene's surfaces are"
    if ev["cameras_inside"] < INSIDE_SHARE and ev["axes_meet_ahead"] > 0.8:
        return "object", (f"{ev['cameras_inside']:.0%} of the cameras inside the content, their optical axes meet "
                          f"ahead of {ev['axes_meet_ahead']:.0%} of them: a capture around an object")
    if ev["floor"] and ev["walls"] >= 2:
        room = f"a level floor below the cameras and {ev['walls']} upright walls rising above them"
        if ev["manhattan"] >= MANHATTAN_SHARE:
            return "manhattan-room", f"{room}, {ev['manhattan']:.0%} of the walls' points at right angles"
        return "room", f"{room}; walls at right angles hold {ev['manhattan']:.0%} of their points"
    return "open", (f"no room around the cameras (floor: {'yes' if ev['floor'] else 'no'}, {ev['walls']} walls "
                    "rising above them)")
