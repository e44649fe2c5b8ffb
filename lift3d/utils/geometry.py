"""Small triangle-mesh helpers shared by the synthetic scenes and the export."""

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
