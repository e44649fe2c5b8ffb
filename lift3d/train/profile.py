"""Which kind of scene this is, from what the scene shows: the profile that decides which priors may run.

The profiles and their premises are :mod:`lift3d.model.profiles`. The evidence, all of it recorded in
``config.yml`` under ``scene.profile``:

* ``bounded``: the scene space (:func:`lift3d.model.normalization.infer_normalization`); unbounded is
  ``outdoor``.
* ``outdoor_label_share``: the share of the training pseudo-labels' pixels whose class name is an outdoor
  word (:data:`OUTDOOR_WORDS`: sky, road, terrain...); more than :data:`OUTDOOR_SHARE` is ``outdoor``.
* planes of the content points (RANSAC, level or upright about the world's up, :func:`cameras_up` refined to
  the largest level plane): ``floor`` (a level plane below the cameras holding at least
  :data:`MIN_PLANE_SHARE` of the points), ``walls`` (upright planes, each that share, reaching above the
  cameras), ``ceiling``. A floor and two walls make a ``room``.
* ``cameras_inside``: the share of cameras inside the box of the content's middle 90 % (per axis). Without a
  room, a capture whose cameras stand outside what they look at, their optical axes meeting ahead of them
  (``axes_meet_ahead``), is an ``object`` capture; anything else is ``open``.
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
from lift3d.utils.geometry import level_up

#: Class-name words of outdoor scenes (matched against the words of a class name).
OUTDOOR_WORDS = frozenset({"sky", "road", "street", "sidewalk", "pavement", "terrain", "vegetation", "grass",
                           "parking", "railroad", "bridge", "mountain"})
#: More than this share of the labels' pixels of outdoor classes makes the scene ``outdoor``.
OUTDOOR_SHARE = 0.05
#: Class-name words of a room's enclosure.
ROOM_WORDS = frozenset({"wall", "ceiling"})
#: With a floor, at least this share of the labels' pixels of walls and ceilings says the walls are there even
#: when too few points lie on them to fit planes (plain walls give stereo next to nothing).
ROOM_LABEL_SHARE = 0.15
#: A plane counts (floor, wall, ceiling) when it holds at least this share of the content points.
MIN_PLANE_SHARE = 0.03
#: Inlier distance of the planes, as a share of the content's diagonal.
PLANE_THRESHOLD = 0.01
#: Walls within this many degrees of two directions at right angles are Manhattan walls.
MANHATTAN_DEG = 5.0
#: Share of the walls' points on Manhattan walls that makes the room a Manhattan room.
MANHATTAN_SHARE = 0.75
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
    outdoor word (:data:`OUTDOOR_WORDS`)."""
    return label_share(scene, frames, OUTDOOR_WORDS, max_frames)


def label_share(scene: Scene, frames: np.ndarray, words: frozenset[str], max_frames: int = 20) -> float:
    """Share of the pseudo-labels' labelled pixels (up to ``max_frames`` frames spread over ``frames``) of
    classes whose name has one of ``words``."""
    outdoor = [c.id for c in scene.categories if words & set(re.split(r"[^a-z]+", c.name.lower()))]
    if not outdoor or not len(frames) or not scene.has_pseudo_labels:
        return 0.0
    pick = np.asarray(frames)[np.linspace(0, len(frames) - 1, min(len(frames), max_frames)).round().astype(int)]
    hit = total = 0
    for i in np.unique(pick):
        sem = scene.pseudo_labels(int(i)).semantic
        hit += int(np.isin(sem, outdoor).sum())
        total += int((sem > 0).sum())
    return hit / total if total else 0.0


def cameras_up(c2w: np.ndarray) -> np.ndarray:
    """The world's up from camera-to-world poses ``[F, 4, 4]`` (OpenGL axes): :func:`lift3d.utils.geometry.level_up`
    when the cameras turn enough for it to be defined, else the mean of their image-up axes (which leans with their
    pitch).

    Examples
    --------
    Three cameras facing one way, 27° down: their right axes say nothing about up, their image-up axes lean.

    >>> from lift3d.data.cameras import look_at
    >>> c2w = np.stack([look_at(np.array([0.0, -3, 1.5]), np.array([0.0, 0, 0]))] * 3)
    >>> np.round(cameras_up(c2w), 3).tolist()
    [0.0, 0.447, 0.894]
    """
    c2w = np.asarray(c2w, np.float64)
    up = level_up(c2w)
    if up is not None:
        return up
    mean_up = c2w[:, :3, 1].mean(0)
    return mean_up / max(np.linalg.norm(mean_up), 1e-12)


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
    # The cameras' mean image-up leans with their pitch (25 degrees in a synthetic room whose views look down):
    # the largest plane within 25 degrees of it is level (as fit_planes refines it), and its normal is up.
    near_level = np.flatnonzero(np.abs(planes.normal @ up) > math.cos(math.radians(25))) if len(planes) else []
    if len(near_level):
        n = planes.normal[near_level[np.argmax(planes.inliers[near_level])]]
        up = n if n @ up > 0 else -n
    eye = float(np.median(cams @ up))
    out: dict[str, Any] = {"floor": False, "walls": 0, "ceiling": False, "manhattan": 0.0, "box_faces": None,
                           "planes": len(planes), "up": np.round(up, 4).tolist()}
    structural, wall_normals, wall_counts = [], [], []  # structural: (normal, offset, points) of floors and walls
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
            structural.append((n, d, len(pts)))
        elif abs(n @ up) < math.sin(math.radians(10)) and np.percentile(height, 98) > eye:  # upright, above the eye
            out["walls"] += 1
            horizontal = n - (n @ up) * up
            wall_normals.append(horizontal / np.linalg.norm(horizontal))
            wall_counts.append(len(pts))
            structural.append((n, d, len(pts)))
    if len(wall_normals) >= 2:
        out["manhattan"] = _manhattan_share(np.asarray(wall_normals), np.asarray(wall_counts, float), up)
    if box is not None and structural:
        normals, offsets, counts = (np.asarray(a, float) for a in zip(*structural))
        out["box_faces"] = box_face_share(normals, offsets, counts, box)
    return out


def box_face_share(normals: np.ndarray, offsets: np.ndarray, weights: np.ndarray, box: np.ndarray) -> float:
    """Share of ``weights`` (per plane ``n · x + d = 0``) on planes that lie on a face of the axis-aligned box
    ``[2, 3]``: normal within :data:`MANHATTAN_DEG` of an axis, at that face within :data:`BOX_FACE_TOLERANCE` of
    the box's diagonal.

    Examples
    --------
    >>> box = np.array([[0, 0, 0], [4, 3, 2.5]])
    >>> normals = np.array([[1.0, 0, 0], [0, 0, 1.0], [0.6, 0.8, 0]])
    >>> box_face_share(normals, np.array([-4.0, 0.0, -1.0]), np.array([2.0, 2.0, 1.0]), box)
    0.8
    """
    normals, offsets, weights = np.asarray(normals, float), np.asarray(offsets, float), np.asarray(weights, float)
    if not len(normals) or weights.sum() <= 0:
        return 0.0
    k = np.argmax(np.abs(normals), axis=1)
    along = np.abs(normals[np.arange(len(k)), k])
    position = -offsets / np.where(along > 0, normals[np.arange(len(k)), k], 1.0)
    tol = BOX_FACE_TOLERANCE * float(np.linalg.norm(box[1] - box[0]))
    near = np.minimum(np.abs(position - box[0][k]), np.abs(position - box[1][k])) <= tol
    on = near & (along >= math.cos(math.radians(MANHATTAN_DEG)))
    return float(weights[on].sum() / weights.sum())


def premises_from_planes(planes, up: np.ndarray, box: np.ndarray | None) -> tuple[frozenset[str], dict[str, Any]]:
    """A room's premises from its stuff planes (the depth targets' planes, fitted with the labels): ``room``
    always, ``manhattan`` when two upright planes or more hold at least :data:`MANHATTAN_SHARE` of the upright
    planes' points on two directions at right angles, ``box`` when a scene box is given and at least
    :data:`BOX_SHARE` of the level and upright planes' points lie on its faces. Returns them and the evidence.

    Plain walls give stereo next to nothing, so the content points before training may not show whether a
    room's walls are square; the stuff planes (which also take the walls' feet from the labels) do."""
    normals, inliers = np.asarray(planes.normal, float), np.asarray(planes.inliers, float)
    tilt = np.abs(normals @ up)
    upright = tilt < math.sin(math.radians(10))
    level = tilt > math.cos(math.radians(10))
    ev: dict[str, Any] = {"upright_planes": int(upright.sum()), "manhattan": 0.0, "box_faces": None}
    if upright.sum() >= 2:
        horizontal = normals[upright] - np.outer(normals[upright] @ up, up)
        horizontal /= np.linalg.norm(horizontal, axis=1, keepdims=True)
        ev["manhattan"] = round(_manhattan_share(horizontal, inliers[upright], up), 4)
    premises = {"room"}
    if upright.sum() >= 2 and ev["manhattan"] >= MANHATTAN_SHARE:
        premises.add("manhattan")
    if box is not None:
        keep = upright | level
        ev["box_faces"] = round(box_face_share(normals[keep], np.asarray(planes.offset, float)[keep], inliers[keep],
                                               box), 4)
        if ev["box_faces"] >= BOX_SHARE:
            premises.add("box")
    return frozenset(premises), ev


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
    up = cameras_up(scene.cameras.c2w[train])
    ev: dict[str, Any] = {"bounded": bool(norm.bounded), "outdoor_label_share": round(outdoor_label_share(scene, train), 4),
                          "room_label_share": round(label_share(scene, train, ROOM_WORDS), 4)}
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
    walls_labelled = ev.get("room_label_share", 0.0) >= ROOM_LABEL_SHARE
    if ev["floor"] and (ev["walls"] >= 2 or walls_labelled):
        room = (f"a level floor below the cameras and {ev['walls']} upright walls rising above them" if ev["walls"] >= 2
                else f"a level floor below the cameras, and walls or ceiling in {ev['room_label_share']:.0%} of the "
                     "labels' pixels")
        if ev["walls"] >= 2 and ev["manhattan"] >= MANHATTAN_SHARE:
            return "manhattan-room", f"{room}, {ev['manhattan']:.0%} of the walls' points at right angles"
        return "room", f"{room}; walls at right angles hold {ev['manhattan']:.0%} of their points"
    if ev["cameras_inside"] < INSIDE_SHARE and ev["axes_meet_ahead"] > 0.8:
        return "object", (f"no room around the cameras; {ev['cameras_inside']:.0%} of them inside the content, their "
                          f"optical axes meet ahead of {ev['axes_meet_ahead']:.0%} of them: a capture around an object")
    return "open", (f"no room around the cameras (floor: {'yes' if ev['floor'] else 'no'}, {ev['walls']} walls "
                    "rising above them)")


def refined_profile(profile: dict[str, Any], premises: list[str], evidence: dict[str, Any]) -> dict[str, Any]:
    """``config.yml``'s ``scene.profile`` after the depth targets' stuff planes decided a room's premises
    (:func:`premises_from_planes`): the name follows them (``manhattan-room`` with square walls, else ``room``).

    Examples
    --------
    >>> p = {"name": "room", "premises": ["room"], "why": "a floor", "evidence": {}}
    >>> r = refined_profile(p, ["manhattan", "room"], {"manhattan": 0.97})
    >>> r["name"], r["premises"], r["evidence"]["stuff_planes"]
    ('manhattan-room', ['manhattan', 'room'], {'manhattan': 0.97})
    """
    name = "manhattan-room" if "manhattan" in premises else "room"
    why = (f"{profile.get('why', '')}; the stuff planes (with the labels' wall feet): {evidence.get('upright_planes')} "
           f"upright, {evidence.get('manhattan', 0):.0%} of their points at right angles"
           + ("" if evidence.get("box_faces") is None else f", {evidence['box_faces']:.0%} on the scene box's faces"))
    return {**profile, "name": name, "premises": sorted(premises), "why": why,
            "evidence": {**profile.get("evidence", {}), "stuff_planes": evidence}}
