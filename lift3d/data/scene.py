"""The scene folder (docs/scene-format.md): reading, validating and writing it.

A scene folder holds posed images plus per-frame 2D panoptic pseudo-labels (and optionally ground truth)::

    <scene>/
      transforms.json               cameras (OpenGL camera-to-world), categories, splits, scene box
      images/<name>.png|jpg
      panoptic/<name>.png           COCO panoptic PNG (id = R + 256 G + 256² B, 0 = void)
      panoptic.json                 COCO panoptic JSON: annotations[].file_name, segments_info[] (+ score)
      gt/panoptic/<name>.png        optional GT with scene-consistent segment ids
      gt/panoptic.json
      gt/points.ply                 optional 3D GT: x, y, z, semantic, instance
      depth/<name>.png              optional uint16 depth (``depth_unit_scale_factor`` metres per unit)
      gt/depth/<name>.png           optional exact depth for evaluation (``gt_depth_file_path``)
      sparse/points3D.ply           optional sparse points from the images (``sparse_points`` in transforms.json)
      sparse/observations.npz         and where each frame sees them (see lift3d.data.stereo)
      mvs/depth|sigma/<name>.png    optional multi-view-stereo depth and its sigma (``mvs_depth_file_path``)

Pseudo-labels may instead come as two PNGs per frame (``semantic_file_path``: category ids,
``instance_file_path``: per-frame instance ids, 0 = none) and optional per-pixel confidence maps
(``confidence_file_path``: 8/16-bit PNG scaled to [0, 1], or ``.npy``).

:func:`load_scene` checks everything that can be checked without decoding pixels and raises
:class:`~lift3d.errors.InputError` (one line naming file and field). The per-frame loaders
(:meth:`Scene.image`, :meth:`Scene.pseudo_labels`, ...) check what they decode; :meth:`Scene.validate`
runs them all.
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from lift3d.data.cameras import CAMERA_MODELS, Cameras, is_rigid
from lift3d.data.categories import Category, parse_categories
from lift3d.data.images import (
    read_depth,
    read_label_map,
    read_panoptic_png,
    read_rgb,
    read_unit_map,
    write_depth,
    write_label_map,
    write_panoptic_png,
    write_rgb,
)
from lift3d.data.ply import read_labelled_ply, write_labelled_ply
from lift3d.data.stereo import SparsePoints, read_sparse_points
from lift3d.errors import InputError
from lift3d.utils.atomic import write_json_atomic
from lift3d.utils.files import read_json
from lift3d.utils.progress import progress_bar

SPLITS = ("train", "val", "test")


@dataclass(frozen=True)
class Segment:
    """One entry of a frame's ``segments_info``. ``score`` is the segmenter's confidence in [0, 1]."""

    id: int
    category_id: int
    score: float = 1.0
    iscrowd: int = 0

    def to_json(self, area: int | None = None) -> dict:
        d: dict[str, Any] = {"id": int(self.id), "category_id": int(self.category_id), "iscrowd": int(self.iscrowd)}
        if area is not None:
            d["area"] = int(area)
        # Not rounded: JSON keeps a Python float exactly, so scores survive a write/read round trip.
        d["score"] = float(self.score)
        return d


@dataclass
class SceneBox:
    """Where the scene lives: ``bounded`` (content inside ``aabb``) or ``unbounded`` (``aabb`` is the
    foreground box; everything outside is contracted)."""

    type: str
    aabb: np.ndarray  # [2, 3] min and max corner, world units

    def to_json(self) -> dict:
        return {"type": self.type, "aabb": np.asarray(self.aabb, float).tolist()}


@dataclass
class PanopticLabels:
    """Per-pixel panoptic labels of one frame.

    Attributes
    ----------
    semantic : np.ndarray
        ``int32 [H, W]`` category ids, 0 = void.
    instance : np.ndarray
        ``int32 [H, W]`` instance ids on thing pixels, 0 on stuff and void. Pseudo-labels: per-frame
        arbitrary ids (the frame's segment ids); ground truth: scene-consistent ids.
    segment : np.ndarray
        ``int32 [H, W]`` per-frame segment ids (stuff segments included), 0 = void.
    confidence : np.ndarray
        ``float32 [H, W]`` λ_p in [0, 1]: segment score × per-pixel confidence (1 when not given).
    """

    semantic: np.ndarray
    instance: np.ndarray
    segment: np.ndarray
    confidence: np.ndarray


@dataclass
class Frame:
    """One posed image and the paths of everything that belongs to it."""

    name: str
    file_path: str
    image_path: Path
    panoptic_path: Path | None = None
    segments: dict[int, Segment] = field(default_factory=dict)
    semantic_path: Path | None = None
    instance_path: Path | None = None
    confidence_path: Path | None = None
    gt_panoptic_path: Path | None = None
    gt_segments: dict[int, Segment] = field(default_factory=dict)
    depth_path: Path | None = None
    mask_path: Path | None = None
    gt_depth_path: Path | None = None
    #: the true camera-to-world matrix when the written one is noisy (``gt_transform_matrix``), else None
    gt_c2w: np.ndarray | None = None
    mvs_depth_path: Path | None = None
    mvs_sigma_path: Path | None = None
    mvs_support_path: Path | None = None


@dataclass
class Scene:
    """A loaded scene folder. Pixels are read on demand by the per-frame methods."""

    root: Path
    frames: list[Frame]
    cameras: Cameras
    categories: list[Category]
    splits: dict[str, np.ndarray]
    scene_box: SceneBox | None = None
    depth_unit_scale_factor: float = 1e-3
    gt_points_path: Path | None = None
    sparse_points_paths: tuple[Path, Path] | None = None

    # ---------------------------------------------------------------- metadata
    @property
    def name(self) -> str:
        return self.root.resolve().name

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def category_by_id(self) -> dict[int, Category]:
        return {c.id: c for c in self.categories}

    @property
    def thing_ids(self) -> list[int]:
        return sorted(c.id for c in self.categories if c.isthing)

    @property
    def stuff_ids(self) -> list[int]:
        return sorted(c.id for c in self.categories if not c.isthing)

    @property
    def has_gt(self) -> bool:
        return all(f.gt_panoptic_path is not None for f in self.frames)

    @property
    def has_depth(self) -> bool:
        return all(f.depth_path is not None for f in self.frames)

    @property
    def has_pseudo_labels(self) -> bool:
        """Whether the frames carry 2D pseudo-labels; False for a scene written to be labelled afterwards
        (``lift3d label``), which loads (images, poses, depth) but cannot be trained on."""
        return any(f.panoptic_path is not None or f.semantic_path is not None for f in self.frames)

    def split(self, name: str) -> np.ndarray:
        """Frame indices of split ``name`` (``train``, ``val`` or ``test``)."""
        if name not in self.splits:
            raise InputError(self.root / "transforms.json", f"unknown split {name!r} (have {sorted(self.splits)})")
        return self.splits[name]

    def true_pose_frames(self, frames: Iterable[int] | None = None) -> list[int]:
        """The frames (of ``frames``, default all) that carry a true pose (``gt_transform_matrix``)."""
        idx = range(len(self.frames)) if frames is None else frames
        return [int(i) for i in idx if self.frames[int(i)].gt_c2w is not None]

    def at_true_poses(self, frames: Iterable[int] | None = None) -> "Scene":
        """The same scene with the true pose (``gt_transform_matrix``) of each of ``frames`` (default all) that
        has one in place of its written ``transform_matrix``; other frames keep theirs.

        A scene whose written poses are noisy (``lift3d synth --pose-noise``, or a capture surveyed
        separately) is scored where its images were really taken.

        Examples
        --------
        >>> scene = load_scene("scenes/room_noisy")  # doctest: +SKIP
        >>> scene.at_true_poses(scene.split("test")).cameras.c2w  # doctest: +SKIP
        """
        c2w = self.cameras.c2w.copy()
        for i in self.true_pose_frames(frames):
            c2w[i] = self.frames[i].gt_c2w
        return dataclasses.replace(self, cameras=dataclasses.replace(self.cameras, c2w=c2w))

    def pose_error(self, frames: Iterable[int] | None = None) -> dict[str, float] | None:
        """RMS rotation (degrees) and translation (world units) between the written and the true poses of
        ``frames`` (default all) that have a true pose; None when none has one."""
        idx = self.true_pose_frames(frames)
        if not idx:
            return None
        written, true = self.cameras.c2w[idx], np.stack([self.frames[i].gt_c2w for i in idx])
        rel = np.einsum("nji,njk->nik", true[:, :3, :3], written[:, :3, :3])
        cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
        moved = np.linalg.norm(written[:, :3, 3] - true[:, :3, 3], axis=1)
        return {"frames": len(idx), "rms_deg": float(np.degrees(np.sqrt(np.mean(np.arccos(cos) ** 2)))),
                "rms_translation": float(np.sqrt(np.mean(moved ** 2)))}

    # ---------------------------------------------------------------- pixels
    def image(self, i: int) -> np.ndarray:
        """``uint8 [H, W, 3]`` RGB of frame ``i``; checks the size against the intrinsics."""
        f = self.frames[i]
        img = read_rgb(f.image_path)
        h, w = int(self.cameras.height[i]), int(self.cameras.width[i])
        if img.shape[:2] != (h, w):
            raise InputError(
                f.image_path, f"image is {img.shape[1]}x{img.shape[0]} but transforms.json says w={w}, h={h}"
            )
        return img

    def _check_size(self, i: int, path: Path, arr: np.ndarray, what: str) -> None:
        h, w = int(self.cameras.height[i]), int(self.cameras.width[i])
        if arr.shape[:2] != (h, w):
            raise InputError(path, f"{what} is {arr.shape[1]}x{arr.shape[0]} but the image is {w}x{h}")

    def pseudo_labels(self, i: int) -> PanopticLabels:
        """The 2D pseudo-labels of frame ``i`` (per-frame arbitrary instance ids)."""
        f = self.frames[i]
        if f.panoptic_path is not None:
            seg_map = read_panoptic_png(f.panoptic_path)
            self._check_size(i, f.panoptic_path, seg_map, "panoptic PNG")
            labels = self._labels_from_segments(f.panoptic_path, seg_map, f.segments)
        elif f.semantic_path is not None:
            sem = read_label_map(f.semantic_path)
            self._check_size(i, f.semantic_path, sem, "semantic PNG")
            inst = np.zeros_like(sem)
            if f.instance_path is not None:
                inst = read_label_map(f.instance_path)
                self._check_size(i, f.instance_path, inst, "instance PNG")
            unknown = np.setdiff1d(np.unique(sem), [0] + [c.id for c in self.categories])
            if unknown.size:
                raise InputError(f.semantic_path, f"unknown category ids {unknown[:5].tolist()} (not in categories)")
            things = np.isin(sem, self.thing_ids)
            inst = np.where(things, inst, 0).astype(np.int32)
            # Segments are the distinct (class, instance) pairs of the frame; void stays 0.
            key = sem.astype(np.int64) * 65536 + inst
            _, seg = np.unique(key, return_inverse=True)
            seg = np.where(sem > 0, seg.reshape(sem.shape) + 1, 0).astype(np.int32)
            labels = PanopticLabels(sem.astype(np.int32), inst, seg, np.ones(sem.shape, np.float32))
        else:
            raise InputError(self.root / "transforms.json", f"frame {f.file_path!r} has no pseudo-labels")
        if f.confidence_path is not None:
            conf = _read_confidence(f.confidence_path)
            self._check_size(i, f.confidence_path, conf, "confidence map")
            labels.confidence = labels.confidence * conf
        return labels

    def gt_labels(self, i: int) -> PanopticLabels:
        """Ground-truth panoptic labels of frame ``i`` (scene-consistent instance ids)."""
        f = self.frames[i]
        if f.gt_panoptic_path is None:
            raise InputError(self.root / "transforms.json", f"frame {f.file_path!r} has no ground truth")
        seg_map = read_panoptic_png(f.gt_panoptic_path)
        self._check_size(i, f.gt_panoptic_path, seg_map, "GT panoptic PNG")
        return self._labels_from_segments(f.gt_panoptic_path, seg_map, f.gt_segments)

    def _labels_from_segments(self, path: Path, seg_map: np.ndarray, segments: dict[int, Segment]) -> PanopticLabels:
        ids = np.unique(seg_map)
        missing = [int(s) for s in ids if s != 0 and s not in segments]
        if missing:
            raise InputError(path, f"segment ids {missing[:5]} are in the PNG but not in its segments_info")
        cats = self.category_by_id
        lut_ids = np.array([0] + list(segments), np.int64)
        lut_sem = np.array([0] + [s.category_id for s in segments.values()], np.int32)
        lut_thing = np.array([False] + [cats[s.category_id].isthing for s in segments.values()])
        lut_score = np.array([0.0] + [s.score for s in segments.values()], np.float32)
        order = np.argsort(lut_ids)
        pos = order[np.searchsorted(lut_ids[order], seg_map)]
        sem = lut_sem[pos]
        inst = np.where(lut_thing[pos], seg_map, 0).astype(np.int32)
        return PanopticLabels(sem, inst, seg_map.astype(np.int32), lut_score[pos])

    def depth(self, i: int) -> np.ndarray | None:
        """``float32 [H, W]`` depth in world units along the optical axis (0 = unknown), or None."""
        f = self.frames[i]
        if f.depth_path is None:
            return None
        d = read_depth(f.depth_path, self.depth_unit_scale_factor)
        self._check_size(i, f.depth_path, d, "depth map")
        return d

    def gt_depth(self, i: int) -> np.ndarray | None:
        """``float32 [H, W]`` exact depth of frame ``i`` for evaluation (``gt_depth_file_path``), or None."""
        f = self.frames[i]
        if f.gt_depth_path is None:
            return None
        d = read_depth(f.gt_depth_path, self.depth_unit_scale_factor)
        self._check_size(i, f.gt_depth_path, d, "GT depth map")
        return d

    def mask(self, i: int) -> np.ndarray | None:
        """``bool [H, W]`` pixels to train on (nerfstudio's ``mask_path``: 0 = ignore), or None."""
        f = self.frames[i]
        if f.mask_path is None:
            return None
        m = read_label_map(f.mask_path) > 0
        self._check_size(i, f.mask_path, m, "mask")
        return m

    def sparse_points(self) -> SparsePoints | None:
        """The scene's sparse points (``sparse_points`` in ``transforms.json``), validated; ``obs_frame``
        indexes ``self.frames``. None when the scene has none."""
        if self.sparse_points_paths is None:
            return None
        return read_sparse_points(*self.sparse_points_paths, frame_names=[f.name for f in self.frames])

    def mvs_depth(self, i: int) -> tuple[np.ndarray, np.ndarray] | None:
        """Multi-view-stereo ``(depth, sigma)`` of frame ``i`` (``float32 [H, W]`` world units, 0 = none),
        or None when the frame has none."""
        f = self.frames[i]
        if f.mvs_depth_path is None:
            return None
        d = read_depth(f.mvs_depth_path, self.depth_unit_scale_factor)
        self._check_size(i, f.mvs_depth_path, d, "MVS depth map")
        if f.mvs_sigma_path is None:
            raise InputError(self.root / "transforms.json", f"frame {f.file_path!r} has mvs_depth_file_path "
                                                            "but no mvs_sigma_file_path")
        s = read_depth(f.mvs_sigma_path, self.depth_unit_scale_factor)
        self._check_size(i, f.mvs_sigma_path, s, "MVS sigma map")
        if np.any((d > 0) & (s <= 0)):
            raise InputError(f.mvs_sigma_path, "sigma must be positive wherever the MVS depth is")
        return d, s

    def mvs_support(self, i: int) -> np.ndarray | None:
        """How many source views confirmed each multi-view-stereo depth of frame ``i`` (``int32 [H, W]``,
        0 where there is no depth), or None when the frame does not record it."""
        f = self.frames[i]
        if f.mvs_support_path is None:
            return None
        n = read_label_map(f.mvs_support_path)
        self._check_size(i, f.mvs_support_path, n, "MVS support map")
        return n

    def gt_points(self) -> dict[str, np.ndarray] | None:
        """``gt/points.ply`` as arrays (``xyz``, ``semantic``, ``instance``), or None."""
        if self.gt_points_path is None:
            return None
        pts = read_labelled_ply(self.gt_points_path)
        for key in ("semantic", "instance"):
            if key not in pts:
                raise InputError(self.gt_points_path, f"GT points need an int {key!r} vertex property")
        return pts

    def validate(self, progress: bool = False) -> None:
        """Decode every file once and raise on the first problem (sizes, ids, readability)."""
        for i in progress_bar(range(len(self)), desc="validate scene", disable=not progress):
            self.image(i)
            if self.has_pseudo_labels:
                self.pseudo_labels(i)
            if self.frames[i].gt_panoptic_path is not None:
                self.gt_labels(i)
            self.depth(i)
            self.gt_depth(i)
            self.mask(i)
            self.mvs_depth(i)
            self.mvs_support(i)
        self.gt_points()
        self.sparse_points()


# --------------------------------------------------------------------------------------------- reading
def _read_confidence(path: Path) -> np.ndarray:
    if path.suffix == ".npy":
        try:
            c = np.load(path).astype(np.float32)
        except (OSError, ValueError) as exc:
            raise InputError(path, f"not a readable .npy confidence map ({exc})") from exc
    else:
        c = read_unit_map(path)
    if not np.all(np.isfinite(c)) or c.min(initial=0) < 0 or c.max(initial=0) > 1:
        raise InputError(path, "confidence must lie in [0, 1]")
    return c


def _number(meta: dict, key: str, where: Path, field_name: str, default: Any = None) -> float:
    val = meta.get(key, default)
    if val is None:
        raise InputError(where, f"{field_name}: missing")
    try:
        out = float(val)
    except (TypeError, ValueError):
        raise InputError(where, f"{field_name}: not a number ({val!r})") from None
    if not math.isfinite(out):
        raise InputError(where, f"{field_name}: not finite")
    return out


def _segments_by_file(coco: Any, where: Path, categories: dict[int, Category]) -> dict[str, dict[int, Segment]]:
    if not isinstance(coco, dict) or not isinstance(coco.get("annotations"), list):
        raise InputError(where, "annotations: missing (expected COCO panoptic JSON)")
    out: dict[str, dict[int, Segment]] = {}
    for a, ann in enumerate(coco["annotations"]):
        if not isinstance(ann, dict) or "file_name" not in ann:
            raise InputError(where, f"annotations[{a}].file_name: missing")
        segs: dict[int, Segment] = {}
        for s, info in enumerate(ann.get("segments_info", [])):
            try:
                sid, cid = int(info["id"]), int(info["category_id"])
                score = float(info.get("score", 1.0))
            except (KeyError, TypeError, ValueError):
                raise InputError(where, f"annotations[{a}].segments_info[{s}]: needs integer id and category_id") from None
            if cid not in categories:
                raise InputError(where, f"annotations[{a}].segments_info[{s}].category_id: unknown category id {cid}")
            if not (0.0 <= score <= 1.0):
                raise InputError(where, f"annotations[{a}].segments_info[{s}].score: {score} is not in [0, 1]")
            if sid <= 0:
                raise InputError(where, f"annotations[{a}].segments_info[{s}].id: must be > 0 (0 is void)")
            segs[sid] = Segment(sid, cid, score, int(info.get("iscrowd", 0)))
        out[os.path.basename(str(ann["file_name"]))] = segs
    return out


def _resolve(root: Path, rel: Any, where: Path, field_name: str, must_exist: bool = True) -> Path:
    if not isinstance(rel, str) or not rel:
        raise InputError(where, f"{field_name}: must be a non-empty path string")
    p = (root / rel) if not os.path.isabs(rel) else Path(rel)
    if must_exist and not p.is_file():
        raise InputError(p, f"file not found (from {field_name} in {where.name})")
    return p


def frame_pose(frame: dict, where: Path, k: int) -> np.ndarray:
    """Frame ``k``'s ``transform_matrix`` as a 4x4 rigid camera-to-world (OpenGL axes; a 3x4 gets its last row),
    or an :class:`InputError` naming ``where`` and the frame."""
    try:
        c2w = np.asarray(frame.get("transform_matrix"), dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(where, f"frames[{k}].transform_matrix: not a 4x4 matrix of numbers") from None
    if c2w.shape == (3, 4):
        c2w = np.vstack([c2w, [0.0, 0.0, 0.0, 1.0]])
    if c2w.shape != (4, 4):
        raise InputError(where, f"frames[{k}].transform_matrix: must be 4x4 (got shape {c2w.shape})")
    if not np.all(np.isfinite(c2w)):
        raise InputError(where, f"frames[{k}].transform_matrix: not finite")
    if not is_rigid(c2w, atol=1e-3):
        raise InputError(where, f"frames[{k}].transform_matrix: not a rigid transform (rotation must be "
                                "orthonormal with det +1)")
    return c2w


def _intrinsics(meta: dict, frame: dict, where: Path, k: int) -> tuple[float, ...]:
    def get(key: str, default: Any = None) -> float:
        if key in frame:
            return _number(frame, key, where, f"frames[{k}].{key}")
        return _number(meta, key, where, key, default)

    w, h = get("w"), get("h")
    if "fl_x" in frame or "fl_x" in meta:
        fx = get("fl_x")
        fy = get("fl_y", fx if "fl_y" not in frame and "fl_y" not in meta else None)
    elif "camera_angle_x" in meta:  # NeRF-synthetic style
        fx = 0.5 * w / math.tan(0.5 * _number(meta, "camera_angle_x", where, "camera_angle_x"))
        fy = fx
    else:
        raise InputError(where, "fl_x: missing (give fl_x fl_y cx cy w h at top level or per frame)")
    cx, cy = get("cx", w / 2), get("cy", h / 2)
    if w < 1 or h < 1 or w != int(w) or h != int(h):
        raise InputError(where, f"w/h: image size must be positive integers (got {w} x {h})")
    if fx <= 0 or fy <= 0:
        raise InputError(where, f"fl_x/fl_y: focal lengths must be positive (got {fx}, {fy})")
    if not (0 <= cx <= w and 0 <= cy <= h):
        raise InputError(where, f"cx/cy: principal point ({cx}, {cy}) lies outside the {int(w)}x{int(h)} image")
    return fx, fy, cx, cy, w, h


#: Every distortion coefficient a ``transforms.json`` may give by name (nerfstudio's keys).
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")


def _distortion(meta: dict, frame: dict, where: Path, k: int) -> dict[str, tuple[float, str]]:
    """The frame's distortion coefficients by name, each with the field it came from (for errors): the
    frame's own value first, then the top level's."""
    out = {}
    for key in DISTORTION_KEYS:
        if key in frame:
            out[key] = (_number(frame, key, where, f"frames[{k}].{key}"), f"frames[{k}].{key}")
        elif key in meta:
            out[key] = (_number(meta, key, where, key), key)
    return out


def _camera_model(meta: dict, coefficients: list[dict[str, tuple[float, str]]], where: Path) -> str:
    """The scene's camera model, checked against the distortion coefficients the frames give.

    ``camera_model`` absent: ``PINHOLE`` when every coefficient is 0, else ``OPENCV`` — nerfstudio applies
    ``k1 k2 k3 p1 p2`` to every perspective camera, whatever its model, so a capture with coefficients and no
    model is distorted. A non-zero coefficient the model does not use (``k4`` under ``OPENCV``, where nerfstudio
    reads it as an r^8 term OpenCV lacks; ``p1 p2`` under ``OPENCV_FISHEYE``; any under ``PINHOLE``) is an
    error rather than being dropped.
    """
    if "camera_model" in meta:
        model = str(meta["camera_model"])
        if model not in CAMERA_MODELS:
            raise InputError(where, f"camera_model: {model!r} is not one of {sorted(CAMERA_MODELS)}")
    else:
        used = sorted({key for coeffs in coefficients for key, (value, _) in coeffs.items() if value != 0.0},
                      key=DISTORTION_KEYS.index)
        model = "OPENCV" if used else "PINHOLE"
        if used and str(where) not in _NOTED_DEFAULT_MODEL:
            _NOTED_DEFAULT_MODEL.add(str(where))
            print(f"lift3d: note: {where}: camera_model is missing but {', '.join(used)} "
                  f"{'is' if len(used) == 1 else 'are'} non-zero: read as camera_model OPENCV, as nerfstudio "
                  "does", file=sys.stderr)
    for coeffs in coefficients:
        for key, (value, field_name) in coeffs.items():
            if value != 0.0 and key not in CAMERA_MODELS[model]:
                raise InputError(where, f"{field_name}: {value} is non-zero, but camera_model {model} has no "
                                        f"{key} (it uses {' '.join(CAMERA_MODELS[model]) or 'no distortion'}); "
                                        "undistort the images or name the right camera_model")
    return model


# Scenes whose missing camera_model was already reported (each is noted once per process, not on every load).
_NOTED_DEFAULT_MODEL: set[str] = set()


def read_transforms(root: str | Path) -> tuple[Path, dict]:
    """The path and content of a scene folder's ``transforms.json``: an object with a non-empty ``frames``
    list (what every reader of a scene folder needs before anything else).

    Raises
    ------
    InputError
        The folder or the file is missing, the file is not JSON, or it has no frames.
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(root, "scene folder not found")
    tpath = root / "transforms.json"
    meta = read_json(tpath)
    if not isinstance(meta, dict):
        raise InputError(tpath, "must hold a JSON object")
    if not isinstance(meta.get("frames"), list) or not meta["frames"]:
        raise InputError(tpath, "frames: missing or empty")
    return tpath, meta


def cameras_from_transforms(meta: dict, where: Path) -> Cameras:
    """The cameras of a ``transforms.json`` (as read by :func:`read_transforms`), checked.

    :func:`load_scene` reads its cameras with this; it is public for readers that need the poses and
    intrinsics of a folder that has no pseudo-labels yet (``lift3d label --geometric``).

    Parameters
    ----------
    meta : dict
        The content of ``transforms.json``.
    where : Path
        The file, named in errors.

    Returns
    -------
    Cameras
        One camera per frame, in the order of ``frames``.

    Raises
    ------
    InputError
        Unknown camera model, a frame that is not an object, a pose that is not a finite rigid 4x4 (or 3x4)
        matrix, missing or invalid intrinsics.
    """
    frames_raw = meta["frames"]
    if "distortion_params" in meta or any(isinstance(f, dict) and "distortion_params" in f for f in frames_raw):
        # nerfstudio's unnamed list (k1 k2 k3 k4 p1 p2, or 12 values for FISHEYE624): refused, not dropped.
        raise InputError(where, "distortion_params: not read; give the coefficients by name (k1 k2 k3 k4 p1 p2), "
                                "or convert the file with `lift3d convert --from nerfstudio`")
    c2ws, intr, coefficients = [], [], []
    for k, fr in enumerate(frames_raw):
        if not isinstance(fr, dict):
            raise InputError(where, f"frames[{k}]: must be an object")
        c2ws.append(frame_pose(fr, where, k))
        intr.append(_intrinsics(meta, fr, where, k))
        coefficients.append(_distortion(meta, fr, where, k))
    camera_model = _camera_model(meta, coefficients, where)
    # Cameras keeps OpenCV's order: k1 k2 p1 p2 k3 (OPENCV) or k1 k2 k3 k4 (OPENCV_FISHEYE), zeros after.
    distortion = np.zeros((len(frames_raw), 5))
    for k, coeffs in enumerate(coefficients):
        for j, key in enumerate(CAMERA_MODELS[camera_model]):
            distortion[k, j] = coeffs.get(key, (0.0, ""))[0]
    intr_a = np.asarray(intr)
    return Cameras(
        c2w=np.stack(c2ws), fx=intr_a[:, 0], fy=intr_a[:, 1], cx=intr_a[:, 2], cy=intr_a[:, 3],
        width=intr_a[:, 4], height=intr_a[:, 5], camera_model=camera_model, distortion=distortion,
    )


def load_scene(root: str | Path) -> Scene:
    """Read and check a scene folder.

    Parameters
    ----------
    root : str or Path
        The folder holding ``transforms.json``.

    Returns
    -------
    Scene

    Raises
    ------
    InputError
        One line naming the file and the field that is wrong.

    Examples
    --------
    >>> from lift3d.data.scene import load_scene          # doctest: +SKIP
    >>> scene = load_scene("scenes/room0")                 # doctest: +SKIP
    >>> scene.image(0).shape, len(scene.split("train"))    # doctest: +SKIP
    ((128, 128, 3), 52)
    """
    root = Path(root)
    tpath, meta = read_transforms(root)
    frames_raw = meta["frames"]

    cameras = cameras_from_transforms(meta, tpath)

    # Categories: transforms.json first, else the COCO panoptic JSON's own list. A scene without any labels
    # yet (written to be labelled afterwards) may have none, or an empty list.
    pan_json_path = root / str(meta.get("panoptic_json", "panoptic.json"))
    pan_json = read_json(pan_json_path) if pan_json_path.is_file() else None
    gt_json_path = root / "gt" / "panoptic.json"
    if meta.get("categories", []) != [] or not _without_labels(root, meta, pan_json, gt_json_path):
        if "categories" in meta:
            categories = parse_categories(meta["categories"], tpath)
        elif isinstance(pan_json, dict) and "categories" in pan_json:
            categories = parse_categories(pan_json["categories"], pan_json_path)
        else:
            raise InputError(tpath, "categories: missing (and panoptic.json has none)")
    else:
        categories = []
    cat_by_id = {c.id: c for c in categories}
    segs_by_file = _segments_by_file(pan_json, pan_json_path, cat_by_id) if pan_json is not None else {}
    gt_segs_by_file = (
        _segments_by_file(read_json(gt_json_path), gt_json_path, cat_by_id) if gt_json_path.is_file() else {}
    )

    frames: list[Frame] = []
    seen_paths: dict[str, int] = {}
    for k, fr in enumerate(frames_raw):
        fp = fr.get("file_path")
        img_path = _resolve(root, fp, tpath, f"frames[{k}].file_path")
        if fp in seen_paths:
            raise InputError(tpath, f"frames[{k}].file_path: duplicate frame {fp!r} (also frames[{seen_paths[fp]}])")
        seen_paths[fp] = k
        name = Path(fp).stem
        frame = Frame(name=name, file_path=fp, image_path=img_path)

        pan = fr.get("panoptic_file_path")
        if pan is None and "semantic_file_path" not in fr and (root / "panoptic" / f"{name}.png").is_file():
            pan = f"panoptic/{name}.png"
        if pan is not None:
            frame.panoptic_path = _resolve(root, pan, tpath, f"frames[{k}].panoptic_file_path")
            if pan_json is None:
                raise InputError(pan_json_path, "file not found (needed for the panoptic PNGs' segments_info)")
            key = os.path.basename(pan)
            if key not in segs_by_file:
                raise InputError(pan_json_path, f"no annotation with file_name {key!r} (frames[{k}])")
            frame.segments = segs_by_file[key]
        elif "semantic_file_path" in fr:
            frame.semantic_path = _resolve(root, fr["semantic_file_path"], tpath, f"frames[{k}].semantic_file_path")
            if "instance_file_path" in fr:
                frame.instance_path = _resolve(root, fr["instance_file_path"], tpath, f"frames[{k}].instance_file_path")
        if "confidence_file_path" in fr:
            frame.confidence_path = _resolve(root, fr["confidence_file_path"], tpath, f"frames[{k}].confidence_file_path")

        gt = fr.get("gt_panoptic_file_path")
        if gt is None and (root / "gt" / "panoptic" / f"{name}.png").is_file():
            gt = f"gt/panoptic/{name}.png"
        if gt is not None:
            frame.gt_panoptic_path = _resolve(root, gt, tpath, f"frames[{k}].gt_panoptic_file_path")
            if not gt_json_path.is_file():
                raise InputError(gt_json_path, "file not found (needed for the GT panoptic PNGs' segments_info)")
            key = os.path.basename(gt)
            if key not in gt_segs_by_file:
                raise InputError(gt_json_path, f"no annotation with file_name {key!r} (frames[{k}])")
            frame.gt_segments = gt_segs_by_file[key]
        if "depth_file_path" in fr:
            frame.depth_path = _resolve(root, fr["depth_file_path"], tpath, f"frames[{k}].depth_file_path")
        if "mask_path" in fr:
            frame.mask_path = _resolve(root, fr["mask_path"], tpath, f"frames[{k}].mask_path")
        if "gt_depth_file_path" in fr:
            frame.gt_depth_path = _resolve(root, fr["gt_depth_file_path"], tpath, f"frames[{k}].gt_depth_file_path")
        if "gt_transform_matrix" in fr:
            try:
                gt_c2w = np.asarray(fr["gt_transform_matrix"], dtype=np.float64)
            except (TypeError, ValueError):
                gt_c2w = np.zeros(0)
            if gt_c2w.shape != (4, 4) or not np.all(np.isfinite(gt_c2w)) or not is_rigid(gt_c2w, atol=1e-3):
                raise InputError(tpath, f"frames[{k}].gt_transform_matrix: must be a finite rigid 4x4 matrix")
            frame.gt_c2w = gt_c2w
        for key in ("mvs_depth_file_path", "mvs_sigma_file_path", "mvs_support_file_path"):
            if key in fr:
                setattr(frame, key.replace("_file", ""), _resolve(root, fr[key], tpath, f"frames[{k}].{key}"))
        frames.append(frame)

    if len({f.name for f in frames}) != len(frames):
        raise InputError(tpath, "frames: two frames share a file name stem (outputs are named by stem)")

    splits = _splits(meta, frames, tpath)

    scene_box = None
    if "scene_box" in meta:
        sb = meta["scene_box"]
        try:
            aabb = np.asarray(sb["aabb"], np.float64)
            kind = str(sb.get("type", "bounded"))
        except (TypeError, KeyError, ValueError):
            raise InputError(tpath, "scene_box: needs 'aabb' [[x,y,z],[x,y,z]]") from None
        if aabb.shape != (2, 3) or not np.all(np.isfinite(aabb)) or np.any(aabb[1] <= aabb[0]):
            raise InputError(tpath, "scene_box.aabb: must be [[min x,y,z],[max x,y,z]] with max > min")
        if kind not in ("bounded", "unbounded"):
            raise InputError(tpath, f"scene_box.type: {kind!r} is not 'bounded' or 'unbounded'")
        scene_box = SceneBox(kind, aabb)

    depth_scale = _number(meta, "depth_unit_scale_factor", tpath, "depth_unit_scale_factor", 1e-3)
    if depth_scale <= 0:  # would silently turn every depth into 0 or negative distances
        raise InputError(tpath, f"depth_unit_scale_factor: must be positive (got {depth_scale})")
    gt_points = root / "gt" / "points.ply"
    sparse = None
    if "sparse_points" in meta:
        sp = meta["sparse_points"]
        if not isinstance(sp, dict) or not all(isinstance(sp.get(key), str) for key in ("points", "observations")):
            raise InputError(tpath, "sparse_points: needs 'points' and 'observations' file paths")
        sparse = (_resolve(root, sp["points"], tpath, "sparse_points.points"),
                  _resolve(root, sp["observations"], tpath, "sparse_points.observations"))
    return Scene(
        root=root, frames=frames, cameras=cameras, categories=categories, splits=splits, scene_box=scene_box,
        depth_unit_scale_factor=depth_scale, gt_points_path=gt_points if gt_points.is_file() else None,
        sparse_points_paths=sparse,
    )


def _without_labels(root: Path, meta: dict, pan_json: Any, gt_json_path: Path) -> bool:
    """Whether a scene holds no labels at all, neither pseudo-labels nor ground truth (so it needs no
    categories): no COCO panoptic JSON, no ``panoptic/`` PNGs, no frame naming a label file."""
    if pan_json is not None or gt_json_path.is_file() or (root / "panoptic").is_dir():
        return False
    keys = ("panoptic_file_path", "semantic_file_path", "gt_panoptic_file_path")
    return not any(isinstance(fr, dict) and any(k in fr for k in keys) for fr in meta["frames"])


def _splits(meta: dict, frames: list[Frame], where: Path) -> dict[str, np.ndarray]:
    """Frame indices of the ``train``/``val``/``test`` splits.

    Explicit lists come from ``train_filenames``, ``val_filenames`` and ``test_filenames`` (entries are
    frame ``file_path``s; an entry that matches no path is matched by file-name stem). An explicit list
    must be non-empty and name existing frames.

    Default rule for what ``transforms.json`` leaves out (the nerfstudio/LLFF habit):

    * no ``train`` and no ``test``: every 8th frame (indices 0, 8, 16, ...) is ``test``, the rest ``train``;
    * ``test`` given, no ``train``: ``train`` is every frame not in ``test`` (every frame when ``test``
      holds them all);
    * ``train`` given, no ``test``: ``test`` is every frame not in ``train``; when ``train`` already holds
      every frame, ``test`` is every ``len(train) // 8``-th train frame (so it overlaps ``train``);
    * no ``val``: ``val`` is ``test``;
    * a single-frame scene: that frame is ``train``, ``val`` and ``test``.
    """
    index = {f.file_path: i for i, f in enumerate(frames)}
    by_name = {f.name: i for i, f in enumerate(frames)}
    splits: dict[str, np.ndarray] = {}
    for s in SPLITS:
        key = f"{s}_filenames"
        if key not in meta:
            continue
        names = meta[key]
        if not isinstance(names, list) or not names:
            raise InputError(where, f"{key}: empty split")
        idx = []
        for n in names:
            if not isinstance(n, str):
                raise InputError(where, f"{key}: entries must be file_path strings (got {n!r})")
            if n in index:
                idx.append(index[n])
            elif Path(n).stem in by_name:
                idx.append(by_name[Path(n).stem])
            else:
                raise InputError(where, f"{key}: {n!r} is not one of the frames")
        splits[s] = np.asarray(idx, dtype=np.int64)
    n = len(frames)
    if "train" not in splits:
        # nerfstudio/LLFF habit: every 8th frame is held out for testing, the rest train.
        held = set(splits.get("test", np.arange(0, n, 8)).tolist()) if n > 1 else set()
        splits["train"] = np.asarray([i for i in range(n) if i not in held] or list(range(n)), np.int64)
    if "test" not in splits:
        rest = np.setdiff1d(np.arange(n), splits["train"])
        splits["test"] = rest if rest.size else splits["train"][:: max(1, len(splits["train"]) // 8)]
    if "val" not in splits:
        splits["val"] = splits["test"]
    return splits


# --------------------------------------------------------------------------------------------- writing
@dataclass(frozen=True)
class FramePseudoLabels:
    """A frame's 2D pseudo-labels as :meth:`SceneWriter.add_frame` writes them: ``panoptic`` segment ids with their
    ``segments`` (COCO panoptic), or else ``semantic`` + ``instance`` maps (the two-PNG layout).

    Attributes
    ----------
    panoptic : np.ndarray, optional
        ``int [H, W]`` per-frame segment ids, 0 = void (``panoptic/<name>.png``).
    segments : iterable of Segment
        One per non-zero id of ``panoptic`` (its category and score).
    semantic, instance : np.ndarray, optional
        ``int [H, W]`` category ids and instance ids, when there is no ``panoptic`` (``semantics/``,
        ``instances/``).
    confidence : np.ndarray, optional
        ``[H, W]`` per-pixel confidence in [0, 1] (``confidence/<name>.png``, 16-bit).
    """

    panoptic: np.ndarray | None = None
    segments: Iterable[Segment] = ()
    semantic: np.ndarray | None = None
    instance: np.ndarray | None = None
    confidence: np.ndarray | None = None


@dataclass(frozen=True)
class FrameGroundTruth:
    """What evaluation reads of a frame, as :meth:`SceneWriter.add_frame` writes it.

    Attributes
    ----------
    panoptic : np.ndarray, optional
        ``int [H, W]`` GT segment ids, scene-consistent (``gt/panoptic/<name>.png``).
    segments : iterable of Segment
        One per non-zero id of ``panoptic``.
    depth : np.ndarray, optional
        ``[H, W]`` exact z-depth in metres (``gt/depth/<name>.png``, ``gt_depth_file_path``).
    c2w : np.ndarray, optional
        ``[4, 4]`` the true camera-to-world (OpenGL axes) when the written pose is noisy (``gt_transform_matrix``).
    """

    panoptic: np.ndarray | None = None
    segments: Iterable[Segment] = ()
    depth: np.ndarray | None = None
    c2w: np.ndarray | None = None


class SceneWriter:
    """Write a scene folder frame by frame (used by ``lift3d synth``, ``convert`` and ``label``).

    Parameters
    ----------
    root : str or Path
        Output folder (created).
    categories : list of Category
        The label vocabulary.
    image_ext : str
        ``.png`` (default, lossless) or ``.jpg``.
    depth_unit_scale_factor : float
        Metres per unit of the uint16 depth PNGs (1e-3 = millimetres; outdoor scenes want 1e-2).

    Examples
    --------
    >>> import numpy as np, tempfile
    >>> cats = [Category(1, "wall", False), Category(2, "chair", True)]
    >>> root = tempfile.mkdtemp()
    >>> with SceneWriter(root, cats) as w:
    ...     for k in range(2):
    ...         seg = np.ones((4, 6), np.int64); seg[:, 3:] = 5
    ...         labels = FramePseudoLabels(seg, [Segment(1, 1, 0.9), Segment(5, 2, 0.8)])
    ...         _ = w.add_frame(f"f{k}", np.zeros((4, 6, 3), np.uint8), np.eye(4), (5.0, 5.0, 3.0, 2.0), labels=labels)
    >>> load_scene(root).pseudo_labels(0).instance[0].tolist()
    [0, 0, 0, 5, 5, 5]
    """

    def __init__(
        self,
        root: str | Path,
        categories: list[Category],
        *,
        image_ext: str = ".png",
        depth_unit_scale_factor: float = 1e-3,
        camera_model: str = "PINHOLE",
        extra_meta: dict | None = None,
    ):
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self.categories = list(categories)
        self.image_ext = image_ext
        self.depth_unit_scale_factor = depth_unit_scale_factor
        self.camera_model = camera_model
        self.extra_meta = dict(extra_meta or {})
        self.frames: list[dict] = []
        self.annotations: list[dict] = []
        self.gt_annotations: list[dict] = []
        self.splits: dict[str, list[str]] = {}
        self.scene_box: SceneBox | None = None

    def __enter__(self) -> "SceneWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()

    def add_frame(
        self,
        name: str,
        image: np.ndarray,
        c2w: np.ndarray,
        intrinsics: tuple[float, float, float, float],
        *,
        labels: FramePseudoLabels | None = None,
        depth: np.ndarray | None = None,
        distortion: dict[str, float] | None = None,
        gt: FrameGroundTruth | None = None,
    ) -> str:
        """Add one frame. ``c2w`` is camera-to-world in OpenGL axes; ``intrinsics`` is ``(fx, fy, cx, cy)``.

        ``labels`` are the 2D pseudo-labels (none: a frame for ``lift3d label`` to label), ``depth`` the input
        depth map (metres), ``distortion`` OpenCV coefficients by name, ``gt`` what evaluation reads (GT panoptic
        labels, exact depth, the true pose when ``c2w`` is noisy). Returns the frame's ``file_path``."""
        labels = FramePseudoLabels() if labels is None else labels
        gt = FrameGroundTruth() if gt is None else gt
        h, w = image.shape[:2]
        file_path = f"images/{name}{self.image_ext}"
        write_rgb(self.root / file_path, image)
        fx, fy, cx, cy = (float(x) for x in intrinsics)
        fr: dict[str, Any] = {
            "file_path": file_path,
            "transform_matrix": np.asarray(c2w, float).tolist(),
            "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, "w": int(w), "h": int(h),
        }
        if distortion:
            fr.update({k: float(v) for k, v in distortion.items()})
        if labels.panoptic is not None:
            rel = f"panoptic/{name}.png"
            write_panoptic_png(self.root / rel, labels.panoptic)
            fr["panoptic_file_path"] = rel
            self.annotations.append(_annotation(name, len(self.frames), labels.panoptic, labels.segments))
        elif labels.semantic is not None:
            fr["semantic_file_path"] = f"semantics/{name}.png"
            write_label_map(self.root / fr["semantic_file_path"], labels.semantic)
            if labels.instance is not None:
                fr["instance_file_path"] = f"instances/{name}.png"
                write_label_map(self.root / fr["instance_file_path"], labels.instance)
        if labels.confidence is not None:
            fr["confidence_file_path"] = f"confidence/{name}.png"
            write_label_map(self.root / fr["confidence_file_path"],
                            np.round(np.clip(labels.confidence, 0, 1) * 65535))
        if gt.panoptic is not None:
            rel = f"gt/panoptic/{name}.png"
            write_panoptic_png(self.root / rel, gt.panoptic)
            fr["gt_panoptic_file_path"] = rel
            self.gt_annotations.append(_annotation(name, len(self.frames), gt.panoptic, gt.segments))
        if depth is not None:
            fr["depth_file_path"] = f"depth/{name}.png"
            write_depth(self.root / fr["depth_file_path"], depth, self.depth_unit_scale_factor)
        if gt.depth is not None:
            fr["gt_depth_file_path"] = f"gt/depth/{name}.png"
            write_depth(self.root / fr["gt_depth_file_path"], gt.depth, self.depth_unit_scale_factor)
        if gt.c2w is not None:
            fr["gt_transform_matrix"] = np.asarray(gt.c2w, float).tolist()
        self.frames.append(fr)
        return file_path

    def set_splits(self, train: list[str], val: list[str] | None = None, test: list[str] | None = None) -> None:
        """Splits as lists of frame ``file_path`` (as returned by :meth:`add_frame`)."""
        self.splits = {"train": list(train)}
        if val:
            self.splits["val"] = list(val)
        if test:
            self.splits["test"] = list(test)

    def set_scene_box(self, kind: str, aabb: np.ndarray) -> None:
        self.scene_box = SceneBox(kind, np.asarray(aabb, float))

    def write_gt_points(self, xyz: np.ndarray, semantic: np.ndarray, instance: np.ndarray,
                        rgb: np.ndarray | None = None) -> None:
        """``gt/points.ply``: observed surface points with scene-consistent semantic and instance ids."""
        write_labelled_ply(self.root / "gt" / "points.ply", xyz, rgb=rgb, semantic=semantic, instance=instance,
                           comments=["lift3d ground-truth points"])

    def close(self) -> None:
        """Write ``transforms.json`` and the COCO panoptic JSONs (atomically)."""
        cats = [c.to_json() for c in self.categories]
        meta: dict[str, Any] = {"camera_model": self.camera_model}
        meta.update(self.extra_meta)
        meta["depth_unit_scale_factor"] = self.depth_unit_scale_factor
        meta["categories"] = cats
        if self.scene_box is not None:
            meta["scene_box"] = self.scene_box.to_json()
        for s, names in self.splits.items():
            meta[f"{s}_filenames"] = names
        meta["frames"] = self.frames
        if self.annotations:
            write_json_atomic(self.root / "panoptic.json", _coco(self.annotations, self.frames, cats))
        if self.gt_annotations:
            write_json_atomic(self.root / "gt" / "panoptic.json", _coco(self.gt_annotations, self.frames, cats))
        write_json_atomic(self.root / "transforms.json", meta)


def _annotation(name: str, image_id: int, seg_map: np.ndarray, segments: Iterable[Segment]) -> dict:
    ids, counts = np.unique(np.asarray(seg_map), return_counts=True)
    area = dict(zip(ids.tolist(), counts.tolist()))
    return {
        "image_id": image_id,
        "file_name": f"{name}.png",
        "segments_info": [s.to_json(area.get(s.id, 0)) for s in segments],
    }


def _coco(annotations: list[dict], frames: list[dict], cats: list[dict]) -> dict:
    images = [{"id": i, "file_name": os.path.basename(f["file_path"]), "width": f["w"], "height": f["h"]}
              for i, f in enumerate(frames)]
    return {"images": images, "annotations": annotations, "categories": cats}
