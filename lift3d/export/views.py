"""Export labels checked against what the training views' 2D labels say at each point.

The field's label heads are smooth at the scale of their grid's cells (10–20 cm in a room): a chair's label
spreads onto the floor around its legs, a table's edge against a wall takes the wall's. The 2D pseudo-labels
are noisy per view but sharp: at 128² a pixel is 4 cm across at 4 m. So each exported point is projected into
every training view; a view *sees* the point when it lands inside the image, in front of the camera, at the
view's depth there (the view's own depth map, or the field's rendered depth for a view without one) to within
``rel_tolerance`` of its depth plus ``abs_tolerance``. Each view that sees the point and labels it (not void)
casts one vote for that class. A point takes the class most of its votes name when at least ``min_views``
views voted and that class has at least ``share`` of the votes; otherwise the field's label stays.

This is the multi-view label fusion of classical semantic mapping (each surface element accumulates the class
evidence of the frames that observe it), used here as a check on the field: where the views agree the field
is overruled, where they do not (occlusion edges, a segmenter's view-dependent mistakes) the field decides.

Examples
--------
Two points, three views voting: the first is seen by all three as class 5, the second by one only:

>>> import numpy as np
>>> counts = np.array([[0, 0, 3], [0, 1, 0]], np.uint16)   # classes [0, 2, 5]
>>> vote_labels(np.array([2, 2]), counts, np.array([0, 2, 5]), min_views=2, share=0.6)[0].tolist()
[5, 2]
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Callable

import cv2
import numpy as np
from scipy.spatial import cKDTree

from lift3d.data.scene import Scene
from lift3d.render.images import render_frame

#: A rendered pixel has a depth when its ray's accumulated opacity reaches this (nerfstudio's rule for its point
#: clouds).
VOTE_MIN_OPACITY = 0.5
#: Fewest views that must see and label a point before their vote can change its class.
VOTE_MIN_VIEWS = 2
#: Share of those votes the winning class needs.
VOTE_SHARE = 0.6
#: A view sees a point when the point's depth is within this fraction of the view's depth there (plus the
#: absolute tolerance, about half a grid cell of the field).
VOTE_REL_TOLERANCE = 0.03
#: Rays rendered over the views that have no depth map of their own (downscaled to stay below).
VOTE_MAX_RAYS = 1_500_000
#: Points whose votes are counted at once (the counts are points × classes).
VOTE_CHUNK = 262_144
#: The vote is taken on at most this many points of a larger cloud; the rest follow their nearest (the
#: projections cost ~60 ms per view for a million points).
VOTE_MAX_POINTS = 250_000


def view_depths(scene: Scene, frames, render: Callable[[int, int], np.ndarray] | None,
                max_rays: int = VOTE_MAX_RAYS, own_depth: bool = True) -> dict[int, tuple[np.ndarray, int]]:
    """Depth (world units, 0 = unknown) of each view in ``frames`` and the downscale it is at.

    A view's own depth map is used as it is (unless ``own_depth`` is False); the other views are rendered by
    ``render(i, downscale)`` (``None``: they are left out), all at one downscale that keeps their rays under
    ``max_rays``.
    """
    out: dict[int, tuple[np.ndarray, int]] = {}
    missing = []
    for i in frames:
        d = scene.depth(int(i)) if own_depth else None
        if d is None:
            missing.append(int(i))
        else:
            out[int(i)] = (d, 1)
    if missing and render is not None:
        cams = scene.cameras
        total = float(sum(int(cams.width[i]) * int(cams.height[i]) for i in missing))
        ds = max(1, int(math.ceil(math.sqrt(total / max(1, max_rays)))))
        for i in missing:
            out[i] = (render(i, ds), ds)
    return out


def view_label_counts(xyz: np.ndarray, scene: Scene, depths: dict[int, tuple[np.ndarray, int]],
                      class_ids: np.ndarray, abs_tolerance: float,
                      rel_tolerance: float = VOTE_REL_TOLERANCE) -> np.ndarray:
    """``uint16 [N, C]``: how many views see each point and label it each class of ``class_ids``.

    Parameters
    ----------
    xyz : np.ndarray
        ``[N, 3]`` points in the scene's (world) frame.
    scene : Scene
        Its cameras and 2D pseudo-labels.
    depths : dict
        Frame → (depth ``[h, w]`` in world units at the frame's resolution divided by the downscale,
        downscale), from :func:`view_depths`: the views that vote.
    class_ids : np.ndarray
        Sorted category ids (void excluded): the columns.
    abs_tolerance, rel_tolerance : float
        A view sees a point when ``|z - depth| < abs_tolerance + rel_tolerance · z``.
    """
    xyz = np.asarray(xyz, np.float64)
    class_ids = np.asarray(class_ids, np.int64)
    lut = np.full(int(class_ids.max(initial=0)) + 2, -1, np.int64)
    lut[class_ids] = np.arange(len(class_ids))
    counts = np.zeros((len(xyz), len(class_ids)), np.uint16)
    for i, (depth, ds) in depths.items():
        sem = scene.pseudo_labels(i).semantic
        h, w = sem.shape
        uv, z = scene.cameras.project(i, xyz)
        with np.errstate(invalid="ignore"):
            k = np.flatnonzero((z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h))
        r, c = uv[k, 1].astype(np.int64), uv[k, 0].astype(np.int64)
        dh, dw = depth.shape
        d = depth[np.minimum(r // ds, dh - 1), np.minimum(c // ds, dw - 1)]
        seen = (d > 0) & (np.abs(z[k] - d) < abs_tolerance + rel_tolerance * z[k])
        label = sem[r[seen], c[seen]].astype(np.int64)
        col = lut[np.clip(label, 0, len(lut) - 1)]
        ok = (label > 0) & (label < len(lut)) & (col >= 0)
        counts[k[seen][ok], col[ok]] += np.uint16(1)  # one vote per view and point: no repeated indices
    return counts


def views_on_surface(xyz: np.ndarray, scene: Scene, depths: dict[int, tuple[np.ndarray, int]],
                     tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """``int [N]`` each: how many views' surfaces pass through each point, and how many views have a surface
    (a depth) at the point's pixel at all. A view's surface passes through a point that lands in its image, in
    front of it, within ``tolerance`` (world units) of the depths the view has around that pixel (its 3 × 3
    neighbours' range: a surface seen at a grazing angle spans many depths within one pixel) (:func:`view_depths`).

    Examples
    --------
    One view looking down -z at a wall 2 units away: a point on the wall is on its surface; one 0.5 behind it
    is not.

    >>> from lift3d.data.cameras import Cameras
    >>> cams = Cameras(c2w=np.eye(4)[None], fx=10.0, fy=10.0, cx=10.0, cy=10.0, width=20, height=20)
    >>> class S: cameras = cams
    >>> xyz = np.array([[0.0, 0.0, -2.0], [0.0, 0.0, -2.5]])
    >>> on, covered = views_on_surface(xyz, S(), {0: (np.full((20, 20), 2.0), 1)}, tolerance=0.1)
    >>> on.tolist(), covered.tolist()
    ([1, 0], [1, 1])
    """
    xyz = np.asarray(xyz, np.float64)
    count = np.zeros(len(xyz), np.int64)
    covered = np.zeros(len(xyz), np.int64)
    cams = scene.cameras
    kernel = np.ones((3, 3), np.uint8)
    for i, (depth, ds) in depths.items():
        depth = np.asarray(depth, np.float32)
        valid = depth > 0
        low = cv2.erode(np.where(valid, depth, np.inf).astype(np.float32), kernel)
        high = cv2.dilate(np.where(valid, depth, 0.0).astype(np.float32), kernel)
        h, w = int(cams.height[i]), int(cams.width[i])
        uv, z = cams.project(i, xyz)
        with np.errstate(invalid="ignore"):
            k = np.flatnonzero((z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h))
        dh, dw = depth.shape
        r = np.minimum(uv[k, 1].astype(np.int64) // ds, dh - 1)
        c = np.minimum(uv[k, 0].astype(np.int64) // ds, dw - 1)
        has = valid[r, c]
        on = has & (z[k] >= low[r, c] - tolerance) & (z[k] <= high[r, c] + tolerance)
        count[k[on]] += 1
        covered[k[has]] += 1
    return count, covered


def vote_labels(semantic: np.ndarray, counts: np.ndarray, class_ids: np.ndarray, *, min_views: int = VOTE_MIN_VIEWS,
                share: float = VOTE_SHARE, targets=None) -> tuple[np.ndarray, np.ndarray]:
    """New labels where the views agree (module docstring): ``(semantic [N], changed [N] bool)``.

    ``targets``: the classes a point may be given (default any)."""
    total = counts.sum(1, dtype=np.int64)
    best = counts.argmax(1)
    top = counts[np.arange(len(counts)), best].astype(np.int64)
    winner = np.asarray(class_ids, np.int64)[best]
    changed = (total >= int(min_views)) & (top >= share * total) & (winner != semantic)
    if targets is not None:
        changed &= np.isin(winner, list(targets))
    out = np.where(changed, winner, semantic).astype(np.asarray(semantic).dtype)
    return out, changed


@dataclass(frozen=True)
class VoteRules:
    """How the views vote (module docstring); the defaults are the module constants."""

    min_views: int = VOTE_MIN_VIEWS
    share: float = VOTE_SHARE
    rel_tolerance: float = VOTE_REL_TOLERANCE
    max_rays: int = VOTE_MAX_RAYS
    max_points: int = VOTE_MAX_POINTS
    seed: int = 0


def vote_point_labels(xyz_world: np.ndarray, semantic: np.ndarray, scene: Scene, frames,
                      render: Callable[[int, int], np.ndarray] | None, abs_tolerance: float, *, targets=None,
                      rules: VoteRules = VoteRules()) -> tuple[np.ndarray, dict[str, Any]]:
    """The export step: labels of ``xyz_world`` after the training views' vote, and what it did.

    With more than ``rules.max_points`` points the vote is taken on a random subset of that many (fixed
    ``rules.seed``); every other point follows its nearest measured point when that one had its class and changed.

    Returns
    -------
    semantic : np.ndarray
        ``[N]`` category ids.
    stats : dict
        ``changed`` (points), ``changes`` (``"from->to": points``), ``views`` (how many voted), ``rendered``
        (of those, rendered because they have no depth map), ``median_votes`` and the settings, for
        ``metadata.json``.
    """
    t0 = time.perf_counter()
    min_views, share, rel_tolerance, max_points = rules.min_views, rules.share, rules.rel_tolerance, rules.max_points
    semantic = np.asarray(semantic)
    xyz_world = np.asarray(xyz_world, np.float64)
    depths = view_depths(scene, frames, render, rules.max_rays)
    class_ids = np.asarray(sorted(c.id for c in scene.categories if c.id != 0), np.int64)
    measured = np.arange(len(semantic))
    if len(semantic) > max_points:
        measured = np.sort(np.random.default_rng(rules.seed).choice(len(semantic), max_points, replace=False))
    new = semantic[measured].copy()
    votes = np.zeros(len(measured), np.int64)
    for s in range(0, len(measured), VOTE_CHUNK):
        part = measured[s:s + VOTE_CHUNK]
        counts = view_label_counts(xyz_world[part], scene, depths, class_ids, abs_tolerance, rel_tolerance)
        new[s:s + VOTE_CHUNK], _ = vote_labels(semantic[part], counts, class_ids, min_views=min_views, share=share,
                                               targets=targets)
        votes[s:s + VOTE_CHUNK] = counts.sum(1, dtype=np.int64)
    out = semantic.copy()
    out[measured] = new
    hit = new != semantic[measured]
    if hit.any() and len(measured) < len(semantic):
        # The other points follow their nearest measured point when it had their class and changed: only
        # points near a changed one can, so those are found against the (small) tree of changed points first.
        rest = np.setdiff1d(np.arange(len(semantic)), measured, assume_unique=True)
        tree = cKDTree(xyz_world[measured])
        spacing = np.median(tree.query(xyz_world[measured[:: max(1, len(measured) // 2000)]], k=2)[0][:, 1])
        d, _ = cKDTree(xyz_world[measured[hit]]).query(xyz_world[rest], distance_upper_bound=4.0 * spacing,
                                                       workers=-1)
        near = rest[np.isfinite(d)]
        if len(near):
            _, j = tree.query(xyz_world[near], workers=-1)
            follow = hit[j] & (semantic[measured[j]] == semantic[near])
            out[near[follow]] = new[j[follow]]
    changed = np.flatnonzero(out != semantic)
    pairs, n = np.unique(np.stack([semantic[changed], out[changed]], 1), axis=0, return_counts=True) \
        if len(changed) else (np.zeros((0, 2), np.int64), np.zeros(0, np.int64))
    stats = {"changed": int(len(changed)), "changes": {f"{int(a)}->{int(b)}": int(k) for (a, b), k in zip(pairs, n)},
             "views": len(depths), "rendered": int(sum(scene.frames[i].depth_path is None for i in depths)),
             "median_votes": float(np.median(votes)) if len(votes) else 0.0, "measured": int(len(measured)),
             "min_views": int(min_views), "share": float(share), "abs_tolerance": float(abs_tolerance),
             "rel_tolerance": float(rel_tolerance), "seconds": round(time.perf_counter() - t0, 3)}
    return out, stats


def rendered_depth(loaded, scene: Scene, cache: dict | None = None) -> Callable[[int, int], np.ndarray]:
    """``render(i, downscale)``: the field's z-depth (world units) of training view ``i`` at that downscale
    (:func:`lift3d.render.images.render_frame`, the pixels of ``downscale`` blocks' centres), 0 where the ray's
    opacity is under :data:`VOTE_MIN_OPACITY`.

    ``cache``: a dict the caller keeps for one loaded run and scene; renders are stored in it by (view,
    downscale) and reused, so an export of points and mesh renders each view once."""
    rays = loaded.rays(scene)

    def render(i: int, ds: int) -> np.ndarray:
        key = (int(i), int(ds))
        if cache is not None and key in cache:
            return cache[key]
        fr = render_frame(loaded.model, rays, i, loaded.norm.scale, downscale=ds, with_labels=False)
        depth = np.where(fr.opacity >= VOTE_MIN_OPACITY, fr.depth, 0.0).astype(np.float32)
        if cache is not None:
            cache[key] = depth
        return depth

    return render


def vote_stuff_labels(xyz_world: np.ndarray, semantic: np.ndarray, channel: np.ndarray, loaded, scene: Scene,
                      frames, abs_tolerance: float, depth_cache: dict | None = None, rules: VoteRules = VoteRules()
                      ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """The export step (points and mesh vertices): :func:`vote_point_labels` with the field's rendered depth
    for views without a depth map, giving stuff classes only (a thing needs an instance, which a vote cannot
    give); a point that leaves a thing class leaves its instance channel too.

    ``depth_cache``: see :func:`rendered_depth`; ``rules``: :class:`VoteRules`. Returns the new ``semantic`` and
    ``channel`` ``[N]`` and the
    step's record for ``metadata.json``.
    """
    semantic, stats = vote_point_labels(xyz_world, semantic, scene, frames, rendered_depth(loaded, scene, depth_cache),
                                        abs_tolerance=abs_tolerance, targets=scene.stuff_ids, rules=rules)
    return semantic, np.where(np.isin(semantic, scene.stuff_ids), 0, channel), stats
