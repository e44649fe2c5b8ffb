"""Stuff labels that follow the surface's orientation: ceiling is not wall where the two meet.

The field's labels live on a grid whose finest cells are a decimetre or more wide (``field.grid``'s
understanding levels), and its training pixels hold far more of a large stuff class (walls) than of the
classes it meets (ceiling, floor). Where two stuff surfaces meet at an edge, the larger class therefore bleeds
a cell or two onto the other: on the tuning rooms 11–12 % of the ceiling's GT points were exported as wall.
The geometry does not blur there. The isosurface resolves the edge to a voxel, and the surface's
orientation tells the two apart: a ceiling faces down, a wall sideways.

:func:`orient_stuff_labels` uses that. For every stuff class it measures how the class's own points are
oriented: the share of them whose surface axis lies within ``cone_degrees`` of a given axis. A stuff point
is relabelled when all of these hold:

- its neighbourhood is planar (its axis is well defined);
- few of its class's points share its axis (below ``own_share``);
- another stuff class lies within ``radius``;
- most of that class's points share the axis (above ``other_share``).

The point then takes that class. Only stuff points move, and only to stuff classes. A class is a target only
when its orientation is concentrated: the walls of a room face two or more ways, so the share for any one
axis stays near a half or below, and floor or ceiling points are not pushed onto them. Classes that share an
orientation (a rug on the floor, a window in a wall) never exchange points.

Chosen on twelve tuning runs (rooms 5–10 with sensor depth, rooms 5, 6, 8, 13 and 15 from images alone):
point mIoU rose on eleven (+0.001 to +0.013; −0.0004 on the twelfth). With sensor depth 94–98 % of the moved
points took their GT class, against 2–6 % before (docs/notes/2026-11-29-benchmark-history.md,
"Why point mIoU trails the 2D mIoU").

Examples
--------
A floor (z = 0) meets a wall twice its size (x = 0); the field called a strip of the floor next to the wall
"wall" (class 1). The strip faces up like the floor (class 2), so it becomes floor, except the row along
the edge itself, whose neighbourhood bends onto the wall:

>>> g = np.linspace(0.0, 1.0, 41)
>>> a, b = np.meshgrid(g, g)
>>> floor = np.c_[a.ravel() + 0.02, b.ravel(), np.zeros(a.size)]
>>> a2, b2 = np.meshgrid(np.linspace(0.0, 2.0, 81), g)
>>> wall = np.c_[np.zeros(a2.size), b2.ravel(), a2.ravel() + 0.02]
>>> xyz, sem = np.r_[floor, wall], np.r_[np.where(floor[:, 0] < 0.1, 1, 2), np.ones(len(wall), int)]
>>> new, stats = orient_stuff_labels(xyz, sem, stuff_ids=[1, 2], radius=0.2)
>>> int((sem[: len(floor)] == 1).sum()), int((new[: len(floor)] == 1).sum()), stats["moves"]
(164, 43, {'1->2': 121})
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from lift3d.sfm.planes import fit_planes
from lift3d.sfm.planes.fit import LEANING_UP_CONE_DEG

#: Points the orientations are measured on: larger exports are subsampled to this many stuff points (the
#: density the rule was chosen at), and every other point follows its nearest measured neighbour.
ORIENTATION_POINTS = 150_000
#: Neighbours of a point that define its surface axis (principal component analysis).
AXIS_NEIGHBOURS = 16
#: Polar rings of the latitude-longitude grid the shares are tabulated on (4 × as many bins around each ring):
#: cells of 5 degrees.
AXIS_POLAR_BINS = 18


def surface_axes(xyz: np.ndarray, k: int = AXIS_NEIGHBOURS) -> tuple[np.ndarray, np.ndarray]:
    """Unit surface axis (normal up to sign) and curvature of each point, from its ``k`` nearest neighbours.

    Returns
    -------
    axes : np.ndarray
        ``[N, 3]`` the direction of least spread of the neighbourhood.
    curvature : np.ndarray
        ``[N]`` the least eigenvalue over the sum (0 on a plane, 1/3 for an isotropic blob).
    """
    xyz = np.asarray(xyz, np.float64)
    k = int(min(k, len(xyz)))
    _, nn = cKDTree(xyz).query(xyz, k=k, workers=-1)
    nb = xyz[nn] - xyz[nn].mean(1, keepdims=True)
    w, v = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb) / k)
    return v[:, :, 0], w[:, 0] / np.maximum(w.sum(1), 1e-300)


def _axis_bins(axes: np.ndarray, polar: int = AXIS_POLAR_BINS) -> tuple[np.ndarray, np.ndarray]:
    """Bin of each axis on a latitude-longitude grid of the half-sphere, and the bins' centre directions.

    An axis and its opposite are one axis: each is folded to z ≥ 0 first. The fold puts two nearly equal
    horizontal axes into bins on opposite sides of the sphere, which is harmless here: bins are compared by
    ``|cos|`` of their centres, so opposite bins agree.
    """
    a = np.where(axes[:, 2:3] < 0, -axes, axes)
    step = 0.5 * np.pi / polar
    theta = np.minimum((np.arccos(np.clip(a[:, 2], -1.0, 1.0)) / step).astype(np.int64), polar - 1)
    around = 4 * polar
    phi = ((np.arctan2(a[:, 1], a[:, 0]) + np.pi) / (2 * np.pi) * around).astype(np.int64) % around
    t, f = np.meshgrid((np.arange(polar) + 0.5) * step, (np.arange(around) + 0.5) / around * 2 * np.pi - np.pi,
                       indexing="ij")
    centres = np.c_[(np.sin(t) * np.cos(f)).ravel(), (np.sin(t) * np.sin(f)).ravel(), np.cos(t).ravel()]
    return theta * around + phi, centres


def orient_stuff_labels(xyz: np.ndarray, semantic: np.ndarray, stuff_ids, radius: float, *,
                        cone_degrees: float = 30.0, own_share: float = 0.1, other_share: float = 0.6,
                        max_curvature: float = 0.05, min_class_points: int = 50,
                        max_points: int = ORIENTATION_POINTS, seed: int = 0) -> tuple[np.ndarray, dict[str, Any]]:
    """Relabel stuff points whose orientation belongs to a neighbouring stuff class (module docstring).

    Parameters
    ----------
    xyz : np.ndarray
        ``[N, 3]`` points of a labelled cloud.
    semantic : np.ndarray
        ``[N]`` their category ids.
    stuff_ids : iterable of int
        Stuff category ids; other points are neither moved nor targets.
    radius : float
        How far (units of ``xyz``) another stuff class may lie for a point to take it: about the width of the
        label grid's blur at an edge.
    cone_degrees : float
        Two axes agree when they are less than this apart.
    own_share, other_share : float
        A point moves when under ``own_share`` of its class's points and over ``other_share`` of the target
        class's points agree with its axis.
    max_curvature : float
        Only points whose neighbourhood is this planar move (:func:`surface_axes`).
    min_class_points : int
        Stuff classes with fewer points are left alone and are no target.
    max_points : int
        Measure on a random subset of this many stuff points when there are more (fixed ``seed``).

    Returns
    -------
    semantic : np.ndarray
        A new ``[N]`` array of category ids.
    stats : dict
        ``moved`` (points), ``moves`` (``"from->to": points``) and the settings, for ``metadata.json``.
    """
    semantic = np.asarray(semantic)
    out = semantic.copy()
    settings = {"radius": float(radius), "cone_degrees": float(cone_degrees), "own_share": float(own_share),
                "other_share": float(other_share), "max_curvature": float(max_curvature)}
    stuff = np.flatnonzero(np.isin(semantic, list(stuff_ids)))
    classes, counts = np.unique(semantic[stuff], return_counts=True)
    classes = classes[counts >= min_class_points]
    if len(classes) < 2:
        return out, {"moved": 0, "moves": {}, **settings}
    stuff = stuff[np.isin(semantic[stuff], classes)]
    measured = stuff
    if len(stuff) > max_points:
        measured = np.sort(np.random.default_rng(seed).choice(stuff, max_points, replace=False))
    pts = np.asarray(xyz, np.float64)[measured]
    own = semantic[measured]
    axes, curvature = surface_axes(pts)

    # Share of each class's points whose axis lies within the cone of each tabulated axis.
    b, bins = _axis_bins(axes)
    agree = (np.abs(bins @ bins.T) > np.cos(np.radians(cone_degrees))).astype(np.float64)
    index = {int(c): k for k, c in enumerate(classes)}
    ci = np.array([index[int(c)] for c in own])
    hist = np.zeros((len(classes), len(bins)))
    np.add.at(hist, (ci, b), 1.0)
    share = (hist @ agree) / hist.sum(1, keepdims=True)  # [C, B]; agree is symmetric

    cand = np.flatnonzero((curvature < max_curvature) & (share[ci, b] < own_share))
    moved_to = np.full(len(measured), -1, np.int64)
    if len(cand):
        # Which other classes lie within the radius of each candidate: one tree per class.
        present = np.zeros((len(cand), len(classes)), bool)
        for k in range(len(classes)):
            d, _ = cKDTree(pts[ci == k]).query(pts[cand], distance_upper_bound=radius, workers=-1)
            present[:, k] = np.isfinite(d)
        present[np.arange(len(cand)), ci[cand]] = False
        score = np.where(present, share[:, b[cand]].T, -1.0)
        best = score.argmax(1)
        ok = score[np.arange(len(cand)), best] > other_share
        moved_to[cand[ok]] = classes[best[ok]]
    hit = moved_to >= 0
    out[measured[hit]] = moved_to[hit]
    if hit.any() and len(measured) < len(stuff):
        # Every other stuff point follows its nearest measured point, when that one had its class and moved.
        # Only points near a moved one can follow: find those against the (small) tree of moved points first,
        # then ask the full tree only for them.
        rest = np.setdiff1d(stuff, measured, assume_unique=True)
        rest_xyz = np.asarray(xyz, np.float64)[rest]
        tree = cKDTree(pts)
        spacing = np.median(tree.query(pts[:: max(1, len(pts) // 2000)], k=2)[0][:, 1])
        d, _ = cKDTree(pts[hit]).query(rest_xyz, distance_upper_bound=4.0 * spacing, workers=-1)
        near = np.flatnonzero(np.isfinite(d))
        if len(near):
            _, j = tree.query(rest_xyz[near], workers=-1)
            follow = (moved_to[j] >= 0) & (own[j] == semantic[rest[near]])
            out[rest[near[follow]]] = moved_to[j[follow]]
    changed = np.flatnonzero(out != semantic)
    pairs, n = np.unique(np.stack([semantic[changed], out[changed]], 1), axis=0, return_counts=True) \
        if len(changed) else (np.zeros((0, 2), np.int64), np.zeros(0, np.int64))
    return out, {"moved": int(len(changed)), "moves": {f"{int(a)}->{int(c)}": int(k) for (a, c), k in zip(pairs, n)},
                 **settings}


#: Stuff points the corner planes are fitted to (a larger export is subsampled, with a fixed seed). RANSAC scores
#: its candidate planes against all of them: 30 000 took 1.1 s of the step's 1.5 s, and 10 000 found the same
#: planes on a reported room (corner points 38 753 → 38 691).
CORNER_FIT_POINTS = 10_000
#: A plane takes part in a corner when it holds at least this share of those points (or half of one of its
#: classes' points): on an images-only tuning room, planes under 1 % were fog in front of a wall (a fifth to two
#: fifths of their points near a GT surface), and the smallest real wall held 5 %.
CORNER_MIN_PLANE_SHARE = 0.02
#: Two planes make a corner when the angle between them is at least this (degrees).
CORNER_MIN_ANGLE = 60.0


def complete_stuff_corners(xyz: np.ndarray, semantic: np.ndarray, stuff_ids, radius: float, threshold: float, *,
                           up: np.ndarray | None = None, up_tolerance_deg: float = LEANING_UP_CONE_DEG,
                           min_plane_share: float = CORNER_MIN_PLANE_SHARE,
                           min_angle: float = CORNER_MIN_ANGLE, max_points: int = CORNER_FIT_POINTS,
                           seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """Carry the stuff planes of a cloud to the edges where they meet.

    A density isosurface rounds a room's corners: where a wall meets the ceiling or the floor it bends over a
    grid cell or two, and its points there belong to neither plane. Those points sit closer to the other
    surface than to their own, so the GT points of a ceiling along a wall find wall points first (images-only
    reported rooms: 13–15 % of the ceiling's GT points). Walls, floors and ceilings are planes that meet at
    sharp edges, so the cloud can say so:

    1. planes are fitted to the stuff points (:func:`lift3d.sfm.planes.fit_planes`, inliers within
       ``threshold``, horizontal or vertical when ``up`` is given); a plane takes part when it holds
       ``min_plane_share`` of the points, or half of the points of one of its classes (a ceiling the views
       barely see is a small plane, but all there is of the ceiling; a sheet of fog in front of a wall holds a
       sliver of the walls);
    2. a stuff point within ``radius`` of two of them that meet at ``min_angle`` or more is a corner point;
    3. it is replaced by its projections onto every such plane within ``radius`` of it, where the projection
       lies within ``radius`` of the plane's extent (its inliers' hull). A projection keeps the point's class
       when that class belongs on the plane: the plane holds it and most of the class's points lie on planes
       facing alike (level or upright, given ``up``: a window along a ceiling stays window on the wall; a wall
       point on the ceiling is ceiling). Otherwise it takes the plane's own class, the one of those with most
       points on it.

    Each corner point becomes two or three points, one on each surface: the strip of the rounded edge turns
    into the two surfaces running up to their common edge, each with its own class. Things are never moved.

    Parameters
    ----------
    xyz : np.ndarray
        ``[N, 3]`` points.
    semantic : np.ndarray
        ``[N]`` their category ids.
    stuff_ids : iterable of int
        Stuff category ids.
    radius : float
        How far from two planes a point counts as a corner point (units of ``xyz``): about the width of the
        isosurface's rounding, two instance link radii in the export.
    threshold : float
        RANSAC inlier distance of the planes.
    up : np.ndarray, optional
        The scene's up direction: planes are then horizontal or vertical.
    up_tolerance_deg : float
        How far ``up`` may be from the floor's normal (:func:`lift3d.sfm.mvs.plane_fit_up`).
    min_plane_share, min_angle, max_points, seed
        See the module constants; ``seed`` fixes the subsample and RANSAC's draws.

    Returns
    -------
    keep : np.ndarray
        ``[N] bool``: the points that stay as they are (all but the corner points).
    source : np.ndarray
        ``int64 [M]``: the point each new point was projected from (its colour and instance follow it).
    new_xyz : np.ndarray
        ``[M, 3]`` the projections.
    new_semantic : np.ndarray
        ``[M]`` their classes.
    stats : dict
        ``planes`` (fitted; ``corner_planes`` those large enough), ``corner_points`` (replaced), ``added``
        (new points), ``relabelled`` (projections whose class differs from their point's), and the settings,
        for ``metadata.json``.

    Examples
    --------
    A floor (class 2) meets a wall (class 1) along a rounded edge of radius 0.2 whose points are labelled
    wall: afterwards the floor runs to the wall and the wall to the floor, each with its own class.

    >>> g = np.linspace(0.2, 2.0, 37)
    >>> a, b = np.meshgrid(g, np.linspace(0.0, 2.0, 41))
    >>> floor = np.c_[a.ravel(), b.ravel(), np.zeros(a.size)]
    >>> wall = np.c_[np.zeros(a.size), b.ravel(), a.ravel()]
    >>> t = np.linspace(0.0, np.pi / 2, 9)[1:-1]
    >>> arc = np.array([[0.2 - 0.2 * np.cos(s), y, 0.2 - 0.2 * np.sin(s)] for s in t for y in b[:, 0]])
    >>> xyz = np.r_[floor, wall, arc]
    >>> sem = np.r_[np.full(len(floor), 2), np.full(len(wall), 1), np.full(len(arc), 1)]
    >>> keep, source, new_xyz, new_sem, stats = complete_stuff_corners(xyz, sem, [1, 2], radius=0.25,
    ...                                                                threshold=0.02, up=np.array([0, 0, 1.0]))
    >>> bool(keep[-len(arc):].any()), stats["corner_planes"]
    (False, 2)
    >>> on_floor = np.abs(new_xyz[:, 2]) < np.abs(new_xyz[:, 0])   # nearer the floor plane than the wall
    >>> off_edge = np.maximum(np.abs(new_xyz[:, 0]), np.abs(new_xyz[:, 2])) > 0.05
    >>> sorted(set(new_sem[on_floor & off_edge].tolist())), sorted(set(new_sem[~on_floor & off_edge].tolist()))
    ([2], [1])
    >>> float(new_xyz[on_floor, 0].min()) < 0.01, float(new_xyz[~on_floor, 2].min()) < 0.01   # they meet
    (True, True)
    """
    xyz = np.asarray(xyz, np.float64)
    semantic = np.asarray(semantic)
    settings = {"radius": float(radius), "threshold": float(threshold), "min_plane_share": float(min_plane_share),
                "min_angle": float(min_angle)}
    keep = np.ones(len(xyz), bool)
    none = (keep, np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, semantic.dtype))
    stuff = np.flatnonzero(np.isin(semantic, [int(c) for c in stuff_ids]))
    fit = stuff
    if len(stuff) > max_points:
        fit = np.sort(np.random.default_rng(seed).choice(stuff, max_points, replace=False))
    stats: dict[str, Any] = {"planes": 0, "corner_planes": 0, "corner_points": 0, "added": 0, "relabelled": 0,
                             **settings}
    if len(fit) < 3:
        return (*none, stats)
    planes = fit_planes(xyz[fit], semantic[fit], stuff_ids, threshold=threshold,
                        min_points=max(50, len(fit) // 200), up=up, seed=seed, up_tolerance_deg=up_tolerance_deg)
    fit_cls = semantic[fit]
    fit_dist = np.abs(xyz[fit] @ planes.normal.T + planes.offset)  # [F, P]

    def most_of_a_class(k: int) -> bool:
        # the ceiling of a room the views barely see: a small plane, but all there is of its class
        return any((fit_dist[fit_cls == c, k] < threshold).mean() >= 0.5 for c in planes.classes[k]
                   if (fit_cls == c).any())

    large = np.flatnonzero([planes.inliers[k] >= min_plane_share * len(fit) or most_of_a_class(k)
                            for k in range(len(planes))])
    stats.update(planes=len(planes), corner_planes=int(len(large)))
    if len(large) < 2:
        return (*none, stats)
    normal, offset = planes.normal[large], planes.offset[large]
    meets = np.abs(normal @ normal.T) <= np.cos(np.radians(min_angle))  # [L, L]; False on the diagonal
    pts, cls = xyz[stuff], semantic[stuff]
    signed = pts @ normal.T + offset  # [S, L]
    near = np.abs(signed) < radius

    def at_corner(near: np.ndarray) -> np.ndarray:
        return ((near.astype(np.int64) @ meets.astype(np.int64)) * near).any(1)

    # a projection counts only within the radius of its plane's extent (checked for the few candidates only)
    cand = np.flatnonzero(at_corner(near))
    near = near[cand]
    for j, k in enumerate(large):
        idx = np.flatnonzero(near[:, j])
        if len(idx):
            q = cand[idx]
            near[idx, j] = planes.beyond_extent(int(k), pts[q] - signed[q, j, None] * normal[j]) <= radius
    corner = np.zeros(len(pts), bool)
    corner[cand] = at_corner(near)
    rows, cols = np.nonzero(near & corner[cand, None])
    rows = cand[rows]
    if not len(rows):
        return (*none, stats)
    # Which classes belong on a plane: those it holds of which most points lie on planes facing its way. The fit
    # counts the walls' top rows among a small ceiling's inliers (a reported room: 7 700 wall points at the
    # ceiling's height against 2 500 ceiling points), but the walls' points lie on upright planes; a rug's lie on
    # level ones, a window's on upright ones. The plane's own class is the one of those with most points on it.
    on = fit_dist[:, large] < threshold  # [F, L]
    if up is not None:  # level planes (floors, ceilings) and upright ones (walls, whichever way they face)
        level = np.abs(normal @ (np.asarray(up, np.float64) / np.linalg.norm(up))) > np.cos(np.radians(45.0))
        facing = level[:, None] == level[None, :]  # [L, L] planes facing alike
    else:
        facing = np.abs(normal @ normal.T) > np.cos(np.radians(min_angle))
    on_facing = (on.astype(np.int64) @ facing.astype(np.int64)) > 0  # [F, L]
    belongs = np.zeros((len(large), int(max(semantic.max(), fit_cls.max())) + 1), bool)
    main = np.empty(len(large), semantic.dtype)
    for j, k in enumerate(large):
        ids = np.array(sorted(planes.classes[k]))
        share = np.array([on_facing[fit_cls == c, j].mean() if (fit_cls == c).any() else 0.0 for c in ids])
        count = np.array([(on[:, j] & (fit_cls == c)).sum() for c in ids])
        own = ids[share >= 0.5]
        belongs[j, own] = True
        main[j] = own[np.argmax(count[share >= 0.5])] if len(own) else ids[np.argmax(share)]
    new_xyz = pts[rows] - signed[rows, cols, None] * normal[cols]
    held = belongs[cols, cls[rows]]
    new_sem = np.where(held, cls[rows], main[cols]).astype(semantic.dtype)
    keep[stuff[corner]] = False
    stats.update(corner_points=int(corner.sum()), added=int(len(rows)), relabelled=int((~held).sum()))
    return keep, stuff[rows].astype(np.int64), new_xyz, new_sem, stats
