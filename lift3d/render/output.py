"""Rendered images on disk: what ``lift3d render`` writes, and the camera paths it can follow.

Layout (``DIR`` = ``--output-dir``, ``<stem>`` = the frame's file-name stem)::

    DIR/rgb/<stem>.png            uint8 RGB
    DIR/depth/<stem>.png          uint16 z-depth in millimetres (world units / 1000), 0 = nothing hit / too far
    DIR/depth_vis/<stem>.png      colourised depth (turbo colour map, one range for all frames)
    DIR/semantic/<stem>.png       uint16 category ids (0 = void)
    DIR/semantic_vis/<stem>.png   the scene's category colours
    DIR/instance/<stem>.png       uint16 3D instance ids (on things: the exported object's id by default,
                                  see lift3d.export.renders; 0 on stuff and void)
    DIR/instance_vis/<stem>.png   one colour per instance id (the same in every frame), black = none
    DIR/panoptic/<stem>.png       COCO panoptic PNG (id = R + 256 G + 256² B)
    DIR/panoptic.json             COCO panoptic JSON of those PNGs (segments_info with area, bbox, score)
    DIR/confidence/<stem>.png     uint16 probability of the chosen class × 65535 (on request)

Panoptic segment ids follow the Cityscapes / Detectron2 convention ``category_id * label_divisor +
instance`` (``label_divisor`` = 1000 unless the model has 1000 or more instance channels; it is written
into ``panoptic.json``). The id of a segment is therefore a function of (class, 3D instance) only, so the
same object carries the same id in every frame and every render, and a stuff class is ``category_id *
label_divisor``.

Every file is written atomically (temporary file + rename): an interrupted render leaves complete images
only. ``panoptic.json`` is written once, after the last frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Sequence

import cv2
import numpy as np

from lift3d.data.cameras import Cameras, is_rigid
from lift3d.data.categories import Category
from lift3d.data.images import write_label_map, write_panoptic_png, write_rgb
from lift3d.errors import InputError
from lift3d.render.images import FrameRender
from lift3d.utils.atomic import write_json_atomic
from lift3d.utils.colors import hash_colors
from lift3d.utils.files import read_json

__all__ = [
    "OUTPUTS",
    "PREVIEWS",
    "DEFAULT_OUTPUTS",
    "RenderedOutputWriter",
    "CameraPath",
    "load_camera_path",
    "panoptic_segment_ids",
    "label_divisor_for",
    "category_palette",
    "instance_colors",
    "colorize_depth",
    "resolve_outputs",
]

#: Outputs ``lift3d render --outputs`` accepts (the ``*_vis`` previews may also be asked for alone).
OUTPUTS = ("rgb", "depth", "depth_vis", "semantic", "semantic_vis", "instance", "instance_vis", "panoptic",
           "confidence")
#: Preview written beside each exact output unless previews are switched off.
PREVIEWS = {"depth": "depth_vis", "semantic": "semantic_vis", "instance": "instance_vis"}
DEFAULT_OUTPUTS = ("rgb", "depth", "semantic", "instance", "panoptic")

#: Depth PNGs hold millimetres of the world unit (the scene folder's metres): 1 unit of the PNG = 1e-3.
DEPTH_PNG_UNIT = 1e-3
_DEPTH_PNG_MAX = 65535 * DEPTH_PNG_UNIT  # 65.535 world units; farther depth is written as 0


def resolve_outputs(requested: Iterable[str], previews: bool = True) -> list[str]:
    """Validate ``--outputs`` and add the colourised previews of depth / semantic / instance.

    Parameters
    ----------
    requested : iterable of str
        Names from :data:`OUTPUTS`.
    previews : bool
        Add ``depth_vis`` / ``semantic_vis`` / ``instance_vis`` for each exact output asked for.

    Returns
    -------
    list of str
        Distinct output names in the order of :data:`OUTPUTS`.

    Examples
    --------
    >>> resolve_outputs(["semantic", "rgb"])
    ['rgb', 'semantic', 'semantic_vis']
    >>> resolve_outputs(["semantic"], previews=False)
    ['semantic']
    """
    want = set()
    for name in requested:
        if name not in OUTPUTS:
            raise InputError("--outputs", f"unknown output {name!r} (choose from {', '.join(OUTPUTS)})")
        want.add(name)
        if previews and name in PREVIEWS:
            want.add(PREVIEWS[name])
    if not want:
        raise InputError("--outputs", "nothing to render (give at least one output)")
    return [o for o in OUTPUTS if o in want]


# --------------------------------------------------------------------------------------- colours and ids
def label_divisor_for(num_instance_channels: int) -> int:
    """Smallest power of ten ≥ 1000 that exceeds every instance id ``1..V``.

    Examples
    --------
    >>> label_divisor_for(32), label_divisor_for(1000)
    (1000, 10000)
    """
    div = 1000
    while div <= num_instance_channels:
        div *= 10
    return div


def panoptic_segment_ids(semantic: np.ndarray, instance: np.ndarray, label_divisor: int = 1000) -> np.ndarray:
    """Scene-consistent COCO panoptic segment ids: ``category * label_divisor + instance`` (0 = void).

    Because the id depends on nothing but the (class, instance) pair, instance ``i`` of class ``c`` has the
    same id in every frame; each stuff class is one segment ``c * label_divisor``.

    Parameters
    ----------
    semantic : np.ndarray
        ``[H, W]`` category ids, 0 = void.
    instance : np.ndarray
        ``[H, W]`` instance ids (0 on stuff); ignored where ``semantic`` is 0.
    label_divisor : int
        Must exceed every instance id.

    Returns
    -------
    np.ndarray
        ``int64 [H, W]`` segment ids.

    Examples
    --------
    >>> panoptic_segment_ids(np.array([[0, 2, 7]]), np.array([[5, 0, 3]])).tolist()
    [[0, 2000, 7003]]
    """
    sem = np.asarray(semantic, np.int64)
    inst = np.asarray(instance, np.int64)
    if inst.size and (inst.min() < 0 or inst.max() >= label_divisor):
        raise ValueError(f"instance ids must lie in [0, {label_divisor}) for label_divisor {label_divisor}")
    ids = np.where(sem > 0, sem * label_divisor + inst, 0)
    if ids.size and ids.max() >= 256**3:
        raise ValueError(f"category id {int(sem.max())} × {label_divisor} does not fit a COCO panoptic PNG (< 256³)")
    return ids


def category_palette(categories: Sequence[Category]) -> np.ndarray:
    """``uint8 [max_id + 1, 3]`` colour per category id (void and unknown ids black).

    Examples
    --------
    >>> category_palette([Category(2, "floor", False, (1, 2, 3))]).tolist()
    [[0, 0, 0], [0, 0, 0], [1, 2, 3]]
    """
    n = max([c.id for c in categories] + [0]) + 1
    lut = np.zeros((n, 3), np.uint8)
    for c in categories:
        lut[c.id] = c.color
    return lut


def instance_colors(n: int) -> np.ndarray:
    """``uint8 [n, 3]`` colours of instance ids ``0..n-1`` (:func:`lift3d.utils.colors.hash_colors`, the
    colour of an id in every picture lift3d draws); id 0 (no instance) is black.

    Examples
    --------
    >>> c = instance_colors(3); c[0].tolist(), len({tuple(x) for x in c.tolist()})
    ([0, 0, 0], 3)
    """
    out = hash_colors(np.arange(max(n, 1)))
    out[0] = 0
    return out


def colorize_depth(depth: np.ndarray, near: float, far: float) -> np.ndarray:
    """Turbo colour map of ``depth`` between ``near`` (red end) and ``far`` (blue end); 0 stays black.

    Parameters
    ----------
    depth : np.ndarray
        ``[H, W]`` depth, 0 = unknown.
    near, far : float
        Depth range mapped onto the colour map (clipped outside).

    Returns
    -------
    np.ndarray
        ``uint8 [H, W, 3]`` RGB.
    """
    d = np.asarray(depth, np.float64)
    span = max(far - near, 1e-9)
    # Near is drawn warm: invert so that small depths land at the red end of turbo.
    t = 1.0 - np.clip((d - near) / span, 0.0, 1.0)
    bgr = cv2.applyColorMap(np.round(t * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    rgb[~(d > 0)] = 0
    return rgb


# --------------------------------------------------------------------------------------- writer
@dataclass
class _SegmentStats:
    area: int
    conf_sum: float
    bbox: tuple[int, int, int, int]  # x, y, w, h


@dataclass
class RenderedOutputWriter:
    """Writes the frames of one render into ``output_dir`` (see the module docstring for the layout).

    Parameters
    ----------
    output_dir : Path
        Root folder; one sub-folder per output.
    outputs : sequence of str
        Names from :data:`OUTPUTS` (use :func:`resolve_outputs`).
    categories : sequence of Category
        Names, thing/stuff flags and colours of the category ids the model predicts.
    num_instance_channels : int
        ``V`` of the model (instance ids are ``1..V``); fixes the panoptic ``label_divisor``.
    depth_range : (float, float), optional
        ``(near, far)`` of the depth preview. By default taken from the first frame (its 2nd and 98th
        percentile of valid depth) and then kept, so a colour means the same depth in every frame.
    """

    output_dir: Path
    outputs: Sequence[str]
    categories: Sequence[Category]
    num_instance_channels: int = 0
    depth_range: tuple[float, float] | None = None
    frames_written: list[str] = field(default_factory=list, init=False)
    _annotations: list[dict] = field(default_factory=list, init=False, repr=False)
    _images: list[dict] = field(default_factory=list, init=False, repr=False)

    def __post_init__(self) -> None:
        self.output_dir = Path(self.output_dir)
        self.outputs = list(self.outputs)
        self.label_divisor = label_divisor_for(self.num_instance_channels)
        self._palette = category_palette(self.categories)
        self._inst_colors = instance_colors(max(self.num_instance_channels, 0) + 1)
        self._by_id = {c.id: c for c in self.categories}

    def path(self, output: str, stem: str) -> Path:
        """Where frame ``stem`` of ``output`` goes."""
        return self.output_dir / output / f"{stem}.png"

    def write(self, stem: str, frame: FrameRender) -> None:
        """Write every requested output of one rendered frame."""
        out = set(self.outputs)
        if "rgb" in out:
            write_rgb(self.path("rgb", stem), np.round(np.clip(frame.rgb, 0, 1) * 255).astype(np.uint8))
        if "depth" in out:
            d = np.asarray(frame.depth, np.float64)
            mm = np.where(np.isfinite(d) & (d > 0) & (d < _DEPTH_PNG_MAX + 0.5 * DEPTH_PNG_UNIT),
                          np.round(d / DEPTH_PNG_UNIT), 0)
            write_label_map(self.path("depth", stem), mm.astype(np.uint16))
        if "depth_vis" in out:
            if self.depth_range is None:
                self.depth_range = _depth_range(frame.depth)
            write_rgb(self.path("depth_vis", stem), colorize_depth(frame.depth, *self.depth_range))
        needs_labels = out & {"semantic", "semantic_vis", "instance", "instance_vis", "panoptic", "confidence"}
        if needs_labels and frame.semantic is None:
            raise InputError("--outputs", f"{', '.join(sorted(needs_labels))} need labels, but the model rendered none")
        sem = inst = None
        if frame.semantic is not None:
            sem = np.asarray(frame.semantic, np.int64)
            inst = np.zeros_like(sem) if frame.instance is None else np.asarray(frame.instance, np.int64)
            inst = np.where(sem > 0, inst, 0)  # instance 0 on void, whatever the head said
        if "semantic" in out:
            write_label_map(self.path("semantic", stem), sem)
        if "semantic_vis" in out:
            write_rgb(self.path("semantic_vis", stem), self._palette[np.clip(sem, 0, len(self._palette) - 1)])
        if "instance" in out:
            write_label_map(self.path("instance", stem), inst)
        if "instance_vis" in out:
            write_rgb(self.path("instance_vis", stem), self._inst_colors[np.clip(inst, 0, len(self._inst_colors) - 1)])
        if "confidence" in out and frame.confidence is not None:
            c = np.clip(np.nan_to_num(np.asarray(frame.confidence, np.float64)), 0, 1)
            write_label_map(self.path("confidence", stem), np.round(c * 65535).astype(np.uint16))
        if "panoptic" in out:
            self._write_panoptic(stem, sem, inst, frame.confidence)
        self.frames_written.append(stem)

    def _write_panoptic(self, stem: str, sem: np.ndarray, inst: np.ndarray, conf: np.ndarray | None) -> None:
        ids = panoptic_segment_ids(sem, inst, self.label_divisor)
        write_panoptic_png(self.path("panoptic", stem), ids)
        h, w = ids.shape
        conf = np.ones((h, w), np.float64) if conf is None else np.nan_to_num(np.asarray(conf, np.float64))
        image_id = len(self._images)
        file_name = f"{stem}.png"
        self._images.append({"id": image_id, "file_name": file_name, "width": int(w), "height": int(h)})
        segments = []
        for sid, st in _segment_stats(ids, conf).items():
            cat = sid // self.label_divisor
            c = self._by_id.get(cat)
            segments.append({
                "id": int(sid),
                "category_id": int(cat),
                "iscrowd": 0,
                "area": st.area,
                "bbox": list(st.bbox),
                # Mean over the segment's pixels of the rendered probability of its class.
                "score": float(st.conf_sum / st.area),
                "instance_id": int(sid % self.label_divisor),
                "isthing": int(bool(c.isthing)) if c is not None else int(sid % self.label_divisor > 0),
            })
        self._annotations.append({"image_id": image_id, "file_name": file_name, "segments_info": segments})

    def finish(self, extra_info: dict[str, Any] | None = None) -> Path | None:
        """Write ``panoptic.json`` (when panoptic was rendered); returns its path."""
        if "panoptic" not in self.outputs:
            return None
        doc = {
            "info": {"description": "lift3d render: panoptic labels of a panoptic radiance field",
                     "label_divisor": self.label_divisor,
                     "segment_id_rule": "category_id * label_divisor + instance_id (0 = void)",
                     **(extra_info or {})},
            "images": self._images,
            "annotations": self._annotations,
            "categories": [c.to_json() for c in self.categories],
        }
        path = self.output_dir / "panoptic.json"
        write_json_atomic(path, doc)
        return path


def _depth_range(depth: np.ndarray) -> tuple[float, float]:
    d = np.asarray(depth, np.float64)
    valid = d[np.isfinite(d) & (d > 0)]
    if valid.size == 0:
        return 0.0, 1.0
    near, far = np.percentile(valid, [2, 98])
    if far - near < 1e-6:
        far = near + 1.0
    return float(near), float(far)


def _segment_stats(ids: np.ndarray, conf: np.ndarray) -> dict[int, _SegmentStats]:
    """Area, confidence sum and bounding box of every non-void segment of one frame."""
    flat = ids.ravel()
    values, inverse, counts = np.unique(flat, return_inverse=True, return_counts=True)
    conf_sum = np.bincount(inverse, weights=conf.ravel(), minlength=len(values))
    h, w = ids.shape
    rows = np.repeat(np.arange(h), w)
    cols = np.tile(np.arange(w), h)
    big = np.iinfo(np.int64).max
    x0 = np.full(len(values), big)
    y0 = np.full(len(values), big)
    x1 = np.full(len(values), -1)
    y1 = np.full(len(values), -1)
    np.minimum.at(x0, inverse, cols)
    np.minimum.at(y0, inverse, rows)
    np.maximum.at(x1, inverse, cols)
    np.maximum.at(y1, inverse, rows)
    out = {}
    for k, sid in enumerate(values.tolist()):
        if sid == 0:
            continue
        out[int(sid)] = _SegmentStats(int(counts[k]), float(conf_sum[k]),
                                      (int(x0[k]), int(y0[k]), int(x1[k] - x0[k] + 1), int(y1[k] - y0[k] + 1)))
    return out


# --------------------------------------------------------------------------------------- camera paths
@dataclass
class CameraPath:
    """Cameras to render that are not frames of the scene, and the file stem of each."""

    cameras: Cameras
    stems: list[str]


_INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h")


def load_camera_path(path: str | Path, defaults: Cameras | None = None) -> CameraPath:
    """Read a camera path JSON (a small, documented subset of nerfstudio's format).

    Accepted layout::

        {
          "w": 640, "h": 480, "fl_x": 500.0, "fl_y": 500.0, "cx": 320.0, "cy": 240.0,   # defaults
          "camera_path": [                          # or "frames"; or the file is just this list
            {"camera_to_world": [[...], [...], [...], [0, 0, 0, 1]],   # 4x4 (or 16 numbers, row-major;
                                                                       #  "transform_matrix" also accepted)
             "fl_x": ..., "fov": 50.0, "name": "pan_000"}             # optional per-camera overrides
          ]
        }

    * Poses are camera-to-world in the **scene's world frame** (the frame of its ``transforms.json``), OpenGL
      axes (x right, y up, looking down −z), as nerfstudio writes them.
    * Intrinsics per camera or at top level: ``fl_x fl_y cx cy w h``; ``render_width``/``render_height`` are
      accepted for ``w``/``h``; a vertical field of view ``fov`` in degrees (nerfstudio's key) or a
      horizontal ``camera_angle_x`` in radians may replace ``fl_x``/``fl_y``. ``cx``/``cy`` default to the
      image centre. What is still missing comes from ``defaults`` (the scene's first camera).
    * ``name`` or ``file_path`` gives the output file stem; default ``frame_00000``, ``frame_00001``, ...

    Parameters
    ----------
    path : str or Path
        The JSON file.
    defaults : Cameras, optional
        Camera whose intrinsics (index 0) fill what the file leaves out.

    Returns
    -------
    CameraPath

    Raises
    ------
    InputError
        Naming the file and the field that is missing or malformed.
    """
    path = Path(path)
    doc = read_json(path, missing="camera path file not found")
    if isinstance(doc, list):
        top: dict = {}
        entries = doc
    elif isinstance(doc, dict):
        top = doc
        entries = doc.get("camera_path", doc.get("frames"))
    else:
        raise InputError(path, "must hold a JSON object or a list of cameras")
    if not isinstance(entries, list) or not entries:
        raise InputError(path, "camera_path: missing or empty (a list of cameras with camera_to_world)")

    c2ws, intr, stems = [], [], []
    for k, cam in enumerate(entries):
        where = f"camera_path[{k}]"
        if not isinstance(cam, dict):
            raise InputError(path, f"{where}: must be an object")
        raw = cam.get("camera_to_world", cam.get("transform_matrix"))
        if raw is None:
            raise InputError(path, f"{where}.camera_to_world: missing")
        try:
            m = np.asarray(raw, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(path, f"{where}.camera_to_world: not a matrix of numbers") from None
        if m.size == 16:
            m = m.reshape(4, 4)
        elif m.size == 12:
            m = np.vstack([m.reshape(3, 4), [0, 0, 0, 1]])
        else:
            raise InputError(path, f"{where}.camera_to_world: needs 4x4 (or 3x4) numbers, got {m.size}")
        if not is_rigid(m, atol=1e-3):
            raise InputError(path, f"{where}.camera_to_world: not a rigid transform (orthonormal rotation, det +1)")
        c2ws.append(m)
        intr.append(_camera_intrinsics(cam, top, defaults, path, where))
        stem = cam.get("name") or (Path(str(cam["file_path"])).stem if cam.get("file_path") else f"frame_{k:05d}")
        stems.append(str(stem))
    if len(set(stems)) != len(stems):
        raise InputError(path, "camera_path: two cameras share a name (outputs are named by it)")
    a = np.asarray(intr)
    cams = Cameras(c2w=np.stack(c2ws), fx=a[:, 0], fy=a[:, 1], cx=a[:, 2], cy=a[:, 3], width=a[:, 4], height=a[:, 5])
    return CameraPath(cams, stems)


def _camera_intrinsics(cam: dict, top: dict, defaults: Cameras | None, path: Path, where: str) -> tuple[float, ...]:
    def get(*keys: str) -> float | None:
        for src in (cam, top):
            for key in keys:
                if key in src and src[key] is not None:
                    try:
                        v = float(src[key])
                    except (TypeError, ValueError):
                        raise InputError(path, f"{where}.{key}: not a number ({src[key]!r})") from None
                    if not math.isfinite(v):
                        raise InputError(path, f"{where}.{key}: not finite")
                    return v
        return None

    w, h = get("w", "render_width"), get("h", "render_height")
    if w is None or h is None:
        if defaults is None:
            raise InputError(path, f"{where}: image size w/h missing (give w and h, or render_width/render_height)")
        w = float(defaults.width[0]) if w is None else w
        h = float(defaults.height[0]) if h is None else h
    if w < 1 or h < 1 or w != int(w) or h != int(h):
        raise InputError(path, f"{where}: image size must be positive integers (got {w} x {h})")
    fx, fy = get("fl_x"), get("fl_y")
    fov, angle_x = get("fov"), get("camera_angle_x")
    if fx is None and fy is None:
        if fov is not None:
            if not 0 < fov < 180:
                raise InputError(path, f"{where}.fov: vertical field of view must be in (0, 180) degrees")
            fx = fy = 0.5 * h / math.tan(math.radians(fov) / 2)
        elif angle_x is not None:
            fx = fy = 0.5 * w / math.tan(angle_x / 2)
        elif defaults is not None:
            # Keep the scene camera's field of view when the image size changes.
            fx = float(defaults.fx[0]) * w / float(defaults.width[0])
            fy = float(defaults.fy[0]) * h / float(defaults.height[0])
        else:
            raise InputError(path, f"{where}: fl_x missing (give fl_x/fl_y, fov or camera_angle_x)")
    fx = fy if fx is None else fx
    fy = fx if fy is None else fy
    if fx <= 0 or fy <= 0:
        raise InputError(path, f"{where}: focal lengths must be positive (got {fx}, {fy})")
    cx = get("cx")
    cy = get("cy")
    cx = w / 2 if cx is None else cx
    cy = h / 2 if cy is None else cy
    return fx, fy, cx, cy, w, h
