"""Plane geometry of ``lift3d synth``'s rooms: floor outlines, footprints and boxes.

Outlines are ``[K, 2]`` corners of a simple polygon, counter-clockwise (the interior on the left of each
edge); footprints are convex polygons, the convex hull of an object's vertices seen from above.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull


def polygon_area(poly: np.ndarray) -> float:
    """Area of a simple polygon ``[K, 2]`` (shoelace formula)."""
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def signed_area(poly: np.ndarray) -> float:
    """Signed area of ``poly`` ``[K, 2]``: positive when its corners run counter-clockwise."""
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def inside_polygon(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """``[N]`` bool: which of ``points`` ``[N, 2]`` lie inside ``poly`` ``[K, 2]`` (even-odd rule)."""
    pts = np.atleast_2d(points)
    inside = np.zeros(len(pts), bool)
    for (xa, ya), (xb, yb) in zip(poly, np.roll(poly, -1, axis=0)):
        crosses = (ya > pts[:, 1]) != (yb > pts[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            x_at = xa + (pts[:, 1] - ya) * (xb - xa) / (yb - ya)
        inside ^= crosses & (pts[:, 0] < x_at)
    return inside


def distance_to_segments(points: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """``[N]`` distance from ``points`` ``[N, 2]`` to the nearest of the segments ``starts[k] -> ends[k]``."""
    pts = np.atleast_2d(points)
    best = np.full(len(pts), np.inf)
    for a, b in zip(np.atleast_2d(starts), np.atleast_2d(ends)):
        ab = b - a
        t = np.clip(((pts - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(pts - (a + t[:, None] * ab), axis=1))
    return best


def distance_to_outline(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """``[N]`` distance from ``points`` ``[N, 2]`` to the nearest edge of ``poly``."""
    return distance_to_segments(points, poly, np.roll(poly, -1, axis=0))


def interior_angles(poly: np.ndarray) -> np.ndarray:
    """``[K]`` interior angle (degrees) at each corner of a counter-clockwise ``poly``; above 180 at a reflex
    corner."""
    prev = poly - np.roll(poly, 1, axis=0)
    nxt = np.roll(poly, -1, axis=0) - poly
    turn = np.arctan2(prev[:, 0] * nxt[:, 1] - prev[:, 1] * nxt[:, 0], np.einsum("ij,ij->i", prev, nxt))
    return 180.0 - np.degrees(turn)


def polygon_triangles(poly: np.ndarray) -> np.ndarray:
    """``[K - 2, 3]`` corner indices triangulating the simple counter-clockwise polygon ``poly`` (ear clipping:
    deterministic, fine for the few dozen corners of a room)."""
    idx = list(range(len(poly)))
    tris = []

    def cross(o, a, b) -> float:
        return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))

    guard = 0
    while len(idx) > 3 and guard < 10 * len(poly) ** 2:
        guard += 1
        n = len(idx)
        for k in range(n):
            i0, i1, i2 = idx[(k - 1) % n], idx[k], idx[(k + 1) % n]
            a, b, c = poly[i0], poly[i1], poly[i2]
            if cross(a, b, c) <= 1e-12:
                continue  # reflex or flat: not an ear
            others = [poly[j] for j in idx if j not in (i0, i1, i2)]
            if any(cross(a, b, p) >= -1e-12 and cross(b, c, p) >= -1e-12 and cross(c, a, p) >= -1e-12
                   for p in others):
                continue
            tris.append((i0, i1, i2))
            idx.pop(k)
            break
        else:
            raise ValueError("polygon_triangles: not a simple counter-clockwise polygon")
    tris.append(tuple(idx))
    return np.asarray(tris, np.int64)


def convex_hull(points: np.ndarray) -> np.ndarray:
    """``[H, 2]`` corners of the convex hull of ``points`` ``[N, 2]``, counter-clockwise."""
    pts = np.asarray(points, np.float64)
    return pts[ConvexHull(pts).vertices]  # scipy lists a 2-D hull's corners counter-clockwise


def _separated(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether an edge normal of ``a`` or ``b`` (convex, counter-clockwise) separates them."""
    for poly in (a, b):
        edges = np.roll(poly, -1, axis=0) - poly
        normals = np.column_stack([edges[:, 1], -edges[:, 0]])  # outward for a counter-clockwise polygon
        pa, pb = a @ normals.T, b @ normals.T
        if np.any((pa.max(0) < pb.min(0)) | (pb.max(0) < pa.min(0))):
            return True
    return False


def convex_gap(a: np.ndarray, b: np.ndarray) -> float:
    """Distance between two convex polygons ``[Ka, 2]`` and ``[Kb, 2]`` (counter-clockwise); 0 when they
    overlap or touch."""
    if not _separated(a, b):
        return 0.0
    d1 = distance_to_outline(a, b).min()
    d2 = distance_to_outline(b, a).min()
    return float(min(d1, d2))


def upright_box(vertices: np.ndarray) -> dict:
    """The smallest-area box around ``vertices`` ``[N, 3]`` that stands upright (z up, turned about z): its
    ``centre``, ``yaw`` (radians, of its ``extent[0]`` axis) and ``extent`` ``(length, width, height)`` with
    length >= width.

    The box of a thing built axis-aligned and turned about z by the generator is its own oriented box; the
    rotating-calipers search over the footprint's hull edges finds it for any mesh.

    Examples
    --------
    >>> sq = np.array([[0, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0], [0, 0, 3.0]])
    >>> b = upright_box(sq @ np.array([[0.6, 0.8, 0], [-0.8, 0.6, 0], [0, 0, 1.0]]))
    >>> np.round(b["extent"], 6).tolist()
    [2.0, 1.0, 3.0]
    """
    v = np.asarray(vertices, np.float64)
    hull = convex_hull(v[:, :2])
    best = None
    for a, b in zip(hull, np.roll(hull, -1, axis=0)):
        e = b - a
        n = np.linalg.norm(e)
        if n < 1e-12:
            continue
        u = e / n
        w = np.array([-u[1], u[0]])
        pu, pw = hull @ u, hull @ w
        area = np.ptp(pu) * np.ptp(pw)
        if best is None or area < best[0] - 1e-12:
            best = (area, u, w, pu, pw)
    _, u, w, pu, pw = best
    lu, lw = float(np.ptp(pu)), float(np.ptp(pw))
    if lw > lu:
        u, w, pu, pw, lu, lw = w, -u, pw, -pu, lw, lu
    mid = u * (pu.min() + pu.max()) / 2 + w * (pw.min() + pw.max()) / 2
    z0, z1 = float(v[:, 2].min()), float(v[:, 2].max())
    yaw = float(np.arctan2(u[1], u[0]) % np.pi)
    return {"centre": np.array([mid[0], mid[1], (z0 + z1) / 2]), "yaw": yaw, "extent": np.array([lu, lw, z1 - z0])}


def yawed_box(vertices: np.ndarray, yaw: float) -> dict:
    """The upright box around ``vertices`` ``[N, 3]`` turned by ``yaw`` (radians) about z, as
    :func:`upright_box` gives it: ``centre``, ``yaw`` of its longer side, ``extent`` (length >= width,
    height)."""
    v = np.asarray(vertices, np.float64)
    u = np.array([np.cos(yaw), np.sin(yaw)])
    w = np.array([-u[1], u[0]])
    pu, pw = v[:, :2] @ u, v[:, :2] @ w
    lu, lw = float(np.ptp(pu)), float(np.ptp(pw))
    mid = u * (pu.min() + pu.max()) / 2 + w * (pw.min() + pw.max()) / 2
    if lw > lu:
        u, lu, lw = w, lw, lu
    z0, z1 = float(v[:, 2].min()), float(v[:, 2].max())
    return {"centre": np.array([mid[0], mid[1], (z0 + z1) / 2]), "yaw": float(np.arctan2(u[1], u[0]) % np.pi),
            "extent": np.array([lu, lw, z1 - z0])}
