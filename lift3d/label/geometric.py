"""Structure-only 2D panoptic pseudo-labels from depth maps (``lift3d label --geometric``).

No 2D segmenter is involved: every frame's depth map is back-projected into the world frame with its pose,
and its pixels are labelled by the shape of what they see.

1. **Capture pass** (:func:`fit_structure`): a sample of points and normals from every frame gives the
   world's *up* direction (the dominant level-surface normal, searched from the cameras' own up), the heights
   of the floor (the lowest large level surface below the cameras, facing up) and the ceiling (the highest
   large level surface above them, facing down), and the walls: large vertical planes that reach above the
   cameras and have (almost) nothing observed behind them.
2. **Frame pass** (:func:`label_frame`): every pixel within a depth-relative distance of one of those planes,
   with a normal that agrees with it, is wall, floor or ceiling (one stuff segment per class and frame). The
   rest splits into depth-connected components (no depth discontinuity inside one); each component of at
   least a minimum share of the frame is one segment of the generic thing class ``object``, the smaller
   leftovers and pixels without depth are void.

All thresholds are :class:`GeometricSettings` fields, relative to the scene (angles, shares of the depth or
of the frame), and are recorded with the up direction and the planes in ``transforms.json``.

Everything here works on plain arrays; :func:`lift3d.label.label_geometric` reads the scene folder and
writes the labels.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from lift3d.data.cameras import Cameras
from lift3d.data.categories import Category
from lift3d.data.scene import Segment
from lift3d.errors import InputError

__all__ = ["GEOMETRIC_CATEGORIES", "STUFF_KINDS", "GeometricSettings", "FrameGeometry", "Plane", "Structure",
           "frame_geometry", "camera_up_prior", "estimate_up", "fit_structure", "label_frame"]

#: The vocabulary of structure-only labels (ids used when the scene has no ground truth to keep).
GEOMETRIC_CATEGORIES = (
    Category(1, "wall", False, (174, 199, 232)),
    Category(2, "floor", False, (152, 223, 138)),
    Category(3, "ceiling", False, (78, 71, 183)),
    Category(4, "object", True, (255, 127, 14)),
)
#: The stuff classes, in the order their segments are numbered in a frame.
STUFF_KINDS = ("wall", "floor", "ceiling")
#: The thing class of every depth-connected component.
THING_KIND = "object"

#: Larger captures are sampled down to about this many points for the capture pass: plane fitting needs the
# surfaces' extent, not every pixel.
CAPTURE_POINTS = 100_000
#: The capture pass reads depth maps with their larger side subsampled to about this many pixels.
CAPTURE_SIDE = 160
# Wall hypotheses tried per plane, and the points they are scored on (the best one is then refit on all).
_WALL_HYPOTHESES = 200
_WALL_SCORE_POINTS = 10_000
_MAX_WALLS = 32


@dataclass(frozen=True)
class GeometricSettings:
    """Thresholds of the structure-only labeller; every one is relative to the scene.

    Attributes
    ----------
    level_angle : float
        Degrees. A normal within this angle of the up direction (or of its opposite) is *level*; within this
        angle of horizontal it is *vertical*. Decides which points may form the floor, the ceiling and walls,
        and how far a plane may tilt when refit in one frame.
    normal_angle : float
        Degrees. A pixel joins a plane only when its normal is within this angle of the plane's normal
        (looser than ``level_angle``: normals are smoothed over a window, so they bend near corners).
    plane_distance : float
        A pixel joins a plane when its distance to it is below this share of its depth (0.02: 4 cm at
        2 m), so the band widens with the depth noise of far pixels.
    min_plane_share : float
        A floor, ceiling or wall needs at least this share of the capture's sampled depth points.
    wall_max_behind : float
        A vertical plane is a wall only when the points observed behind it and above its top (farther than
        twice the distance band, within its horizontal extent) number at most this share of its own points:
        a tall cabinet has the wall showing above it. (Points behind a wall lower down are seen through a
        window or a door, which walls have.)
    depth_jump : float
        Neighbouring pixels whose depths differ by more than this share of the nearer depth are not
        connected: objects are split there, and normals are not estimated across.
    min_object_share : float
        A depth-connected component is an object when it covers at least this share of the frame's pixels;
        smaller ones are void.
    normal_window : float
        Normals are averaged over a square window of this share of the image's larger side (at least 3
        pixels).
    on_plane_share : float
        A depth-connected component with at least this share of its pixels within a plane's distance band
        belongs to that plane (its pixels within ``leftover_band`` bands; the rest is void), whatever its
        normals: a floor or ceiling seen at a grazing angle has no normals and splits into rows.
    leftover_band : float
        Pixels left over in components too small to be objects join a plane they are within this many
        distance bands of, whatever their normal: noisy far surfaces come out whole instead of speckled.
    up : tuple of float or None
        A known up direction in world coordinates (e.g. from an IMU); None estimates it from the capture.

    Examples
    --------
    >>> s = GeometricSettings(plane_distance=0.03)
    >>> s.check()
    >>> s.to_json()["plane_distance"]
    0.03
    """

    level_angle: float = 15.0
    normal_angle: float = 40.0
    plane_distance: float = 0.02
    min_plane_share: float = 0.005
    wall_max_behind: float = 0.1
    depth_jump: float = 0.05
    min_object_share: float = 0.002
    normal_window: float = 0.01
    on_plane_share: float = 0.5
    leftover_band: float = 2.0
    up: tuple[float, float, float] | None = None

    def check(self) -> None:
        """Raise :class:`~lift3d.errors.InputError` naming the flag of the first out-of-range setting."""
        ranges = {
            "level_angle": (0.0, 45.0), "normal_angle": (0.0, 90.0), "plane_distance": (0.0, 1.0),
            "min_plane_share": (0.0, 1.0), "wall_max_behind": (0.0, 10.0), "depth_jump": (0.0, 10.0),
            "min_object_share": (0.0, 1.0), "normal_window": (0.0, 1.0), "on_plane_share": (0.0, 1.0),
            "leftover_band": (0.0, 100.0),
        }
        for name, (lo, hi) in ranges.items():
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not np.isfinite(value) or not lo < value <= hi:
                raise InputError("--" + name.replace("_", "-"), f"must be a number in ({lo:g}, {hi:g}], got {value!r}")
        if self.up is not None:
            up = np.asarray(self.up, np.float64)
            if up.shape != (3,) or not np.all(np.isfinite(up)) or np.linalg.norm(up) < 1e-9:
                raise InputError("--up", f"must be three numbers X,Y,Z, not all zero (got {self.up!r})")

    def to_json(self) -> dict:
        d = asdict(self)
        d["up"] = None if self.up is None else [float(x) for x in self.up]
        return d


# --------------------------------------------------------------------------------------------- per frame
@dataclass
class FrameGeometry:
    """A depth map back-projected into the world frame (on a pixel grid, possibly subsampled).

    Attributes
    ----------
    points : np.ndarray
        ``float64 [h, w, 3]`` world points (meaningless where not ``valid``).
    normals : np.ndarray
        ``float64 [h, w, 3]`` unit world normals facing the camera (zero where not ``has_normal``).
    depth : np.ndarray
        ``float64 [h, w]`` z-depth, 0 = unknown.
    valid : np.ndarray
        ``bool [h, w]`` pixels with depth.
    has_normal : np.ndarray
        ``bool [h, w]`` valid pixels with a normal (some depth-continuous neighbour in both directions).
    linked_right, linked_down : np.ndarray
        ``bool [h, w - 1]`` / ``bool [h - 1, w]``: the pixel and its right / lower neighbour both have depth
        and no depth discontinuity lies between them.
    center : np.ndarray
        ``[3]`` the camera centre.
    """

    points: np.ndarray
    normals: np.ndarray
    depth: np.ndarray
    valid: np.ndarray
    has_normal: np.ndarray
    linked_right: np.ndarray
    linked_down: np.ndarray
    center: np.ndarray


def _dot(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``a @ v`` for ``a [..., 3]`` and ``v [3]`` (per axis: much faster than matmul over an image)."""
    return a[..., 0] * v[0] + a[..., 1] * v[1] + a[..., 2] * v[2]


def _odd(n: float) -> int:
    k = max(3, int(round(n)))
    return k if k % 2 else k + 1


# A step of inverse depth that differs from the steps on both sides by at most this share of itself
# continues a smooth surface (see _linked).
_SMOOTH_STEP = 0.5


def _linked(z: np.ndarray, valid: np.ndarray, jump: float) -> np.ndarray:
    """``bool [h, w - 1]``: pixel ``(r, c)`` and its right neighbour lie on one surface.

    They do when their depths differ by at most ``jump`` times the nearer one, or when the step is part of
    a smooth run: inverse depth is affine in the pixel coordinates on a plane, so on a surface seen at a
    grazing angle (a far floor, a ceiling) the steps of ``1 / z`` between neighbours are large but alike,
    while an occlusion edge is one step unlike those on either side of it (a step continues a run when it
    differs from the steps before and after it by at most half of itself).

    Examples
    --------
    A floor seen at a grazing angle (1/z falls by about 0.2 a pixel, a 25 % jump in depth), then a wall
    0.5 m behind its edge: the floor's inner steps are linked, the step to the wall is not (nor are the run's
    first and last steps):

    >>> z = np.array([[0.8, 1.0, 1.25, 5 / 3, 2.5, 3.0, 3.05]])
    >>> _linked(z, z > 0, 0.05).astype(int).tolist()
    [[0, 1, 1, 0, 0, 1]]
    """
    both = valid[:, :-1] & valid[:, 1:]
    near = np.minimum(z[:, :-1], z[:, 1:])
    small = both & (np.abs(z[:, 1:] - z[:, :-1]) <= jump * near)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(valid, 1.0 / np.where(valid, z, 1.0), np.nan)
    step = inv[:, 1:] - inv[:, :-1]  # NaN next to a pixel without depth
    before = np.full_like(step, np.nan)
    after = np.full_like(step, np.nan)
    before[:, 1:], after[:, :-1] = step[:, :-1], step[:, 1:]
    with np.errstate(invalid="ignore"):
        like_before = np.abs(step - before) <= _SMOOTH_STEP * np.abs(step)
        like_after = np.abs(step - after) <= _SMOOTH_STEP * np.abs(step)
    # Both sides must agree: two alike large steps are a pixel mixing two surfaces across an edge, not a run.
    # (So the first and last steps of a run stay unlinked; their pixels join the run through the rest.)
    return small | (both & like_before & like_after)


def frame_geometry(cameras: Cameras, i: int, depth: np.ndarray, settings: GeometricSettings,
                   stride: int = 1) -> FrameGeometry:
    """Back-project frame ``i``'s depth map and estimate normals from it.

    Normals are the cross product of the image-direction tangents (differences of neighbouring points),
    averaged over a ``normal_window`` box and never taken across a depth discontinuity.

    Parameters
    ----------
    cameras : Cameras
    i : int
        Frame index.
    depth : np.ndarray
        ``[H, W]`` z-depth in world units, 0 = unknown.
    settings : GeometricSettings
    stride : int
        Use every ``stride``-th pixel in both directions (the capture pass samples this way).

    Returns
    -------
    FrameGeometry

    Examples
    --------
    >>> cams = Cameras(c2w=np.eye(4)[None], fx=20.0, fy=20.0, cx=16.0, cy=16.0, width=32, height=32)
    >>> g = frame_geometry(cams, 0, np.full((32, 32), 2.0), GeometricSettings())
    >>> (np.round(g.normals[16, 16], 6) + 0.0).tolist()  # a wall facing the camera (which looks down -z)
    [0.0, 0.0, 1.0]
    """
    z = np.asarray(depth, np.float64)[::stride, ::stride]
    h, w = z.shape
    valid = np.isfinite(z) & (z > 0)
    z = np.where(valid, z, 0.0)
    rows, cols = np.mgrid[0:h, 0:w]
    x, y = cameras.normalized_coords(i, (cols * stride).ravel(), (rows * stride).ravel())
    c2w = cameras.c2w_opencv[i]
    # Cameras.unproject's arithmetic, written out per axis: a matmul with an inner size of 3 over a whole
    # image takes several times longer.
    x, y = x.reshape(h, w) * z, y.reshape(h, w) * z
    points = c2w[:3, 3] + x[..., None] * c2w[:3, 0] + y[..., None] * c2w[:3, 1] + z[..., None] * c2w[:3, 2]
    # Discontinuities are judged between neighbours `stride` pixels apart: allow proportionally more.
    linked_right = _linked(z, valid, settings.depth_jump * stride)
    linked_down = _linked(z.T, valid.T, settings.depth_jump * stride).T

    k = _odd(settings.normal_window * max(cameras.width[i], cameras.height[i]) / stride)
    tan_u = np.zeros((h, w, 3), np.float32)
    tan_v = np.zeros((h, w, 3), np.float32)
    tan_u[:, :-1] = np.where(linked_right[..., None], points[:, 1:] - points[:, :-1], 0.0)
    tan_v[:-1] = np.where(linked_down[..., None], points[1:] - points[:-1], 0.0)
    count_u = np.zeros((h, w), np.float32)
    count_v = np.zeros((h, w), np.float32)
    count_u[:, :-1] = linked_right
    count_v[:-1] = linked_down

    def box(a: np.ndarray) -> np.ndarray:  # window sums; zeros outside the image
        return cv2.boxFilter(a, -1, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT)

    # Sums of the tangents are enough: their cross product has the direction of the averages'.
    normals = np.cross(box(tan_v).astype(np.float64), box(tan_u).astype(np.float64))  # towards the camera
    norm = np.linalg.norm(normals, axis=-1)
    has_normal = valid & (box(count_u) > 0) & (box(count_v) > 0) & (norm > 0)
    normals = np.where(has_normal[..., None], normals / np.where(norm > 0, norm, 1.0)[..., None], 0.0)
    center = cameras.centers[i]
    # The cross product faces the camera for a pinhole; distortion cannot flip it, but keep it certain.
    away = np.einsum("hwc,hwc->hw", normals, center - points) < 0
    normals[away] *= -1.0
    return FrameGeometry(points, normals, z, valid, has_normal, linked_right, linked_down, center)


# --------------------------------------------------------------------------------------------- structure
@dataclass
class Plane:
    """A floor, ceiling or wall plane: ``signed distance(x) = normal · x - offset``, positive on the side
    the cameras see it from.

    Attributes
    ----------
    kind : str
        ``floor``, ``ceiling`` or ``wall``.
    normal : np.ndarray
        ``[3]`` unit normal facing the room.
    offset : float
    share : float
        Its share of the capture's sampled points.
    extent : tuple of float or None
        Walls: the interval it covers along ``up × normal`` (a wall of an L-shaped room does not extend
        through the other wing); None for floor and ceiling.
    """

    kind: str
    normal: np.ndarray
    offset: float
    share: float
    extent: tuple[float, float] | None = None

    def distance(self, points: np.ndarray) -> np.ndarray:
        return _dot(points, self.normal) - self.offset

    def to_json(self) -> dict:
        d = {"kind": self.kind, "normal": [round(float(x), 6) for x in self.normal],
             "offset": round(float(self.offset), 6), "share": round(float(self.share), 4)}
        if self.extent is not None:
            d["extent"] = [round(float(x), 4) for x in self.extent]
        return d


@dataclass
class Structure:
    """What the capture pass found: the up direction and the floor, ceiling and wall planes.

    Attributes
    ----------
    up : np.ndarray
        ``[3]`` unit up direction in world coordinates.
    up_source : str
        ``given`` (``--up``), ``level surfaces`` (refined on the capture's level normals) or ``cameras``
        (the cameras' own up; too few level surfaces to refine it).
    planes : list of Plane
    rejected : dict
        Vertical-plane candidates that were not walls, by reason (``low``: they stay below the cameras;
        ``behind``: points were seen behind them).
    """

    up: np.ndarray
    up_source: str
    planes: list[Plane]
    rejected: dict[str, int] = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"up": [round(float(x), 6) for x in self.up], "up_source": self.up_source,
                "planes": [p.to_json() for p in self.planes], "rejected_walls": dict(self.rejected)}


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def camera_up_prior(c2w: np.ndarray) -> np.ndarray:
    """A first guess of the world's up direction from camera-to-world matrices (OpenGL axes).

    People and robots hold cameras without much roll, so the cameras' right axes are nearly level: when they
    point in varied directions, up is the direction most perpendicular to all of them (a camera tilted down
    still has a level right axis, while its own up axis leans). When they are nearly parallel that says too
    little, and the mean of the cameras' up axes is used. The sign always follows the cameras' up axes.

    Parameters
    ----------
    c2w : np.ndarray
        ``[F, 4, 4]`` camera-to-world matrices, OpenGL axes (x right, y up).

    Returns
    -------
    np.ndarray
        ``[3]`` unit vector.

    Examples
    --------
    >>> from lift3d.data.cameras import look_at
    >>> c2w = np.stack([look_at(np.array([np.cos(a), np.sin(a), 1.5]), np.zeros(3)) for a in (0, 2, 4)])
    >>> np.round(camera_up_prior(c2w), 6).tolist()  # cameras looking down at the origin: still z
    [0.0, 0.0, 1.0]
    """
    c2w = np.asarray(c2w, np.float64)
    mean_up = _unit(c2w[:, :3, 1].sum(0))
    right = c2w[:, :3, 0]
    eigval, eigvec = np.linalg.eigh(right.T @ right / len(right))
    candidate = eigvec[:, 0]
    # The right axes must span a plane (second eigenvalue of the three, summing to 1) for it to say anything.
    if eigval[1] > 0.05 and abs(candidate @ mean_up) > np.cos(np.radians(60.0)):
        return candidate * np.sign(candidate @ mean_up)
    return mean_up


def estimate_up(normals: np.ndarray, prior: np.ndarray, level_angle: float,
                min_count: int = 1) -> tuple[np.ndarray, bool]:
    """The dominant level-surface normal near ``prior``: an axial mean shift on the normals.

    Floor and table tops face up, ceilings face down; both say where up is. Starting from ``prior``, the
    normals within a cone around the current estimate (or its opposite) are averaged, sign-aligned, while
    the cone narrows from 40° to ``level_angle``.

    Parameters
    ----------
    normals : np.ndarray
        ``[N, 3]`` unit normals in world coordinates.
    prior : np.ndarray
        ``[3]`` starting direction (:func:`camera_up_prior`).
    level_angle : float
        Final cone half-angle in degrees.
    min_count : int
        Fewer normals than this in the cone: give up and return ``prior``.

    Returns
    -------
    up : np.ndarray
        ``[3]`` unit vector on the side of ``prior``.
    refined : bool
        False when there were too few level normals and ``prior`` is returned.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> n = rng.normal(size=(3000, 3)) * 0.05 + np.repeat(np.eye(3), 1000, axis=0)  # three surface families
    >>> n /= np.linalg.norm(n, axis=1, keepdims=True)
    >>> up, refined = estimate_up(n, np.array([0.3, 0.2, 0.9]), 15.0)
    >>> (np.round(up, 2) + 0.0).tolist(), refined
    ([0.0, 0.0, 1.0], True)
    """
    up = _unit(np.asarray(prior, np.float64))
    for cone in [c for c in (40.0, 30.0, 20.0) if c > level_angle] + [level_angle]:
        for _ in range(5):
            c = normals @ up
            near = np.abs(c) > np.cos(np.radians(cone))
            if near.sum() < max(min_count, 1):
                return _unit(np.asarray(prior, np.float64)), False
            new = _unit((normals[near] * np.sign(c[near])[:, None]).sum(0))
            done = new @ up > np.cos(np.radians(0.01))
            up = new
            if done:
                break
    return up * np.sign(up @ prior), True


def _level_height(heights: np.ndarray, tol: np.ndarray, min_count: float, lowest: bool) -> tuple[float, int] | None:
    """Height of the lowest (or highest) level surface with at least ``min_count`` points.

    A histogram with bins of the median distance band finds the surfaces (its local maxima); the chosen
    one's height is then the median of the points within their own band of it."""
    if len(heights) < max(min_count, 1):
        return None
    width = float(np.median(tol))
    edges = np.arange(heights.min() - width, heights.max() + 2 * width, width)
    counts = np.histogram(heights, edges)[0].astype(np.float64)
    smooth = np.convolve(counts, [1.0, 1.0, 1.0], mode="same")  # a surface's points straddle bin edges
    padded = np.concatenate([[-1.0], smooth, [-1.0]])
    peaks = [j for j in range(len(smooth))
             if smooth[j] >= min_count and smooth[j] >= padded[j] and smooth[j] >= padded[j + 2]]
    if not peaks:
        return None
    j = peaks[0] if lowest else peaks[-1]
    j += int(np.argmax(counts[max(j - 1, 0):j + 2])) - (j > 0)  # the fullest bin of the three (plateaus)
    height = 0.5 * (edges[j] + edges[j + 1])
    near = np.zeros(len(heights), bool)
    for _ in range(3):
        near = np.abs(heights - height) < tol
        if not near.any():
            return None
        height = float(np.median(heights[near]))
    return height, int(near.sum())


def _refit_vertical(points: np.ndarray, up: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares vertical plane through ``points``: a line fit to their horizontal projections."""
    flat = points - np.outer(points @ up, up)
    centre = flat.mean(0)
    _, vecs = np.linalg.eigh((flat - centre).T @ (flat - centre))
    along = vecs[:, 2]  # the largest spread: the wall's horizontal direction
    n = _unit(np.cross(along, up))
    n *= np.sign(n @ normal) or 1.0
    return n, float(n @ centre)


def _find_walls(points: np.ndarray, normals: np.ndarray, tol: np.ndarray, up: np.ndarray, camera_height: float,
                settings: GeometricSettings, rng: np.random.Generator) -> tuple[list[Plane], dict[str, int]]:
    """Vertical planes by hypothesise-and-verify, then the wall tests (see :class:`GeometricSettings`).

    Each hypothesis is the vertical plane through one point with its own (levelled) normal, so one point is
    a whole hypothesis; it is scored by the points within their distance band that face the same way, the
    best is refit to all its points and removed, and the search repeats while planes are large enough.
    (Open3D's ``segment_plane`` fits unconstrained planes and ignores normals, hence this small loop.)
    """
    n_total = len(points)
    min_count = settings.min_plane_share * n_total
    cos_normal = np.cos(np.radians(settings.normal_angle))
    remaining = np.flatnonzero(np.abs(normals @ up) < np.sin(np.radians(settings.level_angle)))
    candidates: list[tuple[np.ndarray, float, np.ndarray]] = []
    for _ in range(_MAX_WALLS):
        if len(remaining) < max(min_count, 3):
            break
        pts, nrm, band = points[remaining], normals[remaining], tol[remaining]
        hyp = rng.choice(len(remaining), min(len(remaining), _WALL_HYPOTHESES), replace=False)
        hn = nrm[hyp] - np.outer(nrm[hyp] @ up, up)
        hn /= np.linalg.norm(hn, axis=1, keepdims=True)
        hd = np.einsum("ij,ij->i", hn, pts[hyp])
        sub = rng.choice(len(remaining), min(len(remaining), _WALL_SCORE_POINTS), replace=False)
        # Scored in float32 about the sample's centre (a vote needs centimetres, not micrometres).
        centre = pts[sub].mean(0)
        hn32, hd32 = hn.astype(np.float32), (hd - hn @ centre).astype(np.float32)
        dist = np.abs((pts[sub] - centre).astype(np.float32) @ hn32.T - hd32)
        agree = nrm[sub].astype(np.float32) @ hn32.T > cos_normal
        votes = ((dist < band[sub, None].astype(np.float32)) & agree).sum(0)
        n, d = hn[np.argmax(votes)], float(hd[np.argmax(votes)])
        inliers = np.zeros(len(remaining), bool)
        for _ in range(3):
            inliers = (np.abs(pts @ n - d) < band) & (nrm @ n > cos_normal)
            if inliers.sum() < 3:
                break
            n, d = _refit_vertical(pts[inliers], up, n)
        if inliers.sum() < max(min_count, 3):
            break  # the best plane left is too small: so are all others
        candidates.append((n, d, remaining[inliers]))
        remaining = remaining[~inliers]

    walls: list[Plane] = []
    rejected = {"low": 0, "behind": 0}
    heights = points @ up
    for n, d, idx in candidates:
        along_dir = np.cross(up, n)
        along = points[idx] @ along_dir
        lo, hi = np.quantile(along, [0.01, 0.99])
        top = np.quantile(heights[idx], 0.98)
        if top < camera_height:
            rejected["low"] += 1  # a cabinet front or a sofa back, not a wall
            continue
        # Points behind the plane *above* its top: the wall behind a tall cabinet shows there. Lower down,
        # points behind a wall are seen through it (a window, a glass or open door), which a wall may have.
        a = points @ along_dir
        behind = (a > lo) & (a < hi) & (points @ n - d < -2.0 * tol) & (heights > top)
        if behind.sum() > settings.wall_max_behind * len(idx):
            rejected["behind"] += 1
            continue
        walls.append(Plane("wall", n, d, len(idx) / n_total, (float(lo), float(hi))))
    return walls, rejected


def fit_structure(points: np.ndarray, normals: np.ndarray, depth: np.ndarray, camera_c2w: np.ndarray,
                  settings: GeometricSettings, seed: int = 0) -> Structure:
    """Up direction, floor, ceiling and walls of a capture from a sample of its points.

    Parameters
    ----------
    points, normals : np.ndarray
        ``[N, 3]`` world points and their unit normals (facing the cameras that saw them).
    depth : np.ndarray
        ``[N]`` the depth each point was seen at (sets its distance band).
    camera_c2w : np.ndarray
        ``[F, 4, 4]`` the capture's camera-to-world matrices (OpenGL axes).
    settings : GeometricSettings
    seed : int
        Seed of the wall search's random hypotheses.

    Returns
    -------
    Structure

    Examples
    --------
    A floor at height 0 and a wall at x = 3 seen from cameras at 1.5 m (z up):

    >>> rng = np.random.default_rng(0)
    >>> floor = np.c_[rng.uniform(-3, 3, (4000, 2)), np.zeros(4000)]
    >>> wall = np.c_[np.full(3000, 3.0), rng.uniform(-3, 3, 3000), rng.uniform(0, 2.5, 3000)]
    >>> pts = np.r_[floor, wall]
    >>> nrm = np.r_[np.tile([0, 0, 1.0], (4000, 1)), np.tile([-1.0, 0, 0], (3000, 1))]
    >>> from lift3d.data.cameras import look_at
    >>> c2w = np.stack([look_at(np.array([0, 0, 1.5]), np.array([np.cos(a), np.sin(a), 1.5])) for a in (0, 2, 4)])
    >>> s = fit_structure(pts, nrm, np.full(7000, 3.0), c2w, GeometricSettings())
    >>> np.round(s.up, 3).tolist(), [(p.kind, round(p.offset, 3)) for p in s.planes]
    ([0.0, 0.0, 1.0], [('floor', 0.0), ('wall', -3.0)])
    """
    points = np.asarray(points, np.float64)
    normals = np.asarray(normals, np.float64)
    tol = settings.plane_distance * np.asarray(depth, np.float64)
    n_total = len(points)
    min_count = settings.min_plane_share * n_total
    prior = camera_up_prior(camera_c2w)
    if settings.up is not None:
        up, source = _unit(np.asarray(settings.up, np.float64)), "given"
    else:
        up, refined = estimate_up(normals, prior, settings.level_angle, min_count=max(int(min_count), 1))
        source = "level surfaces" if refined else "cameras"

    centers_h = np.asarray(camera_c2w, np.float64)[:, :3, 3] @ up
    heights = points @ up
    facing = normals @ up
    level = np.cos(np.radians(settings.level_angle))
    planes: list[Plane] = []
    below = (facing > level) & (heights < centers_h.min())
    floor = _level_height(heights[below], tol[below], min_count, lowest=True)
    if floor is not None:
        planes.append(Plane("floor", up.copy(), floor[0], floor[1] / n_total))
    above = (facing < -level) & (heights > centers_h.max())
    ceiling = _level_height(heights[above], tol[above], min_count, lowest=False)
    if ceiling is not None:
        planes.append(Plane("ceiling", -up, -ceiling[0], ceiling[1] / n_total))
    walls, rejected = _find_walls(points, normals, tol, up, float(np.median(centers_h)), settings,
                                  np.random.default_rng(seed))
    return Structure(up, source, planes + walls, rejected)


# --------------------------------------------------------------------------------------------- labelling
def _refit_in_frame(plane: Plane, geom: FrameGeometry, tol: np.ndarray, usable: np.ndarray,
                    settings: GeometricSettings) -> Plane:
    """The plane refit to this frame's own pixels near it, so that a pose or depth error of a few
    centimetres does not push a surface out of its band. Kept only when it tilts less than ``level_angle``."""
    near = usable & (np.abs(plane.distance(geom.points)) < 3.0 * tol)
    normal, offset = plane.normal, plane.offset
    for _ in range(2):
        pts = geom.points[near]
        if len(pts) < 10:
            return plane
        centre = pts.mean(0)
        _, vecs = np.linalg.eigh((pts - centre).T @ (pts - centre))
        n = vecs[:, 0] * (np.sign(vecs[:, 0] @ plane.normal) or 1.0)
        if n @ plane.normal < np.cos(np.radians(settings.level_angle)):
            return plane
        normal, offset = n, float(n @ centre)
        near = usable & (np.abs(_dot(geom.points, normal) - offset) < tol)
    return Plane(plane.kind, normal, offset, plane.share, plane.extent)


def label_frame(geom: FrameGeometry, structure: Structure, settings: GeometricSettings,
                category_ids: dict[str, int]) -> tuple[np.ndarray, list[Segment]]:
    """Structure-only panoptic labels of one frame.

    Parameters
    ----------
    geom : FrameGeometry
        The frame at full resolution (:func:`frame_geometry`).
    structure : Structure
        The capture's planes (:func:`fit_structure`).
    settings : GeometricSettings
    category_ids : dict
        Category id of ``wall``, ``floor``, ``ceiling`` and ``object``.

    Returns
    -------
    panoptic : np.ndarray
        ``int64 [H, W]`` per-frame segment ids, 0 = void: one segment per stuff class present (numbered
        first, in the order wall, floor, ceiling), then the objects by decreasing size.
    segments : list of Segment
        Stuff segments score the plane fit (the share of their pixels within half the distance band);
        objects score 1.

    Examples
    --------
    A camera 1.5 m above a floor (z up) looking straight down at a box 0.5 m high:

    >>> from lift3d.data.cameras import look_at
    >>> cams = Cameras(c2w=look_at(np.array([0, 0, 1.5]), np.zeros(3), np.array([0, 1.0, 0]))[None],
    ...                fx=40.0, fy=40.0, cx=32.0, cy=24.0, width=64, height=48)
    >>> depth = np.full((48, 64), 1.5)
    >>> depth[16:32, 24:40] = 1.0
    >>> geom = frame_geometry(cams, 0, depth, GeometricSettings())
    >>> floor = Structure(np.array([0, 0, 1.0]), "given", [Plane("floor", np.array([0, 0, 1.0]), 0.0, 1.0)])
    >>> seg, segs = label_frame(geom, floor, GeometricSettings(), {"wall": 1, "floor": 2, "ceiling": 3, "object": 4})
    >>> [(x.category_id, int((seg == x.id).sum())) for x in segs]  # floor, then the box
    [(2, 2816), (4, 256)]
    """
    h, w = geom.depth.shape
    tol = settings.plane_distance * geom.depth
    safe_tol = np.where(tol > 0, tol, 1.0)
    cos_normal = np.cos(np.radians(settings.normal_angle))
    usable = geom.valid & geom.has_normal
    # Per plane: where it may claim pixels (its extent) and how far each pixel is, in distance bands.
    reach, ratios, kinds = [], [], []
    for plane in structure.planes:
        inside = geom.valid.copy()
        if plane.extent is not None:
            along = _dot(geom.points, np.cross(structure.up, plane.normal))
            lo, hi = plane.extent
            margin = 0.1 * (hi - lo)  # the capture's sample sees a wall's ends only roughly
            inside &= (along > lo - margin) & (along < hi + margin)
        facing = inside & usable & (_dot(geom.normals, plane.normal) > cos_normal)
        if facing.any():
            plane = _refit_in_frame(plane, geom, tol, facing, settings)
        reach.append((inside, facing))
        ratios.append(np.abs(plane.distance(geom.points)) / safe_tol)
        kinds.append(STUFF_KINDS.index(plane.kind))

    def assign(mask: np.ndarray, band: float, need_normal: bool) -> None:
        best = np.full((h, w), np.inf)
        for (inside, facing), ratio, kind in zip(reach, ratios, kinds):
            take = mask & (facing if need_normal else inside) & (ratio < band) & (ratio < best)
            best[take] = ratio[take]
            kind_of[take] = kind

    kind_of = np.full((h, w), -1)
    assign(geom.valid, 1.0, need_normal=True)
    rest = geom.valid & (kind_of < 0)
    comp, sizes = _depth_components(geom, rest)
    # A component lying mostly within a plane's band is part of that plane even where its normals disagree
    # or are missing: a surface seen at a grazing angle has depth jumps between rows (no normals there, and
    # every row its own component).
    on_plane = np.full(len(sizes) + 1, -1)  # index -1 (outside `rest`): none
    most = np.zeros(len(sizes))
    for j, ((inside, _), ratio) in enumerate(zip(reach, ratios)):
        share = np.bincount(comp[rest & inside & (ratio < 1.0)], minlength=len(sizes)) / np.maximum(sizes, 1)
        better = (share >= settings.on_plane_share) & (share > most)
        on_plane[:-1][better], most[better] = j, share[better]
    for j, ((inside, _), ratio, kind) in enumerate(zip(reach, ratios, kinds)):
        take = rest & (on_plane[comp] == j) & inside & (ratio < settings.leftover_band)
        kind_of[take] = kind
    claimed = rest & (on_plane[comp] >= 0)
    rest &= ~claimed
    big = np.append((sizes >= settings.min_object_share * h * w) & (on_plane[:-1] < 0), False)
    # Too small for an object: noisy pieces of a surface (far walls speckle) or crumbs along its edges.
    assign(rest & ~big[comp], settings.leftover_band, need_normal=False)

    panoptic = np.zeros((h, w), np.int64)
    segments: list[Segment] = []
    close = np.zeros((h, w), bool)  # within half the band: how tight the fit is
    for ratio, kind in zip(ratios, kinds):
        close |= (kind_of == kind) & (ratio < 0.5)
    for k, kind in enumerate(STUFF_KINDS):
        on = kind_of == k
        if on.any():
            sid = len(segments) + 1
            panoptic[on] = sid
            segments.append(Segment(sid, category_ids[kind], float(close[on].mean())))
    objects = np.flatnonzero(big)
    objects = objects[np.argsort(-sizes[objects], kind="stable")]
    new_id = np.zeros(len(sizes) + 1, np.int64)  # comp == -1 (not in `rest`) stays void
    new_id[objects] = len(segments) + 1 + np.arange(len(objects))
    on_object = rest & big[comp]
    panoptic[on_object] = new_id[comp[on_object]]
    segments.extend(Segment(int(sid), category_ids[THING_KIND], 1.0) for sid in new_id[objects])
    return panoptic, segments


def _depth_components(geom: FrameGeometry, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Connected components of ``mask`` whose neighbours are linked (no depth discontinuity between them).

    Returns
    -------
    comp : np.ndarray
        ``int64 [h, w]`` component index, -1 outside ``mask``.
    sizes : np.ndarray
        ``[n_components]`` pixel counts.
    """
    n = int(mask.sum())
    comp = np.full(mask.shape, -1, np.int64)
    if n == 0:
        return comp, np.zeros(0, np.int64)
    index = np.full(mask.shape, -1, np.int64)
    index[mask] = np.arange(n)
    right = geom.linked_right & mask[:, :-1] & mask[:, 1:]
    down = geom.linked_down & mask[:-1] & mask[1:]
    a = np.concatenate([index[:, :-1][right], index[:-1][down]])
    b = np.concatenate([index[:, 1:][right], index[1:][down]])
    graph = coo_matrix((np.ones(len(a), np.int8), (a, b)), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    comp[mask] = labels
    return comp, np.bincount(labels)
