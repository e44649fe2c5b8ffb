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


def level_up(c2w: np.ndarray) -> np.ndarray | None:
    """The world's up from camera-to-world poses ``[F, 4, 4]`` (OpenGL axes) as the direction most at right angles
    to the cameras' right axes (level for a camera that does not roll, whatever its pitch), turned to the side of
    their image-up axes; None when the right axes do not turn enough for that to be defined (every camera facing
    one way).

    Examples
    --------
    >>> from lift3d.data.cameras import look_at
    >>> eyes = [[3 * np.cos(a), 3 * np.sin(a), 1.5] for a in np.linspace(0, 2, 8)]
    >>> c2w = np.stack([look_at(np.array(e), np.array([0.0, 0.0, 0.0])) for e in eyes])  # looking down 27 deg
    >>> np.round(level_up(c2w), 3).tolist()
    [0.0, 0.0, 1.0]
    >>> level_up(c2w[:1]) is None
    True
    """
    c2w = np.asarray(c2w, np.float64)
    right = c2w[:, :3, 0]
    values, vectors = np.linalg.eigh(right.T @ right / len(right))
    if not (values[1] > 10 * max(values[0], 1e-12) and values[1] > 0.02):  # the right axes do not span a plane
        return None
    up = vectors[:, 0]
    return up if up @ c2w[:, :3, 1].mean(0) >= 0 else -up
