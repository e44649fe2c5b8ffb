"""``--downscale N``: every output pixel is one N×N block of input pixels, for every kind of map.

lift3d puts pixel ``(c, r)``'s centre at ``(c + 0.5, r + 0.5)``, so output pixel ``(j, i)`` covers input
pixels ``[jN, jN + N) × [iN, iN + N)`` and its centre is the block's centre. A map stays on the image's pixel
centres only when it is reduced over the same block as the image:

* colour and confidence: the block mean (OpenCV's area filter, exact for whole blocks);
* label maps (panoptic segment ids, masks): the most frequent value of the block, so ids stay exact; a tie
  goes to the smallest value (0 = void / ignored, when it is among the tied ones);
* depth: the median of the block's valid (non-zero) depths, 0 where the block has none, so holes do not pull
  depth towards the camera and a depth edge is not smeared into a surface that is in neither object.

Sampling one pixel per block instead (nearest neighbour, OpenCV's ``INTER_NEAREST`` takes the block's top-left
pixel) puts labels and depth 0.5 − 0.5/N output pixels up and left of the image: 0.375 px for N = 4.

Sizes that are not a multiple of N lose their last ``w mod N`` columns and ``h mod N`` rows, so that every
output pixel is a whole block. Cropping at the right and bottom leaves the principal point where it is:
every intrinsic (``fx, fy, cx, cy``) is divided by N exactly.
"""

from __future__ import annotations

import warnings

import cv2
import numpy as np
from scipy import stats


def blocks_shape(w: int, h: int, n: int) -> tuple[int, int]:
    """``(w // n, h // n)``: the output size of a ``w × h`` map downscaled by ``n``.

    Examples
    --------
    >>> blocks_shape(1297, 968, 2)
    (648, 484)
    """
    return w // n, h // n


def _crop(arr: np.ndarray, n: int) -> np.ndarray:
    nw, nh = blocks_shape(arr.shape[1], arr.shape[0], n)
    return arr[: nh * n, : nw * n]


def _blocks(arr: np.ndarray, n: int) -> np.ndarray:
    """``[H, W]`` → ``[H // n, W // n, n * n]``: the values of each output pixel's block."""
    a = _crop(arr, n)
    nh, nw = a.shape[0] // n, a.shape[1] // n
    return a.reshape(nh, n, nw, n).swapaxes(1, 2).reshape(nh, nw, n * n)


def block_mean(arr: np.ndarray, n: int) -> np.ndarray:
    """Mean of every ``n × n`` block (colour ``[H, W, C]`` or a float map ``[H, W]``), in ``arr``'s dtype.

    Examples
    --------
    >>> block_mean(np.arange(16, dtype=np.float32).reshape(4, 4), 2).tolist()
    [[2.5, 4.5], [10.5, 12.5]]
    """
    a = _crop(arr, n)
    return cv2.resize(a, blocks_shape(arr.shape[1], arr.shape[0], n), interpolation=cv2.INTER_AREA)


def block_majority(labels: np.ndarray, n: int) -> np.ndarray:
    """Most frequent value of every ``n × n`` block of an integer or boolean map; ties go to the smallest.

    Examples
    --------
    >>> ids = np.array([[7, 7, 5, 0],
    ...                 [7, 5, 5, 0]])
    >>> block_majority(ids, 2).tolist()  # left block: three 7s; right block: two 0s and two 5s
    [[7, 0]]
    """
    modes = stats.mode(_blocks(labels, n), axis=-1, keepdims=False).mode
    return np.asarray(modes, dtype=labels.dtype)


def block_median_depth(depth: np.ndarray, n: int) -> np.ndarray:
    """Median of the valid (> 0, finite) depths of every ``n × n`` block; 0 where a block has none.

    Examples
    --------
    >>> d = np.array([[1.0, 0.0, 0.0, 0.0],
    ...               [3.0, 0.0, 0.0, 0.0]], np.float32)
    >>> block_median_depth(d, 2).tolist()
    [[2.0, 0.0]]
    """
    b = _blocks(depth, n).astype(np.float32)
    b = np.where(np.isfinite(b) & (b > 0), b, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # "All-NaN slice": a block without depth, 0 below
        med = np.nanmedian(b, axis=-1)
    return np.nan_to_num(med, nan=0.0).astype(np.float32)
