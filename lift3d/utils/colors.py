"""The colour of an id: one formula for instance colours everywhere (render previews, plots, exports).

:func:`hash_colors` hashes the id itself (Fibonacci hashing onto the hue circle, three saturation and two
value levels cycling with the id), so an id has the same colour whatever other ids a picture shows.
"""

from __future__ import annotations

import numpy as np

#: 1/φ: Fibonacci hashing of the id onto the hue circle. Consecutive ids land far apart in hue.
GOLDEN = 0.6180339887498949


def hsv_to_rgb_u8(h: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectorised HSV (each in [0, 1]) → ``uint8 [..., 3]`` RGB, the arithmetic of :func:`colorsys.hsv_to_rgb`
    rounded to the nearest integer."""
    i = np.floor(h * 6.0)
    f = h * 6.0 - i
    i = i.astype(np.int64) % 6
    p, q, t = v * (1.0 - s), v * (1.0 - s * f), v * (1.0 - s * (1.0 - f))
    r = np.choose(i, [v, q, p, p, t, v])
    g = np.choose(i, [t, v, v, q, p, p])
    b = np.choose(i, [p, p, t, v, v, q])
    return np.clip(np.round(np.stack([r, g, b], -1) * 255.0), 0, 255).astype(np.uint8)


def hash_colors(ids, offset: int = 0) -> np.ndarray:
    """Saturated, bright colour of each integer id (≥ 0), ``uint8 [..., 3]``.

    Parameters
    ----------
    ids : array_like of int
        Any shape.
    offset : int
        Added to the ids first (a second, independent family of colours).

    Examples
    --------
    >>> hash_colors([1, 2, 1]).tolist()
    [[45, 106, 255], [112, 191, 0], [45, 106, 255]]
    """
    k = np.asarray(ids, np.int64) + offset
    hue = (k * GOLDEN) % 1.0
    sat = 0.65 + 0.35 * ((k * 7) % 3) / 2.0
    val = 0.75 + 0.25 * ((k * 5) % 2)
    return hsv_to_rgb_u8(hue, sat.astype(np.float64), val.astype(np.float64))
