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
points took their GT class, against 2–6 % before (docs/benchmarks.md).

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
