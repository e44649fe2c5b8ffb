"""The plane model: stuff planes ``n · x + d = 0`` with their classes, extent and margin, where rays meet them,
and the free-space test sight lines put a plane to (docs/sfm.md, "Stuff planes").

A plane's extent is the convex hull of its inliers in its own 2D coordinates, grown by a margin; a ray meets
the plane only inside it (:meth:`StuffPlanes.first_hit`). Sight lines (camera → a point it sees) that pass
through a plane inside its hull contradict it (:func:`contradicted`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from lift3d.utils.geometry import plane_basis


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
    up : np.ndarray, optional
        ``[3]`` the up direction the planes were fitted level and upright to (:func:`fit_planes` refines the
        cameras' mean up to the normal of the largest near-level plane); None when fitted without one.
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
    up: np.ndarray | None = None

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

        >>> from lift3d.sfm.planes import fit_planes
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
                           margin_classes=[*self.margin_classes, frozenset(int(c) for c in np.unique(classes))],
                           up=self.up)

    def subset(self, keep: np.ndarray) -> "StuffPlanes":
        """The planes where ``keep`` (``[P] bool``)."""
        idx = np.flatnonzero(keep)
        return StuffPlanes(self.normal[idx], self.offset[idx], [self.classes[i] for i in idx], self.rms[idx],
                           self.inliers[idx], self.origin[idx], self.basis[idx], [self.hull[i] for i in idx],
                           self.margin, margin_classes=[self.margin_classes[i] for i in idx], up=self.up)

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


def _extent(pts: np.ndarray, n: np.ndarray, threshold: float):
    """``(origin, basis, hull equations)`` of inliers ``pts`` in the plane, or None when they lie along a line."""
    from scipy.spatial import ConvexHull, QhullError

    origin = pts.mean(0)
    basis = plane_basis(n)
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


