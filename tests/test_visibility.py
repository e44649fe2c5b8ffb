"""Which training camera sees a surface point (lift3d.export.visibility.CameraVisibility)."""

import math

import numpy as np

from lift3d.data.cameras import Cameras, look_at
from lift3d.export.visibility import CameraVisibility

VOXEL = 0.05


def camera(eye, target):
    return Cameras(c2w=look_at(np.asarray(eye, float), np.asarray(target, float))[None],
                   fx=np.array([64.0]), fy=np.array([64.0]), cx=np.array([64.0]), cy=np.array([64.0]),
                   width=np.array([128]), height=np.array([128]))


def floor(half: float = 2.0, step: float = VOXEL):
    """A flat floor at z = 0, triangulated on a grid of one-voxel cells (as an isosurface is)."""
    n = int(round(2 * half / step)) + 1
    x = np.linspace(-half, half, n)
    gx, gy = np.meshgrid(x, x, indexing="ij")
    vertices = np.stack([gx, gy, np.zeros_like(gx)], -1).reshape(-1, 3)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])  # counter-clockwise from above
    return vertices, faces


def wall(y: float, height: float, half: float = 2.0):
    """A vertical wall across the floor at ``y``, two triangles."""
    v = np.array([[-half, y, 0.0], [half, y, 0.0], [half, y, height], [-half, y, height]])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def seen(vertices, faces, eye, point):
    vis = CameraVisibility(camera(eye, point), np.array([0]), vertices, faces, near=0.01, tolerance=VOXEL)
    return bool(vis.first_seen_by(np.array([point]), np.array([[0.0, 0.0, 1.0]]))[0] == 0)


POINT = [0.0, 0.45, 0.0]


def test_a_wall_between_camera_and_point_hides_it():
    floor_v, floor_f = floor()
    wall_v, wall_f = wall(y=0.2, height=0.5)  # 25 cm in front of the point, 50 cm high
    vertices = np.concatenate([floor_v, wall_v])
    faces = np.concatenate([floor_f, wall_f + len(floor_v)])
    e = math.radians(20.0)
    eye = [0.0, POINT[1] - 3.0 * math.cos(e), 3.0 * math.sin(e)]
    assert not seen(vertices, faces, eye, POINT)
    # ... and the same wall behind the point does not.
    wall_v, wall_f = wall(y=0.8, height=0.5)
    vertices = np.concatenate([floor_v, wall_v])
    assert seen(vertices, faces, eye, POINT)


def test_the_points_own_surface_does_not_hide_it_but_a_lid_does():
    # Looking straight down at a flat floor: seen (the floor itself is within the one-voxel tolerance).
    vertices, faces = floor()
    assert seen(vertices, faces, [0.0, 0.5, 2.0], [0.0, 0.5, 0.0])
    # A lid 3 voxels above the point hides it.
    lid_v = np.array([[-0.5, 0.0, 0.15], [0.5, 0.0, 0.15], [0.5, 1.0, 0.15], [-0.5, 1.0, 0.15]])
    vertices2 = np.concatenate([vertices, lid_v])
    faces2 = np.concatenate([faces, np.array([[0, 1, 2], [0, 2, 3]]) + len(vertices)])
    assert not seen(vertices2, faces2, [0.0, 0.5, 2.0], [0.0, 0.5, 0.0])
