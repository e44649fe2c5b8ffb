"""Tracks across views and their multi-view triangulation with known cameras.

Pipeline for the observations of every track at once (vectorised over tracks):

1. **Initial point** with ``cv2.triangulatePoints`` from the two observations whose rays are farthest apart
   (found by two sweeps: the ray farthest from the track's mean ray, then the ray farthest from that one);
   the linear midpoint of all rays replaces it when those two rays are (nearly) parallel.
2. **Refinement**: Gauss-Newton on the reprojection error (ideal pixels) over all observations, Huber
   weights with threshold ``max_reprojection_error``, a little Levenberg damping.
3. **Outliers**: observations behind their camera or reprojecting worse than ``max_reprojection_error``
   are removed (and of two observations in one view the worse one), then the point is refined again.
4. **Filters**, each dropped point counted under the first reason it fails: ``short track`` (fewer than
   ``min_views`` views to begin with), ``behind camera``, ``large error`` (fewer than ``min_views`` good
   observations left), ``small angle`` (widest angle between two observing rays below
   ``min_triangulation_angle``), ``outside box``.

**Uncertainty.** With ``J`` the ``[2n, 3]`` Jacobian of a point's reprojections (pixels per world unit) and
``r`` its ``2n`` residuals, the image noise is estimated as ``σ_px = max(sigma_floor, sqrt(|r|² / (2n - 3)))``
and the point's covariance as ``Σ = σ_px² (JᵀJ)⁻¹``. The standard deviation of its z-depth in view ``c`` is
``σ_z = sqrt(a_cᵀ Σ a_c)`` with ``a_c`` the optical axis of ``c``. Σ grows as the rays become parallel: for
two views at distance ``d`` whose rays meet at angle ``α`` it is about ``σ_px d / (f sin α)`` along each
ray, so the triangulation angle enters through ``J``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from lift3d.sfm.config import TrackConfig
from lift3d.sfm.geometry import ray_directions

DROP_REASONS = ("short track", "behind camera", "large error", "small angle", "outside box")


@dataclass
class TriangulatedTracks:
    """Points that passed every filter, with their observations.

    Attributes
    ----------
    xyz : np.ndarray
        ``[P, 3]`` points.
    error : np.ndarray
        ``[P]`` mean reprojection error (pixels).
    obs_index : np.ndarray
        ``[M]`` indices into the input observations that support the points.
    obs_point : np.ndarray
        ``[M]`` point index of each.
    obs_depth, obs_sigma : np.ndarray
        ``[M]`` z-depth in its view and its standard deviation.
    dropped : dict
        Count of candidate tracks dropped per reason (keys :data:`DROP_REASONS`).
    """

    xyz: np.ndarray
    error: np.ndarray
    obs_index: np.ndarray
    obs_point: np.ndarray
    obs_depth: np.ndarray
    obs_sigma: np.ndarray
    dropped: dict


def _group_argmax(values: np.ndarray, group: np.ndarray, n_groups: int) -> np.ndarray:
    """Index of the largest value in each group (``-1`` for empty groups)."""
    order = np.lexsort((-values, group))
    g = group[order]
    first = np.ones(len(g), bool)
    first[1:] = g[1:] != g[:-1]
    out = np.full(n_groups, -1, np.int64)
    out[g[first]] = order[first]
    return out


def _sum_by(group: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Sum rows of ``values [N, ...]`` per group -> ``[n, ...]`` (bincount per column: faster than add.at)."""
    flat = values.reshape(len(values), int(np.prod(values.shape[1:])))
    out = np.stack([np.bincount(group, weights=flat[:, c], minlength=n) for c in range(flat.shape[1])], -1)
    return out.reshape((n,) + values.shape[1:])


def _distinct_views(point: np.ndarray, view: np.ndarray, active: np.ndarray, n_points: int) -> np.ndarray:
    key = np.unique(point[active].astype(np.int64) * (int(view.max(initial=0)) + 1) + view[active])
    return np.bincount(key // (int(view.max(initial=0)) + 1), minlength=n_points)


def initial_points(r, t, k, view, p, point, n_points) -> np.ndarray:
    """``[T, 3]`` initial positions: ``cv2.triangulatePoints`` on the widest pair of rays of each track."""
    d = ray_directions(r, k, view, p)
    centre = -np.einsum("nji,nj->ni", r[view], t[view])  # camera centres -Rᵀ t
    mean = _sum_by(point, d, n_points)
    mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-12)
    a = _group_argmax(-np.einsum("nk,nk->n", d, mean[point]), point, n_points)
    b = _group_argmax(-np.einsum("nk,nk->n", d, d[a[point]]), point, n_points)
    xyz = np.zeros((n_points, 3))
    proj = k @ np.concatenate([r, t[:, :, None]], axis=2)  # [F, 3, 4]
    va, vb = view[a], view[b]
    cos_ab = np.einsum("nk,nk->n", d[a], d[b])
    good = (va != vb) & (cos_ab < np.cos(np.radians(0.05)))
    key = va.astype(np.int64) * (len(r) + 1) + vb
    for kv in np.unique(key[good]):
        sel = np.flatnonzero(good & (key == kv))
        i, j = int(va[sel[0]]), int(vb[sel[0]])
        xh = cv2.triangulatePoints(proj[i], proj[j], p[a[sel]].T.astype(np.float64),
                                   p[b[sel]].T.astype(np.float64))
        w = xh[3]
        ok = np.abs(w) > 1e-12
        xyz[sel[ok]] = (xh[:3, ok] / w[ok]).T
        good[sel[~ok]] = False
    # Fallback: the point closest to all rays, solving sum (I - d dᵀ)(X - C) = 0 per track.
    bad = np.flatnonzero(~good)
    if len(bad):
        m = np.isin(point, bad)
        dd = d[m]
        proj_perp = np.eye(3)[None] - dd[:, :, None] * dd[:, None, :]
        a_sum = _sum_by(point[m], proj_perp, n_points)[bad]
        b_sum = _sum_by(point[m], np.einsum("nij,nj->ni", proj_perp, centre[m]), n_points)[bad]
        a_sum += 1e-9 * np.eye(3)[None]
        xyz[bad] = np.linalg.solve(a_sum, b_sum[..., None])[..., 0]
    return xyz


def _residuals(r, t, k, view, p, xyz_obs):
    xc = np.einsum("nij,nj->ni", r[view], xyz_obs) + t[view]
    z = xc[:, 2]
    zs = np.where(np.abs(z) > 1e-12, z, 1e-12)
    fx, fy = k[view, 0, 0], k[view, 1, 1]
    pred = np.column_stack([fx * xc[:, 0] / zs + k[view, 0, 2], fy * xc[:, 1] / zs + k[view, 1, 2]])
    res = pred - p
    # d(pixel)/d(X_cam), then chain through R: [N, 2, 3].
    jc = np.zeros((len(view), 2, 3))
    jc[:, 0, 0] = fx / zs
    jc[:, 0, 2] = -fx * xc[:, 0] / zs**2
    jc[:, 1, 1] = fy / zs
    jc[:, 1, 2] = -fy * xc[:, 1] / zs**2
    jac = jc @ r[view]
    return res, jac, z


def refine(r, t, k, view, p, point, xyz, active, iterations: int, huber: float):
    """Gauss-Newton (Huber-weighted, damped) on each point's reprojection error over its active
    observations; returns the refined ``[T, 3]`` points."""
    n_points = len(xyz)
    xyz = xyz.copy()
    for _ in range(iterations):
        res, jac, _z = _residuals(r, t, k, view, p, xyz[point])
        err = np.linalg.norm(res, axis=1)
        w = np.where(active, np.minimum(1.0, huber / np.maximum(err, 1e-12)), 0.0)
        jtj = np.einsum("nki,nkj->nij", jac, jac) * w[:, None, None]
        jtr = np.einsum("nki,nk->ni", jac, res) * w[:, None]
        h = _sum_by(point, jtj, n_points)
        g = _sum_by(point, jtr, n_points)
        damp = 1e-6 * np.trace(h, axis1=1, axis2=2)[:, None, None] * np.eye(3)[None] + 1e-12 * np.eye(3)[None]
        step = np.linalg.solve(h + damp, -g[..., None])[..., 0]
        xyz += np.where(np.isfinite(step), step, 0.0)
    return xyz


def triangulate_tracks(r, t, k, view, p, track, config: TrackConfig, aabb: np.ndarray | None = None,
                       bounded: bool = True) -> TriangulatedTracks:
    """Triangulate tracks with known cameras, remove outliers, filter and count what is dropped.

    Parameters
    ----------
    r, t, k : np.ndarray
        World-to-camera rotations ``[F, 3, 3]``, translations ``[F, 3]``, intrinsics ``[F, 3, 3]``.
    view : np.ndarray
        ``[N]`` view index of each observation.
    p : np.ndarray
        ``[N, 2]`` ideal pixel of each observation.
    track : np.ndarray
        ``[N]`` track id of each observation (any integers; tracks are the distinct values).
    config : TrackConfig
    aabb : np.ndarray, optional
        ``[2, 3]`` scene box; with ``bounded`` points outside it (plus the margin) are dropped.

    Returns
    -------
    TriangulatedTracks

    Examples
    --------
    >>> import numpy as np
    >>> from lift3d.sfm.geometry import project
    >>> r = np.stack([np.eye(3)] * 3); t = np.array([[0.0, 0, 0], [-0.5, 0, 0], [0, -0.5, 0]])
    >>> k = np.stack([np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]])] * 3)
    >>> X = np.array([[0.2, 0.1, 3.0], [-0.3, 0.2, 4.0]])
    >>> view = np.array([0, 1, 2, 0, 1, 2]); track = np.array([0, 0, 0, 1, 1, 1])
    >>> p, _, _ = project(r, t, k, view, X[track])
    >>> out = triangulate_tracks(r, t, k, view, p, track, TrackConfig())
    >>> bool(np.allclose(out.xyz, X)), out.obs_point.tolist()
    (True, [0, 0, 0, 1, 1, 1])
    """
    dropped = {reason: 0 for reason in DROP_REASONS}
    _, point = np.unique(track, return_inverse=True)
    point = point.reshape(-1)
    n_all = int(point.max()) + 1 if len(point) else 0
    empty = TriangulatedTracks(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64),
                               np.zeros(0), np.zeros(0), dropped)
    if n_all == 0:
        return empty
    # 1. short tracks never get a point.
    n_views = _distinct_views(point, view, np.ones(len(point), bool), n_all)
    long_enough = n_views >= config.min_views
    dropped["short track"] = int((~long_enough).sum())
    keep_obs = long_enough[point]
    obs_index = np.flatnonzero(keep_obs)
    _, point = np.unique(point[keep_obs], return_inverse=True)
    point = point.reshape(-1)
    view, p = view[keep_obs], p[keep_obs]
    n_pts = int(point.max()) + 1 if len(point) else 0
    if n_pts == 0:
        return empty
    alive = np.ones(n_pts, bool)

    def fail(mask: np.ndarray, reason: str) -> None:
        hit = alive & mask
        dropped[reason] += int(hit.sum())
        alive[hit] = False

    # 2. initial points; observations behind their camera are removed.
    xyz = initial_points(r, t, k, view, p, point, n_pts)
    _, _, z = _residuals(r, t, k, view, p, xyz[point])
    active = z > 0
    fail(_distinct_views(point, view, active, n_pts) < config.min_views, "behind camera")
    # 3. refine, remove outliers (and duplicate views), refine again.
    huber = config.max_reprojection_error
    for _round in range(2):
        xyz = refine(r, t, k, view, p, point, xyz, active & alive[point], config.refine_iterations, huber)
        res, _, z = _residuals(r, t, k, view, p, xyz[point])
        err = np.linalg.norm(res, axis=1)
        behind = active & (z <= 0)
        active &= ~behind
        fail(_distinct_views(point, view, active, n_pts) < config.min_views, "behind camera")
        active &= err <= config.max_reprojection_error
        # One observation per (point, view): keep the best-fitting one.
        key = point.astype(np.int64) * len(r) + view
        order = np.lexsort((np.where(active, err, np.inf), key))
        first = np.ones(len(order), bool)
        first[1:] = key[order][1:] != key[order][:-1]
        dup = np.zeros(len(order), bool)
        dup[order[~first]] = True
        active &= ~dup
        fail(_distinct_views(point, view, active, n_pts) < config.min_views, "large error")
    xyz = refine(r, t, k, view, p, point, xyz, active & alive[point], max(config.refine_iterations // 2, 1),
                 huber)
    res, _, z = _residuals(r, t, k, view, p, xyz[point])
    err = np.linalg.norm(res, axis=1)
    active &= (z > 0) & (err <= config.max_reprojection_error) & alive[point]
    fail(_distinct_views(point, view, active, n_pts) < config.min_views, "large error")
    # 4. widest angle between the remaining observing rays (two sweeps).
    d = ray_directions(r, k, view, p)
    act_idx = np.flatnonzero(active)
    pa, da = point[act_idx], d[act_idx]
    mean = _sum_by(pa, da, n_pts)
    mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-12)
    a = _group_argmax(-np.einsum("nk,nk->n", da, mean[pa]), pa, n_pts)
    cosang = np.einsum("nk,nk->n", da, da[np.maximum(a, 0)][pa])
    min_cos = np.full(n_pts, 1.0)
    np.minimum.at(min_cos, pa, cosang)
    widest = np.degrees(np.arccos(np.clip(min_cos, -1, 1)))
    fail(widest < config.min_triangulation_angle, "small angle")
    if aabb is not None and bounded:
        margin = config.box_margin * (aabb[1] - aabb[0])
        outside = np.any((xyz < aabb[0] - margin) | (xyz > aabb[1] + margin), axis=1)
        fail(outside, "outside box")
    active &= alive[point]

    # 5. uncertainty per observation, from the unweighted normal equations of the final fit.
    ids = np.flatnonzero(alive)
    new_id = np.full(n_pts, -1, np.int64)
    new_id[ids] = np.arange(len(ids))
    sel = np.flatnonzero(active)
    z_obs, sig, err_obs = observation_depths(r, t, k, view[sel], p[sel], new_id[point[sel]], xyz[ids],
                                             config.sigma_floor)
    n_obs = np.bincount(new_id[point[sel]], minlength=len(ids))
    mean_err = np.bincount(new_id[point[sel]], weights=err_obs, minlength=len(ids)) / np.maximum(n_obs, 1)
    return TriangulatedTracks(
        xyz=xyz[ids], error=mean_err, obs_index=obs_index[sel], obs_point=new_id[point[sel]],
        obs_depth=z_obs, obs_sigma=sig, dropped=dropped,
    )


def observation_depths(r, t, k, view, p, point, xyz, sigma_floor: float):
    """Depth, depth uncertainty and reprojection error of every observation of known points.

    Parameters
    ----------
    r, t, k : np.ndarray
        World-to-camera rotations ``[F, 3, 3]``, translations ``[F, 3]``, intrinsics ``[F, 3, 3]``.
    view, point : np.ndarray
        ``[M]`` view and point index of each observation.
    p : np.ndarray
        ``[M, 2]`` observed ideal pixels.
    xyz : np.ndarray
        ``[P, 3]`` the points.
    sigma_floor : float
        Smallest image noise (pixels) assumed.

    Returns
    -------
    z : np.ndarray
        ``[M]`` z-depth of the point in each observing view.
    sigma : np.ndarray
        ``[M]`` standard deviation of that depth: ``sqrt(a_cᵀ Σ a_c)`` with
        ``Σ = σ_px² (JᵀJ)⁻¹``, ``σ_px = max(sigma_floor, sqrt(|r|² / max(2n - 3, 1)))`` (module docstring).
    error : np.ndarray
        ``[M]`` reprojection error in pixels.
    """
    n_pts = len(xyz)
    res, jac, z = _residuals(r, t, k, view, p, xyz[point])
    err = np.linalg.norm(res, axis=1)
    h = _sum_by(point, np.einsum("nki,nkj->nij", jac, jac), n_pts) + 1e-12 * np.eye(3)[None]
    ssq = np.bincount(point, weights=err**2, minlength=n_pts)
    n_obs = np.bincount(point, minlength=n_pts)
    sigma_px2 = np.maximum(sigma_floor**2, ssq / np.maximum(2 * n_obs - 3, 1))
    cov = np.linalg.inv(h) * sigma_px2[:, None, None]
    axis = r[view, 2, :]  # optical axis of each observing camera in world coordinates
    sig = np.sqrt(np.maximum(np.einsum("ni,nij,nj->n", axis, cov[point], axis), 0.0))
    return z, sig, err
