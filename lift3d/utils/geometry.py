"""Small geometry helpers shared by the synthetic scenes, the plane fits, the export and the pictures."""

from __future__ import annotations

import numpy as np


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``[V, 3]`` unit area-weighted vertex normals of a consistently oriented mesh.

    Each face adds its cross product ``(v1 - v0) × (v2 - v0)`` (length twice its area, so larger faces weigh
    more) to its three corners. Vertices that no face uses, or whose normals cancel, get 0.

    Examples
    --------
    >>> v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]])
    >>> vertex_normals(v, np.array([[0, 1, 2]])).tolist()
    [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]
    """
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    face_normal = np.cross(b - a, c - a)
    n = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(n, faces[:, k], face_normal)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def plane_basis(n: np.ndarray) -> np.ndarray:
    """``[2, 3]`` orthonormal vectors spanning the plane with unit normal ``n`` (``n``, ``e1``, ``e2`` right-handed).

    Examples
    --------
    >>> plane_basis(np.array([0.0, 0.0, 1.0])).tolist()
    [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]
    """
    helper = np.eye(3)[int(np.argmin(np.abs(n)))]
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(n, e1)])
