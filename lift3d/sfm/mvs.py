"""Plane-sweep multi-view stereo with known cameras: semi-dense depth and a per-pixel sigma.

For each reference view and its best source views (the pair selection of :mod:`lift3d.sfm.pairs`):

1. **Sweep**: planes fronto-parallel to the reference camera, uniform in inverse depth between a near and
   a far depth (from the view's sparse points when given, else from the scene box); as many as make the
   point move about ``plane_step`` pixels between planes in the source that moves most (``max_planes`` at
   most).
   Each source image is warped onto the reference through the plane's homography
   ``H = K_s (R + t nᵀ / d) K_r⁻¹`` (``cv2.warpPerspective``).
2. **Photo-consistency**: zero-mean normalised cross-correlation over ``window`` x ``window`` patches, from
   box filters (``cv2.boxFilter``) of the images, their squares and products. Per plane the cost is the mean
   of the ``best_k`` best sources (robust to occlusion: a source that does not see the point is ignored), or of
   as many sources as have the point inside their image when fewer do (``fewer_where_fewer_see``: the ends
   of a capture).
3. **Winner-take-all** over the planes, refined between planes by a parabola through the neighbouring
   costs (in inverse depth). Kept when the winner's ZNCC reaches ``min_zncc``, beats every plane more than
   two planes away by ``min_margin`` (uniqueness) and the reference window has texture (``min_texture``).
4. **Geometric consistency**: a depth is kept when, for at least ``consistent_views`` source views, the
   point reprojected into the source, lifted with the source's own depth and projected back lands within
   ``consistency_pixels`` of where it started with a depth within ``consistency_depth`` (relative); with
   ``fewer_where_fewer_see``, every source whose image holds the point suffices when fewer do. The kept depth
   is the mean of the consistent estimates.
5. **Support**: how many sources confirmed each depth, the fewer of step 2's (the sources heard) and step 4's
   (the sources that agreed): ``DenseDepth.support``. A consumer that needs well-confirmed depths (the plane
   fit of :mod:`lift3d.train.image_depth`) leaves out those one source confirmed.

**Sigma.** With ``g_s = |dp_s / dd|`` the image motion (pixels per world unit of reference depth) of the
point in source ``s`` at the chosen depth, and ``σ_m`` = ``match_sigma`` the matching precision in pixels,
``σ_d = σ_m / sqrt(Σ_s g_s²)`` over the sources that agreed (ZNCC ≥ ``min_zncc``) — the same propagation as
the sparse points' (:mod:`lift3d.sfm.triangulation`), widened to the spread of the consistent estimates when
that is larger.

Images larger than ``max_size`` are matched downscaled; depth maps are brought back to the image size
(nearest neighbour). Distorted cameras are matched on undistorted images and the maps resampled back.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from lift3d.data.cameras import Cameras
from lift3d.data.scene import Scene
from lift3d.data.stereo import DenseDepth, SparsePoints
from lift3d.sfm.config import DenseConfig, SfmConfig
from lift3d.sfm.geometry import ideal_pixels, intrinsics, world_to_camera
from lift3d.sfm.pairs import select_pairs
from lift3d.sfm.planes.fit import LEANING_UP_CONE_DEG, LEVEL_UP_CONE_DEG
from lift3d.sfm.sparse import default_frames
from lift3d.utils.geometry import level_up
from lift3d.utils.progress import progress_bar

# Continuous pixel coordinates (centre of pixel c at c + 0.5) to OpenCV's (centre at c) and back.
_TO_CV = np.array([[1.0, 0, -0.5], [0, 1.0, -0.5], [0, 0, 1.0]])
_FROM_CV = np.array([[1.0, 0, 0.5], [0, 1.0, 0.5], [0, 0, 1.0]])


def plane_homography(k_ref: np.ndarray, k_src: np.ndarray, r_rel: np.ndarray, t_rel: np.ndarray,
                     normal: np.ndarray, q: float) -> np.ndarray:
    """Homography mapping reference pixels (OpenCV pixel coordinates) to source pixels for the plane
    ``normalᵀ X_ref = 1 / q`` in reference camera coordinates (``X_src = r_rel X_ref + t_rel``):
    ``H = K_s (R + q t nᵀ) K_r⁻¹``, linear in ``q``, so planes uniform in ``q`` move the image about evenly.

    Examples
    --------
    >>> import numpy as np
    >>> k = np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]])
    >>> h = plane_homography(k, k, np.eye(3), np.array([-0.5, 0, 0]), np.array([0, 0, 1.0]), 0.5)  # z = 2
    >>> p = h @ [49.5, 49.5, 1.0]; (p[:2] / p[2]).round(3).tolist()        # disparity f b / z = 25 px
    [24.5, 49.5]
    """
    h = k_src @ (r_rel + q * np.outer(t_rel, normal)) @ np.linalg.inv(k_ref)
    return _TO_CV @ h @ _FROM_CV


def _box(img: np.ndarray, window: int) -> np.ndarray:
    return cv2.boxFilter(img, cv2.CV_32F, (window, window), normalize=True, borderType=cv2.BORDER_REFLECT)


def _undistort(image: np.ndarray, cams: Cameras, i: int) -> np.ndarray:
    k = cams.K(i)
    if cams.camera_model == "OPENCV_FISHEYE":
        return cv2.fisheye.undistortImage(image, k, cams.distortion[i, :4], Knew=k)
    return cv2.undistort(image, k, cams.distortion[i])


def _grey(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    g = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    if (g.shape[1], g.shape[0]) != size:
        g = cv2.resize(g, size, interpolation=cv2.INTER_AREA)
    return g.astype(np.float32)


def _pixel_rays(k: np.ndarray, h: int, w: int) -> np.ndarray:
    """``[H, W, 3]`` rays ``(x, y, 1)`` through the pixel centres (z-depth 1)."""
    rows, cols = np.indices((h, w))
    return np.stack([((cols + 0.5) - k[0, 2]) / k[0, 0], ((rows + 0.5) - k[1, 2]) / k[1, 1], np.ones((h, w))], -1)


def plane_range(k_ref: np.ndarray, k_src: Sequence[np.ndarray], rel: Sequence[tuple[np.ndarray, np.ndarray]],
                normal: np.ndarray, near: float, far: float, shape: tuple[int, int],
                config: DenseConfig) -> np.ndarray:
    """The plane parameters ``q`` to sweep along ``normal``: every plane that meets the reference frustum
    between ``near`` and ``far`` (rays within ~6 degrees of the planes are left out), spaced so that the
    point moves about ``plane_step`` pixels between planes in the source that moves most."""
    h, w = shape
    g = (np.arange(7) + 0.5) / 7
    pts = np.stack(np.meshgrid(g * w, g * h), -1).reshape(-1, 2)
    ray = np.column_stack([(pts[:, 0] - k_ref[0, 2]) / k_ref[0, 0], (pts[:, 1] - k_ref[1, 2]) / k_ref[1, 1],
                           np.ones(len(pts))])
    c = ray @ normal
    keep = np.abs(c) >= 0.1 * np.linalg.norm(ray, axis=1)
    if not keep.any():
        return np.zeros(0)
    qs = np.concatenate([1.0 / (near * c[keep]), 1.0 / (far * c[keep])])
    q_lo, q_hi = float(qs.min()), float(qs.max())
    motion = 0.0
    hp = np.column_stack([pts - 0.5, np.ones(len(pts))])[keep]  # OpenCV pixel coordinates
    for ks, (r_rel, t_rel) in zip(k_src, rel):
        ends = []
        for q in (q_lo, q_hi):
            p = hp @ plane_homography(k_ref, ks, r_rel, t_rel, normal, q).T
            ends.append(p[:, :2] / np.where(np.abs(p[:, 2:]) > 1e-9, p[:, 2:], 1e-9))
        motion = max(motion, float(np.max(np.linalg.norm(ends[0] - ends[1], axis=1))))
    n = int(np.clip(np.ceil(motion / config.plane_step) + 1, 8, config.max_planes))
    return np.linspace(q_lo, q_hi, n)


@dataclass(frozen=True)
class _Reference:
    """The reference view as the photo-consistency needs it: its grey image and that image's mean and variance
    over the ZNCC window around each pixel (computed once per view, for every plane direction).

    Attributes
    ----------
    grey : np.ndarray
        ``float32 [H, W]`` grey reference image.
    mean, var : np.ndarray
        ``[H, W]`` its windowed mean and variance (``config.window`` box filter).
    """

    grey: np.ndarray
    mean: np.ndarray
    var: np.ndarray

    @classmethod
    def of(cls, grey: np.ndarray, window: int) -> "_Reference":
        mean = _box(grey, window)
        return cls(grey, mean, np.maximum(_box(grey * grey, window) - mean * mean, 0.0))


def _sweep_direction(reference: _Reference, sources, k_ref, k_src, rel, normal, qs, near, far, config, rules):
    """Cost volumes along one plane direction, one per aggregation rule (``rules``: False = the mean of the
    best ``best_k`` sources, True = of as many as hold the point when fewer do). Returns per rule and pixel
    the winner's cost, its depth, the uniqueness margin, whether it is an interior plane, each source's ZNCC
    at the winner and how many sources' images held the winner's point."""
    ref, mu_r, var_r = reference.grey, reference.mean, reference.var
    h, w = ref.shape
    win = config.window
    n_src = len(sources)
    k_best = min(config.best_k, n_src)
    c_pix = (_pixel_rays(k_ref, h, w) @ normal).astype(np.float32)  # nᵀ ray per pixel: z = 1 / (q c)
    min_var = config.min_texture**2 * 0.25  # sources need some texture too (ZNCC of a flat patch is noise)
    relaxes = k_best > 1 and any(rules)
    # the distinct means to sweep: with one source asked the fewer-sources rule's mean is the full rule's, and one
    # cost volume serves both (False = the full rule's mean, True = the fewer-sources rule's)
    kinds = sorted({bool(fewer) and relaxes for fewer in rules})
    cost = {kind: np.empty((len(qs), h, w), np.float32) for kind in kinds}
    best_zncc = {kind: np.full((h, w), -np.inf, np.float32) for kind in kinds}
    best_src = {kind: np.zeros((n_src, h, w), np.float32) for kind in kinds}
    best_covering = {kind: np.zeros((h, w), np.int32) for kind in kinds}
    fewer_here = np.zeros((h, w), bool)  # pixels where some plane's point is in fewer than k_best sources' images
    # H(q) = A + q B (plane_homography is linear in q): two matrices per source instead of one per plane.
    hom_a = [plane_homography(k_ref, ks, r_rel, t_rel, normal, 0.0) for ks, (r_rel, t_rel) in zip(k_src, rel)]
    hom_b = [plane_homography(k_ref, ks, r_rel, t_rel, normal, 1.0) - a
             for a, ks, (r_rel, t_rel) in zip(hom_a, k_src, rel)]
    lo, hi = np.float32(0.8 * near), np.float32(1.25 * far)
    for p, q in enumerate(qs):
        with np.errstate(divide="ignore", invalid="ignore"):
            z_plane = np.float32(1.0) / (np.float32(q) * c_pix)
        in_range = (z_plane > lo) & (z_plane < hi)
        zs = np.empty((n_src, h, w), np.float32)
        top = np.full((k_best, h, w), -1.0, np.float32)  # the k best ZNCCs so far, sorted high to low
        covering = np.zeros((h, w), np.int32)  # sources whose image holds the point
        for s, src in enumerate(sources):
            hom = hom_a[s] + q * hom_b[s]
            # Outside the source reads -1e4 (a pixel that interpolates with it goes negative), is marked and
            # zeroed; never NaN: OpenCV's box filter keeps running sums, so a NaN would spread along the row.
            img = cv2.warpPerspective(src, hom, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                      borderMode=cv2.BORDER_CONSTANT, borderValue=-1e4)
            inside = img >= 0
            covering += inside
            np.maximum(img, 0.0, out=img)
            stats = _box(np.dstack([img, img * img, img * ref]), win)
            mu_s = stats[..., 0]
            var_s = stats[..., 1] - mu_s * mu_s
            cov = stats[..., 2] - mu_s * mu_r
            z = cov / np.sqrt(np.maximum(var_s * var_r, 1e-12))
            z = np.where(inside & (var_s >= min_var), np.clip(z, -1, 1), np.float32(-1.0))
            zs[s] = z
            for j in range(k_best):  # insertion into the sorted top-k (cheaper than a partition per plane)
                hi_j = np.maximum(top[j], z)
                z = np.minimum(top[j], z)
                top[j] = hi_j
        # the mean of the best k_best sources and, for the fewer-sources rule, of the best min(k_best, covering):
        # sources that cannot see the point do not vote. One running sum gives both (the same sums, in the same
        # order, as a mean over the top k).
        total = top[0].copy()
        relaxed = total.copy() if relaxes else None
        for j in range(1, k_best):
            if relaxes:
                np.copyto(relaxed, total / np.float32(j), where=covering == j)
            total += top[j]
        total /= np.float32(k_best)
        if relaxes:
            np.copyto(relaxed, total, where=covering >= k_best)
            fewer_here |= in_range & (covering < k_best)
        for kind in kinds:
            agg = np.where(in_range, relaxed if kind else total, np.float32(-1.0))
            cost[kind][p] = 1.0 - agg
            better = agg > best_zncc[kind]
            np.copyto(best_zncc[kind], agg, where=better)  # in place: this runs per plane and mean
            np.copyto(best_src[kind], zs, where=better[None])
            np.copyto(best_covering[kind], covering, where=better)
    out = {}
    for kind in kinds:  # the full rule's first
        if kind and False in out:
            # the fewer-sources rule's cost differs from the full rule's only where some plane's point is in fewer
            # than k_best sources' images: elsewhere the full rule's winner is its winner
            c0, depth, margin, interior = (np.array(x) for x in out[False][:4])
            sub = _winner(cost[kind][:, fewer_here][:, None], qs, c_pix[fewer_here][None])
            for full, part in zip((c0, depth, margin, interior), sub):
                full[fewer_here] = part[0]
            out[kind] = (c0, depth, margin, interior, best_src[kind], best_covering[kind])
        else:
            out[kind] = _winner(cost[kind], qs, c_pix) + (best_src[kind], best_covering[kind])
    return [out[bool(fewer) and relaxes] for fewer in rules]


def _winner(cost: np.ndarray, qs: np.ndarray, c_pix: np.ndarray) -> tuple[np.ndarray, ...]:
    """Winner-take-all over a ``[P, H, W]`` cost volume, refined by a parabola: the winner's cost, its depth,
    the uniqueness margin and whether it is an interior plane."""
    n, h, w = cost.shape
    idx = cost.argmin(0)
    rows, cols = np.indices((h, w))
    c0 = cost[idx, rows, cols]
    cm = cost[np.maximum(idx - 1, 0), rows, cols]
    cp = cost[np.minimum(idx + 1, n - 1), rows, cols]
    denom = cm - 2 * c0 + cp
    with np.errstate(invalid="ignore", divide="ignore"):
        offset = np.where(denom > 1e-9, 0.5 * (cm - cp) / denom, 0.0)
    interior = (idx > 0) & (idx < n - 1)
    offset = np.clip(np.where(interior, offset, 0.0), -0.5, 0.5)
    q_best = qs[idx] + offset * (qs[1] - qs[0])
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = 1.0 / (q_best * c_pix)
    planes = np.arange(n)[:, None, None]
    far_cost = np.where(np.abs(planes - idx[None]) > 2, cost, np.inf).min(0)
    margin = far_cost - c0
    return c0, np.nan_to_num(depth, nan=0.0, posinf=0.0, neginf=0.0), margin, interior


def sweep_view(ref: np.ndarray, sources: Sequence[np.ndarray], k_ref: np.ndarray, k_src: Sequence[np.ndarray],
               rel: Sequence[tuple[np.ndarray, np.ndarray]], near: float, far: float, config: DenseConfig,
               normals: Sequence[np.ndarray] = (np.array([0.0, 0.0, 1.0]),), rules: Sequence[bool] = (False,)
               ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Plane sweep of one reference view, along one or more plane directions.

    Parameters
    ----------
    ref : np.ndarray
        ``float32 [H, W]`` grey reference image.
    sources : sequence of np.ndarray
        Grey source images (any sizes).
    k_ref, k_src : np.ndarray
        Intrinsics (continuous pixel coordinates) of the reference and of each source at these sizes.
    rel : sequence of (R, t)
        Pose of each source relative to the reference: ``X_src = R X_ref + t``.
    near, far : float
        Depth range of the sweep (z-depth along the reference's optical axis).
    config : DenseConfig
    normals : sequence of np.ndarray
        Plane normals in reference camera coordinates; ``(0, 0, 1)`` is fronto-parallel. Each pixel takes
        the direction whose best plane is most photo-consistent.
    rules : sequence of bool
        Photo-consistency rules, each giving its own maps from the same warps: False = the mean of the best
        ``best_k`` sources; True = of as many as hold the point when fewer do (``fewer_where_fewer_see``).

    Returns
    -------
    list of (depth, sigma, support)
        One per rule: ``float32 [H, W]`` z-depth, 0 where rejected; ``float32 [H, W]`` its standard deviation,
        0 where rejected; ``uint8 [H, W]`` the sources the photo-consistency heard (of the best ``best_k``,
        those whose image holds the point), 0 where rejected.
    """
    h, w = ref.shape
    reference = _Reference.of(ref, config.window)
    best = None
    for normal in normals:
        normal = np.asarray(normal, np.float64)
        qs = plane_range(k_ref, k_src, rel, normal, near, far, (h, w), config)
        if len(qs) < 3:
            continue
        res = [list(x) for x in _sweep_direction(reference, sources, k_ref, k_src, rel, normal, qs, near, far,
                                                  config, rules)]
        if best is None:
            best = res
            continue
        for b, x in zip(best, res):
            take = x[0] < b[0]
            for k in (0, 1, 2, 3, 5):
                b[k] = np.where(take, x[k], b[k])
            b[4] = np.where(take[None], x[4], b[4])
    if best is None:
        empty = (np.zeros((h, w), np.float32), np.zeros((h, w), np.float32), np.zeros((h, w), np.uint8))
        return [empty for _ in rules]
    return [_accept(reference.var, k_ref, k_src, rel, config, *b) for b in best]


def _accept(var_r, k_ref, k_src, rel, config, c0, depth, margin, interior, best_src, covering):
    """The winners that pass the ZNCC, uniqueness and texture tests (``var_r``: the reference's windowed grey-level
    variance), with their sigma and support."""
    h, w = var_r.shape
    zncc = 1.0 - c0
    ok = ((var_r >= config.min_texture**2) & interior & (zncc >= config.min_zncc) & (margin >= config.min_margin)
          & (depth > 0))

    # Sigma from the image motion per unit depth in the sources that agree.
    ray = _pixel_rays(k_ref, h, w)  # dX_ref / dd for z-depth d
    info = np.zeros((h, w))
    for s, (ks, (r_rel, t_rel)) in enumerate(zip(k_src, rel)):
        xs = (ray * depth[..., None]) @ r_rel.T + t_rel
        dxs = ray @ r_rel.T
        zc = np.maximum(xs[..., 2], 1e-9)
        du = ks[0, 0] * (dxs[..., 0] * zc - xs[..., 0] * dxs[..., 2]) / zc**2
        dv = ks[1, 1] * (dxs[..., 1] * zc - xs[..., 1] * dxs[..., 2]) / zc**2
        agree = best_src[s] >= config.min_zncc
        info += np.where(agree, du * du + dv * dv, 0.0)
    sigma = config.match_sigma / np.sqrt(np.maximum(info, 1e-12))
    ok &= info > 0
    support = np.where(ok, np.minimum(covering, min(config.best_k, len(k_src))), 0).astype(np.uint8)
    return (np.where(ok, depth, 0.0).astype(np.float32), np.where(ok, sigma, 0.0).astype(np.float32), support)


def geometric_filter(depths: list[np.ndarray], sigmas: list[np.ndarray], supports: list[np.ndarray],
                     ks: list[np.ndarray], r: np.ndarray, t: np.ndarray, neighbours: list[np.ndarray],
                     config: DenseConfig, fewer: bool = False
                     ) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """Keep depths that at least ``consistent_views`` source depth maps agree with (``fewer``: or every source
    whose image holds the point, when fewer do); average them. A kept depth's support becomes the smaller of
    its photo-consistency support and the agreeing sources."""
    out_d, out_s, out_n = [], [], []
    for v, (d, s, n_photo) in enumerate(zip(depths, sigmas, supports)):
        h, w = d.shape
        valid = d > 0
        rows, cols = np.nonzero(valid)
        if config.consistent_views == 0 or len(rows) == 0:
            out_d.append(d)
            out_s.append(s)
            out_n.append(n_photo)
            continue
        z = d[rows, cols].astype(np.float64)
        k = ks[v]
        x_cam = np.column_stack([((cols + 0.5) - k[0, 2]) / k[0, 0] * z, ((rows + 0.5) - k[1, 2]) / k[1, 1] * z, z])
        x_w = (x_cam - t[v]) @ r[v]  # Rᵀ (X - t)
        count = np.zeros(len(z), np.int64)
        covering = np.zeros(len(z), np.int64)  # neighbours whose image holds the point
        z_sum = z.copy()
        z_sq = z * z
        for n in neighbours[v]:
            dn = depths[n]
            kn = ks[n]
            xn = x_w @ r[n].T + t[n]
            with np.errstate(divide="ignore", invalid="ignore"):
                un = kn[0, 0] * xn[:, 0] / xn[:, 2] + kn[0, 2]
                vn = kn[1, 1] * xn[:, 1] / xn[:, 2] + kn[1, 2]
            hn, wn = dn.shape
            inside = (xn[:, 2] > 0) & (un >= 0) & (un < wn) & (vn >= 0) & (vn < hn)
            covering += inside
            ci = np.clip(np.nan_to_num(un, nan=0.0).astype(np.int64), 0, wn - 1)
            ri = np.clip(np.nan_to_num(vn, nan=0.0).astype(np.int64), 0, hn - 1)
            zn = np.where(inside, dn[ri, ci], 0.0).astype(np.float64)
            # Lift with the source's own depth at that pixel and bring it back to the reference.
            xn2 = np.column_stack([((ci + 0.5) - kn[0, 2]) / kn[0, 0] * zn, ((ri + 0.5) - kn[1, 2]) / kn[1, 1] * zn, zn])
            xw2 = (xn2 - t[n]) @ r[n]
            xr2 = xw2 @ r[v].T + t[v]
            with np.errstate(divide="ignore", invalid="ignore"):
                ur = k[0, 0] * xr2[:, 0] / xr2[:, 2] + k[0, 2]
                vr = k[1, 1] * xr2[:, 1] / xr2[:, 2] + k[1, 2]
                dist = np.hypot(ur - (cols + 0.5), vr - (rows + 0.5))
                rel = np.abs(xr2[:, 2] - z) / z
            agree = (zn > 0) & (dist <= config.consistency_pixels) & (rel <= config.consistency_depth)
            count += agree
            z_sum += np.where(agree, xr2[:, 2], 0.0)
            z_sq += np.where(agree, xr2[:, 2] ** 2, 0.0)
        need = np.clip(covering, 1, config.consistent_views) if fewer else config.consistent_views
        keep = count >= need
        mean = z_sum / (count + 1)
        spread = np.sqrt(np.maximum(z_sq / (count + 1) - mean**2, 0.0))
        nd = np.zeros_like(d)
        ns = np.zeros_like(s)
        nn = np.zeros_like(n_photo)
        rk, ck = rows[keep], cols[keep]
        nd[rk, ck] = mean[keep]
        ns[rk, ck] = np.maximum(s[rk, ck], spread[keep])
        nn[rk, ck] = np.minimum(n_photo[rk, ck], np.minimum(count[keep], 255))
        out_d.append(nd)
        out_s.append(ns)
        out_n.append(nn)
    return out_d, out_s, out_n


def _depth_range(v: int, frame_index: int, graph, sparse: SparsePoints | None) -> tuple[float, float]:
    """Sweep range of view ``v``: its sparse points' depths (2nd-98th percentile, widened by 1.4x) when it
    sees at least 20, else its frustum inside the scene box."""
    near, far = graph.depth_range[v]
    if sparse is not None and frame_index >= 0:
        z = sparse.obs_depth[sparse.obs_frame == frame_index]
        if len(z) >= 20:
            lo, hi = np.percentile(z, [2, 98])
            near, far = lo / 1.4, hi * 1.4
    far = max(far, near * 1.5)
    near = max(near, far * 0.01)
    return float(near), float(far)


def scene_up(cams: Cameras) -> np.ndarray | None:
    """The world direction the cameras agree is up (mean of their image-up axes), or None when they do not
    (a capture rolled every which way has no preferred horizontal planes)."""
    up = cams.c2w[:, :3, 1].mean(0)  # OpenGL camera y axis = image up
    n = np.linalg.norm(up)
    return up / n if n > 0.7 else None


def plane_fit_up(cams: Cameras) -> tuple[np.ndarray | None, float]:
    """The world's up for a fit of level and upright planes, and how far it may be from the floor's normal (the cone
    :func:`lift3d.sfm.planes.fit_planes` refines it in): at right angles to the cameras' right axes
    (:func:`lift3d.utils.geometry.level_up`, level whatever their pitch, off by their roll only); when every camera
    faces one way, their mean image-up axis (:func:`scene_up`, which leans with their pitch); None when they do not
    agree on one. Not the mean image-up first: it leans 25° in a room whose views all look down, and then the floor
    is missed. The cones: :data:`lift3d.sfm.planes.fit.LEVEL_UP_CONE_DEG`, ``LEANING_UP_CONE_DEG``."""
    leaning = scene_up(cams)
    if leaning is None:
        return None, LEANING_UP_CONE_DEG
    level = level_up(cams.c2w)
    return (leaning, LEANING_UP_CONE_DEG) if level is None else (level, LEVEL_UP_CONE_DEG)


def plane_sweep_scene(scene: Scene, frames: Sequence[int] | None = None, config: SfmConfig | None = None,
                      sparse: SparsePoints | None = None, progress: bool = False) -> DenseDepth:
    """Semi-dense depth and sigma maps of a scene's frames by plane-sweep stereo.

    Parameters
    ----------
    scene : Scene
        A loaded scene folder.
    frames : sequence of int, optional
        Frames to compute maps for, and the only frames used as sources (default: the ``train`` split).
    config : SfmConfig, optional
        ``config.dense`` holds the stereo knobs, ``config.pairs`` the view selection.
    sparse : SparsePoints, optional
        Sparse points of the scene (their depths narrow each view's sweep range).
    progress : bool
        Progress bars on stderr.

    Returns
    -------
    DenseDepth
        Maps at the scene's image sizes; ``info`` holds coverage, seconds and warnings.
    """
    cfg = (config or SfmConfig()).check()
    dc = cfg.dense
    frames = default_frames(scene) if frames is None else np.asarray(frames, np.int64)
    cams = scene.cameras[frames]
    t_start = time.perf_counter()
    box = scene.scene_box
    graph = select_pairs(cams, cfg.pairs, aabb=None if box is None else box.aabb)
    warnings = []
    if not graph.usable.any():
        warnings.append("no view has a source view with enough overlap and baseline: no dense depth")
    r, t = world_to_camera(cams)
    k_full = intrinsics(cams)
    greys, ks, sizes = [], [], []
    for v, i in enumerate(frames):
        img = scene.image(int(i))
        if cams.has_distortion:
            img = _undistort(img, cams, v)
        h, w = img.shape[:2]
        scale = min(1.0, dc.max_size / max(h, w))
        size = (max(1, round(w * scale)), max(1, round(h * scale)))
        greys.append(_grey(img, size))
        kv = k_full[v].copy()
        kv[0] *= size[0] / w
        kv[1] *= size[1] / h
        ks.append(kv)
        sizes.append((w, h))
    names = [scene.frames[int(i)].name for i in frames]
    sparse_index = {}
    if sparse is not None:
        sparse_index = {n: k for k, n in enumerate(sparse.frame_names)}
    up = scene_up(cams) if dc.sweep_up else None
    # the full rule first; the one for points fewer sources see fills only where the full rule found nothing
    # (with one source and one agreeing view asked, the second rule asks the same: not run)
    relaxes = dc.fewer_where_fewer_see and (dc.best_k > 1 or dc.consistent_views > 1)
    rules = (False, True) if relaxes else (False,)
    maps = [([], [], []) for _ in rules]  # per rule: depths, sigmas, supports
    used = []
    t0 = time.perf_counter()
    for v in progress_bar(range(len(frames)), desc="plane sweep", unit="view", disable=not progress):
        nb = graph.ranked(v, dc.target_angle)[:dc.neighbors]
        used.append(nb)
        if len(nb) == 0:
            for m in maps:
                m[0].append(np.zeros_like(greys[v]))
                m[1].append(np.zeros_like(greys[v]))
                m[2].append(np.zeros(greys[v].shape, np.uint8))
            continue
        near, far = _depth_range(v, sparse_index.get(names[v], -1), graph, sparse)
        rel = []
        for n in nb:
            r_rel = r[n] @ r[v].T
            rel.append((r_rel, t[n] - r_rel @ t[v]))
        normals = [np.array([0.0, 0.0, 1.0])]
        if up is not None:
            normals.append(r[v] @ up)
        for m, res in zip(maps, sweep_view(greys[v], [greys[n] for n in nb], ks[v], [ks[n] for n in nb], rel, near,
                                           far, dc, normals, rules)):
            for a, x in zip(m, res):
                a.append(x)
    seconds = {"sweep": time.perf_counter() - t0}
    t0 = time.perf_counter()
    depths, sigmas, supports = geometric_filter(*maps[0], ks, r, t, used, dc)
    if len(rules) > 1:
        # Where the full rule kept no depth, the depth kept by the fewer-sources rule, with support 1: the plane
        # fit leaves such depths out, so it sees exactly what the full rule gives (it is sensitive to its input).
        extra = geometric_filter(*maps[1], ks, r, t, used, dc, fewer=True)
        for v in range(len(frames)):
            add = (depths[v] <= 0) & (extra[0][v] > 0)
            depths[v] = np.where(add, extra[0][v], depths[v])
            sigmas[v] = np.where(add, extra[1][v], sigmas[v])
            supports[v] = np.where(add, np.minimum(extra[2][v], 1), supports[v]).astype(np.uint8)
    seconds["consistency"] = time.perf_counter() - t0
    out_d, out_s, out_n = [], [], []
    for v in range(len(frames)):
        w, h = sizes[v]
        view_maps = (depths[v], sigmas[v], supports[v])
        if cams.has_distortion:
            view_maps = _redistort(view_maps, cams, v)
        elif view_maps[0].shape != (h, w):
            view_maps = tuple(cv2.resize(m, (w, h), interpolation=cv2.INTER_NEAREST) for m in view_maps)
        out_d.append(view_maps[0].astype(np.float32))
        out_s.append(view_maps[1].astype(np.float32))
        out_n.append(view_maps[2].astype(np.uint8))
    seconds["total"] = time.perf_counter() - t_start
    dense = DenseDepth(names, out_d, out_s, support=out_n)
    dense.info = {"source": "lift3d triangulate --dense", "seconds": {k: round(v, 3) for k, v in seconds.items()},
                  "warnings": warnings}
    return dense


def _redistort(maps: Sequence[np.ndarray], cams: Cameras, v: int) -> tuple[np.ndarray, ...]:
    """Resample maps computed on the undistorted (and possibly downscaled) image onto the original pixels."""
    w, h = int(cams.width[v]), int(cams.height[v])
    rows, cols = np.indices((h, w))
    uv = np.column_stack([cols.ravel() + 0.5, rows.ravel() + 0.5])
    p = ideal_pixels(cams, v, uv)
    sx, sy = maps[0].shape[1] / w, maps[0].shape[0] / h
    mx = (p[:, 0] * sx - 0.5).reshape(h, w).astype(np.float32)
    my = (p[:, 1] * sy - 0.5).reshape(h, w).astype(np.float32)
    return tuple(cv2.remap(m, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0) for m in maps)
