"""Where the 2D labels put one class directly on another, in 3D: a wall's foot on the floor plane (the points up
a wall from it, the floor line the views' boundaries draw), and the ceiling's height where its boundary with a
wall meets the wall's plane. These need no texture, only the labels and a plane the points fix."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lift3d.sfm.planes.fit import _ransac_planes
from lift3d.sfm.planes.model import StuffPlanes, ray_plane_distance


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


def ceiling_boundary_points(cameras, frames, labels: dict[int, np.ndarray], planes: "StuffPlanes", normal: np.ndarray,
                            ceiling_classes, min_rows: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Where the 2D labels put a ceiling class directly above a wall whose plane is known: the ray through that
    boundary meets the wall's plane where the ceiling meets the wall.

    Parameters
    ----------
    planes : StuffPlanes
        The planes found so far; walls are those within 10° of vertical.
    normal : np.ndarray
        The floor's normal (up).
    ceiling_classes : iterable of int
        Classes that may be the ceiling (stuff that no floor or wall plane holds).

    Returns
    -------
    points : np.ndarray
        ``[N, 3]`` the boundary points (world units).
    eyes : np.ndarray
        ``[F, 3]`` the centres of the cameras that saw any of them.
    """
    normal = np.asarray(normal, np.float64)
    vertical = planes.vertical(normal)
    ceiling = [int(c) for c in ceiling_classes]
    walls = sorted(set().union(*[c for c, v in zip(planes.classes, vertical) if v]) - set(ceiling)) \
        if vertical.any() else []
    points, eyes = [np.zeros((0, 3))], [np.zeros((0, 3))]
    if not walls or not ceiling:
        return points[0], eyes[0]
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
        points.append(o[ok] + t[ok, None] * d[ok])
        eyes.append(cameras.c2w_opencv[i][:3, 3][None])
    return np.concatenate(points), np.concatenate(eyes)


def ceiling_height(cameras, frames, labels: dict[int, np.ndarray], planes: "StuffPlanes", normal: np.ndarray,
                   offset: float, ceiling_classes, threshold: float, min_points: int, min_rows: int = 2
                   ) -> tuple[float | None, int]:
    """The ceiling's height above the floor, from where the 2D labels put a ceiling class directly above a wall
    whose plane is known (:func:`ceiling_boundary_points`).

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

    >>> from lift3d.sfm.planes import fit_planes
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
    points, eyes = ceiling_boundary_points(cameras, frames, labels, planes, normal, ceiling_classes, min_rows)
    return level_ceiling_height(points, eyes, normal, offset, threshold, min_points), int(len(points))


def level_ceiling_height(points: np.ndarray, eyes: np.ndarray, normal: np.ndarray, offset: float, threshold: float,
                         min_points: int) -> float | None:
    """The median height of ceiling boundary points ``[N, 3]`` above the floor ``normal · x + offset = 0``; None
    when there are fewer than ``min_points``, when their heights' median absolute deviation exceeds
    ``threshold``, or when it is not above the median of the ``eyes`` ``[F, 3]`` (a ceiling is above the
    cameras)."""
    h = np.asarray(points, np.float64) @ normal + offset
    if len(h) < min_points:
        return None
    height = float(np.median(h))
    if np.median(np.abs(h - height)) > threshold or height <= np.median(np.asarray(eyes) @ normal + offset):
        return None
    return height


def sloped_ceiling(points: np.ndarray, eyes: np.ndarray, normal: np.ndarray, threshold: float, min_points: int, *,
                   min_tilt_deg: float = 3.0, max_tilt_deg: float = 45.0, min_share: float = 0.6,
                   iterations: int = 500, seed: int = 0) -> tuple[np.ndarray, float] | None:
    """One tilted plane through the ceiling-on-wall boundary points (:func:`ceiling_boundary_points`), when a
    level one does not hold them: the ceiling of an attic or a lean-to meets its walls along lines at different
    heights, and all of those lines lie in the ceiling's plane.

    The plane is RANSAC's through three points, refitted to its inliers by least squares. It is returned only
    when all of these hold: at least ``min_points`` inliers and ``min_share`` of the boundary points; their median
    distance to it at most ``threshold``; they span the plane in two directions (points along a single wall's top
    edge fit every plane through that line); it tilts between ``min_tilt_deg`` and ``max_tilt_deg`` from level;
    and every eye in ``eyes`` lies below it (a ceiling is above the cameras). A barrel vault or two roof pitches
    fit no single plane so well, and get none.

    Parameters
    ----------
    points : np.ndarray
        ``[N, 3]`` boundary points.
    eyes : np.ndarray
        ``[F, 3]`` camera centres.
    normal : np.ndarray
        The floor's normal (up).
    threshold : float
        Inlier distance (world units).
    min_points : int
        Fewest inliers.

    Returns
    -------
    (normal, offset) or None
        The plane ``normal · x + offset = 0``, its normal turned up.

    Examples
    --------
    The top edges of four walls of a 6 × 4 m room whose ceiling falls from 3.4 m (x = -3) to 2.4 m (x = 3):

    >>> t = np.linspace(0.0, 1.0, 30)
    >>> height = lambda x: 2.9 - x / 6.0
    >>> sides = [np.c_[-3 + 6 * t, np.full(30, y), height(-3 + 6 * t)] for y in (-2.0, 2.0)]
    >>> ends = [np.c_[np.full(30, x), -2 + 4 * t, np.full(30, height(x))] for x in (-3.0, 3.0)]
    >>> n, d = sloped_ceiling(np.concatenate(sides + ends), np.array([[0, 0, 1.5]]), np.array([0, 0, 1.0]), 0.02, 20)
    >>> [round(float(v), 3) + 0.0 for v in n], round(d, 2)
    ([0.164, 0.0, 0.986], -2.86)
    >>> sloped_ceiling(np.concatenate(ends[:1]), np.array([[0, 0, 1.5]]), np.array([0, 0, 1.0]), 0.02, 20) is None
    True
    """
    x = np.asarray(points, np.float64)
    up = np.asarray(normal, np.float64) / np.linalg.norm(normal)
    if len(x) < max(min_points, 3):
        return None
    found = _ransac_planes(x, threshold, iterations, np.random.default_rng(seed))
    if not found:
        return None
    (n, d), = found
    inl = np.abs(x @ n + d) < threshold
    c = x[inl].mean(0)
    _, sv, vt = np.linalg.svd(x[inl] - c, full_matrices=False)
    best, offset = vt[2], float(-vt[2] @ c)
    if best @ up < 0:
        best, offset = -best, -offset
    inl = np.abs(x @ best + offset) < threshold
    tilt = np.degrees(np.arccos(np.clip(best @ up, -1.0, 1.0)))
    # the inliers' spread across their main direction: a line of points leaves the plane's turn about it free
    spread = sv[1] / np.sqrt(max(int(inl.sum()), 1))
    if (inl.sum() < max(min_points, min_share * len(x)) or np.median(np.abs(x[inl] @ best + offset)) > threshold
            or spread < threshold or not min_tilt_deg <= tilt <= max_tilt_deg
            or np.any(np.asarray(eyes, np.float64) @ best + offset >= 0)):
        return None
    return best, offset


#: A tilted ceiling plane replaces a level height when it holds this many times as many boundary points.
SLOPE_GAIN = 1.1


def ceiling_plane(points: np.ndarray, eyes: np.ndarray, cameras: np.ndarray, normal: np.ndarray, offset: float,
                  threshold: float, min_points: int, *, slope: bool = True
                  ) -> tuple[tuple[np.ndarray, float] | None, float | None]:
    """The ceiling's plane from its boundary points with the walls (:func:`ceiling_boundary_points`).

    The level height (:func:`level_ceiling_height`) unless, with ``slope``, a tilted plane qualifies
    (:func:`sloped_ceiling`) and there is no level height or the tilted plane holds :data:`SLOPE_GAIN` times as
    many of the points within ``threshold``: a sloped ceiling's boundary points can agree on one height when most
    of them lie along its low wall (tuning attic 101: 744 of 1080 within the threshold of 2.43 m; its tilted
    plane held 962).

    Parameters
    ----------
    points, eyes : np.ndarray
        ``[N, 3]`` boundary points and ``[F, 3]`` the centres of the cameras that saw them.
    cameras : np.ndarray
        ``[C, 3]`` every training camera's centre (a ceiling is above all of them).
    normal, offset : np.ndarray, float
        The floor plane (``normal`` up).
    threshold : float
        Plane threshold (world units).
    min_points : int
        Fewest boundary points.

    Returns
    -------
    plane : (np.ndarray, float) or None
        ``(normal, offset)`` of the ceiling plane, normal up.
    height : float or None
        Its height above the floor when it is level.

    Examples
    --------
    Most boundary points along the low wall (2.2 m at x = 3), fewer up the sloped side walls: the level height
    holds the low wall's, the tilted plane all of them.

    >>> t = np.linspace(0.0, 1.0, 40)
    >>> low = np.c_[np.full(120, 3.0), np.linspace(-2, 2, 120), np.full(120, 2.2)]
    >>> sides = [np.c_[-3 + 6 * t, np.full(40, y), 2.5 - 0.1 * (-3 + 6 * t)] for y in (-2.0, 2.0)]
    >>> up, eye = np.array([0, 0, 1.0]), np.array([[0, 0, 1.5]])
    >>> plane, height = ceiling_plane(np.concatenate([low] + sides), eye, eye, up, 0.0, 0.05, 20)
    >>> height is None, round(float(np.degrees(np.arccos(plane[0] @ up))), 1)
    (True, 5.7)
    >>> ceiling_plane(np.concatenate([low] + sides), eye, eye, up, 0.0, 0.05, 20, slope=False)[1]
    2.2
    """
    top = level_ceiling_height(points, eyes, normal, offset, threshold, min_points)
    plane = None if top is None else (np.asarray(normal, np.float64), offset - top)
    if not slope:
        return plane, top
    tilted = sloped_ceiling(points, cameras, normal, threshold, min_points)
    if tilted is None:
        return plane, top
    if plane is None or _held(points, tilted, threshold) > SLOPE_GAIN * _held(points, plane, threshold):
        return tilted, None
    return plane, top


def _held(points: np.ndarray, plane: tuple[np.ndarray, float], threshold: float) -> int:
    """How many of ``points`` lie within ``threshold`` of ``plane = (normal, offset)``."""
    return int((np.abs(np.asarray(points, np.float64) @ plane[0] + plane[1]) < threshold).sum())


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
