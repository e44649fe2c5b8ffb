"""Which views to match: pair selection from the known poses (no image content needed).

Each view's frustum is sampled — a grid of pixels, each at a few depths between the camera and where its
ray leaves the scene box — and the samples are projected into every other view. A pair qualifies when the
optical axes differ by at most ``max_view_angle``, when enough samples are seen by the other view
(``min_overlap``) and when the rays of the two cameras meet at those samples at a median angle of at least
``min_baseline_angle`` (a smaller angle gives depth noise, not depth). Each view keeps its ``neighbors``
best-scoring partners; the score is the overlap weighted by how useful the triangulation angle is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lift3d.data.cameras import Cameras
from lift3d.sfm.config import PairConfig
from lift3d.sfm.geometry import intrinsics, project, world_to_camera

_GRID = 7  # pixels per image side in the frustum sample grid
_DEPTH_FRACTIONS = (0.2, 0.45, 0.7, 0.95)  # of the way to where the ray leaves the scene box


@dataclass
class ViewGraph:
    """Pair selection result (indices are positions in the list of views given).

    Attributes
    ----------
    pairs : np.ndarray
        ``int64 [P, 2]`` unique pairs ``(i, j)``, ``i < j``.
    neighbors : list of np.ndarray
        Per view, the qualifying partners, best first (for plane sweep).
    overlap : np.ndarray
        ``[V, V]`` fraction of view i's frustum samples seen by view j.
    angle : np.ndarray
        ``[V, V]`` median ray angle (degrees) at those samples.
    depth_range : np.ndarray
        ``[V, 2]`` near and far depth (along the optical axis) of each view's samples.
    usable : np.ndarray
        ``bool [V, V]`` pairs within every limit (symmetric).
    """

    pairs: np.ndarray
    neighbors: list
    overlap: np.ndarray
    angle: np.ndarray
    depth_range: np.ndarray
    usable: np.ndarray

    def ranked(self, v: int, target_angle: float, spread: float = 10.0) -> np.ndarray:
        """Usable partners of view ``v``, best first by overlap x closeness of the ray angle to
        ``target_angle`` degrees (a Gaussian of width ``spread``)."""
        cand = np.flatnonzero(self.usable[v])
        score = np.minimum(self.overlap[v, cand], self.overlap[cand, v]) * np.exp(
            -0.5 * ((self.angle[v, cand] - target_angle) / spread) ** 2)
        return cand[np.argsort(-score, kind="stable")]


def ray_box_exit(origins: np.ndarray, dirs: np.ndarray, aabb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Entry and exit distances of rays through an axis-aligned box (slab method); exit < entry: a miss.

    Examples
    --------
    >>> import numpy as np
    >>> t0, t1 = ray_box_exit(np.zeros((1, 3)), np.array([[1.0, 0, 0]]), np.array([[-1.0] * 3, [2.0] * 3]))
    >>> float(t0[0]), float(t1[0])
    (0.0, 2.0)
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / dirs
        a = (aabb[0] - origins) * inv
        b = (aabb[1] - origins) * inv
    lo = np.nan_to_num(np.minimum(a, b), nan=-np.inf)
    hi = np.nan_to_num(np.maximum(a, b), nan=np.inf)
    return np.maximum(lo.max(1), 0.0), hi.min(1)


def masked_median(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Row-wise median of ``values [R, C]`` over the entries where ``mask`` is true (0 for empty rows)."""
    v = np.where(mask, values, np.inf)
    v.sort(axis=1)
    cnt = mask.sum(1)
    rows = np.arange(len(v))
    lo = v[rows, np.maximum((cnt - 1) // 2, 0)]
    hi = v[rows, np.maximum(cnt // 2, 0)]
    return np.where(cnt > 0, 0.5 * (lo + hi), 0.0)


def frustum_samples(cameras: Cameras, i: int, aabb: np.ndarray | None, far_default: float) -> np.ndarray:
    """``[S, 3]`` world points spread through view ``i``'s frustum, inside ``aabb`` when given."""
    w, h = int(cameras.width[i]), int(cameras.height[i])
    us = (np.arange(_GRID) + 0.5) / _GRID * w - 0.5
    vs = (np.arange(_GRID) + 0.5) / _GRID * h - 0.5
    u, v = (a.ravel() for a in np.meshgrid(us, vs))
    o, d = cameras.rays(i, u, v)
    if aabb is not None:
        near, far = ray_box_exit(o, d, aabb)
        hit = far > near
        near, far = np.where(hit, near, 0.0), np.where(hit, far, far_default)
    else:
        near, far = np.zeros(len(o)), np.full(len(o), far_default)
    fr = np.asarray(_DEPTH_FRACTIONS)
    t = near[:, None] + (far - near)[:, None] * fr[None, :]
    return (o[:, None, :] + d[:, None, :] * t[..., None]).reshape(-1, 3)


def select_pairs(cameras: Cameras, config: PairConfig, aabb: np.ndarray | None = None,
                 neighbors: int | None = None) -> ViewGraph:
    """Choose the view pairs to match.

    Parameters
    ----------
    cameras : Cameras
        The views (any subset of a scene's cameras).
    config : PairConfig
        Angle, overlap and count limits.
    aabb : np.ndarray, optional
        ``[2, 3]`` scene box; without it the frustums reach 4x the spread of the camera centres.
    neighbors : int, optional
        Partners per view (default ``config.neighbors``).

    Returns
    -------
    ViewGraph
    """
    k = config.neighbors if neighbors is None else neighbors
    n = len(cameras)
    r, t, kk = *world_to_camera(cameras), intrinsics(cameras)
    centres = cameras.centers
    spread = float(np.median(np.linalg.norm(centres - centres.mean(0), axis=1))) if n > 1 else 1.0
    far_default = 4.0 * max(spread, 1e-3)
    overlap = np.zeros((n, n))
    angle = np.zeros((n, n))
    depth_range = np.zeros((n, 2))
    fwd = cameras.forward
    for i in range(n):
        x = frustum_samples(cameras, i, aabb, far_default)
        zi = (x - centres[i]) @ fwd[i]
        depth_range[i] = (max(zi.min(), 1e-6), zi.max())
        views = np.repeat(np.arange(n), len(x))
        xs = np.tile(x, (n, 1))
        p, z, _ = project(r, t, kk, views, xs)
        w = cameras.width[views]
        h = cameras.height[views]
        inside = (z > 1e-9) & (p[:, 0] >= 0) & (p[:, 0] <= w) & (p[:, 1] >= 0) & (p[:, 1] <= h)
        inside = inside.reshape(n, len(x))
        overlap[i] = inside.mean(1)
        # Angle at each sample between the rays from camera i and camera j.
        di = x - centres[i]
        di /= np.linalg.norm(di, axis=1, keepdims=True)
        dj = x[None, :, :] - centres[:, None, :]
        dj /= np.maximum(np.linalg.norm(dj, axis=2, keepdims=True), 1e-12)
        ang = np.degrees(np.arccos(np.clip(np.einsum("sk,vsk->vs", di, dj), -1, 1)))
        angle[i] = masked_median(ang, inside)
    axis_angle = np.degrees(np.arccos(np.clip(fwd @ fwd.T, -1, 1)))
    sym_overlap = np.minimum(overlap, overlap.T)
    sym_angle = 0.5 * (angle + angle.T)
    ok = ((axis_angle <= config.max_view_angle) & (sym_overlap >= max(config.min_overlap, 1e-9))
          & (sym_angle >= config.min_baseline_angle))
    np.fill_diagonal(ok, False)
    # Triangulation angles of ~5-30 degrees are most useful; tiny ones give noisy depth, wide ones change
    # appearance too much for descriptors and ZNCC.
    useful = np.clip(sym_angle / 5.0, 0, 1) * np.clip((60.0 - sym_angle) / 30.0, 0.1, 1)
    score = np.where(ok, sym_overlap * useful, -1.0)
    neighbours = []
    pairs = set()
    for i in range(n):
        order = np.argsort(-score[i], kind="stable")
        best = [int(j) for j in order if score[i, j] > 0]
        neighbours.append(np.asarray(best, np.int64))
        for j in best[:k]:
            pairs.add((min(i, j), max(i, j)))
    pair_arr = np.asarray(sorted(pairs), np.int64).reshape(-1, 2)
    return ViewGraph(pair_arr, neighbours, overlap, sym_angle, depth_range, ok)
