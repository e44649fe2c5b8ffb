"""Which training camera sees a point: the training frames, the cameras in normalised coordinates, the
direction a camera sees a point along, and the occlusion test.

:class:`CameraVisibility` decides which training camera sees a point of the isosurface: the
point projects inside that camera's image, lies beyond its near plane, and the segment from the camera
centre to the point crosses no part of the isosurface (one exact Embree occlusion ray per point and
camera, via Open3D's ``RaycastingScene``; occluders within one grid voxel of the point are its own
surface; a camera behind the surface at the point is skipped without a ray). Because ``τ`` was fitted to
the rendered median depth, this is the test "in front of the rendered depth of that camera", without
rendering every training view and without the pixel-size tolerance a depth map would need (which would let
the underside of a thin table top through).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from lift3d.data.scene import Scene
from lift3d.model.run import LoadedRun


def train_frames(scene: Scene) -> np.ndarray:
    """Training frame indices (every frame when the scene has no train split)."""
    frames = np.asarray(scene.split("train"), np.int64)
    return frames if len(frames) else np.arange(len(scene))


# ------------------------------------------------------------------------------------------ visibility
class CameraVisibility:
    """Which training camera sees a point (see the module docstring).

    Parameters
    ----------
    cameras : lift3d.data.cameras.Cameras
        Cameras with poses in *normalised* coordinates.
    frames : np.ndarray
        Indices of the cameras to use, in the order they are tried.
    vertices, faces : np.ndarray
        The occluding surface (normalised coordinates).
    near : float
        Near plane (normalised units).
    tolerance : float
        Occluders closer than this to the point itself are ignored (the point's own surface), normalised
        units; about one grid voxel.
    """

    def __init__(self, cameras, frames, vertices: np.ndarray, faces: np.ndarray, *, near: float, tolerance: float):
        import open3d as o3d

        self.cameras, self.frames = cameras, np.asarray(frames, np.int64)
        self.near, self.tolerance = float(near), float(tolerance)
        self.centers = cameras.centers
        self.scene = o3d.t.geometry.RaycastingScene()
        self.empty = len(faces) == 0
        if not self.empty:
            self.scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(vertices, np.float32)),
                                     o3d.core.Tensor(np.ascontiguousarray(faces, np.uint32)))

    def unoccluded(self, origin: np.ndarray, points: np.ndarray) -> np.ndarray:
        """``[N]`` bool: nothing of the surface lies between ``origin`` and each point (minus the tolerance).

        One Embree occlusion query per point: the ray direction is the segment to the point shortened by the
        tolerance, so ``tfar = 1`` ends the search just before the point.
        """
        import open3d as o3d

        if self.empty or len(points) == 0:
            return np.ones(len(points), bool)
        seg = np.asarray(points, np.float32) - np.asarray(origin, np.float32)
        dist = np.sqrt(np.einsum("ij,ij->i", seg, seg))[:, None]
        seg *= np.clip(dist - self.tolerance, 0.0, None) / np.maximum(dist, 1e-12)
        rays = np.empty((len(seg), 6), np.float32)
        rays[:, :3] = origin
        rays[:, 3:] = seg
        return ~self.scene.test_occlusions(o3d.core.Tensor(rays), tnear=0.0, tfar=1.0).numpy().astype(bool)

    def first_seen_by(self, points: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
        """Index of the first camera (in ``frames`` order) that sees each point, or -1.

        Cameras are tried one after the other on the points no camera has claimed yet, so most points cost
        one or two projections and occlusion rays.

        Parameters
        ----------
        points : np.ndarray
            ``[N, 3]`` points on the surface (normalised coordinates).
        normals : np.ndarray, optional
            ``[N, 3]`` outward surface normals (towards lower density). A camera behind the surface at a
            point cannot see it (its ray would have entered the solid earlier), so such pairs skip the
            occlusion ray.
        """
        # The unclaimed points are kept compacted (float32 copies shrink as cameras claim points), so each
        # camera costs time proportional to what is left.
        seen_by = np.full(len(points), -1, np.int64)
        todo = np.arange(len(points))
        p = np.asarray(points, np.float32)
        n = None if normals is None else np.asarray(normals, np.float32)
        for i in self.frames:
            if len(todo) == 0:
                break
            i = int(i)
            in_view = self._in_view(i, p)
            if n is not None:
                in_view &= np.einsum("ij,ij->i", n, self.centers[i].astype(np.float32) - p) >= 0
            cand = np.flatnonzero(in_view)
            ok = cand[self.unoccluded(self.centers[i], p[cand])]
            if len(ok) == 0:
                continue
            seen_by[todo[ok]] = i
            rest = np.ones(len(todo), bool)
            rest[ok] = False
            todo, p = todo[rest], p[rest]
            if n is not None:
                n = n[rest]
        return seen_by

    def _in_view(self, i: int, p: np.ndarray) -> np.ndarray:
        """``[N]`` bool: inside camera ``i``'s image and beyond its near plane."""
        cams = self.cameras
        if cams.has_distortion:
            uv, z = cams.project(i, p)
        else:  # pinhole: the same projection, without a matrix inverse and a copy per call
            c2w = cams.c2w_opencv[i].astype(p.dtype)
            pc = (p - c2w[:3, 3]) @ c2w[:3, :3]
            z = pc[:, 2]
            with np.errstate(divide="ignore", invalid="ignore"):
                uv = np.stack([cams.fx[i] * pc[:, 0] / z + cams.cx[i], cams.fy[i] * pc[:, 1] / z + cams.cy[i]], -1)
        w, h = float(cams.width[i]), float(cams.height[i])
        with np.errstate(invalid="ignore"):
            return (z > self.near) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)


def normalized_cameras(loaded: LoadedRun, scene: Scene):
    """The scene's cameras with poses expressed in the run's normalised coordinates."""
    return replace(scene.cameras, c2w=loaded.norm.c2w_normalized(scene.cameras.c2w))


def view_directions(points: np.ndarray, camera_centers: np.ndarray) -> np.ndarray:
    """Unit directions from camera centres to points (``[N, 3]`` each) as float32."""
    d = np.asarray(points, np.float64) - camera_centers
    return (d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)).astype(np.float32)
