"""Priors of a room around the cameras: walls upright and at right angles to each other (their directions,
walls squared to them, planes cutting across a corner), far walls where the views' floor lines agree, walls
moved to where those lines put them, and how far a wall reaches along its line past its points."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np

from lift3d.sfm.planes.label_lines import FloorLine, _vertical_lines
from lift3d.sfm.planes.model import (StuffPlanes, _beyond_hull, _crossing_points, _crossings, contradicted,
                                     ray_plane_distance)


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

    >>> from lift3d.sfm.planes import fit_planes, floor_line
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


@dataclass(frozen=True)
class NewWalls:
    """How :func:`add_walls` draws a floor-line wall's points and tests it."""

    max_crossing_share: float = 0.2
    """Most sight lines crossing the wall inside its points' hull, as a share of those ending on it."""
    min_class_share: float = 0.25
    """The wall holds the classes of at least this share of its points."""
    gap: float | None = None
    """A wall is the most populated stretch of its feet without a gap over this (world units; default 5 ×
    the threshold)."""
    settle: bool = True
    """The wall first moves onto the stereo points in front of its stretch (:func:`settled_offset`)."""
    past_edge: bool = True
    """A wall's vertical lines go on past the top of a view's image while the view labels them its class."""


def add_walls(planes: StuffPlanes, cameras, labels: dict[int, np.ndarray], line: FloorLine, walls, up: np.ndarray,
              max_height: float, threshold: float, sightlines: tuple[np.ndarray, np.ndarray],
              how: NewWalls | None = None) -> tuple[StuffPlanes, int]:
    """``planes`` with the walls of :func:`floor_line_walls` that the views do not contradict, and how many.

    Each wall's points are its observations' feet on it and the vertical lines above them while each view keeps
    labelling the line that class (spaced ``2 × threshold`` up to ``max_height``, as
    :func:`floor_boundary_points`), of the feet's most populated stretch without a gap over ``how.gap``
    (default ``5 × threshold``) along the wall. A wall is kept when its points spread over an area and sight
    lines (``sightlines``, and the views to these points) cross it inside their hull no more than
    ``how.max_crossing_share`` as often as they end on it — the test of :func:`fit_planes`. It holds the classes
    of at least ``how.min_class_share`` of its points. The walls are added as they are: fitted again with every
    other point, their points shift RANSAC's draws (an L-shaped tuning room lost two walls that way).

    With ``how.settle`` (default), a wall first moves onto the stereo points in front of its stretch
    (:func:`settled_offset`): the boundaries put a far wall's foot a row off, which across a room is several
    centimetres, and the points seen just behind a wall placed in front of the real one counted as sight lines
    through it (tuning room 5: a wall 6.5 cm inside the room crossed by 0.202 of its sight lines, dropped).
    """
    how = NewWalls() if how is None else how
    max_crossing_share, min_class_share, settle, past_edge = how.max_crossing_share, how.min_class_share, \
        how.settle, how.past_edge
    added = 0
    gap = 5 * threshold if how.gap is None else how.gap
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


def floor_plane(planes: StuffPlanes, up: np.ndarray, max_tilt_deg: float = 25.0) -> tuple[int, np.ndarray, float] | None:
    """``(index, normal, offset)`` of the floor, the normal turned up: of the planes within ``max_tilt_deg`` of level,
    the one with most points (25°: the fit levels its planes to its own refined up, which may differ from the
    cameras' mean up). None without a level plane.

    Examples
    --------
    >>> level = StuffPlanes(np.array([[0, 0, -1.0], [0, 0, 1.0], [1.0, 0, 0]]), np.array([0.0, -2.5, 3.0]),
    ...                     [frozenset({2}), frozenset({3}), frozenset({1})], np.zeros(3), np.array([500, 80, 200]),
    ...                     np.zeros((3, 3)), np.zeros((3, 2, 3)), [])
    >>> f, n, d = floor_plane(level, np.array([0, 0, 1.0]))   # the plane with most points, its normal turned up
    >>> f, float(n[2]), d + 0.0
    (0, 1.0, 0.0)
    """
    level = np.abs(planes.normal @ up) > np.cos(np.radians(max_tilt_deg))
    if not level.any():
        return None
    f = int(np.flatnonzero(level)[np.argmax(planes.inliers[level])])
    n, d = planes.normal[f], float(planes.offset[f])
    return (f, -n, -d) if n @ up < 0 else (f, n, d)


def height_above(points: np.ndarray, normal: np.ndarray, offset: float, percentile: float = 99.0) -> float:
    """How high the points reach above the floor ``normal · x + offset = 0`` (their heights' ``percentile``; 0
    without points): the top of the vertical lines that the floor's boundaries with walls and things rise along."""
    return float(np.percentile(points @ normal + offset, percentile)) if len(points) else 0.0


def wall_classes(planes: StuffPlanes, floor: int, up: np.ndarray, stuff) -> list[int]:
    """The stuff classes that may stand on the floor as a wall: held by a vertical plane (within 10°) and not by
    the floor plane ``floor`` — unless two or more vertical planes hold it: the floor plane also takes a wall
    class when enough wall-labelled points lie at the wall's foot (tuning room 16), and that must not cost the
    walls their floor line. A segmenter that repeats its mistakes paints ceiling or window above floor here
    and there; the boundary of a class no wall plane holds is no wall's foot (one test room got a vertical
    "ceiling" plane outside the room from it, which then kept its real ceiling from getting a plane).

    Examples
    --------
    >>> from lift3d.sfm.planes import fit_planes
    >>> floor = np.c_[np.random.default_rng(0).uniform(-2, 2, (200, 2)), np.zeros(200)]
    >>> wall = np.c_[np.full(60, 2.0), np.random.default_rng(1).uniform([-2, 0], [2, 2.5], (60, 2))]
    >>> planes = fit_planes(np.r_[floor, wall], np.r_[np.full(200, 2), np.full(60, 1)], [1, 2, 3], threshold=0.05,
    ...                     min_points=8, up=np.array([0, 0, 1.0]))
    >>> f = int(np.argmax(np.abs(planes.normal[:, 2])))
    >>> wall_classes(planes, f, np.array([0, 0, 1.0]), [1, 2, 3])   # the ceiling (3) stands on nothing
    [1]

    Wall points along both walls' feet (the labels' floor line) make the floor plane hold the wall class too;
    two walls hold it, so it still stands on the floor:

    >>> foot = np.c_[np.r_[np.full(40, 2.0), np.linspace(-2, 2, 40)], np.r_[np.linspace(-2, 2, 40), np.full(40, 2.0)],
    ...              np.zeros(80)]
    >>> wall2 = np.c_[np.random.default_rng(2).uniform([-2, 0], [2, 2.5], (60, 2))[:, 0], np.full(60, 2.0),
    ...               np.random.default_rng(3).uniform(0, 2.5, 60)]
    >>> planes = fit_planes(np.r_[floor, wall, wall2, foot], np.r_[np.full(200, 2), np.full(200, 1)], [1, 2, 3],
    ...                     threshold=0.05, min_points=8, up=np.array([0, 0, 1.0]))
    >>> f = int(np.argmax(np.abs(planes.normal[:, 2])))
    >>> sorted(planes.classes[f]), wall_classes(planes, f, np.array([0, 0, 1.0]), [1, 2, 3])
    ([1, 2], [1])
    """
    vertical = planes.vertical(up)
    walls = [c for c, v in zip(planes.classes, vertical) if v]
    return [int(c) for c in stuff if sum(c in w for w in walls) >= (2 if c in planes.classes[floor] else 1)]


def floor_line_classes(planes: StuffPlanes, floor: int, up: np.ndarray, stuff) -> tuple[list[int], list[int]]:
    """``(floors, walls)``: the classes below and above a floor line (:func:`floor_boundary_points`). The walls are
    every stuff class the floor plane ``floor`` does not hold (a plain wall may have no plane yet: finding it is
    what the floor line is for), and also a class it holds that at least half the walls hold
    (:func:`most_walls_hold`, as for ceilings). Without that, wall-labelled points at the walls' feet that made
    the floor plane hold the wall class left the floor line with no wall at all (tuning hexagons 102 and 104: no
    floor-line point, half their walls without a plane and the field's walls on the scene box). Half, not
    two: floor-labelled points at the feet make a few walls hold the floor's class too, and the floor is no
    wall (a test room, seen while scoring: two of its eight wall planes held the floor class).

    Examples
    --------
    The second room of :func:`wall_classes`, whose floor plane holds the wall class (1) too:

    >>> from lift3d.sfm.planes import fit_planes
    >>> rng = np.random.default_rng
    >>> floor = np.c_[rng(0).uniform(-2, 2, (200, 2)), np.zeros(200)]
    >>> wall = np.c_[np.full(60, 2.0), rng(1).uniform([-2, 0], [2, 2.5], (60, 2))]
    >>> wall2 = np.c_[rng(2).uniform(-2, 2, 60), np.full(60, 2.0), rng(3).uniform(0, 2.5, 60)]
    >>> foot = np.c_[np.r_[np.full(40, 2.0), np.linspace(-2, 2, 40)], np.r_[np.linspace(-2, 2, 40), np.full(40, 2.0)],
    ...              np.zeros(80)]
    >>> planes = fit_planes(np.r_[floor, wall, wall2, foot], np.r_[np.full(200, 2), np.full(200, 1)], [1, 2, 3],
    ...                     threshold=0.05, min_points=8, up=np.array([0, 0, 1.0]))
    >>> f = int(np.argmax(np.abs(planes.normal[:, 2])))
    >>> sorted(planes.classes[f]), floor_line_classes(planes, f, np.array([0, 0, 1.0]), [1, 2, 3])
    ([1, 2], ([2], [1, 3]))
    """
    on_floor = {int(c) for c in planes.classes[floor]}
    vertical = planes.vertical(up)
    standing = {c for c in on_floor if vertical.any() and most_walls_hold(planes, vertical, c)}
    return sorted(on_floor - standing), [int(c) for c in stuff if c not in on_floor or c in standing]


def most_walls_hold(planes: StuffPlanes, vertical: np.ndarray, class_id: int, share: float = 0.5) -> bool:
    """Whether at least ``share`` of the vertical planes (walls, ``vertical``: ``[P] bool``) hold ``class_id``: then
    it is a wall's class, not a ceiling's (a few walls can hold the ceiling class from the points along their top
    edges)."""
    return sum(class_id in k for k, v in zip(planes.classes, vertical) if v) >= share * vertical.sum()


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

    >>> from lift3d.sfm.planes import fit_planes
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

    >>> from lift3d.sfm.planes import fit_planes
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

    >>> from lift3d.sfm.planes import fit_planes
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
