"""Descriptor matching between two views with the epipolar geometry of the known poses.

Distances are computed as one matrix per pair (``[Ni, Nj]``, in row chunks): for RootSIFT the squared L2
distance of unit vectors ``2 - 2 a·b``, for ORB the Hamming distance. Two modes:

* **plain**: Lowe's ratio test over all candidates, then the Sampson distance to the epipolar geometry of
  the known poses must be below ``max_epipolar_error`` pixels;
* **guided** (default): candidates farther than ``max_epipolar_error`` from the epipolar geometry are
  removed first, and the ratio test runs among the rest. Known poses turn a global search into a search
  along a line, so repeated or weak texture elsewhere in the image no longer fails the ratio test.

With ``mutual`` each keypoint must also be the other's best (allowed) candidate, and no match may be farther
than ``max_distance`` in descriptor space.
"""

from __future__ import annotations

import numpy as np

from lift3d.sfm.config import MatchConfig
from lift3d.sfm.geometry import epipolar_mask, sampson_distance

_CHUNK = 2048  # rows of the distance matrix at a time (2048 x 4000 float32 = 33 MB)


def descriptor_distances(di: np.ndarray, dj: np.ndarray) -> np.ndarray:
    """``float32 [Ni, Nj]``: squared L2 of unit float descriptors, or Hamming distance of ``uint8`` ones."""
    if di.dtype == np.uint8:
        bi = np.unpackbits(di, axis=1).astype(np.float32)
        bj = np.unpackbits(dj, axis=1).astype(np.float32)
        return bi.sum(1)[:, None] + bj.sum(1)[None, :] - 2.0 * (bi @ bj.T)
    return np.maximum(2.0 - 2.0 * (di @ dj.T), 0.0)


def _ratio_ok(best: np.ndarray, second: np.ndarray, ratio: float, hamming: bool) -> np.ndarray:
    # Lowe's test compares distances; the L2 matrix holds squared distances.
    if hamming:
        return best < ratio * second
    return best < (ratio * ratio) * second


def match_pair(di: np.ndarray, dj: np.ndarray, pi: np.ndarray, pj: np.ndarray, f: np.ndarray,
               config: MatchConfig) -> np.ndarray:
    """Match the keypoints of two views.

    Parameters
    ----------
    di, dj : np.ndarray
        Descriptors ``[Ni, D]``, ``[Nj, D]`` (float RootSIFT or uint8 ORB).
    pi, pj : np.ndarray
        ``[Ni, 2]``, ``[Nj, 2]`` ideal pixels (undistorted).
    f : np.ndarray
        ``[3, 3]`` fundamental matrix with ``p_jᵀ F p_i = 0``.
    config : MatchConfig

    Returns
    -------
    matches : np.ndarray
        ``int64 [M, 2]`` keypoint index pairs ``(index in i, index in j)``.
    ratio : np.ndarray
        ``float32 [M]`` best / second-best descriptor distance (0 when there was no second candidate):
        lower is a more distinctive match.

    Examples
    --------
    A keypoint whose descriptor is repeated elsewhere in the other view fails the plain ratio test but is
    matched by guided matching, which only looks along the epipolar line:

    >>> import numpy as np
    >>> f = np.array([[0.0, 0, 0], [0, 0, -1], [0, 1, 0]])   # pure x-translation: same image row
    >>> d = np.eye(4, dtype=np.float32)                       # unit descriptors at distance sqrt(2)
    >>> di = d[:2]; dj = np.stack([d[0], d[0], d[1]])         # j has the first descriptor twice
    >>> pi = np.array([[10.0, 10], [20, 30]]); pj = np.array([[5.0, 10], [5, 50], [15, 30]])
    >>> match_pair(di, dj, pi, pj, f, MatchConfig(guided=True))[0].tolist()
    [[0, 0], [1, 2]]
    >>> match_pair(di, dj, pi, pj, f, MatchConfig(guided=False))[0].tolist()
    [[1, 2]]
    >>> match_pair(di, dj[::-1], pi, pj[::-1], f, MatchConfig(guided=True))[0].tolist()  # reordered: same
    [[0, 2], [1, 0]]
    """
    ni, nj = len(di), len(dj)
    if ni == 0 or nj < 1:
        return np.zeros((0, 2), np.int64), np.zeros(0, np.float32)
    hamming = di.dtype == np.uint8
    # On the matrix's own scale: squared L2 of unit vectors, or Hamming bits (config is on a [0, 2] scale).
    max_d = config.max_distance * di.shape[1] * 8 / 2 if hamming else config.max_distance**2
    best_j = np.full(ni, -1, np.int64)
    ok_i = np.zeros(ni, bool)
    ratio = np.zeros(ni, np.float32)
    # Column-wise best (for the mutual check) accumulated across row chunks.
    col_best = np.full(nj, np.inf, np.float32)
    col_arg = np.full(nj, -1, np.int64)
    for a in range(0, ni, _CHUNK):
        b = min(a + _CHUNK, ni)
        dist = descriptor_distances(di[a:b], dj).astype(np.float32)
        if config.guided:
            dist[~epipolar_mask(f, pi[a:b], pj, config.max_epipolar_error)] = np.inf
        rows = np.arange(b - a)
        first = dist.argmin(1)
        best = dist[rows, first]
        # Column-wise best (mutual check) before the row minima are masked for the second best.
        cb = dist.argmin(0)
        cv = dist[cb, np.arange(nj)]
        better = cv < col_best
        col_best[better] = cv[better]
        col_arg[better] = cb[better] + a
        dist[rows, first] = np.inf
        second = dist.min(1) if nj >= 2 else np.full(b - a, np.inf, np.float32)
        best_j[a:b] = first
        ok_i[a:b] = np.isfinite(best) & _ratio_ok(best, second, config.ratio, hamming) & (best <= max_d)
        with np.errstate(divide="ignore", invalid="ignore"):
            q = best / second if hamming else np.sqrt(best / second)
        ratio[a:b] = np.where(np.isfinite(second) & (second > 0), q, 0.0)
    idx_i = np.flatnonzero(ok_i)
    idx_j = best_j[idx_i]
    if config.mutual:
        keep = col_arg[idx_j] == idx_i
        idx_i, idx_j = idx_i[keep], idx_j[keep]
    if not config.guided and len(idx_i):
        keep = sampson_distance(f, pi[idx_i], pj[idx_j]) <= config.max_epipolar_error
        idx_i, idx_j = idx_i[keep], idx_j[keep]
    return np.column_stack([idx_i, idx_j]).astype(np.int64), ratio[idx_i]
