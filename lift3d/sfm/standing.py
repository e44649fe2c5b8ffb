"""Upright faces of things that stand on the floor, from where the views' 2D labels put them on it.

A plain cabinet has no texture for stereo (the plane sweep finds no depth on most of its pixels) and is no
stuff plane; without a target its front is drawn onto the wall behind it. It does stand on the floor,
whose plane the stuff planes fix.

1. **Feet.** Where a view's labels put rows of a thing directly above rows of floor, the ray through that
   boundary meets the floor plane at the thing's foot, as for a wall's foot
   (:func:`lift3d.sfm.planes.floor_boundary_points`). A foot that one pixel of boundary moves by more than
   ``tolerance`` (a ray grazing the floor far away) is dropped.
2. **Heights.** The vertical line above each foot is carved where enough views that see a point of it label
   that point a stuff class (the wall behind, the floor beyond); the foot keeps the height below its first
   carved point. An edge that overhangs the floor (a table's top seen above the floor under it) puts its
   "foot" on the floor behind it; other views see the floor through the low part of that line, so it is
   carved at once and dropped.
3. **Faces.** Per class, straight runs of feet that at least ``min_views`` views agree on within
   ``threshold`` (sequential RANSAC on the floor, then split where the run has a gap of ``3 × threshold``): the feet of one
   cabinet front seen from many views line up; an overhang's feet move with the viewpoint and do not. Each
   run is an upright rectangle from the floor to the median height of its feet.

A pixel labelled a thing gets the depth where its ray first meets a face of its class
(:meth:`StandingFaces.first_hit`), in every view, also those that do not see the thing's foot.

Examples
--------
A 1 m cube standing 3 m in front of a row of five cameras 1.5 m above the floor: one face, along the cube's
front, about 1 m high; the middle view's ray to the cube's centre meets it at y = 3.

>>> from lift3d.data.cameras import Cameras, look_at
>>> eyes = np.array([[x, 0.0, 1.5] for x in (-2.0, -1.0, 0.0, 1.0, 2.0)])
>>> cams = Cameras(np.stack([look_at(e, np.array([0, 3.5, 0.5])) for e in eyes]), fx=48.0, fy=48.0, cx=32.0, cy=32.0,
...                width=64, height=64)
>>> def labels(i):  # 2 = floor (z = 0), 1 = wall (y = 5), 6 = the cube [-0.5, 0.5] x [3, 4] x [0, 1]
...     v, u = np.mgrid[0:64, 0:64]
...     o, d = cams.rays(i, u.ravel().astype(float), v.ravel().astype(float))
...     t_floor = np.where(d[:, 2] < 0, -o[:, 2] / np.minimum(d[:, 2], -1e-9), np.inf)
...     t_wall = np.where(d[:, 1] > 0, (5 - o[:, 1]) / np.maximum(d[:, 1], 1e-9), np.inf)
...     lo, hi = np.array([-0.5, 3, 0]), np.array([0.5, 4, 1])
...     with np.errstate(divide="ignore", invalid="ignore"):
...         a, b = (lo - o) / d, (hi - o) / d
...     t_in, t_out = np.minimum(a, b).max(1), np.maximum(a, b).min(1)
...     t_cube = np.where((t_in < t_out) & (t_out > 0), t_in, np.inf)
...     sem = np.where(t_floor < t_wall, 2, 1)
...     return np.where(t_cube < np.minimum(t_floor, t_wall), 6, sem).reshape(64, 64)
>>> sem = {i: labels(i) for i in range(5)}
>>> faces = standing_faces(cams, range(5), sem, np.array([0, 0, 1.0]), 0.0, [2], [6], [1, 2], threshold=0.05,
...                        step=0.05, max_height=2.5)
>>> len(faces), round(float(faces.start[0, 1]), 2), bool(0.9 <= faces.height[0] <= 1.1)
(1, 3.0, True)
>>> t, k = faces.first_hit(*cams.rays(2, np.array([32.0]), np.array([40.0])), np.array([6]))
>>> o, d = cams.rays(2, np.array([32.0]), np.array([40.0]))
>>> int(k[0]), round(float((o + t[:, None] * d)[0, 1]), 2)
(0, 3.0)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lift3d.sfm.planes.label_lines import boundary_floor_hits
from lift3d.sfm.planes.model import ray_plane_distance
from lift3d.sfm.planes.room_rules import stretch_ids
from lift3d.utils.geometry import plane_basis


@dataclass
class StandingFaces:
    """Upright rectangles standing on the floor, one per straight run of a thing's feet.

    Attributes
    ----------
    start, end : np.ndarray
        ``[K, 3]`` the ends of each face's foot on the floor.
    height : np.ndarray
        ``[K]`` how high each face rises along ``up``.
    classes : np.ndarray
        ``int64 [K]`` each face's class.
    rms : np.ndarray
        ``[K]`` the feet's distance from their line (root mean square, world units).
    views : np.ndarray
        ``int64 [K]`` how many views' feet each face holds.
    facing : np.ndarray
        ``[K, 3]`` each face's horizontal unit normal, on the side of the cameras that saw its feet.
    up : np.ndarray
        ``[3]`` the floor's unit normal.
    """

    start: np.ndarray
    end: np.ndarray
    height: np.ndarray
    classes: np.ndarray
    rms: np.ndarray
    views: np.ndarray
    facing: np.ndarray
    up: np.ndarray

    def __len__(self) -> int:
        return len(self.classes)

    def subset(self, keep: np.ndarray) -> "StandingFaces":
        """The faces where ``keep`` (``bool [K]``) is true."""
        return StandingFaces(self.start[keep], self.end[keep], self.height[keep], self.classes[keep],
                             self.rms[keep], self.views[keep], self.facing[keep], self.up)

    def first_hit(self, origins: np.ndarray, directions: np.ndarray, classes: np.ndarray,
                  min_cos: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
        """Where each ray first meets a face of its class, from the side its feet were seen from.

        A ray that first meets a face of its class from behind has passed over the thing's top into it (the
        top of a low cabinet): it gets nothing rather than the far face's depth.

        Parameters
        ----------
        origins, directions : np.ndarray
            ``[R, 3]`` rays (unit directions).
        classes : np.ndarray
            ``[R]`` the class each ray's pixel is labelled.
        min_cos : float
            A ray closer to parallel with a face than this (``|cos|`` to its normal) ignores it.

        Returns
        -------
        t : np.ndarray
            ``[R]`` distance along the ray (``inf`` when no face is met).
        face : np.ndarray
            ``int64 [R]`` index of the face met (``-1`` when none).
        """
        r = len(origins)
        t_best, best = np.full(r, np.inf), np.full(r, -1, np.int64)
        behind = np.zeros(r, bool)
        for k in range(len(self)):
            along = self.end[k] - self.start[k]
            length = float(np.linalg.norm(along))
            along = along / max(length, 1e-12)
            normal = self.facing[k]
            mine = np.flatnonzero(classes == self.classes[k])
            if not len(mine):
                continue
            t, cos = ray_plane_distance(origins[mine], directions[mine], normal, -float(normal @ self.start[k]))
            x = origins[mine] + t[:, None] * directions[mine]
            s = (x - self.start[k]) @ along
            h = (x - self.start[k]) @ self.up
            ok = (np.abs(cos) >= min_cos) & (t > 0) & (t < t_best[mine]) & (s >= 0) & (s <= length) & (h >= 0) & (
                h <= self.height[k])
            t_best[mine[ok]], best[mine[ok]] = t[ok], k
            behind[mine[ok]] = cos[ok] > 0
        t_best[behind], best[behind] = np.inf, -1
        return t_best, best


@dataclass(frozen=True)
class StandingSettings:
    """How :func:`standing_faces` finds feet, carves the lines above them and fits faces to them.

    Attributes
    ----------
    tolerance : float
        Largest distance a foot may move when the boundary moves by one pixel (world units).
    min_views : int
        Fewest views whose feet make a face.
    min_rows : int
        Rows of thing above and of floor below a boundary.
    carve_share, min_carve_views : float, int
        A point of a line is carved when at least ``min_carve_views`` views, and at least ``carve_share`` of
        the views that have it in their image, label it a stuff class.
    iterations, seed : int
        RANSAC draws per face, and their generator's seed.
    """

    tolerance: float = np.inf
    min_views: int = 3
    min_rows: int = 2
    carve_share: float = 0.25
    min_carve_views: int = 2
    iterations: int = 300
    seed: int = 0


def standing_faces(cameras, frames, labels: dict[int, np.ndarray], normal: np.ndarray, offset: float,
                   floor_classes, thing_classes, stuff_classes, threshold: float, step: float, max_height: float,
                   settings: StandingSettings | None = None) -> StandingFaces:
    """The upright faces of things standing on the floor that the views' labels agree on (module docstring).

    Parameters
    ----------
    cameras : lift3d.data.cameras.Cameras
    frames : array of int
        The views whose labels give feet and carve the lines above them.
    labels : dict
        Frame → ``[H, W]`` semantic labels.
    normal, offset : np.ndarray, float
        The floor plane ``normal · x + offset = 0`` (``normal`` up).
    floor_classes, thing_classes, stuff_classes : iterable of int
        The floor plane's classes; the classes that may stand on it; the classes that carve a line (every
        stuff class: a thing's face is seen as wall or floor only where the segmenter errs).
    threshold : float
        How far a foot may lie from its face's line (world units); a gap of three times this along the line
        splits it.
    step : float
        Spacing of the points up each vertical line (world units): how finely the top is found.
    max_height : float
        Highest point of a line above the floor.
    settings : StandingSettings, optional
        The feet's tolerance, the views a face and a carve need, RANSAC's draws (default:
        :class:`StandingSettings`'s).

    Returns
    -------
    StandingFaces
    """
    s = StandingSettings() if settings is None else settings
    normal = np.asarray(normal, np.float64)
    normal = normal / np.linalg.norm(normal)
    feet, cls, view, eye = [], [], [], []
    for i in frames:
        i = int(i)
        hits = boundary_floor_hits(cameras, i, labels[i], normal, offset, thing_classes, floor_classes, s.min_rows)
        if hits is None:
            continue
        r, c, o, d, t, cos = hits
        moved = t / (min(cameras.fx[i], cameras.fy[i]) * np.abs(cos))  # one pixel along a grazing ray
        ok = moved < s.tolerance
        feet.append(o[ok] + t[ok, None] * d[ok]), cls.append(labels[i][r[ok], c[ok]]), eye.append(o[ok])
        view.append(np.full(int(ok.sum()), i))
    empty = StandingFaces(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64), np.zeros(0),
                          np.zeros(0, np.int64), np.zeros((0, 3)), normal)
    if not feet or not sum(len(f) for f in feet):
        return empty
    feet, cls, view = np.concatenate(feet), np.concatenate(cls).astype(np.int64), np.concatenate(view)
    eye = np.concatenate(eye)
    top = _line_tops(cameras, frames, labels, feet, normal, step, max_height, stuff_classes, s.carve_share,
                     s.min_carve_views)
    keep = top > 0
    feet, cls, view, top, eye = feet[keep], cls[keep], view[keep], top[keep], eye[keep]
    rng = np.random.default_rng(s.seed)
    basis = plane_basis(normal)
    faces = []
    for c in np.unique(cls):
        m = cls == c
        faces += [(c,) + f for f in _runs(feet[m], view[m], top[m], eye[m], basis, threshold, s.min_views,
                                          s.iterations, rng)]
    if not faces:
        return empty
    c, start, end, height, rms, views, facing = zip(*faces)
    return StandingFaces(np.asarray(start), np.asarray(end), np.asarray(height), np.asarray(c, np.int64),
                         np.asarray(rms), np.asarray(views, np.int64), np.asarray(facing), normal)


def _runs(feet: np.ndarray, view: np.ndarray, top: np.ndarray, eye: np.ndarray, basis: np.ndarray,
          threshold: float, min_views: int, iterations: int, rng: np.random.Generator) -> list[tuple]:
    """Sequential RANSAC of lines through one class's feet (``[F, 3]``, on the floor, seen from ``eye``):
    ``(start, end, height, rms, views, facing)`` of each straight run, split at gaps over ``3 × threshold``, that ``min_views`` views' feet hold."""
    out = []
    origin = feet.mean(0)
    p = (feet - origin) @ basis.T  # [F, 2]
    left = np.ones(len(p), bool)
    while len(np.unique(view[left])) >= min_views:
        idx = np.flatnonzero(left)
        pairs = rng.integers(0, len(idx), size=(iterations, 2))
        a, b = p[idx[pairs[:, 0]]], p[idx[pairs[:, 1]]]
        along = b - a
        norm = np.linalg.norm(along, axis=1)
        good = norm > threshold
        if not good.any():
            break
        a, n = a[good], np.c_[-along[good, 1], along[good, 0]] / norm[good, None]
        dist = np.abs(p[idx] @ n.T - np.einsum("lk,lk->l", a, n)[None]) / threshold  # [F, L]
        # MSAC: a line through a box's corner, across its front and side feet, gathers as many feet within
        # the threshold as the front itself, but not as close
        best = int(np.argmax(np.maximum(0.0, 1.0 - dist ** 2).sum(0)))
        inl = idx[dist[:, best] < 1.0]
        if len(np.unique(view[inl])) < min_views:
            break
        # refit by least squares, then take the inliers again
        centre = p[inl].mean(0)
        direction = np.linalg.svd(p[inl] - centre, full_matrices=False)[2][0]
        perp = np.array([-direction[1], direction[0]])
        dist = (p[idx] - centre) @ perp
        inl = idx[np.abs(dist) < threshold]
        # a face's stragglers (a boundary half a pixel off, far away) would make a second face just behind it
        left[idx[np.abs(dist) < 2 * threshold]] = False
        run = stretch_ids((p[inl] - centre) @ direction, 3 * threshold)
        for k in np.unique(run):
            members = inl[run == k]
            if len(np.unique(view[members])) < min_views:
                continue
            sk = (p[members] - centre) @ direction
            rk = (p[members] - centre) @ perp
            ends = [origin + (centre + v * direction + float(np.mean(rk)) * perp) @ basis for v in (sk.min(), sk.max())]
            facing = perp @ basis
            if np.mean((eye[members] - feet[members]) @ facing) < 0:
                facing = -facing
            out.append((ends[0], ends[1], float(np.median(top[members])), float(np.sqrt(np.mean(
                (rk - rk.mean()) ** 2))), int(len(np.unique(view[members]))), facing))
    return out


def _line_tops(cameras, frames, labels, foot: np.ndarray, normal: np.ndarray, step: float, max_height: float,
               stuff_classes, carve_share: float, min_carve_views: int) -> np.ndarray:
    """The height of each foot's vertical line below its first carved point (``[F]``; 0 when the line is carved
    at its first step above the floor)."""
    heights = np.arange(step, max_height + 1e-9, step)
    if not len(heights):
        return np.zeros(len(foot))
    line = (foot[:, None, :] + heights[None, :, None] * normal).reshape(-1, 3)
    stuff = np.zeros(len(line), np.int64)
    seen = np.zeros(len(line), np.int64)
    stuff_ids = [int(s) for s in stuff_classes]
    for j in frames:
        j = int(j)
        sem = labels[j]
        hh, ww = sem.shape
        uv, z = cameras.project(j, line)
        u, v = np.floor(uv[:, 0]), np.floor(uv[:, 1])
        inside = (z > 0) & (u >= 0) & (u < ww) & (v >= 0) & (v < hh)
        lab = sem[v[inside].astype(np.int64), u[inside].astype(np.int64)]
        seen[inside] += 1
        stuff[inside] += np.isin(lab, stuff_ids)
    carved = ((stuff >= min_carve_views) & (stuff >= carve_share * seen)).reshape(len(foot), -1)
    first = np.where(carved.any(1), np.argmax(carved, axis=1), len(heights))
    return np.where(first > 0, heights[np.maximum(first - 1, 0)], 0.0)


def stereo_agreement(faces: StandingFaces, cameras, views, labels: dict[int, np.ndarray], depths,
                     tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """How many stereo depths each face meets, and how many of those lie within ``tolerance`` of it.

    A face drawn from a thing's feet is wrong wherever the thing is not upright above them (a plant's leaves
    spread wider than its pot, a shelf is open to its back): where stereo matched that thing's texture, its
    depths lie in front of or behind the face. A plain box has no such depths and agrees wherever it has any.

    Parameters
    ----------
    faces : StandingFaces
    cameras : lift3d.data.cameras.Cameras
    views : iterable of int
        Frames with a depth map in ``depths`` (same order).
    labels : dict
        Frame → ``[H, W]`` semantic labels.
    depths : iterable of np.ndarray
        ``[H, W]`` z-depth maps (0 = none), e.g. the plane sweep's.
    tolerance : float
        Largest z-distance (world units) at which a depth agrees with its face.

    Returns
    -------
    met, agreeing : np.ndarray
        ``int64 [K]`` each.
    """
    met = np.zeros(len(faces), np.int64)
    agreeing = np.zeros(len(faces), np.int64)
    if not len(faces):
        return met, agreeing
    for i, depth in zip(views, depths):
        i = int(i)
        depth = np.asarray(depth)
        r, c = np.nonzero(depth > 0)
        cls = labels[i][r, c]
        on = np.isin(cls, faces.classes)
        if not on.any():
            continue
        r, c, cls = r[on], c[on], cls[on]
        o, d = cameras.rays(i, c.astype(np.float64), r.astype(np.float64))
        t, k = faces.first_hit(o, d, cls)
        hit = k >= 0
        z = t[hit] * (d[hit] @ cameras.c2w_opencv[i][:3, 2])
        np.add.at(met, k[hit], 1)
        np.add.at(agreeing, k[hit], np.abs(z - depth[r[hit], c[hit]]) < tolerance)
    return met, agreeing
