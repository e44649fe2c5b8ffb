"""Cameras: intrinsics, poses and the one place where axis conventions are converted.

Conventions
-----------
* ``transforms.json`` stores camera-to-world matrices in **OpenGL** axes (x right, y up, looking down -z),
  as nerfstudio and instant-ngp do. :class:`Cameras` keeps them that way (``c2w``, shape ``[F, 4, 4]``).
* COLMAP, OpenCV and most robotics code use **OpenCV** axes (x right, y down, looking down +z).
  :func:`opengl_to_opencv` / :func:`opencv_to_opengl` convert camera-to-world matrices between the two;
  nothing else in lift3d flips axes.
* Pixel ``(u, v)`` has its centre at ``(u + 0.5, v + 0.5)`` in continuous image coordinates; a 3D point in
  OpenCV camera coordinates ``(x, y, z)`` lands at ``(fx x/z + cx, fy y/z + cy)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Flipping y and z turns OpenGL camera axes into OpenCV camera axes (and back: it is an involution).
_GL_CV_FLIP = np.diag([1.0, -1.0, -1.0, 1.0])

# cv2.undistortPoints stops after 5 fixed-point iterations by default, which left reprojection errors of
# 0.02 px (k1 = -0.3) to 0.08 px (k1 = 0.2) at the corners of a 160x120 image: rays() and project() did not
# invert each other.
# Iterate until the reprojection error is below 1e-8 px instead (about 20 iterations, still a few ms for
# a full image).
_UNDISTORT_CRITERIA = (3, 100, 1e-8)  # cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS; cv2 imported lazily

#: Camera models understood by :class:`Cameras` and the distortion parameters each one uses.
CAMERA_MODELS = {
    "PINHOLE": (),
    "OPENCV": ("k1", "k2", "p1", "p2", "k3"),
    "OPENCV_FISHEYE": ("k1", "k2", "k3", "k4"),
}


def opengl_to_opencv(c2w: np.ndarray) -> np.ndarray:
    """Convert camera-to-world matrices from OpenGL axes to OpenCV axes.

    Parameters
    ----------
    c2w : np.ndarray
        ``[..., 4, 4]`` (or ``[..., 3, 4]``) camera-to-world in OpenGL axes.

    Returns
    -------
    np.ndarray
        The same cameras with OpenCV axes (x right, y down, +z forward).

    Examples
    --------
    >>> import numpy as np
    >>> opengl_to_opencv(np.eye(4))[:3, :3].diagonal().tolist()
    [1.0, -1.0, -1.0]
    """
    c2w = np.asarray(c2w, dtype=np.float64)
    out = c2w.copy()
    out[..., :3, 1:3] *= -1.0
    return out


def opencv_to_opengl(c2w: np.ndarray) -> np.ndarray:
    """Convert camera-to-world matrices from OpenCV axes to OpenGL axes (inverse of
    :func:`opengl_to_opencv`, which is its own inverse)."""
    return opengl_to_opencv(c2w)


def is_rigid(c2w: np.ndarray, atol: float = 1e-3) -> bool:
    """True when the 3×3 block of a camera-to-world matrix is a rotation (orthonormal, det +1) and the last
    row is ``[0, 0, 0, 1]``."""
    c2w = np.asarray(c2w, dtype=np.float64)
    if c2w.shape != (4, 4) or not np.all(np.isfinite(c2w)):
        return False
    r = c2w[:3, :3]
    return (
        np.allclose(r @ r.T, np.eye(3), atol=atol)
        and abs(np.linalg.det(r) - 1.0) < atol
        and np.allclose(c2w[3], [0, 0, 0, 1], atol=atol)
    )


@dataclass
class Cameras:
    """Pinhole cameras (optionally with OpenCV distortion) for ``F`` frames.

    Attributes
    ----------
    c2w : np.ndarray
        ``[F, 4, 4]`` float64 camera-to-world, OpenGL axes (the ``transforms.json`` convention).
    fx, fy, cx, cy : np.ndarray
        ``[F]`` float64 focal lengths and principal points in pixels.
    width, height : np.ndarray
        ``[F]`` int64 image sizes in pixels.
    camera_model : str
        One of :data:`CAMERA_MODELS`.
    distortion : np.ndarray
        ``[F, 5]`` float64 ``k1 k2 p1 p2 k3`` for ``OPENCV``; ``k1 k2 k3 k4 0`` for ``OPENCV_FISHEYE``;
        zeros for ``PINHOLE``.
    """

    c2w: np.ndarray
    fx: np.ndarray
    fy: np.ndarray
    cx: np.ndarray
    cy: np.ndarray
    width: np.ndarray
    height: np.ndarray
    camera_model: str = "PINHOLE"
    distortion: np.ndarray = field(default=None)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        n = len(self.c2w)
        self.c2w = np.asarray(self.c2w, dtype=np.float64).reshape(n, 4, 4)
        for name in ("fx", "fy", "cx", "cy"):
            setattr(self, name, np.broadcast_to(np.asarray(getattr(self, name), np.float64), (n,)).copy())
        for name in ("width", "height"):
            setattr(self, name, np.broadcast_to(np.asarray(getattr(self, name), np.int64), (n,)).copy())
        if self.distortion is None:
            self.distortion = np.zeros((n, 5))
        self.distortion = np.broadcast_to(np.asarray(self.distortion, np.float64), (n, 5)).copy()
        if self.camera_model not in CAMERA_MODELS:
            raise ValueError(f"unknown camera model {self.camera_model!r}")

    def __len__(self) -> int:
        return len(self.c2w)

    def __getitem__(self, idx) -> "Cameras":
        idx = np.atleast_1d(np.arange(len(self))[idx])
        return Cameras(
            c2w=self.c2w[idx], fx=self.fx[idx], fy=self.fy[idx], cx=self.cx[idx], cy=self.cy[idx],
            width=self.width[idx], height=self.height[idx], camera_model=self.camera_model,
            distortion=self.distortion[idx],
        )

    @property
    def has_distortion(self) -> bool:
        return self.camera_model != "PINHOLE" and bool(np.any(self.distortion != 0))

    def K(self, i: int) -> np.ndarray:
        """3×3 intrinsic matrix of frame ``i`` (pixel centres at +0.5, see module docstring)."""
        return np.array([[self.fx[i], 0, self.cx[i]], [0, self.fy[i], self.cy[i]], [0, 0, 1.0]])

    @property
    def c2w_opencv(self) -> np.ndarray:
        """``[F, 4, 4]`` camera-to-world in OpenCV axes."""
        return opengl_to_opencv(self.c2w)

    @property
    def centers(self) -> np.ndarray:
        """``[F, 3]`` camera centres in world coordinates."""
        return self.c2w[:, :3, 3].copy()

    @property
    def forward(self) -> np.ndarray:
        """``[F, 3]`` unit viewing directions (OpenGL -z axis) in world coordinates."""
        return -self.c2w[:, :3, 2].copy()

    def normalized_coords(self, i: int, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Undistorted normalised image coordinates (OpenCV axes, z = 1) of pixel centres.

        Parameters
        ----------
        i : int
            Frame index.
        u, v : np.ndarray
            ``[N]`` integer (or continuous) pixel column and row; the pixel centre ``+0.5`` is used.

        Returns
        -------
        x, y : np.ndarray
            ``[N]`` normalised coordinates such that the ray direction is ``(x, y, 1)`` in OpenCV axes.
        """
        pu = np.asarray(u, np.float64) + 0.5
        pv = np.asarray(v, np.float64) + 0.5
        if not self.has_distortion:
            return (pu - self.cx[i]) / self.fx[i], (pv - self.cy[i]) / self.fy[i]
        import cv2  # only distorted cameras need OpenCV's iterative undistortion

        pts = np.stack([pu, pv], -1).reshape(-1, 1, 2)
        if self.camera_model == "OPENCV_FISHEYE":
            und = cv2.fisheye.undistortPoints(pts, self.K(i), self.distortion[i, :4], criteria=_UNDISTORT_CRITERIA)
        elif hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x: the plain call has no criteria argument
            und = cv2.undistortPointsIter(pts, self.K(i), self.distortion[i], None, None, _UNDISTORT_CRITERIA)
        else:  # OpenCV 5 folded undistortPointsIter into undistortPoints
            und = cv2.undistortPoints(pts, self.K(i), self.distortion[i], criteria=_UNDISTORT_CRITERIA)
        und = und.reshape(-1, 2)
        return und[:, 0], und[:, 1]

    def unproject(self, i: int, u: np.ndarray, v: np.ndarray, z: np.ndarray) -> np.ndarray:
        """World points of pixel centres ``(u, v)`` of frame ``i`` at z-depth ``z`` (along the optical axis).

        Returns
        -------
        np.ndarray
            ``[N, 3]`` float64.

        Examples
        --------
        >>> cams = Cameras(c2w=np.eye(4)[None], fx=2.0, fy=2.0, cx=2.0, cy=2.0, width=4, height=4)
        >>> cams.unproject(0, np.array([1.5]), np.array([1.5]), np.array([3.0])).tolist()  # the image centre
        [[0.0, 0.0, -3.0]]
        """
        x, y = self.normalized_coords(i, u, v)
        z = np.asarray(z, np.float64)
        c2w = self.c2w_opencv[i]
        return np.stack([x * z, y * z, z], -1) @ c2w[:3, :3].T + c2w[:3, 3]

    def rays(self, i: int, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World-space ray origins and unit directions through pixel centres of frame ``i``.

        Returns
        -------
        origins, directions : np.ndarray
            ``[N, 3]`` float64 each.
        """
        x, y = self.normalized_coords(i, u, v)
        d_cam = np.stack([x, y, np.ones_like(x)], -1)  # OpenCV camera axes
        c2w = self.c2w_opencv[i]
        d = d_cam @ c2w[:3, :3].T
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        o = np.broadcast_to(c2w[:3, 3], d.shape).copy()
        return o, d

    def project(self, i: int, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points into frame ``i`` (pinhole part; distortion applied when present).

        Returns
        -------
        uv : np.ndarray
            ``[N, 2]`` continuous pixel coordinates (pixel ``(c, r)`` covers ``[c, c+1) × [r, r+1)``).
        depth : np.ndarray
            ``[N]`` z-depth along the optical axis (negative or zero when behind the camera).
        """
        w2c = np.linalg.inv(self.c2w_opencv[i])
        p = np.asarray(points, np.float64) @ w2c[:3, :3].T + w2c[:3, 3]
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xn, yn = p[:, 0] / z, p[:, 1] / z
        if self.has_distortion:
            import cv2

            obj = np.stack([xn, yn, np.ones_like(xn)], -1).reshape(-1, 1, 3)
            obj = np.nan_to_num(obj)
            if self.camera_model == "OPENCV_FISHEYE":
                uv, _ = cv2.fisheye.projectPoints(obj, np.zeros(3), np.zeros(3), self.K(i), self.distortion[i, :4])
            else:
                uv, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), self.K(i), self.distortion[i])
            uv = uv.reshape(-1, 2)
        else:
            uv = np.stack([self.fx[i] * xn + self.cx[i], self.fy[i] * yn + self.cy[i]], -1)
        return uv, z


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera-to-world matrix (OpenGL axes) of a camera at ``eye`` looking at ``target``.

    Examples
    --------
    >>> import numpy as np
    >>> c2w = look_at(np.array([0., -2., 0.]), np.zeros(3))
    >>> np.round(-c2w[:3, 2], 6).tolist()  # the camera looks along +y
    [0.0, 1.0, 0.0]
    """
    eye = np.asarray(eye, np.float64)
    fwd = np.asarray(target, np.float64) - eye
    fwd /= np.linalg.norm(fwd)
    up = np.asarray(up, np.float64)
    right = np.cross(fwd, up)
    if np.linalg.norm(right) < 1e-8:  # looking straight along `up`: pick any perpendicular
        right = np.cross(fwd, np.array([1.0, 0.0, 0.0]) if abs(fwd[0]) < 0.9 else np.array([0.0, 1.0, 0.0]))
    right /= np.linalg.norm(right)
    true_up = np.cross(right, fwd)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, true_up, -fwd, eye
    return c2w
