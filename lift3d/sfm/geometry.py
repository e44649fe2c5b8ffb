"""Two- and multi-view geometry with known cameras: projection matrices, the fundamental matrix from poses,
Sampson distances, angles between rays, and the depth uncertainty of a triangulated point.

Conventions (see :mod:`lift3d.data.cameras`): world-to-camera ``R, t`` in **OpenCV** axes (x right, y down,
+z forward); *normalised* coordinates ``x = (X_c / Z_c, Y_c / Z_c)`` are undistorted; *ideal pixels*
``p = (fx x + cx, fy y + cy)`` are the pixels an undistorted camera would see (equal to the stored pixels
for ``PINHOLE`` scenes). Pixel errors (reprojection, Sampson) are measured in ideal pixels.
"""

from __future__ import annotations

import numpy as np

from lift3d.data.cameras import Cameras


def world_to_camera(cameras: Cameras) -> tuple[np.ndarray, np.ndarray]:
    """``R [F, 3, 3]``, ``t [F, 3]`` with ``X_cam = R X_world + t`` (OpenCV axes)."""
    c2w = cameras.c2w_opencv
    r = np.transpose(c2w[:, :3, :3], (0, 2, 1))
    t = -np.einsum("fij,fj->fi", r, c2w[:, :3, 3])
    return r, t


def intrinsics(cameras: Cameras) -> np.ndarray:
    """``K [F, 3, 3]``."""
    k = np.zeros((len(cameras), 3, 3))
    k[:, 0, 0], k[:, 1, 1], k[:, 0, 2], k[:, 1, 2], k[:, 2, 2] = (cameras.fx, cameras.fy, cameras.cx,
                                                                  cameras.cy, 1.0)
    return k


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix ``[v]_x`` of a 3-vector."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def fundamental(r: np.ndarray, t: np.ndarray, k: np.ndarray, i: int, j: int) -> np.ndarray:
    """Fundamental matrix ``F`` with ``p_jᵀ F p_i = 0`` for ideal pixels (homogeneous) of views ``i``, ``j``.

    ``E = [t_ij]_x R_ij`` with the relative pose ``R_ij = R_j R_iᵀ``, ``t_ij = t_j - R_ij t_i``, and
    ``F = K_j^-T E K_i^-1`` (Hartley & Zisserman, eq. 9.12).

    Examples
    --------
    >>> import numpy as np
    >>> r = np.stack([np.eye(3)] * 2); t = np.array([[0.0, 0, 0], [-1.0, 0, 0]])
    >>> k = np.stack([np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]])] * 2)
    >>> X = np.array([0.3, -0.2, 4.0])
    >>> p = [k[v] @ (r[v] @ X + t[v]) for v in (0, 1)]
    >>> p = [q / q[2] for q in p]
    >>> abs(float(p[1] @ fundamental(r, t, k, 0, 1) @ p[0])) < 1e-9
    True
    """
    r_ij = r[j] @ r[i].T
    t_ij = t[j] - r_ij @ t[i]
    e = skew(t_ij) @ r_ij
    return np.linalg.inv(k[j]).T @ e @ np.linalg.inv(k[i])


def epipolar_mask(f: np.ndarray, pi: np.ndarray, pj: np.ndarray, max_distance: float) -> np.ndarray:
    """Which pairs of points of views ``i`` and ``j`` are within ``max_distance`` pixels (Sampson distance)
    of the epipolar geometry ``F``.

    The Sampson distance is the first-order approximation of the smallest total image displacement that
    makes a correspondence satisfy the epipolar constraint (Hartley & Zisserman, section 11.4.3)::

        d = |p_jᵀ F p_i| / sqrt((F p_i)_1² + (F p_i)_2² + (Fᵀ p_j)_1² + (Fᵀ p_j)_2²)

    compared here as ``(p_jᵀ F p_i)² <= max_distance² (...)``, without roots or divisions.

    Parameters
    ----------
    f : np.ndarray
        ``[3, 3]`` fundamental matrix of ideal pixels.
    pi, pj : np.ndarray
        ``[Ni, 2]`` and ``[Nj, 2]`` ideal pixels.
    max_distance : float
        Pixels.

    Returns
    -------
    np.ndarray
        ``bool [Ni, Nj]``.
    """
    hi = np.column_stack([pi, np.ones(len(pi))])
    hj = np.column_stack([pj, np.ones(len(pj))])
    li = hi @ f.T  # [Ni, 3] epipolar lines F p_i in view j
    lj = hj @ f  # [Nj, 3] lines Fᵀ p_j in view i
    num = li.astype(np.float32) @ hj.T.astype(np.float32)  # p_jᵀ F p_i
    t2 = np.float32(max_distance**2)
    den_i = ((li[:, 0] ** 2 + li[:, 1] ** 2) * t2).astype(np.float32)[:, None]
    den_j = ((lj[:, 0] ** 2 + lj[:, 1] ** 2) * t2).astype(np.float32)[None, :]
    num *= num
    num -= den_i
    return num <= den_j


def sampson_distance(f: np.ndarray, pi: np.ndarray, pj: np.ndarray) -> np.ndarray:
    """Sampson distance (pixels) of corresponding points ``pi[k] <-> pj[k]`` (``[N, 2]`` each) -> ``[N]``."""
    hi = np.column_stack([pi, np.ones(len(pi))])
    hj = np.column_stack([pj, np.ones(len(pj))])
    li = hi @ f.T
    lj = hj @ f
    num = np.einsum("nk,nk->n", hj, li)
    den = li[:, 0] ** 2 + li[:, 1] ** 2 + lj[:, 0] ** 2 + lj[:, 1] ** 2
    return np.abs(num) / np.sqrt(np.maximum(den, 1e-300))


def ideal_pixels(cameras: Cameras, i: int, uv: np.ndarray) -> np.ndarray:
    """Undistort stored pixel positions ``uv`` (``[N, 2]``, continuous) of view ``i`` to ideal pixels."""
    if not cameras.has_distortion or len(uv) == 0:
        return np.asarray(uv, np.float64).reshape(-1, 2)
    # normalized_coords takes integer-style pixel indices and adds the half pixel itself.
    x, y = cameras.normalized_coords(i, uv[:, 0] - 0.5, uv[:, 1] - 0.5)
    return np.column_stack([cameras.fx[i] * x + cameras.cx[i], cameras.fy[i] * y + cameras.cy[i]])


def ray_directions(r: np.ndarray, k: np.ndarray, views: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Unit world-space directions of the rays through ideal pixels ``p [N, 2]`` of ``views [N]``."""
    x = (p[:, 0] - k[views, 0, 2]) / k[views, 0, 0]
    y = (p[:, 1] - k[views, 1, 2]) / k[views, 1, 1]
    d_cam = np.column_stack([x, y, np.ones_like(x)])
    d = np.einsum("nji,nj->ni", r[views], d_cam)  # Rᵀ d_cam
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def project(r: np.ndarray, t: np.ndarray, k: np.ndarray, views: np.ndarray, x: np.ndarray):
    """Project world points ``x [N, 3]`` into ``views [N]``.

    Returns
    -------
    p : np.ndarray
        ``[N, 2]`` ideal pixels.
    z : np.ndarray
        ``[N]`` depth along each camera's optical axis (<= 0: behind the camera).
    xc : np.ndarray
        ``[N, 3]`` camera-frame coordinates.
    """
    xc = np.einsum("nij,nj->ni", r[views], x) + t[views]
    z = xc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        p = np.column_stack([k[views, 0, 0] * xc[:, 0] / z + k[views, 0, 2],
                             k[views, 1, 1] * xc[:, 1] / z + k[views, 1, 2]])
    return p, z, xc


def depth_sigma(cov: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Standard deviation of a point's depth along ``axis``: ``sqrt(axisᵀ Σ axis)``.

    Parameters
    ----------
    cov : np.ndarray
        ``[N, 3, 3]`` covariance of each point (world units²).
    axis : np.ndarray
        ``[N, 3]`` unit vectors: a camera's optical axis for z-depth, the ray direction for ray depth.
    """
    return np.sqrt(np.maximum(np.einsum("ni,nij,nj->n", axis, cov, axis), 0.0))
