"""Fitting stuff planes to points: each point's class from its observations, then sequential RANSAC over the
stuff classes' points, constrained to level and upright planes and tested against the sight lines."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lift3d.sfm.planes.model import StuffPlanes, _crossings, _extent

#: How far the given up may be from the floor's normal, the cone the fit refines it in: about the cameras' mean
#: image-up axis, which leans with their pitch, and about an up level to their right axes, off by their roll only
#: (:func:`lift3d.sfm.mvs.plane_fit_up`; a wider cone about a level up let a small test room's fit take a plane
#: tilted 25° through the floor and the walls' feet for the floor).
LEANING_UP_CONE_DEG = 25.0
LEVEL_UP_CONE_DEG = 10.0


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


@dataclass(frozen=True)
class FitSettings:
    """How :func:`fit_planes` searches for planes and which classes a plane holds."""

    max_planes: int = 24
    """Most planes."""
    iterations: int = 500
    """RANSAC draws per plane."""
    min_class_share: float = 0.25
    """A plane holds every class with at least this share of its inliers."""
    min_class_cover: float = 0.5
    """A plane also holds every class of which it has at least this share of the points (and 3): a rug on the
    floor or a window in a wall has too few points to make a quarter of the plane's inliers, and without this
    their pixels got no targets (tuning scenes 100-111: rugs 3-12 % covered on six of them, windows 5-9 %)."""
    candidates: int = 64
    """With sight lines: RANSAC planes (distinct from each other) scored against them per plane found."""
    max_crossing_share: float = 0.2
    """With sight lines: most sight lines crossing a plane, as a share of those ending on it. On indoor tuning
    scenes real walls had up to 0.12 (sight lines to wrong plane-sweep depths behind them) and false planes from
    0.23."""


def fit_planes(points: np.ndarray, classes: np.ndarray, stuff_ids, threshold: float, min_points: int = 15,
               margin: float = 0.0, up: np.ndarray | None = None,
               sightlines: tuple[np.ndarray, np.ndarray] | None = None, seed: int = 0,
               settings: FitSettings | None = None, up_tolerance_deg: float = LEANING_UP_CONE_DEG) -> StuffPlanes:
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
    margin : float
        Stored in the result: how far beyond its inliers' hull a plane extends.
    up : np.ndarray, optional
        The scene's up direction. Given, planes are horizontal or vertical (floors, ceilings, walls, roads,
        façades): a horizontal plane needs one point and a vertical one two, so a few points per wall
        suffice and a horizontal slab through the feet of all walls is not a candidate for a wall. The up
        direction is first refined to the normal of the largest plane within ``up_tolerance_deg`` of it.
    sightlines : (np.ndarray, np.ndarray), optional
        ``[M, 3]`` camera centres and ``[M, 3]`` the points they see (every observation, things too). A
        plane that sight lines cross inside its extent is contradicted by the views. Of the
        ``settings.candidates`` best RANSAC planes, those crossed by more than ``settings.max_crossing_share`` of
        the sight lines that end on them are dropped, and the one with most inliers × (1 − that share) wins.
        Without this, objects' points the labels call floor make horizontal slabs above the floor, which floor
        pixels' rays meet first. (A share, not a count: points are thinned before fitting, sight lines are not.)
    seed : int
        RANSAC's random draws (the result is deterministic for a seed).
    settings : FitSettings, optional
        How many planes and draws, and which classes a plane holds (default: :class:`FitSettings`'s).
    up_tolerance_deg : float
        How far ``up`` may be from the floor's normal (:data:`LEANING_UP_CONE_DEG`, :data:`LEVEL_UP_CONE_DEG`).
    """
    s = FitSettings() if settings is None else settings
    max_planes, iterations, candidates = s.max_planes, s.iterations, s.candidates
    max_crossing_share, min_class_share, min_class_cover = s.max_crossing_share, s.min_class_share, s.min_class_cover
    rng = np.random.default_rng(seed)
    points = np.asarray(points, np.float64)
    classes = np.asarray(classes, np.int64)
    stuff = np.isin(classes, [int(c) for c in stuff_ids])
    left, left_cls = points[stuff], classes[stuff]
    class_total = np.bincount(left_cls, minlength=1) if len(left_cls) else np.zeros(1, np.int64)
    if up is not None:
        up = np.asarray(up, np.float64) / np.linalg.norm(up)
    if up is not None and len(left) >= min_points:
        up = _refined_up(left, up, threshold, min_points, rng, tolerance_deg=up_tolerance_deg)
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
                           float(margin), up=up)
    n, d, cls, rms, cnt, origin, basis, hull, main = zip(*rows)
    return StuffPlanes(np.array(n), np.array(d), list(cls), np.array(rms), np.array(cnt, np.int64),
                       np.array(origin), np.array(basis), list(hull), float(margin), margin_classes=list(main), up=up)


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
                rng: np.random.Generator, iterations: int = 500, tolerance_deg: float = LEANING_UP_CONE_DEG) -> np.ndarray:
    """``up`` replaced by the normal of the largest plane among ``x`` within ``tolerance_deg`` of it, when that plane
    holds ``2 × min_points`` points (the cameras' mean image-up axis is only roughly up: cameras that all look one
    way and down tilt it by 10° and more)."""
    idx = rng.integers(0, len(x), size=(iterations, 3))
    n, d = _unit_planes(np.cross(x[idx[:, 1]] - x[idx[:, 0]], x[idx[:, 2]] - x[idx[:, 0]]), x[idx[:, 0]])
    side = np.sign(n @ up)
    n, d = n * side[:, None], d * side
    ok = n @ up > np.cos(np.radians(tolerance_deg))
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
