"""COLMAP sparse models (text or binary) into a scene folder.

COLMAP's conventions (its "Output Format" documentation):

* ``images.txt|bin`` hold, per registered image, the **world-to-camera** pose as a unit quaternion
  ``QW QX QY QZ`` (Hamilton, w first) and a translation ``TX TY TZ``; the camera centre is ``-Rᵀ t``.
* Camera axes are **OpenCV** axes: x right, y down, z forward.
* Pixel coordinates put the centre of the top-left pixel at ``(0.5, 0.5)``, as lift3d does, so ``cx, cy``
  are used unchanged.
* Binary files are little endian: ``cameras.bin`` = ``uint64 n`` then per camera ``uint32 id, int32 model,
  uint64 width, uint64 height, float64 params[]``; ``images.bin`` = ``uint64 n`` then per image ``uint32 id,
  float64 qw qx qy qz tx ty tz, uint32 camera_id, NUL-terminated name, uint64 n_points2D`` and
  ``n_points2D × (float64 x, float64 y, int64 point3D_id)``; ``points3D.bin`` = ``uint64 n`` then per point
  ``uint64 id, float64 x y z, uint8 r g b, float64 error, uint64 track_length`` and
  ``track_length × (uint32 image_id, uint32 point2D_idx)``.

The reader here is written from that description with :mod:`struct`; no COLMAP install is needed. Newer
COLMAP versions add ``rigs``/``frames`` files, but keep writing each image's composed camera pose into
``images``, so those files are not needed either.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from lift3d.convert import FrameInput, WriteOptions, every_nth, note, split_every, write_scene
from lift3d.convert.predictions import PredictionFolder
from lift3d.data.scene import Category, Scene, load_scene
from lift3d.data.stereo import SparsePoints, write_sparse_points
from lift3d.errors import InputError
from lift3d.sfm.config import TrackConfig
from lift3d.sfm.geometry import ideal_pixels, intrinsics, project, world_to_camera
from lift3d.sfm.triangulation import observation_depths

#: COLMAP camera model id → (name, number of parameters), from COLMAP's camera model list.
COLMAP_CAMERA_MODELS: dict[int, tuple[str, int]] = {
    0: ("SIMPLE_PINHOLE", 3),
    1: ("PINHOLE", 4),
    2: ("SIMPLE_RADIAL", 4),
    3: ("RADIAL", 5),
    4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8),
    6: ("FULL_OPENCV", 12),
    7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5),
    10: ("THIN_PRISM_FISHEYE", 12),
}
_MODEL_BY_NAME = {name: (mid, n) for mid, (name, n) in COLMAP_CAMERA_MODELS.items()}

# Where `SRC` may keep its model: the folder itself, COLMAP's workspace layout, nerfstudio's layout.
_MODEL_SUBDIRS = (".", "sparse/0", "sparse", "colmap/sparse/0")


@dataclass
class ColmapCamera:
    """One entry of ``cameras.txt|bin``."""

    id: int
    model: str
    width: int
    height: int
    params: np.ndarray


@dataclass
class ColmapImage:
    """One registered image of ``images.txt|bin``: world-to-camera quaternion (w first) and translation,
    and its keypoints (``xys [n, 2]`` in COLMAP pixels, ``point3d_ids [n]``, -1 = not triangulated)."""

    id: int
    qvec: np.ndarray
    tvec: np.ndarray
    camera_id: int
    name: str
    xys: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    point3d_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))


@dataclass
class ColmapPoints:
    """``points3D.txt|bin``: ``P`` points and their tracks, flattened (``track_*[offsets[k]:offsets[k+1]]``
    belong to point ``k``)."""

    ids: np.ndarray  # [P] int64 POINT3D_ID
    xyz: np.ndarray  # [P, 3] float64
    rgb: np.ndarray  # [P, 3] uint8
    error: np.ndarray  # [P] float64, mean reprojection error (pixels)
    track_image: np.ndarray  # [T] int64 IMAGE_ID
    track_point2d: np.ndarray  # [T] int64 POINT2D_IDX (index into that image's keypoints)
    offsets: np.ndarray  # [P + 1] int64


@dataclass
class ColmapModel:
    """A sparse model: cameras by id, images by id, and (lazily) the 3D points."""

    path: Path
    format: str  # "bin" or "txt"
    cameras: dict[int, ColmapCamera]
    images: dict[int, ColmapImage]

    @property
    def points_file(self) -> Path:
        return self.path / f"points3D.{self.format}"

    def points(self) -> ColmapPoints | None:
        """The 3D points with their tracks, or None when the model has no ``points3D`` file."""
        p = self.points_file
        if not p.is_file():
            return None
        return read_points3d_binary(p) if self.format == "bin" else read_points3d_text(p)

    def points_xyz(self) -> np.ndarray | None:
        """``[N, 3]`` float64 sparse points, or None when the model has no ``points3D`` file."""
        pts = self.points()
        return None if pts is None else pts.xyz

    @property
    def images_file(self) -> Path:
        return self.path / f"images.{self.format}"


# ----------------------------------------------------------------------------------------------- geometry
def qvec_to_rotmat(qvec: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion ``(w, x, y, z)`` (Hamilton convention, as COLMAP and Eigen).

    Examples
    --------
    >>> import numpy as np
    >>> R = qvec_to_rotmat(np.array([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)]))  # 90° about z
    >>> np.round(R @ [1.0, 0.0, 0.0], 6).tolist()
    [0.0, 1.0, 0.0]
    """
    w, x, y, z = np.asarray(qvec, np.float64) / np.linalg.norm(qvec)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def image_c2w_opencv(image: ColmapImage) -> np.ndarray:
    """Camera-to-world (OpenCV axes) of a COLMAP image: the inverse of its world-to-camera pose."""
    r = qvec_to_rotmat(image.qvec)
    c2w = np.eye(4)
    c2w[:3, :3] = r.T
    c2w[:3, 3] = -r.T @ np.asarray(image.tvec, np.float64)
    return c2w


def camera_to_lift3d(cam: ColmapCamera, where: Path) -> tuple[str, tuple[float, float, float, float], dict]:
    """A COLMAP camera as lift3d intrinsics.

    Returns
    -------
    model : str
        ``PINHOLE``, ``OPENCV`` or ``OPENCV_FISHEYE``.
    intrinsics : tuple
        ``(fx, fy, cx, cy)`` in pixels (same pixel-centre convention, so unchanged).
    distortion : dict
        ``k1 k2 p1 p2 [k3]`` (OpenCV) or ``k1 k2 k3 k4`` (fisheye); empty for pinhole cameras.

    Raises
    ------
    InputError
        For camera models lift3d cannot represent (undistort the images with ``colmap image_undistorter``).
    """
    p = [float(v) for v in cam.params]
    m = cam.model
    if m == "SIMPLE_PINHOLE":
        return "PINHOLE", (p[0], p[0], p[1], p[2]), {}
    if m == "PINHOLE":
        return "PINHOLE", (p[0], p[1], p[2], p[3]), {}
    # SIMPLE_RADIAL and RADIAL are OpenCV's radial polynomial with k1 (and k2) only.
    if m == "SIMPLE_RADIAL":
        return "OPENCV", (p[0], p[0], p[1], p[2]), {"k1": p[3], "k2": 0.0, "p1": 0.0, "p2": 0.0}
    if m == "RADIAL":
        return "OPENCV", (p[0], p[0], p[1], p[2]), {"k1": p[3], "k2": p[4], "p1": 0.0, "p2": 0.0}
    if m == "OPENCV":
        return "OPENCV", (p[0], p[1], p[2], p[3]), {"k1": p[4], "k2": p[5], "p1": p[6], "p2": p[7]}
    if m == "OPENCV_FISHEYE":
        return "OPENCV_FISHEYE", (p[0], p[1], p[2], p[3]), {"k1": p[4], "k2": p[5], "k3": p[6], "k4": p[7]}
    if m == "FULL_OPENCV" and not any(p[9:12]):
        # The rational model's denominator (k4..k6) is unused: what is left is plain OPENCV with k3.
        return "OPENCV", (p[0], p[1], p[2], p[3]), {"k1": p[4], "k2": p[5], "p1": p[6], "p2": p[7], "k3": p[8]}
    raise InputError(where, f"camera {cam.id}: COLMAP model {m} is not supported (lift3d reads PINHOLE, "
                            "SIMPLE_PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, OPENCV_FISHEYE); undistort the "
                            "images with `colmap image_undistorter` and convert its output")


# ----------------------------------------------------------------------------------------------- text files
def _data_lines(path: Path) -> list[tuple[int, str]]:
    """``(line number, text)`` of every line (comments included, so callers can keep the empty POINTS2D
    lines of ``images.txt``); a missing or unreadable file is an :class:`InputError`."""
    if not path.is_file():
        raise InputError(path, "file not found")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot be read ({exc})") from exc
    return list(enumerate(text.splitlines(), 1))


def read_cameras_text(path: Path) -> dict[int, ColmapCamera]:
    """Parse ``cameras.txt`` (``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`` per line)."""
    cams: dict[int, ColmapCamera] = {}
    for lineno, line in _data_lines(path):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        tok = line.split()
        if len(tok) < 4:
            raise InputError(path, f"line {lineno}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]")
        model = tok[1]
        if model not in _MODEL_BY_NAME:
            raise InputError(path, f"line {lineno}: unknown camera model {model!r}")
        n = _MODEL_BY_NAME[model][1]
        if len(tok) != 4 + n:
            raise InputError(path, f"line {lineno}: {model} takes {n} parameters (got {len(tok) - 4})")
        try:
            cam = ColmapCamera(int(tok[0]), model, int(tok[2]), int(tok[3]), np.array([float(t) for t in tok[4:]]))
        except ValueError:
            raise InputError(path, f"line {lineno}: not numbers where numbers are expected") from None
        cams[cam.id] = cam
    return cams


def read_images_text(path: Path) -> dict[int, ColmapImage]:
    """Parse ``images.txt``: two lines per image, the second (POINTS2D) possibly empty."""
    images: dict[int, ColmapImage] = {}
    lines = _data_lines(path)
    k = 0
    while k < len(lines):
        lineno, line = lines[k]
        k += 1
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        # Like COLMAP's own reader: the line after an image line is its keypoint list, even when empty.
        points_line = lines[k] if k < len(lines) else (lineno + 1, "")
        k += 1
        tok = line.split(maxsplit=9)  # NAME is the rest of the line (it may contain spaces)
        if len(tok) < 10:
            raise InputError(path, f"line {lineno}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME")
        try:
            vals = [float(t) for t in tok[1:8]]
            image = ColmapImage(int(tok[0]), np.array(vals[:4]), np.array(vals[4:]), int(tok[8]), tok[9].strip())
        except ValueError:
            raise InputError(path, f"line {lineno}: not numbers where numbers are expected") from None
        ptok = points_line[1].split()
        if len(ptok) % 3:
            raise InputError(path, f"line {points_line[0]}: POINTS2D must be triples X Y POINT3D_ID")
        try:
            trip = np.array([float(t) for t in ptok], np.float64).reshape(-1, 3)
        except ValueError:
            raise InputError(path, f"line {points_line[0]}: not numbers where numbers are expected") from None
        image.xys, image.point3d_ids = trip[:, :2], trip[:, 2].astype(np.int64)
        images[image.id] = image
    return images


def read_points3d_text(path: Path) -> ColmapPoints:
    """Parse ``points3D.txt`` (``POINT3D_ID X Y Z R G B ERROR TRACK[] as (IMAGE_ID, POINT2D_IDX)``)."""
    ids, xyz, rgb, err, timg, tidx, counts = [], [], [], [], [], [], []
    for lineno, line in _data_lines(path):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        tok = line.split()
        if len(tok) < 8 or (len(tok) - 8) % 2:
            raise InputError(path, f"line {lineno}: expected POINT3D_ID X Y Z R G B ERROR TRACK[] "
                                   "(IMAGE_ID POINT2D_IDX pairs)")
        try:
            ids.append(int(tok[0]))
            xyz.append([float(t) for t in tok[1:4]])
            rgb.append([int(t) for t in tok[4:7]])
            err.append(float(tok[7]))
            track = [int(t) for t in tok[8:]]
        except ValueError:
            raise InputError(path, f"line {lineno}: not numbers where numbers are expected") from None
        timg += track[0::2]
        tidx += track[1::2]
        counts.append(len(track) // 2)
    return ColmapPoints(
        ids=np.asarray(ids, np.int64), xyz=np.asarray(xyz, np.float64).reshape(-1, 3),
        rgb=np.clip(np.asarray(rgb, np.int64).reshape(-1, 3), 0, 255).astype(np.uint8),
        error=np.asarray(err, np.float64), track_image=np.asarray(timg, np.int64),
        track_point2d=np.asarray(tidx, np.int64), offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64))


# ----------------------------------------------------------------------------------------------- binary files
class _BinaryReader:
    """Little-endian cursor over a whole file, raising :class:`InputError` when it runs past the end."""

    def __init__(self, path: Path):
        if not path.is_file():
            raise InputError(path, "file not found")
        self.path = path
        try:
            self.buf = path.read_bytes()
        except OSError as exc:
            raise InputError(path, f"cannot be read ({exc})") from exc
        self.pos = 0

    def read(self, fmt: str) -> tuple:
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.buf):
            raise InputError(self.path, f"truncated at byte {self.pos} (not a complete COLMAP binary file)")
        out = struct.unpack_from("<" + fmt, self.buf, self.pos)
        self.pos += size
        return out

    def skip(self, nbytes: int) -> None:
        if self.pos + nbytes > len(self.buf):
            raise InputError(self.path, f"truncated at byte {self.pos} (not a complete COLMAP binary file)")
        self.pos += nbytes

    def cstring(self) -> str:
        end = self.buf.find(b"\0", self.pos)
        if end < 0:
            raise InputError(self.path, f"truncated at byte {self.pos} (image name without terminator)")
        raw = self.buf[self.pos:end]
        self.pos = end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise InputError(self.path, f"image name at byte {self.pos} is not UTF-8") from None

    def done(self) -> None:
        if self.pos != len(self.buf):
            raise InputError(self.path, f"{len(self.buf) - self.pos} unexpected bytes after the last record")


def read_cameras_binary(path: Path) -> dict[int, ColmapCamera]:
    """Parse ``cameras.bin``."""
    r = _BinaryReader(path)
    (n,) = r.read("Q")
    cams: dict[int, ColmapCamera] = {}
    for _ in range(n):
        cid, model_id, width, height = r.read("IiQQ")
        if model_id not in COLMAP_CAMERA_MODELS:
            raise InputError(path, f"camera {cid}: unknown camera model id {model_id}")
        name, nparams = COLMAP_CAMERA_MODELS[model_id]
        cams[cid] = ColmapCamera(cid, name, width, height, np.array(r.read(f"{nparams}d")))
    r.done()
    return cams


_POINT2D = np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<i8")])


def read_images_binary(path: Path) -> dict[int, ColmapImage]:
    """Parse ``images.bin`` (poses and keypoints)."""
    r = _BinaryReader(path)
    (n,) = r.read("Q")
    images: dict[int, ColmapImage] = {}
    for _ in range(n):
        iid, qw, qx, qy, qz, tx, ty, tz, cam_id = r.read("I7dI")
        name = r.cstring()
        (n_points,) = r.read("Q")
        start = r.pos
        r.skip(24 * n_points)  # float64 x, float64 y, int64 point3D_id
        pts = np.frombuffer(r.buf, _POINT2D, count=n_points, offset=start)
        images[iid] = ColmapImage(iid, np.array([qw, qx, qy, qz]), np.array([tx, ty, tz]), cam_id, name,
                                  np.stack([pts["x"], pts["y"]], -1).astype(np.float64), pts["id"].astype(np.int64))
    r.done()
    return images


def read_points3d_binary(path: Path) -> ColmapPoints:
    """Parse ``points3D.bin``."""
    r = _BinaryReader(path)
    (n,) = r.read("Q")
    ids = np.empty(n, np.int64)
    xyz = np.empty((n, 3), np.float64)
    rgb = np.empty((n, 3), np.uint8)
    err = np.empty(n, np.float64)
    counts = np.empty(n, np.int64)
    tracks = []
    for k in range(n):
        pid, x, y, z, cr, cg, cb, e, track_len = r.read("Q3d3BdQ")
        ids[k], xyz[k], rgb[k], err[k], counts[k] = pid, (x, y, z), (cr, cg, cb), e, track_len
        start = r.pos
        r.skip(8 * track_len)  # uint32 image_id, uint32 point2D_idx
        tracks.append(np.frombuffer(r.buf, "<u4", count=2 * track_len, offset=start))
    r.done()
    flat = np.concatenate(tracks).astype(np.int64) if tracks else np.zeros(0, np.int64)
    return ColmapPoints(ids=ids, xyz=xyz, rgb=rgb, error=err, track_image=flat[0::2], track_point2d=flat[1::2],
                        offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64))


# ----------------------------------------------------------------------------------------------- model folder
def find_model(src: str | Path) -> Path:
    """The folder holding ``cameras`` and ``images``: ``SRC`` itself, ``SRC/sparse/0``, ``SRC/sparse`` or
    ``SRC/colmap/sparse/0`` (first match).

    Raises
    ------
    InputError
        Naming the missing ``cameras`` file when no candidate holds a model.
    """
    src = Path(src)
    if not src.exists():
        raise InputError(src, "not found")
    for sub in _MODEL_SUBDIRS:
        d = (src / sub).resolve() if sub != "." else src
        if any((d / f"cameras.{ext}").is_file() for ext in ("bin", "txt")):
            return d
    # A folder with images but no cameras file is the common mistake: name the missing file precisely.
    for sub in _MODEL_SUBDIRS:
        d = src / sub if sub != "." else src
        for ext in ("bin", "txt"):
            if (d / f"images.{ext}").is_file():
                raise InputError(d / f"cameras.{ext}", f"file not found (the COLMAP model in {d} needs it)")
    raise InputError(src / "cameras.bin", "no COLMAP model found: expected cameras.bin|txt and images.bin|txt "
                                          "in SRC, SRC/sparse/0, SRC/sparse or SRC/colmap/sparse/0")


def read_model(model_dir: str | Path) -> ColmapModel:
    """Read ``cameras`` and ``images`` of a model folder, preferring binary files as COLMAP does."""
    model_dir = Path(model_dir)
    fmt = "bin" if (model_dir / "cameras.bin").is_file() else "txt"
    if fmt == "bin":
        cams = read_cameras_binary(model_dir / "cameras.bin")
        images = read_images_binary(model_dir / "images.bin")
    else:
        cams = read_cameras_text(model_dir / "cameras.txt")
        images = read_images_text(model_dir / "images.txt")
    if not images:
        raise InputError(model_dir / f"images.{fmt}", "no registered images")
    for img in images.values():
        if img.camera_id not in cams:
            raise InputError(model_dir / f"images.{fmt}", f"image {img.name!r} uses camera {img.camera_id}, "
                                                          f"which cameras.{fmt} does not define")
        if not np.all(np.isfinite(img.qvec)) or np.linalg.norm(img.qvec) < 1e-8:
            raise InputError(model_dir / f"images.{fmt}", f"image {img.name!r}: invalid quaternion {img.qvec}")
    return ColmapModel(model_dir, fmt, cams, images)


def default_images_dir(src: Path, model_dir: Path) -> Path:
    """``SRC/images``, else an ``images`` folder beside the model folder or one of its three parents
    (COLMAP workspace: ``ws/sparse/0`` → ``ws/images``; nerfstudio: ``data/colmap/sparse/0`` →
    ``data/images``)."""
    candidates = [src / "images", model_dir / "images"] + [p / "images" for p in list(model_dir.parents)[:3]]
    for c in candidates:
        if c.is_dir():
            return c
    raise InputError(src / "images", "image folder not found (pass --images DIR)")


def check_points(points: ColmapPoints, model: ColmapModel) -> None:
    """Check that every track entry of ``points3D`` names a registered image and one of its keypoints, and
    that the keypoint says it belongs to that point.

    Raises
    ------
    InputError
        Naming the ``points3D`` file: an unknown image id, a POINT2D_IDX out of range, a keypoint that
        ``images`` gives to another point (a points3D from another reconstruction), or non-finite points.
    """
    path = model.points_file
    if not np.all(np.isfinite(points.xyz)):
        raise InputError(path, "point coordinates are not finite")
    owner = np.repeat(points.ids, np.diff(points.offsets))
    known = np.array(sorted(model.images), np.int64)
    unknown = ~np.isin(points.track_image, known)
    if unknown.any():
        k = int(np.flatnonzero(unknown)[0])
        raise InputError(path, f"point {owner[k]}: its track names image id {points.track_image[k]}, which "
                               f"{model.images_file.name} does not list (points3D does not match the images)")
    for iid in np.unique(points.track_image):
        img = model.images[int(iid)]
        sel = np.flatnonzero(points.track_image == iid)
        idx = points.track_point2d[sel]
        bad = idx >= len(img.xys)
        if bad.any():
            k = sel[np.flatnonzero(bad)[0]]
            raise InputError(path, f"point {owner[k]}: POINT2D_IDX {points.track_point2d[k]} is out of range for "
                                   f"image {iid} ({len(img.xys)} keypoints in {model.images_file.name})")
        other = img.point3d_ids[idx] != owner[sel]
        if other.any():
            k = sel[np.flatnonzero(other)[0]]
            raise InputError(path, f"point {owner[k]}: keypoint {points.track_point2d[k]} of image {iid} belongs "
                                   f"to point {img.point3d_ids[points.track_point2d[k]]} in "
                                   f"{model.images_file.name} (points3D does not match the images)")


def sparse_points_from_colmap(points: ColmapPoints, model: ColmapModel, scene: Scene,
                              frame_of_image: dict[int, int]) -> SparsePoints:
    """COLMAP's points as the scene's sparse points (call :func:`check_points` first).

    Keypoint positions keep COLMAP's pixel convention (the same as lift3d's), scaled when the written
    images were resized or downscaled. Depth and its sigma per observation come from the scene's cameras with
    the same formula as ``lift3d triangulate`` (:func:`lift3d.sfm.triangulation.observation_depths`). Observations
    behind their camera are left out, and points left with fewer than two observations; both are counted
    in ``info["dropped"]``.
    """
    cams = scene.cameras
    n_pts = len(points.ids)
    point = np.repeat(np.arange(n_pts), np.diff(points.offsets))
    frame = np.array([frame_of_image[int(i)] for i in points.track_image], np.int64).reshape(-1)
    uv = np.zeros((len(point), 2))
    ideal = np.zeros((len(point), 2))
    for iid in np.unique(points.track_image):
        img = model.images[int(iid)]
        cam = model.cameras[img.camera_id]
        sel = points.track_image == iid
        f = frame_of_image[int(iid)]
        # The written focal lengths over COLMAP's: pixel coordinates (corner origin) scale with them through
        # any resize of the images on disk and any --downscale (which may also crop the last rows/columns).
        _, (fx, fy, _, _), _ = camera_to_lift3d(cam, model.path)
        scale = np.array([cams.fx[f] / fx, cams.fy[f] / fy])
        uv[sel] = img.xys[points.track_point2d[sel]] * scale
        ideal[sel] = ideal_pixels(cams, f, uv[sel])
    r, t = world_to_camera(cams)
    k = intrinsics(cams)
    _, z, _ = project(r, t, k, frame, points.xyz[point])
    front = z > 0
    counts = np.bincount(point[front], minlength=n_pts)
    keep_pt = counts >= 2
    keep = front & keep_pt[point]
    new_id = np.cumsum(keep_pt) - 1
    z, sigma, _ = observation_depths(r, t, k, frame[keep], ideal[keep], new_id[point[keep]], points.xyz[keep_pt],
                                     TrackConfig().sigma_floor)
    return SparsePoints(
        xyz=points.xyz[keep_pt], rgb=points.rgb[keep_pt], error=points.error[keep_pt].astype(np.float32),
        track_length=counts[keep_pt].astype(np.int32), frame_names=[f.name for f in scene.frames],
        obs_frame=frame[keep].astype(np.int32), obs_point=new_id[point[keep]].astype(np.int32),
        obs_uv=uv[keep].astype(np.float32), obs_depth=z.astype(np.float32), obs_sigma=sigma.astype(np.float32),
        info={"source": "colmap", "file": str(model.points_file),
              "dropped": {"behind camera (observations)": int((~front).sum()),
                          "fewer than 2 observations": int((~keep_pt).sum())}},
    )


def scene_box_from_points(xyz: np.ndarray, centers: np.ndarray) -> tuple[str, np.ndarray]:
    """A bounded box around the sparse points (1st–99th percentile, so stray points do not inflate it)
    and the camera centres, padded by 5 % per side."""
    pts = np.concatenate([np.percentile(xyz, [1, 99], axis=0), centers]) if len(xyz) else centers
    lo, hi = pts.min(0), pts.max(0)
    pad = 0.05 * np.maximum(hi - lo, 1e-3)
    return "bounded", np.stack([lo - pad, hi + pad])


# ----------------------------------------------------------------------------------------------- conversion
def convert(
    src: str | Path,
    out: str | Path,
    *,
    predictions: str | Path,
    images: str | Path | None = None,
    categories: list[Category] | None = None,
    things: list[int] | None = None,
    test_every: int = 8,
    scene_box: bool = False,
    keep_points: bool = True,
    options: WriteOptions | None = None,
) -> Scene:
    """Convert a COLMAP model plus per-image 2D panoptic predictions into a scene folder.

    Parameters
    ----------
    src : str or Path
        The model folder or a workspace holding it (see :func:`find_model`).
    out : str or Path
        Output scene folder.
    predictions : str or Path
        Folder of 2D panoptic predictions (see :mod:`lift3d.convert.predictions`).
    images : str or Path, optional
        Folder the COLMAP image names are relative to (default: :func:`default_images_dir`).
    categories : list of Category, optional
        Overrides the predictions' categories.
    things : list of int, optional
        Thing ids for generic categories when the predictions carry none.
    test_every : int
        Every N-th image (sorted by name) is a test image; 0 keeps all for training.
    scene_box : bool
        Write a ``bounded`` scene box around the sparse points (needs ``points3D``).
    keep_points : bool
        Keep ``points3D`` (when the model has one) as the scene's sparse points: ``sparse/points3D.ply`` +
        ``sparse/observations.npz``, referenced from ``transforms.json`` (docs/scene-format.md).
    options : WriteOptions, optional
        Output options.

    Returns
    -------
    Scene
        The written scene, loaded back.
    """
    src = Path(src)
    model = read_model(find_model(src))
    images_dir = Path(images) if images is not None else default_images_dir(src, model.path)
    if not images_dir.is_dir():
        raise InputError(images_dir, "image folder not found")
    preds = PredictionFolder(predictions, categories, things)

    ordered = every_nth(sorted(model.images.values(), key=lambda im: im.name), (options or WriteOptions()).frame_step)
    kinds = {}
    for img in ordered:
        kinds[img.camera_id] = camera_to_lift3d(model.cameras[img.camera_id], model.path / f"cameras.{model.format}")
    models_used = {k[0] for k in kinds.values()}
    if "OPENCV_FISHEYE" in models_used and len(models_used) > 1:
        raise InputError(model.path / f"cameras.{model.format}", "fisheye and perspective cameras are mixed; "
                                                                 "lift3d needs one camera model per scene")
    camera_model = "OPENCV_FISHEYE" if "OPENCV_FISHEYE" in models_used else (
        "OPENCV" if "OPENCV" in models_used else "PINHOLE")

    stems = [Path(img.name).stem for img in ordered]
    for img in ordered:
        p = images_dir / img.name
        if not p.is_file():
            raise InputError(p, f"file not found (listed in {model.images_file.name})")
    preds.check(stems)
    cats = preds.resolve_categories(stems, progress=options.progress if options else True)

    frames = []
    for img, stem in zip(ordered, stems):
        cam = model.cameras[img.camera_id]
        _, intr, dist = kinds[img.camera_id]
        frames.append(FrameInput(
            name=stem, image_path=images_dir / img.name, c2w_opencv=image_c2w_opencv(img),
            pose_source=model.images_file, intrinsics=intr, intrinsics_size=(int(cam.width), int(cam.height)),
            labels=_labels_of(preds, stem), distortion=dist,
        ))
    box = None
    points = model.points() if (scene_box or keep_points) else None
    if points is not None:
        check_points(points, model)  # before anything is written
    if scene_box:
        if points is None:
            raise InputError(model.points_file, "file not found (needed by --scene-box)")
        centers = np.stack([f.c2w_opencv[:3, 3] for f in frames])
        box = scene_box_from_points(points.xyz, centers)
    on_disk = sum(1 for p in images_dir.rglob("*") if p.suffix.lower() in (".jpg", ".jpeg", ".png"))
    if on_disk > len(model.images):
        note(f"{on_disk - len(model.images)} images in {images_dir} are not registered in the COLMAP model "
             "and are left out")
    scene = write_scene(out, frames, cats, camera_model=camera_model, splits=split_every(stems, test_every),
                        scene_box=box, options=options,
                        extra_meta={"converted_from": {"source": "colmap", "model": str(model.path)}})
    if keep_points and points is not None:
        index = {f.name: k for k, f in enumerate(scene.frames)}
        frame_of_image = {img.id: index[stem] for img, stem in zip(ordered, stems)}
        write_sparse_points(out, sparse_points_from_colmap(points, model, scene, frame_of_image))
        scene = load_scene(out)
    return scene


def _labels_of(preds: PredictionFolder, stem: str) -> Callable:
    return lambda: preds.labels(stem)
