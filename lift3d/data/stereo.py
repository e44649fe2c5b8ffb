"""Geometry from the images, stored in the scene folder: sparse points and dense (multi-view stereo) depth.

Layout (docs/scene-format.md, section "Geometry from the images")::

    <scene>/
      sparse/points3D.ply          one vertex per 3D point: float x y z, uchar red green blue,
                                   float error (mean reprojection error, pixels), int track_length
      sparse/observations.npz      which frame sees which point where (arrays below)
      mvs/depth/<name>.png         dense z-depth, uint16 in depth_unit_scale_factor units, 0 = none
      mvs/sigma/<name>.png         its standard deviation, same encoding

``observations.npz`` holds, for ``M`` observations of ``P`` points seen in the frames ``frame_names``:

==============  =================  ==================================================================
array           dtype / shape      meaning
==============  =================  ==================================================================
``frame_names`` ``str [F]``        frame names (image file stems) the observations refer to
``frame``       ``int32 [M]``      index into ``frame_names``
``point``       ``int32 [M]``      index of the vertex in ``points3D.ply``
``uv``          ``float32 [M, 2]`` pixel position (continuous: pixel (c, r)'s centre is (c+.5, r+.5))
``depth``       ``float32 [M]``    z-depth of the point in that frame (along the optical axis)
``sigma``       ``float32 [M]``    standard deviation of that depth (world units)
==============  =================  ==================================================================

``transforms.json`` refers to them::

    "sparse_points": {"points": "sparse/points3D.ply", "observations": "sparse/observations.npz",
                      "source": "lift3d triangulate", "count": 1234, "median_error_px": 0.61, ...}

and, per frame, ``"mvs_depth_file_path"`` / ``"mvs_sigma_file_path"`` for the dense maps, and
``"mvs_support_file_path"`` (optional) for how many source views confirmed each depth.
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
from plyfile import PlyData, PlyElement

from lift3d.data.images import write_depth, write_label_map
from lift3d.errors import InputError
from lift3d.utils.atomic import write_bytes_atomic, write_json_atomic
from lift3d.utils.files import read_json

POINTS_FILE = "sparse/points3D.ply"
OBSERVATIONS_FILE = "sparse/observations.npz"
MVS_DEPTH_DIR = "mvs/depth"
MVS_SIGMA_DIR = "mvs/sigma"
MVS_SUPPORT_DIR = "mvs/support"

_OBS_ARRAYS = ("frame_names", "frame", "point", "uv", "depth", "sigma")


@dataclass
class SparsePoints:
    """Triangulated 3D points and where each frame sees them.

    Attributes
    ----------
    xyz : np.ndarray
        ``float64 [P, 3]`` world coordinates (the frame of ``transforms.json``).
    rgb : np.ndarray
        ``uint8 [P, 3]`` colour.
    error : np.ndarray
        ``float32 [P]`` mean reprojection error in pixels.
    track_length : np.ndarray
        ``int32 [P]`` number of observations.
    frame_names : list of str
        Frame names the observations index into (a scene's frame names when read through
        :meth:`lift3d.data.scene.Scene.sparse_points`, so ``obs_frame`` is then a scene frame index).
    obs_frame, obs_point : np.ndarray
        ``int32 [M]`` frame index and point index of each observation.
    obs_uv : np.ndarray
        ``float32 [M, 2]`` continuous pixel position (pixel ``(c, r)``'s centre at ``(c + .5, r + .5)``).
    obs_depth, obs_sigma : np.ndarray
        ``float32 [M]`` z-depth of the point in that frame and its standard deviation (world units).
        Depth along the ray is ``obs_depth * sqrt(1 + x² + y²)`` with ``(x, y)`` the normalised coordinates.
    info : dict
        Provenance and statistics (``source``, dropped counts, timings), recorded in ``transforms.json``.
    """

    xyz: np.ndarray
    rgb: np.ndarray
    error: np.ndarray
    track_length: np.ndarray
    frame_names: list[str]
    obs_frame: np.ndarray
    obs_point: np.ndarray
    obs_uv: np.ndarray
    obs_depth: np.ndarray
    obs_sigma: np.ndarray
    info: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.xyz)

    @property
    def median_error(self) -> float:
        """Median reprojection error (pixels) over the points, NaN when there are none."""
        return float(np.median(self.error)) if len(self) else float("nan")

    def frame_observations(self, index: int) -> dict[str, np.ndarray]:
        """The observations of frame ``index``: ``uv [n, 2]``, ``depth [n]``, ``sigma [n]``, ``point [n]``.

        This is what depth supervision needs: a ray through ``uv`` should end at ``depth`` (z) ± ``sigma``.
        """
        m = self.obs_frame == index
        return {"uv": self.obs_uv[m], "depth": self.obs_depth[m], "sigma": self.obs_sigma[m],
                "point": self.obs_point[m]}

    def summary(self) -> dict[str, Any]:
        """What ``transforms.json`` records beside the file names."""
        out: dict[str, Any] = {"count": len(self), "observation_count": int(len(self.obs_point))}
        if len(self):
            out["median_error_px"] = round(self.median_error, 4)
            out["median_track_length"] = float(np.median(self.track_length))
        for k, v in self.info.items():
            out.setdefault(k, v)
        return out


@dataclass
class DenseDepth:
    """Dense (semi-dense) depth maps from multi-view stereo.

    Attributes
    ----------
    frame_names : list of str
        The frames that have maps.
    depth : list of np.ndarray
        ``float32 [H, W]`` z-depth per frame (world units), 0 where there is none.
    sigma : list of np.ndarray
        ``float32 [H, W]`` its standard deviation, 0 where there is no depth.
    info : dict
        Provenance and statistics (coverage, seconds), recorded in ``transforms.json``.
    support : list of np.ndarray, optional
        ``uint8 [H, W]`` how many source views confirmed each depth (:mod:`lift3d.sfm.mvs`: the fewer of the
        photo-consistency's sources that saw the point and the sources whose depth agreed), 0 where there is
        none; None when not recorded (every depth counts as confirmed by as many views as the sweep asks).
    """

    frame_names: list[str]
    depth: list
    sigma: list
    info: dict = field(default_factory=dict)
    support: list | None = None

    def __len__(self) -> int:
        return len(self.frame_names)

    @property
    def coverage(self) -> float:
        """Mean fraction of pixels with a depth."""
        return float(np.mean([(d > 0).mean() for d in self.depth])) if self.depth else 0.0


# --------------------------------------------------------------------------------------------- writing
def write_sparse_points_files(root: str | Path, sparse: SparsePoints) -> dict:
    """Write ``sparse/points3D.ply`` and ``sparse/observations.npz`` under ``root`` (atomically); return the
    ``sparse_points`` entry that refers to them (file names relative to ``root`` + :meth:`~SparsePoints.summary`)."""
    root = Path(root)
    p = len(sparse)
    vertex = np.empty(p, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"),
                                ("blue", "u1"), ("error", "f4"), ("track_length", "i4")])
    if p:
        vertex["x"], vertex["y"], vertex["z"] = sparse.xyz[:, 0], sparse.xyz[:, 1], sparse.xyz[:, 2]
        vertex["red"], vertex["green"], vertex["blue"] = sparse.rgb[:, 0], sparse.rgb[:, 1], sparse.rgb[:, 2]
        vertex["error"], vertex["track_length"] = sparse.error, sparse.track_length
    buf = io.BytesIO()
    source = str(sparse.info.get("source", "unknown"))
    PlyData([PlyElement.describe(vertex, "vertex")], text=False, byte_order="<",
            comments=[f"lift3d sparse points ({source})"]).write(buf)
    write_bytes_atomic(root / POINTS_FILE, buf.getvalue())

    buf = io.BytesIO()
    np.savez_compressed(
        buf, frame_names=np.asarray(list(sparse.frame_names), dtype=str),
        frame=np.asarray(sparse.obs_frame, np.int32), point=np.asarray(sparse.obs_point, np.int32),
        uv=np.asarray(sparse.obs_uv, np.float32).reshape(-1, 2), depth=np.asarray(sparse.obs_depth, np.float32),
        sigma=np.asarray(sparse.obs_sigma, np.float32))
    write_bytes_atomic(root / OBSERVATIONS_FILE, buf.getvalue())
    return {"points": POINTS_FILE, "observations": OBSERVATIONS_FILE, **sparse.summary()}


def write_sparse_points(root: str | Path, sparse: SparsePoints) -> dict:
    """Write the sparse point files into a scene folder and record them under ``sparse_points`` in its
    ``transforms.json`` (atomically). Returns that entry."""
    entry = write_sparse_points_files(root, sparse)
    update_transforms(root, lambda meta: meta.__setitem__("sparse_points", entry))
    return entry


def update_transforms(root: str | Path, change: Callable[[dict], Any]) -> None:
    """Read ``transforms.json``, apply ``change(meta)`` in place, write it back atomically."""
    path = Path(root) / "transforms.json"
    meta = read_json(path)
    if not isinstance(meta, dict):
        raise InputError(path, "must hold a JSON object")
    change(meta)
    write_json_atomic(path, meta)


def write_mvs_maps(root: str | Path, dense: DenseDepth, unit_scale: float) -> dict:
    """Write ``mvs/depth/<name>.png`` and ``mvs/sigma/<name>.png`` under ``root`` (uint16 in ``unit_scale``
    metres, 0 = no depth; a sigma below one unit is stored as one unit, since 0 would read as 'no depth'), and
    ``mvs/support/<name>.png`` (source views that confirmed each depth) when the maps record it.
    Returns the ``mvs_depth`` summary entry."""
    root = Path(root)
    supports = dense.support if dense.support is not None else [None] * len(dense)
    for name, d, s, n in zip(dense.frame_names, dense.depth, dense.sigma, supports):
        write_depth(root / MVS_DEPTH_DIR / f"{name}.png", d, unit_scale)
        s = np.where(d > 0, np.maximum(s, unit_scale), 0.0)
        write_depth(root / MVS_SIGMA_DIR / f"{name}.png", s, unit_scale)
        if n is not None:
            write_label_map(root / MVS_SUPPORT_DIR / f"{name}.png", np.where(d > 0, n, 0))
    dirs = {"depth_dir": MVS_DEPTH_DIR, "sigma_dir": MVS_SIGMA_DIR}
    if dense.support is not None:
        dirs["support_dir"] = MVS_SUPPORT_DIR
    return {**dirs, "frames": len(dense), "coverage": round(dense.coverage, 4), **dense.info}


def write_mvs_depth(root: str | Path, dense: DenseDepth, unit_scale: float) -> dict:
    """Write the dense maps into a scene folder and reference them per frame (``mvs_depth_file_path``,
    ``mvs_sigma_file_path``) and under ``mvs_depth`` in its ``transforms.json``. Returns that entry."""
    entry = write_mvs_maps(root, dense, unit_scale)
    wanted = set(dense.frame_names)

    def change(meta: dict) -> None:
        for fr in meta.get("frames", []):
            name = Path(str(fr.get("file_path", ""))).stem
            if name in wanted:
                fr["mvs_depth_file_path"] = f"{MVS_DEPTH_DIR}/{name}.png"
                fr["mvs_sigma_file_path"] = f"{MVS_SIGMA_DIR}/{name}.png"
                if dense.support is not None:
                    fr["mvs_support_file_path"] = f"{MVS_SUPPORT_DIR}/{name}.png"
                else:
                    fr.pop("mvs_support_file_path", None)
        meta["mvs_depth"] = entry

    update_transforms(root, change)
    return entry


# --------------------------------------------------------------------------------------------- reading
def read_sparse_points(points_path: str | Path, observations_path: str | Path,
                       frame_names: Sequence[str] | None = None) -> SparsePoints:
    """Read and validate sparse points.

    Parameters
    ----------
    points_path, observations_path : str or Path
        ``points3D.ply`` and ``observations.npz``.
    frame_names : sequence of str, optional
        The scene's frame names: every observed frame must be one of them, and the result's
        ``obs_frame`` then indexes this list.

    Raises
    ------
    InputError
        One line naming the file: missing or unreadable, missing arrays or properties, shapes that do not
        agree, point indices out of range, unknown frames, non-finite values, depth or sigma <= 0.
    """
    points_path, observations_path = Path(points_path), Path(observations_path)
    if not points_path.is_file():
        raise InputError(points_path, "file not found")
    try:
        v = PlyData.read(str(points_path))["vertex"].data
    except Exception as exc:  # plyfile raises several types for corrupt files
        raise InputError(points_path, f"not a readable PLY file ({exc})") from exc
    names = set(v.dtype.names or ())
    need = {"x", "y", "z", "error", "track_length"}
    if not need <= names:
        raise InputError(points_path, f"vertex properties {sorted(need - names)} are missing")
    xyz = np.stack([v["x"], v["y"], v["z"]], -1).astype(np.float64).reshape(-1, 3)
    p = len(xyz)
    if {"red", "green", "blue"} <= names:
        rgb = np.stack([v["red"], v["green"], v["blue"]], -1).astype(np.uint8).reshape(-1, 3)
    else:
        rgb = np.full((p, 3), 128, np.uint8)
    error = np.asarray(v["error"], np.float32)
    track = np.asarray(v["track_length"], np.int32)
    if not (np.all(np.isfinite(xyz)) and np.all(np.isfinite(error))):
        raise InputError(points_path, "point coordinates or errors are not finite")

    if not observations_path.is_file():
        raise InputError(observations_path, "file not found")
    try:
        with np.load(observations_path, allow_pickle=False) as z:
            missing = [k for k in _OBS_ARRAYS if k not in z.files]
            if missing:
                raise InputError(observations_path, f"arrays {missing} are missing")
            arr = {k: z[k] for k in _OBS_ARRAYS}
    except InputError:
        raise
    except Exception as exc:  # zipfile/pickle/format errors
        raise InputError(observations_path, f"not a readable .npz file ({exc})") from exc
    names_f = [str(n) for n in np.asarray(arr["frame_names"]).reshape(-1)]
    m = len(np.asarray(arr["point"]).reshape(-1))
    try:
        frame = np.asarray(arr["frame"]).astype(np.int64).reshape(-1)
        point = np.asarray(arr["point"]).astype(np.int64).reshape(-1)
        uv = np.asarray(arr["uv"], np.float32).reshape(-1, 2)
        depth = np.asarray(arr["depth"], np.float32).reshape(-1)
        sigma = np.asarray(arr["sigma"], np.float32).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise InputError(observations_path, f"arrays of the wrong type or shape ({exc})") from None
    if not (len(frame) == len(uv) == len(depth) == len(sigma) == m):
        raise InputError(observations_path, f"frame, point, uv, depth and sigma must have one entry per "
                                            f"observation (got {len(frame)}, {m}, {len(uv)}, {len(depth)}, "
                                            f"{len(sigma)})")
    if m and (frame.min() < 0 or frame.max() >= len(names_f)):
        raise InputError(observations_path, f"frame indices must lie in [0, {len(names_f)})")
    if m and (point.min() < 0 or point.max() >= p):
        raise InputError(observations_path, f"point indices must lie in [0, {p}) ({points_path.name} has {p} "
                                            "points)")
    if not (np.all(np.isfinite(uv)) and np.all(np.isfinite(depth)) and np.all(np.isfinite(sigma))):
        raise InputError(observations_path, "uv, depth or sigma are not finite")
    if m and (depth.min() <= 0 or sigma.min() <= 0):
        raise InputError(observations_path, "depth and sigma must be positive")
    counts = np.bincount(point, minlength=p)
    if not np.array_equal(counts, track):
        raise InputError(points_path, "track_length does not match the observations in "
                                      f"{observations_path.name}")
    if frame_names is not None:
        index = {n: k for k, n in enumerate(frame_names)}
        unknown = [n for n in names_f if n not in index]
        if unknown:
            raise InputError(observations_path, f"frames {unknown[:3]} are not in transforms.json")
        remap = np.array([index[n] for n in names_f], np.int64)
        frame = remap[frame] if m else frame
        names_f = list(frame_names)
    return SparsePoints(xyz=xyz, rgb=rgb, error=error, track_length=track, frame_names=names_f,
                        obs_frame=frame.astype(np.int32), obs_point=point.astype(np.int32), obs_uv=uv,
                        obs_depth=depth, obs_sigma=sigma)
