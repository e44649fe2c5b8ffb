"""Planes of the stuff classes, fitted to triangulated points: depth where the images have too little texture.

Walls, floors and ceilings are most of an indoor view, and the part that photo-consistency pins down least:
docs/sfm.md measures 1–2 sparse observations per 1000 wall pixels and a few percent of dense coverage. They
are also planes. A handful of triangulated points that the 2D labels put on one wall fixes that wall's
plane, and then every pixel the labels call wall has a depth: where its ray first meets one of the scene's
stuff planes, provided that plane is of the pixel's class (a ray that meets the floor plane first cannot see
a wall; a furniture pixel the segmenter called wall gets no target when the plane it meets first disagrees).

1. **Each point's class**: the majority of the pseudo-label classes at its observations (at least
   ``min_share`` of them agree), so keypoints on an object's edge that the labels split go nowhere.
2. **Planes per stuff class**: sequential RANSAC (inliers within ``threshold`` of the plane), refined by a
   least-squares fit of the inliers, each plane kept when it holds ``min_points`` inliers spread over an
   area (not a line); the inliers leave and the next plane is searched among the rest.
3. **Extent**: the convex hull of a plane's inliers in its own 2D coordinates, grown by ``margin``. A ray
   meets the plane only inside it, so the plane of one wing of an L-shaped room does not cut through the
   other wing. (For a convex room the nearest plane a ray meets is the room's surface whatever the extent.)

Examples
--------
Two walls of a box room, 40 points each; the ray from the middle looking along +x meets the wall x = 2:

>>> rng = np.random.default_rng(0)
>>> a = np.c_[np.full(40, 2.0), rng.uniform(-2, 2, 40), rng.uniform(0, 3, 40)]
>>> b = np.c_[rng.uniform(-2, 2, 40), np.full(40, 2.0), rng.uniform(0, 3, 40)]
>>> planes = fit_planes(np.r_[a, b], np.r_[np.full(40, 1), np.full(40, 1)], [1], threshold=0.02)
>>> len(planes)
2
>>> t, k = planes.first_hit(np.array([[0.0, 0.0, 1.5]]), np.array([[1.0, 0.0, 0.0]]))
>>> round(float(t[0]), 3), sorted(planes.classes[k[0]])
(2.0, [1])
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace

import numpy as np


@dataclass
class StuffPlanes:
    """Planes ``n · x + d = 0`` with a class, a residual and an extent.

    Attributes
    ----------
    normal : np.ndarray
        ``[P, 3]`` unit normals.
    offset : np.ndarray
        ``[P]`` ``d``.
    classes : list of frozenset
        Per plane, the categories of its inliers (those with a share of them, see :func:`fit_planes`).
    rms : np.ndarray
        ``[P]`` root mean square distance of the inliers to the plane (world units).
    inliers : np.ndarray
        ``int64 [P]`` number of inlier points.
    origin, basis : np.ndarray
        ``[P, 3]`` and ``[P, 2, 3]``: the plane's 2D coordinates of ``x`` are ``basis @ (x - origin)``.
    hull : list of np.ndarray
        Per plane, ``[E, 3]`` half-planes ``a · p + b <= margin`` (unit ``a``) of the inliers' convex hull.
    margin : float
        How far beyond its hull a plane still counts (world units).
    seen_through : list of np.ndarray, optional
        Per plane, the cells (keys of :func:`_cell_keys`) of its margin that sight lines pass through
        (:meth:`with_seen_through`): a ray meets the margin only outside them. None: the whole margin counts.
    cell : float
        The size of those cells (world units).
    margin_classes : list of frozenset, optional
        Per plane, the classes whose pixels its margin takes (:meth:`first_hit` given their classes): those with
        a share of its inliers (see :func:`fit_planes`). A class held for a few of its points (a ceiling's edge
        along a wall's top, a window in a wall) is there only where those points are; past them the margin
        would give its pixels the wall's depth where the wall has ended. Default: every class of ``classes``.
    """

    normal: np.ndarray
    offset: np.ndarray
    classes: list
    rms: np.ndarray
    inliers: np.ndarray
    origin: np.ndarray
    basis: np.ndarray
    hull: list = field(default_factory=list)
    margin: float = 0.0
    seen_through: list | None = None
    cell: float = 0.0
    margin_classes: list | None = None

    def __post_init__(self) -> None:
        if self.margin_classes is None:
            self.margin_classes = list(self.classes)

    def __len__(self) -> int:
        return len(self.offset)

    def with_seen_through(self, cameras: np.ndarray, points: np.ndarray, threshold: float,
                          cell: float | None = None) -> "StuffPlanes":
        """These planes with the parts of their margins that the views see through taken away.

        A margin fills a room's corners, where a wall's points stop short of the next wall. It also reaches
        past the end of a wall into open space: the inner wall of an L-shaped room, when the other inner wall
        has no plane to stop it, reaches 1.1 m into the other wing, and the rays that look along that wing met it
        (a test room: 16 % of its depth targets more than 1 % of the diagonal off, most of them there). Sight
        lines to points beyond the plane cross it there; a cell of the margin (``cell``, default
        ``2 × threshold``) that one crosses no longer counts. (Chosen on tuning rooms 5–16 over a cell's eight
        neighbours too, or two or three crossings per cell: a stray sight line through a corner costs least.)

        Parameters
        ----------
        cameras, points : np.ndarray
            ``[M, 3]`` sight lines: camera centres and the points they see.
        threshold : float
            A point counts as beyond a plane when more than this behind it (world units).

        Examples
        --------
        A wall x = 0 whose points end at y = 1, a margin of 1 m, and a camera at (-2, 1.5) that sees a point at
        (2, 1.5) past the wall's end: a ray meeting the margin there passes, one meeting it above the wall's top
        (z = 3.5, no sight line) still ends on it.

        >>> rng = np.random.default_rng(0)
        >>> wall = np.c_[np.zeros(50), rng.uniform(-2, 1, 50), rng.uniform(0, 3, 50)]
        >>> planes = fit_planes(wall, np.ones(50, int), [1], threshold=0.05, margin=1.0)
        >>> cam, seen = np.array([[-2.0, 1.5, 1.5]]), np.array([[2.0, 1.5, 1.5]])
        >>> ray = np.array([[-1.0, 1.0, 1.5], [-1.0, 0.0, 3.3]]), np.array([[1.0, 0.5, 0.0], [1.0, 0.0, 0.2]])
        >>> planes.first_hit(ray[0], ray[1] / np.linalg.norm(ray[1], axis=1, keepdims=True))[1].tolist()
        [0, 0]
        >>> planes.with_seen_through(cam, seen, 0.05).first_hit(
        ...     ray[0], ray[1] / np.linalg.norm(ray[1], axis=1, keepdims=True))[1].tolist()
        [-1, 0]
        """
        cell = 2.0 * threshold if cell is None else float(cell)
        cameras, points = np.asarray(cameras, np.float64), np.asarray(points, np.float64)
        blocked = []
        for k in range(len(self)):
            x = _crossing_points((cameras, points), self.normal[k], self.offset[k], threshold)
            p2, beyond = _beyond_hull(x, self.origin[k], self.basis[k], self.hull[k])
            p2 = p2[(beyond > 0) & (beyond <= self.margin + cell)]
            blocked.append(np.unique(_cell_keys(np.floor(p2 / cell).astype(np.int64))))
        return replace(self, seen_through=blocked, cell=cell)

    def seen_through_at(self, k: int, p2: np.ndarray) -> np.ndarray:
        """``[N] bool``: sight lines pass through the cells of plane ``k`` at its 2D points ``p2`` (``[N, 2]``;
        needs :meth:`with_seen_through`)."""
        return np.isin(_cell_keys(np.floor(p2 / self.cell).astype(np.int64)), self.seen_through[k])

    def with_plane(self, normal: np.ndarray, offset: float, points: np.ndarray, classes: np.ndarray,
                   threshold: float) -> "StuffPlanes":
        """These planes and one more, ``normal · x + offset = 0``, over the hull of ``points`` of ``classes``
        (``[N]``: it holds them all; unchanged when the points lie along a line)."""
        normal = np.asarray(normal, np.float64)
        extent = _extent(np.asarray(points, np.float64), normal, threshold) if len(points) >= 3 else None
        if extent is None:
            return self
        origin, basis, hull = extent
        rms = float(np.sqrt(np.mean((points @ normal + offset) ** 2)))
        return StuffPlanes(np.r_[self.normal.reshape(-1, 3), normal[None]], np.r_[self.offset, offset],
                           [*self.classes, frozenset(int(c) for c in np.unique(classes))], np.r_[self.rms, rms],
                           np.r_[self.inliers, len(points)].astype(np.int64), np.r_[self.origin.reshape(-1, 3), origin[None]],
                           np.r_[self.basis.reshape(-1, 2, 3), basis[None]], [*self.hull, hull], self.margin,
                           margin_classes=[*self.margin_classes, frozenset(int(c) for c in np.unique(classes))])

    def subset(self, keep: np.ndarray) -> "StuffPlanes":
        """The planes where ``keep`` (``[P] bool``)."""
        idx = np.flatnonzero(keep)
        return StuffPlanes(self.normal[idx], self.offset[idx], [self.classes[i] for i in idx], self.rms[idx],
                           self.inliers[idx], self.origin[idx], self.basis[idx], [self.hull[i] for i in idx],
                           self.margin, margin_classes=[self.margin_classes[i] for i in idx])

    def _moved(self, k: int, normal: np.ndarray, offset: float) -> "StuffPlanes":
        """These planes with plane ``k`` replaced by ``normal · x + offset = 0`` (a small turn and shift of
        it): its origin is projected onto the new plane, its 2D axes are kept as near as the new plane allows,
        so its hull still bounds the same stretch."""
        normal = np.asarray(normal, np.float64)
        origin = self.origin[k] - (self.origin[k] @ normal + offset) * normal
        b0 = self.basis[k][0] - (self.basis[k][0] @ normal) * normal
        b0 /= np.linalg.norm(b0)
        b1 = np.cross(normal, b0)
        b1 *= np.sign(b1 @ self.basis[k][1]) or 1.0
        out = replace(self, normal=self.normal.copy(), offset=self.offset.astype(np.float64),
                      origin=self.origin.copy(), basis=self.basis.copy(), seen_through=None)
        out.normal[k], out.offset[k], out.origin[k], out.basis[k] = normal, offset, origin, np.stack([b0, b1])
        return out

    def vertical(self, up: np.ndarray, max_tilt_deg: float = 10.0) -> np.ndarray:
        """``[P] bool``: the plane is within ``max_tilt_deg`` of vertical (a wall) for the direction ``up``."""
        return np.abs(self.normal.reshape(-1, 3) @ up) < np.sin(np.radians(max_tilt_deg))

    def beyond_extent(self, k: int, x: np.ndarray) -> np.ndarray:
        """``[N]`` how far points ``x`` (``[N, 3]``, on plane ``k``) lie beyond its inliers' hull (≤ 0 inside)."""
        return _beyond_hull(np.asarray(x, np.float64), self.origin[k], self.basis[k], self.hull[k])[1]

    def holds(self, plane: np.ndarray, class_id: np.ndarray) -> np.ndarray:
        """``[R] bool``: plane ``plane[r]`` (``-1`` = none) holds class ``class_id[r]``."""
        out = np.zeros(len(plane), bool)
        for k, cls in enumerate(self.classes):
            m = plane == k
            out[m] = np.isin(class_id[m], list(cls))
        return out

    def first_hit(self, origins: np.ndarray, directions: np.ndarray, min_cos: float = 0.1,
                  t_min: float = 1e-6, classes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Where each ray first meets a plane inside the plane's extent.

        Parameters
        ----------
        origins, directions : np.ndarray
            ``[R, 3]`` rays (unit directions).
        min_cos : float
            A ray closer to parallel with a plane than this (``|cos|`` of the angle to its normal) ignores it.
        classes : np.ndarray, optional
            ``int [R]`` the class of each ray's pixel: a plane's margin then counts only for the rays of its
            ``margin_classes``, the others pass through it.

        Returns
        -------
        t : np.ndarray
            ``[R]`` distance along the ray (``inf`` when no plane is met).
        plane : np.ndarray
            ``int64 [R]`` index of the plane met (``-1`` when none).
        """
        r = len(origins)
        t_best = np.full(r, np.inf)
        best = np.full(r, -1, np.int64)
        for k in range(len(self)):
            t, cos = ray_plane_distance(origins, directions, self.normal[k], self.offset[k])
            ok = (np.abs(cos) >= min_cos) & (t > t_min) & (t < t_best)
            if not ok.any():
                continue
            idx = np.flatnonzero(ok)
            p = origins[idx] + t[idx, None] * directions[idx]
            p2, beyond = _beyond_hull(p, self.origin[k], self.basis[k], self.hull[k])
            inside = beyond <= self.margin
            # Beyond its hull a plane reaches only where no other plane separates the spot from its points: the
            # margin fills a room's corners, but an inner wall of an L-shaped room does not reach across the room.
            ext = inside & (beyond > 0)
            for j in range(len(self)):
                if j != k and ext.any():
                    side = np.sign(self.origin[k] @ self.normal[j] + self.offset[j])
                    ext &= (p @ self.normal[j] + self.offset[j]) * side > -1e-9
            if self.seen_through is not None and ext.any():
                ext[ext] = ~self.seen_through_at(k, p2[ext])
            if classes is not None and ext.any():
                ext[ext] = np.isin(classes[idx[ext]], sorted(self.margin_classes[k]))
            inside &= (beyond <= 0) | ext
            idx = idx[inside]
            t_best[idx] = t[idx]
            best[idx] = k
        return t_best, best


def ray_plane_distance(origins: np.ndarray, directions: np.ndarray, normal: np.ndarray,
                       offset: float) -> tuple[np.ndarray, np.ndarray]:
    """Where rays meet the plane ``normal · x + offset = 0``.

    Parameters
    ----------
    origins, directions : np.ndarray
        ``[R, 3]`` rays (``t`` is in units of the directions' length).
    normal, offset : np.ndarray, float
        The plane (unit normal).

    Returns
    -------
    t : np.ndarray
        ``[R]`` ray parameter of the meeting point: negative behind the origin, ``±inf`` or NaN for rays
        parallel to the plane.
    cos : np.ndarray
        ``[R]`` ``directions · normal`` (the cosine to the normal for unit directions).

    Examples
    --------
    >>> t, cos = ray_plane_distance(np.array([[0.0, 0, 2]]), np.array([[0.0, 0, -1]]), np.array([0, 0, 1.0]), 0.0)
    >>> t.tolist(), cos.tolist()
    ([2.0], [-1.0])
    """
    cos = directions @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        return -(origins @ normal + offset) / cos, cos


def point_classes(obs_point: np.ndarray, obs_class: np.ndarray, num_points: int,
                  min_share: float = 0.6) -> np.ndarray:
    """Each point's class: the majority of its observations' classes, when ``min_share`` of them agree.

    Parameters
    ----------
    obs_point, obs_class : np.ndarray
        ``[M]`` point index and label class (0 = void, ignored) of every observation.

    Returns
    -------
    np.ndarray
        ``int64 [num_points]`` class id, 0 where the observations disagree or are void.
    """
    obs_point = np.asarray(obs_point, np.int64)
    obs_class = np.asarray(obs_class, np.int64)
    labelled = obs_class > 0
    out = np.zeros(num_points, np.int64)
    if not labelled.any():
        return out
    p, c = obs_point[labelled], obs_class[labelled]
    pairs, counts = np.unique(p * (int(c.max()) + 1) + c, return_counts=True)
    pp, cc = pairs // (int(c.max()) + 1), pairs % (int(c.max()) + 1)
    order = np.lexsort((-counts, pp))  # per point, the most observed class first
    first = np.r_[True, pp[order][1:] != pp[order][:-1]]
    top_point, top_class, top_count = pp[order][first], cc[order][first], counts[order][first]
    total = np.bincount(p, minlength=num_points)[top_point]
    agree = top_count >= min_share * total
    out[top_point[agree]] = top_class[agree]
    return out


def fit_planes(points: np.ndarray, classes: np.ndarray, stuff_ids, threshold: float, min_points: int = 15,
               max_planes: int = 24, iterations: int = 500, margin: float = 0.0, min_class_share: float = 0.25,
               up: np.ndarray | None = None, sightlines: tuple[np.ndarray, np.ndarray] | None = None,
               candidates: int = 64, max_crossing_share: float = 0.2, min_class_cover: float = 0.5,
               seed: int = 0) -> StuffPlanes:
    """Sequential RANSAC planes of the stuff classes' points (see the module docstring).

    The points of all stuff classes are fitted together and each plane takes the classes of its inliers: fitted
    class by class, the bottom edges of four walls (a wall's points near the floor, which the labels call
    wall) make a horizontal "wall" plane that wins over every single wall; fitted together, they join the floor.

    Parameters
    ----------
    points : np.ndarray
        ``[N, 3]`` world points.
    classes : np.ndarray
        ``[N]`` class of each point (:func:`point_classes`; 0 = none).
    stuff_ids : iterable of int
        Classes to fit planes to.
    threshold : float
        Inlier distance (world units).
    min_points : int
        Fewest inliers of a plane.
    max_planes : int
        Most planes.
    margin : float
        Stored in the result: how far beyond its inliers' hull a plane extends.
    min_class_share : float
        A plane holds every class with at least this share of its inliers.
    min_class_cover : float
        A plane also holds every class of which it has at least this share of the points (and 3): a rug on the
        floor or a window in a wall has too few points to make a quarter of the plane's inliers, and without
        this their pixels got no targets (tuning scenes 100-111: rugs 3-12 % covered on six of them, windows
        5-9 %).
    up : np.ndarray, optional
        The scene's up direction. Given, planes are horizontal or vertical (floors, ceilings, walls, roads,
        façades): a horizontal plane needs one point and a vertical one two, so a few points per wall
        suffice and a horizontal slab through the feet of all walls is not a candidate for a wall. The up
        direction is first refined to the normal of the largest plane within 25° of it.
    sightlines : (np.ndarray, np.ndarray), optional
        ``[M, 3]`` camera centres and ``[M, 3]`` the points they see (every observation, things too). A
        plane that sight lines cross inside its extent is contradicted by the views. Of the ``candidates``
        best RANSAC planes, those crossed by more than ``max_crossing_share`` of the sight lines that end on
        them are dropped, and the one with most inliers × (1 − that share) wins. Without this, objects'
        points the labels call floor make horizontal slabs above the floor, which floor pixels' rays meet
        first. (A share, not a count: points are thinned before fitting, sight lines are not.)
    candidates : int
        RANSAC planes (distinct from each other) scored against the sight lines per plane found.
    max_crossing_share : float
        Most sight lines crossing a plane, as a share of those ending on it. On indoor tuning scenes real
        walls had up to 0.12 (sight lines to wrong plane-sweep depths behind them) and false planes from 0.23.
    seed : int
        RANSAC's random draws (the result is deterministic for a seed).
    """
    rng = np.random.default_rng(seed)
    points = np.asarray(points, np.float64)
    classes = np.asarray(classes, np.int64)
    stuff = np.isin(classes, [int(c) for c in stuff_ids])
    left, left_cls = points[stuff], classes[stuff]
    class_total = np.bincount(left_cls, minlength=1) if len(left_cls) else np.zeros(1, np.int64)
    if up is not None and len(left) >= min_points:
        up = _refined_up(left, np.asarray(up, np.float64) / np.linalg.norm(up), threshold, min_points, rng)
    rows: list[tuple] = []
    for _ in range(max_planes):
        if len(left) < min_points:
            break
        best = None
        for n, d in _ransac_planes(left, threshold, iterations, rng, up, candidates if sightlines else 1,
                                     min_points):
            inl = np.abs(left @ n + d) < threshold
            if inl.sum() < min_points:
                continue
            n, d = _least_squares_plane(left[inl], n if up is not None else None)
            inl = np.abs(left @ n + d) < threshold
            extent = _extent(left[inl], n, threshold)
            if extent is None:
                continue
            score = float(inl.sum())
            if sightlines is not None:
                # Crossings and support are both counted in sight lines (every observation, not thinned), so
                # their ratio is the share of the views that contradict the plane; scaled to inliers, the
                # score stays comparable with min_points however densely the points were thinned.
                crossings, support = _crossings(sightlines, n, d, extent, threshold)
                if crossings > max_crossing_share * support:
                    continue
                score *= 1.0 - crossings / max(support, 1)
            if score >= min_points and (best is None or score > best[0]):
                best = (score, n, d, inl, extent)
        if best is None:
            break
        _, n, d, inl, (origin, basis, hull) = best
        pts, pts_cls = left[inl], left_cls[inl]
        left, left_cls = left[~inl], left_cls[~inl]
        ids, counts = np.unique(pts_cls, return_counts=True)
        main = (counts >= min_class_share * len(pts)) | (counts == counts.max())
        held = ids[main | ((counts >= min_class_cover * class_total[ids]) & (counts >= 3))]
        rms = float(np.sqrt(np.mean((pts @ n + d) ** 2)))
        rows.append((n, d, frozenset(int(c) for c in held), rms, len(pts), origin, basis, hull,
                     frozenset(int(c) for c in ids[main])))
    if not rows:
        z3 = np.zeros((0, 3))
        return StuffPlanes(z3, np.zeros(0), [], np.zeros(0), np.zeros(0, np.int64), z3, np.zeros((0, 2, 3)), [],
                           float(margin))
    n, d, cls, rms, cnt, origin, basis, hull, main = zip(*rows)
    return StuffPlanes(np.array(n), np.array(d), list(cls), np.array(rms), np.array(cnt, np.int64),
                       np.array(origin), np.array(basis), list(hull), float(margin), margin_classes=list(main))


def floor_boundary_points(cameras, frames, labels: dict[int, np.ndarray], normal: np.ndarray, offset: float,
                          floor_classes, wall_classes, step: float, max_height: float, tolerance: float = np.inf,
                          min_rows: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points on walls from where the 2D labels put a wall directly above the floor, given the floor's plane.

    Where a pixel labelled wall sits on one labelled floor, the wall meets the floor: the ray through the
    boundary between the two pixels meets the floor plane at a point of the wall's foot. Walls are vertical,
    so the vertical line up from that point lies on the wall too, as far as the view keeps labelling it
    wall. This needs no texture at all (stereo finds next to nothing on a plain wall), only the labels and
    the floor plane that the floor's many points fix.

    Parameters
    ----------
    cameras : lift3d.data.cameras.Cameras
        The scene's cameras.
    frames : array of int
        Frames to use.
    labels : dict
        Frame → ``[H, W]`` semantic labels.
    normal, offset : np.ndarray, float
        The floor plane ``normal · x + offset = 0`` (``normal`` is up).
    floor_classes, wall_classes : iterable of int
        Classes of the floor plane and classes that may stand on it.
    step : float
        Spacing of the points up the vertical line (world units).
    max_height : float
        Highest point above the floor.
    tolerance : float
        Largest distance a foot may move when the boundary moves by one pixel (world units): far from the
        camera, a ray grazes the floor and a label boundary one pixel off puts the foot metres away.
    min_rows : int
        Rows of wall above and of floor below the boundary (a one-pixel label speck is no boundary).

    Returns
    -------
    xyz : np.ndarray
        ``[N, 3]`` points.
    classes : np.ndarray
        ``int64 [N]`` the wall pixel's class.
    centres : np.ndarray
        ``[N, 3]`` the centre of the camera that saw each point (its sight line).

    Examples
    --------
    A camera 1.5 m above the floor z = 0 looking along +y at a wall y = 3 that the labels show above the
    floor: the points lie on the wall.

    >>> from lift3d.data.cameras import Cameras
    >>> c2w = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 1.5], [0, 0, 0, 1]])  # OpenGL: looks along +y
    >>> cams = Cameras(c2w[None], fx=32.0, fy=32.0, cx=32.0, cy=32.0, width=64, height=64)
    >>> rows = np.arange(64)[:, None].repeat(64, 1)
    >>> horizon = 32 + 32 * 1.5 / 3.0                          # the wall's foot is 1.5 m below the eye, 3 m away
    >>> sem = np.where(rows < horizon, 1, 2)
    >>> xyz, cls, _ = floor_boundary_points(cams, [0], {0: sem}, np.array([0, 0, 1.0]), 0.0, [2], [1],
    ...                                     step=0.25, max_height=3.0)
    >>> bool(np.allclose(xyz[:, 1], 3.0, atol=0.1)), bool((cls == 1).all()), round(float(xyz[:, 2].max()), 2) > 2.5
    (True, True, True)
    """
    normal = np.asarray(normal, np.float64)
    floor_ids, wall_ids = [int(c) for c in floor_classes], [int(c) for c in wall_classes]
    heights = np.arange(0.0, max_height + 1e-9, step)
    out_xyz, out_cls, out_cam = [], [], []
    for i in frames:
        i = int(i)
        sem = labels[i]
        hits = boundary_floor_hits(cameras, i, sem, normal, offset, wall_ids, floor_ids, min_rows)
        if hits is None:
            continue
        r, c, o, d, t, denom = hits
        # one pixel turns the ray by ~1/f; along the floor the foot moves t/f / sin(grazing angle)
        ok = t / (min(cameras.fx[i], cameras.fy[i]) * np.abs(denom)) < tolerance
        foot, cls = o[ok] + t[ok, None] * d[ok], sem[r[ok], c[ok]].astype(np.int64)
        if not len(foot):
            continue
        xyz, xyz_cls = _vertical_lines(cameras, i, sem, foot, cls, heights, normal)
        out_xyz.append(xyz)
        out_cls.append(xyz_cls)
        out_cam.append(np.broadcast_to(cameras.c2w_opencv[i][:3, 3], (len(xyz), 3)))
    if not out_xyz:
        return np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros((0, 3))
    return np.concatenate(out_xyz), np.concatenate(out_cls), np.concatenate(out_cam)


def boundary_floor_hits(cameras, i: int, sem: np.ndarray, normal: np.ndarray, offset: float, wall_ids, floor_ids,
                         min_rows: int):
    """Where the rays through view ``i``'s label boundaries with ``wall_ids`` rows directly on ``floor_ids`` rows
    (a wall's foot, or a thing's: :mod:`lift3d.sfm.standing`) meet the floor plane ahead, from above:
    ``(rows, cols, origins, directions, t, cos)`` of those that do (``rows`` the last upper row, ``cos`` the ray's
    cosine with ``normal``, negative), or None for a rolled view (an image column far from vertical) or one
    without such a boundary."""
    if abs(cameras.c2w_opencv[i][:3, 0] @ normal) > 0.3:
        return None
    r, c = label_boundary(sem, wall_ids, floor_ids, min_rows, same="upper")  # r: the last wall row
    if not len(r):
        return None
    o, d = cameras.rays(i, c.astype(np.float64), r + 0.5)
    t, denom = ray_plane_distance(o, d, normal, offset)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(t) & (t > 0) & (denom < 0)
    if not ok.any():
        return None
    return r[ok], c[ok], o[ok], d[ok], t[ok], denom[ok]


def _vertical_lines(cameras, i: int, sem: np.ndarray, foot: np.ndarray, cls: np.ndarray, heights: np.ndarray,
                    normal: np.ndarray, past_edge: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Points up the vertical line above each wall foot (``[F, 3]``, class ``cls``) at ``heights``, while view
    ``i``'s labels keep calling the line that class: ``(xyz [N, 3], classes [N])``. With ``past_edge``, a line
    that leaves the image with the labels still calling it that class goes on up to the last height: nothing in
    the view says where the wall ends."""
    h, w = sem.shape
    line = foot[:, None, :] + heights[None, :, None] * normal  # [F, S, 3]
    uv, z = cameras.project(i, line.reshape(-1, 3))
    u = np.floor(uv[:, 0]).reshape(len(foot), -1)
    v = np.floor(uv[:, 1]).reshape(len(foot), -1)
    inside = (z.reshape(len(foot), -1) > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    same = np.zeros_like(inside)
    same[inside] = sem[v[inside].astype(np.int64), u[inside].astype(np.int64)] == np.repeat(cls, len(heights))[
        inside.ravel()]
    same[:, 0] = True  # the foot itself
    if past_edge:
        # outside the image from some height on (a view looking down at a far wall's foot): the part past the
        # edge is not contradicted by this view; it counts as seen, up to where the labels stopped inside
        left = ~inside & (np.cumsum(inside[:, ::-1], axis=1)[:, ::-1] == 0)  # outside, and never back in above
        same |= left
    keep = np.cumprod(same, axis=1).astype(bool)
    return line[keep], np.repeat(cls, keep.sum(1))


@dataclass
class FloorLine:
    """The labels' wall-on-floor boundaries of several views, as rays and the floor tracks they may slide along.

    Each boundary pixel of a view is an observation: the ray through the boundary (``origin``, ``ray``), the
    observed row (as the normalised image coordinate ``y``, with the camera's ``fy`` and world-to-camera
    rotation ``rotation``), the foot where the ray meets the floor, and ``track``: the horizontal direction on
    the floor within the plane of the pixel's image column. A vertical wall ``n · x + e = 0`` puts the foot
    seen in that column at the point of the track on it; :meth:`residual` is how many pixels that point's row
    is from the observed one. Fitting walls in pixels, not in metres, weighs a far view's boundary as what it
    is: a row known to a pixel, which across the room is a foot known to half a metre, skewed outwards."""

    frame: np.ndarray
    origin: np.ndarray
    rotation: np.ndarray
    fy: np.ndarray
    y: np.ndarray
    foot: np.ndarray
    track: np.ndarray
    classes: np.ndarray
    width: np.ndarray
    shift: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.frame)

    def subset(self, keep: np.ndarray) -> "FloorLine":
        return FloorLine(*(None if getattr(self, f) is None else getattr(self, f)[keep]
                           for f in self.__dataclass_fields__))

    def feet(self, normal: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """``[..., N, 3]`` the point of each observation's track on the vertical plane(s) ``normal · x + offset =
        0`` (``offset`` a scalar or ``[G, 1]``); NaN where the track runs along the plane."""
        along = self.track @ normal
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = -(self.foot @ normal + offset) / np.where(np.abs(along) > 0.2, along, np.nan)
        return self.foot + lam[..., None] * self.track

    def residual(self, normal: np.ndarray, offset) -> np.ndarray:
        """``[..., N]`` pixels between the observed boundary row and the row of the foot on the plane(s)
        ``normal · x + offset = 0``; NaN where the foot is behind the camera or undefined."""
        x = self.feet(normal, offset)
        pc = np.einsum("nij,...nj->...ni", self.rotation, x - self.origin)
        with np.errstate(divide="ignore", invalid="ignore"):
            res = self.fy * (pc[..., 1] / pc[..., 2] - self.y)
        if self.shift is not None:
            res = res - self.shift
        return np.where(pc[..., 2] > 0, res, np.nan)

    def closest_residual(self, known: "StuffPlanes") -> np.ndarray:
        """``[N]`` each observation's residual (:meth:`residual`) to the plane of ``known`` holding its class that
        it is closest to in pixels; ``inf`` where no such plane gives one."""
        best = np.full(len(self), np.inf)
        for k in range(len(known)):
            holds = np.isin(self.classes, list(known.classes[k]))
            if holds.any():
                res = self.subset(holds).residual(known.normal[k], known.offset[k])
                idx = np.flatnonzero(holds)
                closer = np.abs(res) < np.abs(best[idx])
                best[idx[closer]] = res[closer]
        return best

    def calibrated(self, known: "StuffPlanes", window: float = 3.0, min_count: int = 5,
                   unmeasured: float = 0.0) -> "FloorLine":
        """These observations with each view's boundary shift (``shift``) measured against the walls of
        ``known``: a segmenter draws a frame's wall a pixel or two too fat or too thin all along it, and where
        a known wall's foot is within ``window`` rows of the boundary, the median of those residuals (over at
        least ``min_count`` of them) is that view's shift. Views without a known wall get ``unmeasured`` (NaN
        makes their residuals NaN: they take no part)."""
        best = replace(self, shift=None).closest_residual(known)
        shift = np.full(len(self), float(unmeasured))
        for f in np.unique(self.frame):
            m = (self.frame == f) & (np.abs(best) <= window)
            if m.sum() >= min_count:
                shift[self.frame == f] = float(np.median(best[m]))
        return replace(self, shift=shift)


def floor_line(cameras, frames, labels: dict[int, np.ndarray], normal: np.ndarray, offset: float, floor_classes,
               wall_classes, min_rows: int = 2) -> FloorLine:
    """Every wall-on-floor boundary pixel of ``frames`` as a :class:`FloorLine` (the floor ``normal · x + offset
    = 0``, ``normal`` up; see :func:`floor_boundary_points`)."""
    normal = np.asarray(normal, np.float64)
    floor_ids, wall_ids = [int(c) for c in floor_classes], [int(c) for c in wall_classes]
    parts = []
    for i in frames:
        i = int(i)
        sem = labels[i]
        hits = boundary_floor_hits(cameras, i, sem, normal, offset, wall_ids, floor_ids, min_rows)
        if hits is None:
            continue
        r, c, o, d, t, _ = hits
        rot = cameras.c2w_opencv[i][:3, :3].T
        cam = d @ rot.T
        xn = cam[:, 0] / cam[:, 2]
        # the plane of the pixel's column holds the rays (xn, y, 1): its normal is (1, 0, -xn) in the camera
        column = np.c_[np.ones_like(xn), np.zeros_like(xn), -xn] @ rot
        track = np.cross(column, normal)
        track /= np.linalg.norm(track, axis=1, keepdims=True)
        parts.append((np.full(len(r), i, np.int64), o, np.broadcast_to(rot, (len(r), 3, 3)),
                      np.full(len(r), float(cameras.fy[i])), cam[:, 1] / cam[:, 2], o + t[:, None] * d, track,
                      sem[r, c].astype(np.int64), np.full(len(r), sem.shape[1], np.int64)))
    if not parts:
        z3 = np.zeros((0, 3))
        return FloorLine(np.zeros(0, np.int64), z3, np.zeros((0, 3, 3)), np.zeros(0), np.zeros(0), z3, z3,
                         np.zeros(0, np.int64), np.zeros(0, np.int64))
    return FloorLine(*(np.concatenate(a) for a in zip(*parts)))


def floor_line_walls(line: FloorLine, directions: np.ndarray, known: "StuffPlanes", threshold: float,
                     pixel_tolerance: float = 1.0, min_views: int = 3, view_share: float = 0.05,
                     max_walls: int = 8) -> list[tuple[np.ndarray, float, np.ndarray]]:
    """Vertical walls that many views' wall-on-floor boundaries agree on, found in pixels.

    For each direction (a unit horizontal normal: a room's walls are few directions, usually two at right
    angles), the wall's offset is searched on a grid of ``threshold / 4``. A view supports an offset when the
    wall's foot lands within ``pixel_tolerance`` rows of its boundary in at least ``view_share`` of its image
    columns: any one foot admits a wall through it in any direction, but only a wall that is there runs along
    the boundary for a stretch. The offset with most supporting observations, in at least ``min_views``
    views, wins and is refined to where the supporting views' median residuals balance (the median of each
    view's median: a view's boundary tends to be off by the same pixel along its length). Its observations
    leave and the next is searched, up to ``max_walls`` per direction.

    Observations that a plane of ``known`` holding their class explains already (within the tolerance) take
    no part. A wall within ``3 × threshold`` of a parallel known or already found one is the same wall seen
    through boundaries a pixel or two off: it is not returned, and its observations leave.

    Parameters
    ----------
    line : FloorLine
        The boundaries (:func:`floor_line`).
    directions : np.ndarray
        ``[D, 3]`` unit horizontal wall normals to try.
    known : StuffPlanes
        The planes found so far.
    threshold : float
        The plane threshold (world units); the offset grid is a quarter of it.

    Returns
    -------
    list of (normal, offset, observations)
        Each wall ``normal · x + offset = 0`` and the indices into ``line`` of its observations.

    Examples
    --------
    Three cameras 1.5 m above the floor look at a plain wall y = 6 from 3, 4 and 6 m; each labels the wall
    above the floor row where its foot is:

    >>> from lift3d.data.cameras import Cameras
    >>> c2w = np.array([np.array([[1.0, 0, 0, x], [0, 0, -1, y], [0, 1, 0, 1.5], [0, 0, 0, 1]])
    ...                 for x, y in [(-1, 3), (0, 2), (1, 0)]])
    >>> cams = Cameras(c2w, fx=64.0, fy=64.0, cx=64.0, cy=64.0, width=128, height=128)
    >>> rows = np.arange(128)[:, None].repeat(128, 1)
    >>> labels = {i: np.where(rows < round(64 + 64 * 1.5 / (6 - c2w[i, 1, 3])), 1, 2) for i in range(3)}
    >>> line = floor_line(cams, [0, 1, 2], labels, np.array([0, 0, 1.0]), 0.0, [2], [1])
    >>> walls = floor_line_walls(line, np.array([[0, 1.0, 0]]), fit_planes(np.zeros((0, 3)), np.zeros(0, int), [1],
    ...                          threshold=0.1), threshold=0.1)
    >>> [(round(-e, 1), len(obs)) for _, e, obs in walls]
    [(6.0, 384)]
    """
    if not len(line):
        return []
    line = line.calibrated(known, window=3 * pixel_tolerance)
    free = ~(np.abs(line.closest_residual(known)) <= pixel_tolerance)
    walls: list[tuple[np.ndarray, float, np.ndarray]] = []
    step = threshold / 4
    for n in np.asarray(directions, np.float64).reshape(-1, 3):
        parallel = np.abs(known.normal @ n) > np.cos(np.radians(5)) if len(known) else np.zeros(0, bool)
        taken = list(known.offset[parallel] * np.sign(known.normal[parallel] @ n))
        for _ in range(4 * max_walls):  # duplicates do not count towards max_walls
            if sum(1 for w in walls if w[0] is n) >= max_walls:
                break
            idx = np.flatnonzero(free)
            if not len(idx):
                break
            obs = line.subset(idx)
            through = -(obs.foot @ n)  # the offset of the wall through each observed foot
            ok = np.abs(obs.track @ n) > 0.2
            if not ok.any():
                break
            lo, hi = np.percentile(through[ok], [1, 99])
            grid = np.arange(lo, hi + step, step)
            score = _line_support(obs, n, grid, pixel_tolerance, view_share, min_views)
            g = int(np.argmax(score))
            if score[g] <= 0:
                break
            near, inl = _line_inliers(obs, n, grid[g], pixel_tolerance, view_share)
            e = _balanced_offset(obs.subset(inl), n, grid[g], step)
            free[idx[near]] = False
            if any(abs(e - t) < 3 * threshold for t in taken):
                continue
            taken.append(e)
            walls.append((n, e, idx[inl]))
    return walls


def correct_walls(line: FloorLine, directions: np.ndarray, known: "StuffPlanes", threshold: float,
                  pixel_tolerance: float = 1.0, min_views: int = 3, view_share: float = 0.05, reach: float = 4.0,
                  min_gain: float = 1.5, max_tilt_deg: float = 10.0, sightlines=None,
                  max_crossing_share: float = 1.0) -> tuple["StuffPlanes", int]:
    """``known`` with each wall moved to where the views' wall-on-floor boundaries put it, when they
    clearly disagree with it, and how many moved.

    Stereo fits a plain wall to a few triangulated points; across a long room those can hold it 10–20 cm
    inside the room or turn it a few degrees. The boundary is known to a row in every view that sees the
    wall's foot. For each vertical plane within ``max_tilt_deg`` of one of ``directions``, the observations
    of its classes score the plane as it is and the plane turned to that direction at offsets within
    ``reach × threshold`` of it (:func:`floor_line_walls`' support: rows within ``pixel_tolerance``, a stretch
    of ``view_share`` of a view's columns, ``min_views`` views). The best offset, refined where the views'
    median residuals balance, may replace the plane when it has at least ``min_gain`` times the support of the
    plane as it is and lies more than ``threshold / 2`` from it (or the plane turns). Each view's label
    shift is measured against the other walls only (not against this one or another plane of the same wall);
    a view that sees no other wall cannot tell a shifted boundary from a misplaced wall and takes no part. A
    wrong wall skews the shift measured against it, so the wall that gains most observations moves first and
    the rest are judged again, until none qualifies. The plane keeps its extent (its hull in its own 2D
    coordinates), classes and residual. With ``sightlines``, a wall does not move to where more sight lines
    cross it inside its extent than ``max_crossing_share`` times those that end on it, and more than cross it
    where it is: the labels' boundary can sit off a wall's foot along a whole stretch (a sofa's base, a
    window's sill). A reported room's right wall moved 12–15 cm into the room, from a plane 0.02 of its sight
    lines crossed to one they crossed 2.6 times as often as they ended on it. (A right move of another wall
    of that room raised its share 0.11 → 0.43: at the true wall it is 0.26, so a share of 0.2 is no test here.)

    Parameters
    ----------
    line : FloorLine
        The boundaries (:func:`floor_line`), not yet calibrated.
    directions : np.ndarray
        ``[D, 3]`` unit horizontal wall normals (the room's wall directions).
    known : StuffPlanes
        The planes found so far.
    threshold : float
        The plane threshold (world units); the offset grid is a quarter of it.
    sightlines : (np.ndarray, np.ndarray), optional
        ``[M, 3]`` camera centres and the points they see.

    Returns
    -------
    (StuffPlanes, int)
        The planes, and how many walls moved.
    """
    if not len(line) or not len(known):
        return known, 0
    directions = np.asarray(directions, np.float64).reshape(-1, 3)
    moved: set[int] = set()
    refuted: set[int] = set()

    def share(planes: "StuffPlanes", k: int) -> float:
        crossings, support = _crossings(sightlines, planes.normal[k], planes.offset[k],
                                        (planes.origin[k], planes.basis[k], planes.hull[k]), threshold)
        return crossings / max(support, 1)

    while True:
        best = None
        for k in range(len(known)):
            if k in moved or k in refuted:
                continue
            found = _wall_correction(line, directions, known, k, threshold, pixel_tolerance, min_views, view_share,
                                     reach, min_gain, max_tilt_deg)
            if found is not None and sightlines is not None:
                there = share(known._moved(k, found[1], found[2]), k)
                if there > max_crossing_share and there > share(known, k):
                    refuted.add(k)
                    found = None
            if found is not None and (best is None or found[0] > best[0]):
                best = (*found, k)
        if best is None:
            return known, len(moved)
        _, n, e, k = best
        known = known._moved(k, n, e)
        moved.add(k)


def _wall_correction(line: FloorLine, directions: np.ndarray, known: "StuffPlanes", k: int, threshold: float,
                     pixel_tolerance: float, min_views: int, view_share: float, reach: float, min_gain: float,
                     max_tilt_deg: float) -> tuple[float, np.ndarray, float] | None:
    """``(more, normal, offset)`` that :func:`correct_walls` would move plane ``k`` to (``more``: how many more
    observations support it there), or None."""
    n = _nearest_direction(directions, known.normal[k], max_tilt_deg)
    if n is None:
        return None
    holds = np.isin(line.classes, list(known.classes[k]))
    if not holds.any():
        return None
    step = threshold / 4
    centre = -float(n @ known.origin[k])  # the turned plane through the middle of the plane's points
    grid = centre + np.arange(-reach * 4, reach * 4 + 1) * step
    same = (np.abs(known.normal @ n) > np.cos(np.radians(max_tilt_deg))) & \
        (np.abs(-(known.origin @ n) - centre) <= reach * threshold)
    obs = line.calibrated(known.subset(~same), window=3 * pixel_tolerance, unmeasured=np.nan).subset(holds)
    # the observations that the plane as it is or a candidate explains: within the tolerance of the plane, or of
    # the grid's ends, or with the grid's ends on either side of them
    ends = obs.residual(n, grid[[0, -1]][:, None])  # [2, N]
    with np.errstate(invalid="ignore"):
        band = np.abs(obs.residual(known.normal[k], known.offset[k])) <= pixel_tolerance
        band |= (np.abs(ends) <= pixel_tolerance).any(0) | (ends[0] * ends[1] < 0)
    band &= np.isfinite(ends).all(0)
    if band.sum() < min_views:
        return None
    obs = obs.subset(band)
    now = float(_line_support(obs, known.normal[k], [known.offset[k]], pixel_tolerance, view_share, min_views)[0])
    score = _line_support(obs, n, grid, pixel_tolerance, view_share, min_views)
    g = int(np.argmax(score))
    gain = score[g] / max(now, 1.0)
    if score[g] <= 0 or gain < min_gain:
        return None
    _, inl = _line_inliers(obs, n, grid[g], pixel_tolerance, view_share)
    e = _balanced_offset(obs.subset(inl), n, grid[g], step)
    turned = float(n @ known.normal[k]) < np.cos(np.radians(0.5))
    if abs(e - centre) <= threshold / 2 and not turned:
        return None
    return float(score[g] - now), n, e


def _views_and_need(obs: FloorLine, view_share: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(views, view_of, need)``: the views of ``obs``, each observation's index among them, and how many
    observations each view needs to support a wall (``view_share`` of its image width, at least one)."""
    views, view_of = np.unique(obs.frame, return_inverse=True)
    return views, view_of, np.maximum(view_share * np.bincount(view_of, weights=obs.width)[:len(views)]
                                      / np.bincount(view_of), 1.0)


def _line_support(obs: FloorLine, n: np.ndarray, offsets: np.ndarray, pixel_tolerance: float, view_share: float,
                  min_views: int, chunk: int = 64) -> np.ndarray:
    """``[G]`` support of each vertical wall ``n · x + offsets[g] = 0``: the observations within
    ``pixel_tolerance`` rows of it in views where at least ``view_share`` of the image columns (and one
    observation) are, when at least ``min_views`` views are; 0 otherwise."""
    views, view_of, need = _views_and_need(obs, view_share)
    onehot = np.zeros((len(obs), len(views)))
    onehot[np.arange(len(obs)), view_of] = 1.0
    offsets = np.asarray(offsets, np.float64)
    score = np.zeros(len(offsets))
    for s in range(0, len(offsets), chunk):
        near = np.abs(obs.residual(n, offsets[s:s + chunk, None])) <= pixel_tolerance  # [g, N]
        per_view = near.astype(np.float64) @ onehot  # [g, V]
        good = per_view >= need
        score[s:s + chunk] = np.where(good.sum(1) >= min_views, (per_view * good).sum(1), 0.0)
    return score


def _line_inliers(obs: FloorLine, n: np.ndarray, offset: float, pixel_tolerance: float,
                  view_share: float) -> tuple[np.ndarray, np.ndarray]:
    """``(near, inliers)``: the observations within ``pixel_tolerance`` rows of the wall ``n · x + offset = 0``,
    and those of them in views that support it (:func:`_line_support`)."""
    views, view_of, need = _views_and_need(obs, view_share)
    near = np.abs(obs.residual(n, offset)) <= pixel_tolerance
    per_view = np.bincount(view_of, weights=near.astype(np.float64), minlength=len(views))
    return near, near & (per_view >= need)[view_of]


def _balanced_offset(sub: FloorLine, n: np.ndarray, offset: float, step: float) -> float:
    """The offset near ``offset`` (within 40 ``step``) where the views' median residuals balance: the median of
    each view's median, as a view's boundary tends to be off by the same pixel along its length."""
    fine = offset + np.arange(-80, 81) * (step / 2)  # the inliers span a pixel: metres across a room
    res = sub.residual(n, fine[:, None])  # [F, M]
    frames = np.unique(sub.frame)
    with warnings.catch_warnings():  # a view whose feet all fall behind it at some offset: NaN, skipped
        warnings.simplefilter("ignore", RuntimeWarning)
        balance = [abs(np.median([np.nanmedian(r[sub.frame == f]) for f in frames])) for r in res]
    return float(fine[int(np.nanargmin(balance))])


def _main_stretch(along: np.ndarray, gap: float) -> np.ndarray:
    """``[N] bool``: the positions ``along`` (a line) of the longest-populated run without a gap over ``gap``.

    >>> _main_stretch(np.array([0.0, 0.1, 0.3, 2.5, 2.6]), 0.5).tolist()
    [True, True, True, False, False]
    """
    run = stretch_ids(along, gap)
    return run == np.argmax(np.bincount(run))


def stretch_ids(along: np.ndarray, gap: float) -> np.ndarray:
    """``int64 [N]``: which stretch of the positions ``along`` (a line) each one is in, stretches being runs
    without a gap over ``gap``, numbered in order along the line.

    >>> stretch_ids(np.array([2.6, 0.0, 2.5, 0.3]), 0.5).tolist()
    [1, 0, 1, 0]
    """
    order = np.argsort(along)
    run = np.empty(len(along), np.int64)
    run[order] = np.r_[0, np.cumsum(np.diff(along[order]) > gap)]
    return run


def add_walls(planes: StuffPlanes, cameras, labels: dict[int, np.ndarray], line: FloorLine, walls, up: np.ndarray,
              max_height: float, threshold: float, sightlines: tuple[np.ndarray, np.ndarray],
              max_crossing_share: float = 0.2, min_class_share: float = 0.25, gap: float | None = None,
              settle: bool = True, past_edge: bool = True) -> tuple[StuffPlanes, int]:
    """``planes`` with the walls of :func:`floor_line_walls` that the views do not contradict, and how many.

    Each wall's points are its observations' feet on it and the vertical lines above them while each view keeps
    labelling the line that class (spaced ``2 × threshold`` up to ``max_height``, as
    :func:`floor_boundary_points`), of the feet's most populated stretch without a gap over ``gap`` (default
    ``5 × threshold``) along the wall. A wall is kept when its points spread over an area and sight lines
    (``sightlines``, and the views to these points) cross it inside their hull no more than
    ``max_crossing_share`` as often as they end on it — the test of :func:`fit_planes`. It holds the classes
    of at least ``min_class_share`` of its points. The walls are added as they are: fitted again with every
    other point, their points shift RANSAC's draws (an L-shaped tuning room lost two walls that way).

    With ``settle`` (default), a wall first moves onto the stereo points in front of its stretch
    (:func:`settled_offset`): the boundaries put a far wall's foot a row off, which across a room is several
    centimetres, and the points seen just behind a wall placed in front of the real one counted as sight lines
    through it (tuning room 5: a wall 6.5 cm inside the room crossed by 0.202 of its sight lines, dropped).
    """
    added = 0
    gap = 5 * threshold if gap is None else gap
    for normal, offset, obs in walls:
        sub = line.subset(obs)
        feet = sub.feet(normal, offset)
        # A wall is one stretch: a few feet of another wall that happen to line up with it across the room
        # would stretch its hull over the room (tuning room 15's inner wall, 4 m long, reached 6.4 m).
        keep = _main_stretch(feet @ np.cross(up, normal), gap)
        sub, feet = sub.subset(keep), feet[keep]
        if settle:
            settled = settled_offset(sightlines[1], normal, offset, feet, np.cross(up, normal), up, max_height,
                                     threshold, cameras.centers[np.unique(sub.frame)])
            if settled != offset:
                offset, feet = settled, sub.feet(normal, settled)
        xyz, cls, cam = [], [], []
        for i in np.unique(sub.frame):
            m = sub.frame == i
            p, c = _vertical_lines(cameras, int(i), labels[int(i)], feet[m], sub.classes[m],
                                   np.arange(0.0, max_height + 1e-9, 2 * threshold), up, past_edge=past_edge)
            xyz.append(p), cls.append(c), cam.append(np.broadcast_to(cameras.centers[int(i)], (len(p), 3)))
        xyz, cls = np.concatenate(xyz), np.concatenate(cls)
        if contradicted((np.r_[sightlines[0], *cam], np.r_[sightlines[1], xyz]), normal, offset, xyz, threshold,
                        max_crossing_share):
            continue
        ids, counts = np.unique(cls, return_counts=True)
        held = np.isin(cls, ids[counts >= min_class_share * len(cls)])
        planes = planes.with_plane(normal, offset, xyz[held], cls[held], threshold)
        added += 1
    return planes, added


def wall_directions(planes: StuffPlanes, up: np.ndarray, agree_deg: float = 1.5) -> np.ndarray | None:
    """``[2, 3]`` a room's two horizontal wall normals at right angles: the vertical planes' normals' mean
    direction modulo a right angle, weighted by their inliers, then again over the planes within ``agree_deg``
    of it (a bay wall at 4° pulled the mean of tuning room 15's four square walls 0.35° off, which across its
    8 m wall is 5 cm); None without a vertical plane.

    Examples
    --------
    >>> up = np.array([0, 0, 1.0])
    >>> walls = StuffPlanes(np.array([[1.0, 0, 0], [0, 1.0, 0], [np.cos(0.1), np.sin(0.1), 0]]), np.zeros(3),
    ...                     [frozenset()] * 3, np.zeros(3), np.array([100, 100, 1]), np.zeros((3, 3)),
    ...                     np.zeros((3, 2, 3)), [])
    >>> main, other = wall_directions(walls, up)
    >>> round(float(np.degrees(np.arctan2(main[1], main[0])) % 90), 2), round(float(main @ other), 6)
    (0.0, 0.0)
    """
    up = np.asarray(up, np.float64)
    vertical = np.flatnonzero(planes.vertical(up))
    if not len(vertical):
        return None
    basis = np.linalg.svd(up[None])[2][1:]  # two horizontal axes
    flat = planes.normal[vertical] @ basis.T
    angle = np.arctan2(flat[:, 1], flat[:, 0])
    weight = planes.inliers[vertical].astype(np.float64)
    mean = np.angle(np.sum(weight * np.exp(4j * angle))) / 4
    agree = np.abs(np.angle(np.exp(4j * (angle - mean)))) / 4 <= np.radians(agree_deg)
    if agree.any():
        mean = np.angle(np.sum(weight[agree] * np.exp(4j * angle[agree]))) / 4
    main = np.cos(mean) * basis[0] + np.sin(mean) * basis[1]
    return np.stack([main, np.cross(up, main)])


def corner_cutters(planes: StuffPlanes, points: np.ndarray, classes: np.ndarray, threshold: float, up: np.ndarray,
                   eye: np.ndarray, near: float = 2.0, min_end_share: float = 0.15, min_ends_share: float = 0.4,
                   max_tilt_deg: float = 10.0) -> np.ndarray:
    """``[P] bool``: walls that cut across a corner of two other walls, made of those walls' points.

    Sequential RANSAC takes first the plane with most inliers. Where two walls meet in a corner that stereo
    covers poorly, a vertical plane through the end of one wall, the end of the other and a stray cluster
    between them (an object the labels call wall) can outnumber either wall, and wins. It then holds the
    corner's wall pixels at a depth up to a metre short of the walls, and its extent stops the real walls from
    reaching into the corner (:func:`wall_reach`). An images-only reported room (seed 1): 800 of the 2 930 depth
    targets on one wall were more than 1 % of the diagonal off, all of them on such a plane, and 858 pixel
    samples of that wall got no target because it blocked the wall's reach.

    Such a wall ``j`` has two other walls ``a`` and ``b``, not parallel to each other nor to it, that each hold
    at least ``min_end_share`` of ``j``'s points of its own classes within ``near × threshold`` (together at
    least ``min_ends_share``), and meet behind ``j``: their corner lies on the far side of ``j`` from ``eye``
    (the cameras' mean centre) by more than ``near × threshold``. A wall of a rectangular room touches only
    walls parallel to each other at its ends, and a wall whose two neighbours meet in front of it is the one
    that closes their corner. A real cut corner (a chamfer) narrower than about ``near × threshold`` over
    ``min_ends_share`` looks the same and is dropped too; the two walls' margins then close the corner.

    Parameters
    ----------
    planes : StuffPlanes
        The fitted planes.
    points, classes : np.ndarray
        ``[N, 3]`` the points they were fitted to and ``[N]`` their classes.
    threshold : float
        The fit's inlier distance (world units).
    up, eye : np.ndarray
        The up direction and a point inside the room that the views look from.

    Examples
    --------
    A room's corner x = 3, y = 4, and a plane cutting it from (3, 2.5) to (1.5, 4) whose points are the ends of
    the two walls: it is dropped, the two walls are kept.

    >>> z = np.tile(np.linspace(0.2, 2.4, 6), 10)
    >>> side = np.c_[np.full(60, 3.0), np.repeat(np.linspace(-3, 4, 10), 6), z]
    >>> back = np.c_[np.repeat(np.linspace(-3, 3, 10), 6), np.full(60, 4.0), z]
    >>> s = np.repeat(np.linspace(0.0, 1.0, 10), 6)[:, None]
    >>> cut = np.array([3.0, 2.5, 0]) + s * np.array([-1.5, 1.5, 0]) + np.c_[0 * z, 0 * z, z]
    >>> pts = np.r_[side, back, cut]
    >>> planes = fit_planes(pts, np.ones(len(pts), int), [1], threshold=0.05, min_points=20, up=np.array([0, 0, 1.0]))
    >>> drop = corner_cutters(planes, pts, np.ones(len(pts), int), 0.05, np.array([0, 0, 1.0]), np.zeros(3),
    ...                       near=4.0)
    >>> sorted(np.round(np.abs(planes.normal[drop][:, :2]), 2).ravel().tolist())
    [0.71, 0.71]
    >>> int((~drop).sum())
    2
    """
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    points, classes = np.asarray(points, np.float64), np.asarray(classes, np.int64)
    walls = np.flatnonzero(planes.vertical(up, max_tilt_deg))
    drop = np.zeros(len(planes), bool)
    band = near * threshold
    for j in walls:
        nj, dj = planes.normal[j], planes.offset[j]
        own = (np.abs(points @ nj + dj) < threshold) & np.isin(classes, sorted(planes.margin_classes[j]))
        pts = points[own]
        if not len(pts):
            continue
        eye_side = np.sign(eye @ nj + dj)
        others = [k for k in walls if k != j and abs(planes.normal[k] @ nj) < 0.9]
        share = {k: float(np.mean(np.abs(pts @ planes.normal[k] + planes.offset[k]) < band)) for k in others}
        ends = [k for k in others if share[k] >= min_end_share]
        for i, a in enumerate(ends):
            for b in ends[i + 1:]:
                if abs(planes.normal[a] @ planes.normal[b]) >= 0.9 or share[a] + share[b] < min_ends_share:
                    continue
                # the corner of a and b: a vertical line; its point at the eye's height
                m = np.stack([planes.normal[a], planes.normal[b], up])
                corner = np.linalg.solve(m, -np.array([planes.offset[a], planes.offset[b], -(eye @ up)]))
                if (corner @ nj + dj) * eye_side < -band:
                    drop[j] = True
    return drop


def square_walls(planes: StuffPlanes, directions: np.ndarray, points: np.ndarray, threshold: float,
                 max_turn_deg: float = 5.0, min_kept: float = 0.9) -> tuple[StuffPlanes, int]:
    """``planes`` with each vertical plane within ``max_turn_deg`` of one of the room's wall ``directions``
    turned onto it about the middle of its points (its ``origin``), and how many turned.

    A plain wall gets its plane from a few stereo points and the feet of its boundary; over its length they turn
    it by a degree or more. A plane turns only while ``min_kept`` of the ``points`` within ``threshold`` of it
    (inside its hull) stay within ``threshold``: a wall that is really at an angle keeps its points only as it
    is.

    Parameters
    ----------
    directions : np.ndarray
        ``[D, 3]`` unit horizontal wall normals (:func:`wall_directions`).
    points : np.ndarray
        ``[N, 3]`` the points the planes were fitted to.

    Examples
    --------
    A wall along y = 2 whose plane stereo turned by 2°:

    >>> rng = np.random.default_rng(0)
    >>> pts = np.c_[rng.uniform(-2, 2, 300), 2 + rng.normal(0, 0.01, 300), rng.uniform(0, 2.5, 300)]
    >>> turn = np.radians(2)
    >>> tilted = fit_planes(pts, np.ones(300, int), [1], threshold=0.1, up=np.array([0, 0, 1.0]))
    >>> tilted = tilted._moved(0, np.array([np.sin(turn), np.cos(turn), 0]), -2.0)
    >>> square, turned = square_walls(tilted, np.array([[1.0, 0, 0], [0, 1.0, 0]]), pts, 0.1)
    >>> turned, np.round(square.normal[0], 3).tolist(), round(float(square.offset[0]), 2)
    (1, [0.0, 1.0, 0.0], -2.0)
    """
    directions = np.asarray(directions, np.float64).reshape(-1, 3)
    points = np.asarray(points, np.float64)
    turned = 0
    for k in range(len(planes)):
        n = _nearest_direction(directions, planes.normal[k], max_turn_deg)
        if n is None or n @ planes.normal[k] > np.cos(np.radians(0.05)):  # too far to turn, or square already
            continue
        e = -float(n @ planes.origin[k])
        near = np.abs(points @ planes.normal[k] + planes.offset[k]) < threshold
        near[near] = _beyond_hull(points[near], planes.origin[k], planes.basis[k], planes.hull[k])[1] <= 0
        if near.any() and np.mean(np.abs(points[near] @ n + e) < threshold) < min_kept:
            continue
        planes = planes._moved(k, n, e)
        turned += 1
    return planes, turned


def _nearest_direction(directions: np.ndarray, normal: np.ndarray, max_deg: float) -> np.ndarray | None:
    """The one of ``directions`` (``[D, 3]`` unit wall normals) nearest ``normal``, signed to face its way, when
    within ``max_deg`` of it; else None."""
    cos = directions @ normal
    j = int(np.argmax(np.abs(cos)))
    if np.abs(cos[j]) < np.cos(np.radians(max_deg)):
        return None
    return directions[j] * np.sign(cos[j])


def settled_offset(points: np.ndarray, normal: np.ndarray, offset: float, feet: np.ndarray, along: np.ndarray,
                   up: np.ndarray, max_height: float, threshold: float, cameras: np.ndarray,
                   min_points: int = 30, rounds: int = 3) -> float:
    """The offset of the vertical wall ``normal · x + offset = 0`` moved onto the points near it: the median
    signed distance of the ``points`` within ``threshold`` of it, over the stretch of its ``feet`` (along the
    unit horizontal ``along``) and below ``max_height`` above the feet, taken ``rounds`` times, in all at most
    ``threshold`` from where it started. Unchanged with fewer than ``min_points`` points.

    Parameters
    ----------
    points : np.ndarray
        ``[N, 3]`` points seen by the views (stereo depths, sparse points, wall feet).
    cameras : np.ndarray
        ``[C, 3]`` centres of the views that place the wall (their side of it is its front).

    Examples
    --------
    A wall placed at y = 3.95 whose points scatter around y = 4.0, seen from the origin:

    >>> rng = np.random.default_rng(0)
    >>> pts = np.c_[rng.uniform(-2, 2, 400), 4.0 + rng.normal(0, 0.02, 400), rng.uniform(0, 2.5, 400)]
    >>> feet = np.c_[np.linspace(-2, 2, 50), np.full(50, 3.95), np.zeros(50)]
    >>> e = settled_offset(pts, np.array([0, 1.0, 0]), -3.95, feet, np.array([1.0, 0, 0]), np.array([0, 0, 1.0]),
    ...                    2.5, 0.1, np.zeros((1, 3)))
    >>> round(-e, 2)
    4.0
    """
    points = np.asarray(points, np.float64)
    side = np.sign(np.mean(cameras @ normal + offset)) or 1.0
    a = feet @ along
    base = float(np.median(feet @ up))
    pa, ph = points @ along, points @ up - base
    region = (pa >= a.min()) & (pa <= a.max()) & (ph >= -threshold) & (ph <= max_height + threshold)
    signed = (points[region] @ normal + offset) * side  # > 0: in front of the wall
    shift = 0.0
    for _ in range(rounds):
        near = np.abs(signed - shift) < threshold
        if near.sum() < min_points:
            break
        shift = float(np.clip(np.median(signed[near]), -threshold, threshold))
    return float(offset - shift * side)


@dataclass
class WallReach:
    """Where walls reach past their margin, along a wall that few views see (see :func:`wall_reach`).

    Attributes
    ----------
    planes : StuffPlanes
        The planes with an unbounded margin, and the cells of it that sight lines pass through.
    margin : float
        The planes' own margin: another plane's extent within it separates a wall from its reach.
    walls : np.ndarray
        ``[P] bool``: vertical planes (only they reach).
    along : np.ndarray
        ``[P, 3]`` each wall's horizontal direction in its plane.
    behind : list of np.ndarray
        Per plane, sorted ``int64`` columns (``floor(along · x / cell)``) where a view sees floor behind it.
    box : np.ndarray
        ``[2, 3]`` the region reach stays in (world units).
    """

    planes: StuffPlanes
    margin: float
    walls: np.ndarray
    along: np.ndarray
    behind: list
    box: np.ndarray

    def first_hit(self, origins: np.ndarray, directions: np.ndarray, min_cos: float = 0.1,
                  t_min: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
        """Where each ray first meets a wall outside its points' hull, where the wall still reaches.

        A spot beyond the hull counts when no other plane's extent (hull and margin) lies between it and the
        wall's points (the segment from the wall's origin to it crosses no plane there), no sight line
        passes through its cell, no view sees floor behind its column, and it lies in ``box``.
        Same returns as :meth:`StuffPlanes.first_hit` (``inf`` / ``-1`` where no wall reaches).
        """
        p = self.planes
        r = len(origins)
        t_best = np.full(r, np.inf)
        best = np.full(r, -1, np.int64)
        for k in np.flatnonzero(self.walls):
            t, cos = ray_plane_distance(origins, directions, p.normal[k], p.offset[k])
            idx = np.flatnonzero((np.abs(cos) >= min_cos) & (t > t_min) & (t < t_best))
            if not len(idx):
                continue
            x = origins[idx] + t[idx, None] * directions[idx]
            p2, beyond = _beyond_hull(x, p.origin[k], p.basis[k], p.hull[k])
            ok = (beyond > 0) & np.all((x >= self.box[0]) & (x <= self.box[1]), axis=1)
            for j in range(len(p)):
                if j == k or not ok.any():
                    continue
                # the spot and the wall's points on either side of plane j, where plane j's extent is
                a = p.origin[k] @ p.normal[j] + p.offset[j]
                b = x @ p.normal[j] + p.offset[j]
                crossing = np.flatnonzero(ok & (np.sign(b) != np.sign(a)) & (b != 0))
                if not len(crossing):
                    continue
                at = p.origin[k] + (a / (a - b[crossing]))[:, None] * (x[crossing] - p.origin[k])
                ok[crossing[_beyond_hull(at, p.origin[j], p.basis[j], p.hull[j])[1] <= self.margin]] = False
            if p.seen_through is not None and ok.any():
                ok[ok] = ~p.seen_through_at(k, p2[ok])
            if len(self.behind[k]) and ok.any():
                ok[ok] = ~np.isin(np.floor(x[ok] @ self.along[k] / p.cell).astype(np.int64), self.behind[k])
            idx = idx[ok]
            t_best[idx] = t[idx]
            best[idx] = k
        return t_best, best


def wall_reach(planes: StuffPlanes, sightlines, floor_sightlines, up: np.ndarray, threshold: float,
               box: np.ndarray, max_tilt_deg: float = 10.0) -> WallReach:
    """How far the walls among ``planes`` reach past their margin.

    A wall's plane reaches as far past its points as its margin (``planes.margin``). A long wall that only
    two views see end-on, from across the room, has no points on most of its length (stereo at a grazing
    angle, its foot too far to place), so its pixels there got no target although its plane is right. Walls
    are long and straight; what stops one is another wall, or open space. So a wall reaches on, inside
    ``box``, until

    * another plane's extent lies between the spot and the wall's points (the inner wall of an L-shaped room
      stops at the wall across its end),
    * a sight line passes through the spot's cell (as :meth:`StuffPlanes.with_seen_through`, over the whole
      plane), or
    * a view sees floor behind the wall at that place along it (``floor_sightlines``: the floor plane's points
      under floor-labelled pixels, more than ``threshold`` behind the wall): a wall stands on the floor from
      the floor to the ceiling, so floor seen past its line means it is not there, at any height. Plain walls
      give stereo few sight lines; the floor is labelled in every view.

    Parameters
    ----------
    planes : StuffPlanes
        The planes (their ``seen_through`` is not used).
    sightlines, floor_sightlines : (np.ndarray, np.ndarray)
        ``[M, 3]`` camera centres and ``[M, 3]`` the points they see: every observation, and the floor.
    up : np.ndarray
        The scene's up direction.
    threshold : float
        The plane threshold (world units); cells and columns are ``2 × threshold``.
    box : np.ndarray
        ``[2, 3]`` min and max corner that reach stays in.

    Examples
    --------
    A wall x = -3 whose points stop at y = 0, in a room 8 m long, and a wall x = 3 whose points stop there too
    but behind whose line a view sees floor at y = 2 (an opening): the first reaches on, the second does not.

    >>> rng = np.random.default_rng(0)
    >>> left = np.c_[np.full(40, -3.0), rng.uniform(-4, 0, 40), rng.uniform(0, 2.5, 40)]
    >>> right = left * [-1, 1, 1]
    >>> planes = fit_planes(np.r_[left, right], np.ones(80, int), [1], threshold=0.05, margin=0.5)
    >>> eye = np.array([0.0, 0.0, 1.5])
    >>> floor = (np.array([eye]), np.array([[6.0, 4.0, 0.0]]))  # crosses x = 3 at y = 2
    >>> reach = wall_reach(planes, (np.zeros((0, 3)), np.zeros((0, 3))), floor, np.array([0, 0, 1.0]), 0.05,
    ...                    np.array([[-3.1, -4.1, -0.1], [3.1, 4.1, 3.0]]))
    >>> d = np.array([[-3.0, 2.0, 0.0], [3.0, 2.0, 0.0]]) / np.sqrt(13)
    >>> t, k = reach.first_hit(np.tile(eye, (2, 1)), d)
    >>> float(planes.offset[k[0]]), int(k[1]), round(float(t[0]), 3)  # the left wall x = -3; the right: none
    (3.0, -1, 3.606)
    >>> planes.first_hit(np.tile(eye, (2, 1)), d)[1].tolist()  # 2 m past the points, 0.5 m margin
    [-1, -1]
    """
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    far = replace(planes, margin=np.inf, seen_through=None).with_seen_through(*sightlines, threshold)
    walls = planes.vertical(up, max_tilt_deg)
    along = np.zeros((len(planes), 3))
    behind = []
    fc, fp = (np.asarray(a, np.float64) for a in floor_sightlines)
    for k in range(len(planes)):
        if not walls[k]:
            behind.append(np.zeros(0, np.int64))
            continue
        h = np.cross(up, planes.normal[k])
        along[k] = h / np.linalg.norm(h)
        x = _crossing_points((fc, fp), planes.normal[k], planes.offset[k], threshold)
        _, beyond = _beyond_hull(x, planes.origin[k], planes.basis[k], planes.hull[k])
        col = np.floor(x[beyond > 0] @ along[k] / far.cell).astype(np.int64)
        # a column's neighbours too: the floor is seen through the wall's line between sampled pixels
        behind.append(np.unique(np.r_[col - 1, col, col + 1]))
    return WallReach(far, float(planes.margin), walls, along, behind, np.asarray(box, np.float64))


def ceiling_height(cameras, frames, labels: dict[int, np.ndarray], planes: "StuffPlanes", normal: np.ndarray,
                   offset: float, ceiling_classes, threshold: float, min_points: int, min_rows: int = 2
                   ) -> tuple[float | None, int]:
    """The ceiling's height above the floor, from where the 2D labels put a ceiling class directly above a wall
    whose plane is known: the ray through that boundary meets the wall's plane at the ceiling.

    Parameters
    ----------
    planes : StuffPlanes
        The planes found so far; walls are those within 10° of vertical.
    normal, offset : np.ndarray, float
        The floor plane (``normal`` up).
    ceiling_classes : iterable of int
        Classes that may be the ceiling (stuff that no floor or wall plane holds).
    threshold : float
        The heights must agree: their median absolute deviation is at most this (world units).
    min_points : int
        Fewest boundary points.

    Returns
    -------
    height : float or None
        Median height of the boundary points above the floor; None when too few, when they disagree, or when
        it is not above the cameras (a ceiling is).
    count : int
        Boundary points found.

    Examples
    --------
    A camera 1.5 m above the floor looking along +y at the wall y = 2 of a room 2.5 m high:

    >>> from lift3d.data.cameras import Cameras
    >>> c2w = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 1.5], [0, 0, 0, 1]])
    >>> cams = Cameras(c2w[None], fx=32.0, fy=32.0, cx=32.0, cy=32.0, width=64, height=64)
    >>> rows = np.arange(64)[:, None].repeat(64, 1)
    >>> sem = np.where(rows < 16, 3, 1)                        # 1 m above the eye, 2 m away
    >>> wall = fit_planes(np.c_[np.linspace(-3, 3, 20), np.full(20, 2.0), np.tile([0.5, 2.5], 10)],
    ...                   np.ones(20, int), [1], threshold=0.05, min_points=8, up=np.array([0, 0, 1.0]))
    >>> height, count = ceiling_height(cams, [0], {0: sem}, wall, np.array([0, 0, 1.0]), 0.0, [3], 0.05, 8)
    >>> round(height, 2), count
    (2.5, 64)
    """
    normal = np.asarray(normal, np.float64)
    vertical = planes.vertical(normal)
    ceiling = [int(c) for c in ceiling_classes]
    walls = sorted(set().union(*[c for c, v in zip(planes.classes, vertical) if v]) - set(ceiling)) \
        if vertical.any() else []
    if not walls or not ceiling:
        return None, 0
    heights, eyes = [], []
    for i in frames:
        i = int(i)
        sem = labels[i]
        r, c = label_boundary(sem, ceiling, walls, min_rows, same="lower")
        # Nothing of a wall lies above a ceiling in the image; above a window or a picture its wall goes on. A
        # window's sill is no ceiling, even above the eyes (a test room's made a level plane at 1.67 m of 3.2).
        wall_above = np.maximum.accumulate(np.isin(sem, walls), axis=0)
        keep = ~wall_above[r, c]
        r, c = r[keep], c[keep]
        if not len(r):
            continue
        o, d = cameras.rays(i, c.astype(np.float64), r + 0.5)
        t, k = planes.first_hit(o, d)
        ok = (k >= 0) & planes.holds(k, sem[r + 1, c].astype(np.int64))
        ok[ok] &= vertical[k[ok]]
        heights.append((o[ok] + t[ok, None] * d[ok]) @ normal + offset)
        eyes.append(float(cameras.c2w_opencv[i][:3, 3] @ normal + offset))
    h = np.concatenate(heights) if heights else np.zeros(0)
    if len(h) < min_points:
        return None, int(len(h))
    height = float(np.median(h))
    if np.median(np.abs(h - height)) > threshold or height <= np.median(eyes):
        return None, int(len(h))
    return height, int(len(h))


def ceiling_points(cameras, frames, labels: dict[int, np.ndarray], normal: np.ndarray, offset: float,
                   ceiling_classes, stride: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the rays of the pixels the labels call ceiling (every ``stride``-th row and column) meet the ceiling
    plane ``normal · x + offset = 0``: points on a plain ceiling, for the plane fit (or the floor's, for any
    level plane and its classes). Returns ``xyz``,
    ``classes`` and the camera centres (sight lines), as :func:`floor_boundary_points`."""
    normal = np.asarray(normal, np.float64)
    ids = [int(c) for c in ceiling_classes]
    out_xyz, out_cls, out_cam = [], [], []
    for i in frames:
        i = int(i)
        sem = labels[i][stride // 2::stride, stride // 2::stride]
        r, c = np.nonzero(np.isin(sem, ids))
        if not len(r):
            continue
        o, d = cameras.rays(i, (c * stride + stride // 2).astype(np.float64), (r * stride + stride // 2).astype(np.float64))
        t, _ = ray_plane_distance(o, d, normal, offset)
        ok = np.isfinite(t) & (t > 0)
        out_xyz.append(o[ok] + t[ok, None] * d[ok])
        out_cls.append(sem[r[ok], c[ok]].astype(np.int64))
        out_cam.append(o[ok])
    if not out_xyz:
        return np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros((0, 3))
    return np.concatenate(out_xyz), np.concatenate(out_cls), np.concatenate(out_cam)


def enclosed_segments(cameras, i: int, sem: np.ndarray, classes, planes: StuffPlanes, stride: int = 4,
                      min_share: float = 0.6, min_ring: int = 8, targeted: np.ndarray | None = None,
                      max_targeted: float = 0.5, margin: bool = False
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pixels of segments that one plane surrounds in view ``i``, on that plane: a window in a wall.

    A stuff class no plane holds (a window with a repeating pattern, which stereo matches wrongly, so no plane
    gathers half its points) gets no depth target, though its segment sits inside a wall whose pixels have one.
    Each connected segment of ``classes`` in ``sem`` is looked at on its own: the pixels just around it (its
    one-pixel ring, void left out) cast their rays at the planes, and when ``min_share`` of the ring meets one
    plane that holds the ring pixel's class, the segment's pixels (every ``stride``-th row and column) take
    the depth where their rays meet that plane, inside the hull of its points (no margin): sky above the
    top of a building's face is not in that face's hull.

    With ``targeted``, held classes can be enclosed too: a window in a second wall, when the plane that holds
    the window class is the first wall. Pixels that already have a target keep it, and a segment of which more
    than ``max_targeted`` of the kept pixels already have one is left alone (a floor segment that a wall's
    plane happens to surround is the floor plane's).

    Parameters
    ----------
    cameras : lift3d.data.cameras.Cameras
    i : int
        The view.
    sem : np.ndarray
        ``[H, W]`` its semantic labels (0 = void).
    classes : iterable of int
        Classes whose segments may be enclosed (stuff that no plane holds; any stuff with ``targeted``).
    planes : StuffPlanes
    stride : int
        Pixels of the segments kept: rows and columns ``stride // 2 + k · stride`` (as the plane targets).
    min_share : float
        Share of the ring that must meet the one plane.
    min_ring : int
        Fewest ring pixels (a smaller segment is noise).
    targeted : np.ndarray, optional
        ``bool [H, W]``: pixels that already have a target (they are not returned).
    max_targeted : float
        With ``targeted``: most share of a segment's kept pixels that may already have a target.
    margin : bool
        Pixels whose rays meet the plane within its margin count too (where :meth:`StuffPlanes.first_hit`
        meets it first). For a room, where no sky lies above a wall: a window high on a wall whose points stop
        below it.

    Returns
    -------
    rows, cols : np.ndarray
        ``int64 [N]`` pixels.
    t : np.ndarray
        ``[N]`` distance along each pixel's unit ray to the plane.
    plane : np.ndarray
        ``int64 [N]`` the plane.

    Examples
    --------
    A window (class 5) in the middle of a wall x = 3 (class 1) that a view from the origin looks at:

    >>> from lift3d.data.cameras import Cameras, look_at
    >>> wall = np.c_[np.full(40, 3.0), np.random.default_rng(0).uniform(-2, 2, (40, 2))]
    >>> planes = fit_planes(wall, np.ones(40, int), [1], threshold=0.02)
    >>> cams = Cameras(look_at(np.zeros(3), np.array([1.0, 0, 0]))[None], fx=40.0, fy=40.0, cx=32.0, cy=32.0,
    ...                width=64, height=64)
    >>> sem = np.ones((64, 64), np.int64); sem[24:40, 24:40] = 5
    >>> r, c, t, k = enclosed_segments(cams, 0, sem, [5], planes, stride=4)
    >>> len(r), k.tolist() == [0] * len(r), bool(np.allclose(cams.rays(0, c, r)[1][:, 0] * t, 3.0))
    (16, True, True)
    """
    from scipy import ndimage

    sem = np.asarray(sem)
    empty = np.zeros(0, np.int64)
    out = []
    for cl in sorted(int(c) for c in classes):
        segments, n = ndimage.label(sem == cl)
        if n == 0:
            continue
        owner = ndimage.grey_dilation(segments, size=(3, 3))
        rr, cc = np.nonzero((owner > 0) & (segments == 0) & (sem > 0))
        if not len(rr):
            continue
        o, d = cameras.rays(i, cc, rr)
        _, hit = planes.first_hit(o, d)
        hit = np.where(planes.holds(hit, sem[rr, cc].astype(np.int64)), hit, -1)
        ring_owner = owner[rr, cc]
        ring_size = np.bincount(ring_owner, minlength=n + 1)
        for j in np.flatnonzero(ring_size >= min_ring):
            k = hit[(ring_owner == j) & (hit >= 0)]
            if not len(k):
                continue
            host = int(np.bincount(k).argmax())
            if (k == host).sum() < min_share * ring_size[j]:
                continue
            pr, pc = np.nonzero(segments[stride // 2::stride, stride // 2::stride] == j)
            pr, pc = pr * stride + stride // 2, pc * stride + stride // 2
            if targeted is not None and len(pr):
                done = targeted[pr, pc]
                if done.mean() > max_targeted:
                    continue
                pr, pc = pr[~done], pc[~done]
            if not len(pr):
                continue
            po, pd = cameras.rays(i, pc, pr)
            t, cos = ray_plane_distance(po, pd, planes.normal[host], planes.offset[host])
            with np.errstate(invalid="ignore"):
                ok = np.isfinite(t) & (t > 0) & (np.abs(cos) >= 0.1)
            _, beyond = _beyond_hull(po[ok] + t[ok, None] * pd[ok], planes.origin[host], planes.basis[host],
                                     planes.hull[host])
            inside = beyond <= 0
            if margin and not inside.all():
                inside |= planes.first_hit(po[ok], pd[ok])[1] == host
            ok[ok] = inside
            out.append((pr[ok], pc[ok], t[ok], np.full(int(ok.sum()), host, np.int64)))
    if not out:
        return empty, empty, np.zeros(0), empty
    return tuple(np.concatenate(a) for a in zip(*out))


def label_support(cameras, frames, labels: dict[int, np.ndarray], planes: StuffPlanes, points: np.ndarray,
                  plane: np.ndarray, own_frame: int, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """How many other views' 2D labels agree that plane points are the plane's stuff.

    A plane target comes from one view's label: a wardrobe that one view's segmenter calls wall gets the
    wall's depth behind it. The other views that look at that spot of the wall see the wardrobe in front of
    it and label it wardrobe. Each point is projected into every view of ``frames`` but ``own_frame``; a
    view votes when the point falls inside its image, in front of it, not behind another plane (from that
    camera the first plane met lies no nearer than the point, less ``tolerance``) and its label there is not
    void. The vote supports the point when that label is a class the point's plane holds.

    Parameters
    ----------
    cameras : lift3d.data.cameras.Cameras
    frames : np.ndarray
        The views that vote (training frames).
    labels : dict
        Frame index → ``[H, W]`` semantic pseudo-labels (0 = void).
    planes : StuffPlanes
    points : np.ndarray
        ``[N, 3]`` points on the planes (world units).
    plane : np.ndarray
        ``int64 [N]`` the plane of each point.
    own_frame : int
        The view the points came from (does not vote).
    tolerance : float
        How much nearer than the point another plane may be met and still not hide it (world units).

    Returns
    -------
    support, votes : np.ndarray
        ``int64 [N]`` supporting views and voting views.

    Examples
    --------
    A wall x = 2 that every view labels wall (class 1) on its left half and wardrobe (class 9) on its right:

    >>> from lift3d.data.cameras import Cameras, look_at
    >>> rng = np.random.default_rng(0)
    >>> wall = np.c_[np.full(60, 2.0), rng.uniform(-2, 2, 60), rng.uniform(0, 3, 60)]
    >>> planes = fit_planes(wall, np.full(60, 1), [1], threshold=0.02)
    >>> eyes = [np.array([0.0, y, 1.5]) for y in (-0.5, 0.0, 0.5)]
    >>> c2w = np.stack([look_at(e, e + np.array([1.0, 0, 0])) for e in eyes])
    >>> cams = Cameras(c2w=c2w, fx=np.full(3, 50.0), fy=np.full(3, 50.0), cx=np.full(3, 50.0),
    ...                cy=np.full(3, 50.0), width=np.full(3, 100), height=np.full(3, 100))
    >>> sem = np.ones((100, 100), np.int64); sem[:, 50:] = 9
    >>> pts = np.array([[2.0, 1.0, 1.5], [2.0, -1.0, 1.5]])  # left of the views, right of the views
    >>> label_support(cams, [0, 1, 2], {i: sem for i in range(3)}, planes, pts, np.zeros(2, np.int64), 0, 0.05)
    (array([2, 0]), array([2, 2]))
    """
    points = np.asarray(points, np.float64)
    support = np.zeros(len(points), np.int64)
    votes = np.zeros(len(points), np.int64)
    plane = np.asarray(plane, np.int64)
    for j in frames:
        j = int(j)
        if j == int(own_frame) or j not in labels:
            continue
        sem = labels[j]
        h, w = sem.shape
        uv, z = cameras.project(j, points)
        with np.errstate(invalid="ignore"):
            k = np.flatnonzero((z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h))
        if not len(k):
            continue
        cls = sem[uv[k, 1].astype(np.int64), uv[k, 0].astype(np.int64)]
        k, cls = k[cls != 0], cls[cls != 0]
        if not len(k):
            continue
        center = cameras.centers[j]
        seg = points[k] - center
        dist = np.linalg.norm(seg, axis=1)
        t, _ = planes.first_hit(np.broadcast_to(center, seg.shape), seg / dist[:, None])
        open_ = t >= dist - tolerance
        k, cls = k[open_], cls[open_]
        votes[k] += 1
        support[k] += planes.holds(plane[k], cls)
    return support, votes


def label_boundary(sem: np.ndarray, upper, lower, min_rows: int = 2, same: str = "upper") -> tuple[np.ndarray, np.ndarray]:
    """Pixels where ``min_rows`` rows of ``upper`` classes sit directly on ``min_rows`` rows of ``lower`` ones.

    Parameters
    ----------
    sem : np.ndarray
        ``[H, W]`` labels.
    upper, lower : iterable of int
    same : str
        ``upper`` or ``lower``: the side whose rows must all hold one class (the wall's side).

    Returns
    -------
    rows, cols : np.ndarray
        The last ``upper`` row of each boundary and its column.
    """
    if same not in ("upper", "lower"):
        raise ValueError(f"label_boundary: same must be 'upper' or 'lower', not {same!r}")
    h, _ = sem.shape
    k = min_rows
    if h < 2 * k:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    up, lo = np.isin(sem, [int(c) for c in upper]), np.isin(sem, [int(c) for c in lower])
    n = h - 2 * k + 1
    edge = np.ones((n, sem.shape[1]), bool)
    ref = sem[k - 1:k - 1 + n] if same == "upper" else sem[k:k + n]
    for j in range(k):
        edge &= up[j:j + n] & lo[k + j:k + j + n]
        edge &= (sem[j:j + n] if same == "upper" else sem[k + j:k + j + n]) == ref
    r, c = np.nonzero(edge)
    return r + k - 1, c


def _ransac_planes(x: np.ndarray, threshold: float, iterations: int, rng: np.random.Generator,
                   up: np.ndarray | None = None, keep: int = 1, min_count: int = 1) -> list[tuple[np.ndarray, float]]:
    """The ``keep`` planes (distinct, each with at least ``min_count`` of ``x`` within ``threshold``) that most
    of ``x`` lie within ``threshold`` of, among planes through 3 random points (with ``up``: horizontal planes
    through one point and vertical ones through two)."""
    idx = rng.integers(0, len(x), size=(iterations, 3))
    a, b, c = x[idx[:, 0]], x[idx[:, 1]], x[idx[:, 2]]
    if up is None:
        n = np.cross(b - a, c - a)
    else:
        along = b - a
        along -= np.outer(along @ up, up)
        vertical = np.cross(up, along)
        n = np.concatenate([vertical, np.broadcast_to(up, (iterations, 3))])
        a = np.concatenate([a, c])
    n, d = _unit_planes(n, a)
    if not len(n):
        return []
    near = np.abs(x @ n.T + d) < threshold
    counts = near.sum(0)
    out, kept = [], []
    for k in np.argsort(-counts, kind="stable"):
        if len(out) == keep or counts[k] < max(min_count, 1):
            break
        # distinct: most of its inliers are not those of any one plane already kept. (Not of their union: a
        # few horizontal slabs through a wall's points at different heights together cover that wall.)
        if any((near[:, k] & near[:, j]).sum() > 0.5 * counts[k] for j in kept):
            continue
        kept.append(k)
        out.append((n[k], float(d[k])))
    return out


def _extent(pts: np.ndarray, n: np.ndarray, threshold: float):
    """``(origin, basis, hull equations)`` of inliers ``pts`` in the plane, or None when they lie along a line."""
    from scipy.spatial import ConvexHull, QhullError

    origin = pts.mean(0)
    basis = _plane_basis(n)
    p2 = (pts - origin) @ basis.T
    # Points along a line (one row of keypoints, or the corner where two walls meet, which every plane through
    # it fits) do not fix a plane: most of them must spread in both directions of the plane.
    axes = np.linalg.svd(p2 - p2.mean(0), full_matrices=False)[2]
    lo, hi = np.percentile(p2 @ axes.T, [10, 90], axis=0)
    if np.min(hi - lo) < 6 * threshold:
        return None
    try:
        return origin, basis, ConvexHull(p2).equations
    except QhullError:
        return None


def contradicted(sightlines, normal: np.ndarray, offset: float, points: np.ndarray, threshold: float,
                 max_crossing_share: float = 0.2) -> bool:
    """Whether the plane ``normal · x + offset = 0`` over the hull of ``points`` is not there: sight lines
    (``(cameras, seen points)``, ``[M, 3]`` each) cross it inside that hull more than ``max_crossing_share`` as
    often as they end on it (the test :func:`fit_planes` puts its planes to), or its points lie along a line.

    Examples
    --------
    A level plane at 1.7 m over a 4 m square, and a camera at 1.5 m that sees wall points at 2.5 m through it:

    >>> square = np.c_[np.random.default_rng(0).uniform(-2, 2, (100, 2)), np.full(100, 1.7)]
    >>> seen = np.c_[np.linspace(-1.5, 1.5, 20), np.full(20, 1.9), np.full(20, 2.5)]
    >>> contradicted((np.tile([0.0, 0.0, 1.5], (20, 1)), seen), np.array([0, 0, 1.0]), -1.7, square, 0.05)
    True
    >>> contradicted((np.tile([0.0, 0.0, 1.5], (20, 1)), seen), np.array([0, 0, 1.0]), -3.0, square + [0, 0, 1.3], 0.05)
    False
    """
    normal = np.asarray(normal, np.float64)
    extent = _extent(np.asarray(points, np.float64), normal, threshold) if len(points) >= 3 else None
    if extent is None:
        return True
    crossings, support = _crossings(sightlines, normal, offset, extent, threshold)
    return crossings > max_crossing_share * support


def _crossings(sightlines, n: np.ndarray, d: float, extent, threshold: float) -> tuple[int, int]:
    """``(crossings, support)``: how many sight lines (camera → seen point) pass through the plane inside its
    inliers' hull (grown by ``threshold``), their point more than ``threshold`` beyond it, and how many end on
    it (point within ``threshold``, inside the same region).

    Only the hull counts, not the margin targets may reach beyond it: the margin of an inner wall of an
    L-shaped room reaches into the room, where every sight line to the far walls crosses it (tuning scene 100:
    1.6 crossings per supporting sight line with a margin of 10 % of the diagonal, 0.05 without)."""
    pt = sightlines[1]

    def inside(x: np.ndarray) -> int:
        return int((_beyond_hull(x, *extent)[1] <= threshold).sum())

    return inside(_crossing_points(sightlines, n, d, threshold)), inside(pt[np.abs(pt @ n + d) < threshold])


def _crossing_points(sightlines, n: np.ndarray, d: float, threshold: float) -> np.ndarray:
    """``[K, 3]``: where the sight lines (``(cameras, seen points)``) whose point lies more than ``threshold``
    beyond the plane ``n · x + d = 0``, on the other side from its camera, pass through it."""
    cam, pt = sightlines
    sc, sp = cam @ n + d, pt @ n + d
    cross = (np.sign(sc) != np.sign(sp)) & (np.abs(sp) > threshold) & (np.abs(sc) > 0)
    c, p = cam[cross], pt[cross]
    return c + (sc[cross] / (sc[cross] - sp[cross]))[:, None] * (p - c)


def _beyond_hull(x: np.ndarray, origin: np.ndarray, basis: np.ndarray, hull: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Points ``x`` (``[N, 3]``, on a plane) in the plane's 2D coordinates (``[N, 2]``) and how far beyond the
    hull (``[E, 3]`` half-planes, unit normals) each lies (``[N]``; at most 0 inside)."""
    p2 = (x - origin) @ basis.T
    return p2, (np.max(p2 @ hull[:, :2].T + hull[:, 2], axis=1) if len(p2) else np.zeros(0))


def _cell_keys(ij: np.ndarray) -> np.ndarray:
    """``int64 [N]`` one key per 2D cell index ``ij`` (``[N, 2]``, each within ±2^30)."""
    return (ij[:, 0] + 2 ** 30) * 2 ** 31 + (ij[:, 1] + 2 ** 30)


def _unit_planes(n: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Planes with (unnormalised) normals ``n`` ``[K, 3]`` through points ``a`` ``[K, 3]`` as unit normals and
    offsets ``d`` (``n · x + d = 0``); degenerate ones (zero normal: a repeated or collinear draw) dropped."""
    norm = np.linalg.norm(n, axis=1)
    ok = norm > 1e-9
    n = n[ok] / norm[ok, None]
    return n, -np.einsum("ij,ij->i", n, a[ok])


def _least_squares_plane(x: np.ndarray, like: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Least-squares plane of ``x``; with ``like`` (a unit normal), that normal is kept and only the offset
    fitted (the horizontal and vertical candidates of an ``up``-constrained fit stay so)."""
    c = x.mean(0)
    if like is None:
        n = np.linalg.svd(x - c, full_matrices=False)[2][2]
        return n, float(-n @ c)
    return like, float(-like @ c)


def _refined_up(x: np.ndarray, up: np.ndarray, threshold: float, min_points: int,
                rng: np.random.Generator, iterations: int = 500) -> np.ndarray:
    """``up`` replaced by the normal of the largest plane among ``x`` within 25° of it, when that plane holds
    ``2 × min_points`` points (the cameras' mean image-up axis is only roughly up: cameras that all look one
    way and down tilt it by 10° and more)."""
    idx = rng.integers(0, len(x), size=(iterations, 3))
    n, d = _unit_planes(np.cross(x[idx[:, 1]] - x[idx[:, 0]], x[idx[:, 2]] - x[idx[:, 0]]), x[idx[:, 0]])
    side = np.sign(n @ up)
    n, d = n * side[:, None], d * side
    ok = n @ up > np.cos(np.radians(25))
    if not ok.any():
        return up
    n, d = n[ok], d[ok]
    counts = (np.abs(x @ n.T + d) < threshold).sum(0)
    k = int(np.argmax(counts))
    if counts[k] < 2 * min_points:
        return up
    inl = np.abs(x @ n[k] + d[k]) < threshold
    pts = x[inl]
    m = np.linalg.svd(pts - pts.mean(0), full_matrices=False)[2][2]
    return m if m @ up > 0 else -m


def _plane_basis(n: np.ndarray) -> np.ndarray:
    """``[2, 3]`` orthonormal vectors spanning the plane with normal ``n``."""
    helper = np.eye(3)[int(np.argmin(np.abs(n)))]
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(n, e1)])
