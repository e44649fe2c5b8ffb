"""``lift3d convert``: other capture layouts into the scene folder of docs/scene-format.md.

Every source reader (:mod:`~lift3d.convert.colmap`, :mod:`~lift3d.convert.panoptic_lifting`,
:mod:`~lift3d.convert.scannet`, :mod:`~lift3d.convert.open3d_rgbd`) only *describes* its frames as
:class:`FrameInput` records: where the image is, its camera-to-world pose in **OpenCV** axes, its intrinsics
and a loader for its 2D panoptic pseudo-labels. :func:`write_scene` then does the work that is the same for
all of them, in one place:

* reads each image and checks (or rescales) the intrinsics against its real size,
* converts the pose to ``transforms.json``'s OpenGL camera-to-world with
  :func:`lift3d.data.cameras.opencv_to_opengl` (the only axis conversion in lift3d),
* optionally downscales images, labels, confidence and depth together,
* writes everything through :class:`lift3d.data.scene.SceneWriter` and finally reads the result back with
  :func:`lift3d.data.scene.load_scene`, so a converted folder is always a valid scene.

Pixel convention: lift3d puts pixel ``(c, r)``'s centre at ``(c + 0.5, r + 0.5)`` (as COLMAP does). Readers
whose source puts pixel centres on integer coordinates (ScanNet calibration files, Panoptic Lifting's ray
generation, Open3D) add 0.5 to ``cx, cy`` before building their :class:`FrameInput`.
"""

from __future__ import annotations

import colorsys
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Sequence

import cv2
import numpy as np

from lift3d.convert import downscale
from lift3d.data.cameras import is_rigid, opencv_to_opengl
from lift3d.data.images import read_depth, read_label_map, read_rgb, write_label_map
from lift3d.data.scene import Category, FrameGroundTruth, FramePseudoLabels, Scene, SceneWriter, Segment, load_scene
from lift3d.errors import InputError
from lift3d.sfm.pose_check import FIX_MEANS, check_pose_convention, with_fix
from lift3d.utils.progress import progress_bar

#: The ``--from`` choices and the module that reads each.
SOURCES = {
    "colmap": "lift3d.convert.colmap",
    "nerfstudio": "lift3d.convert.nerfstudio",
    "instant-ngp": "lift3d.convert.nerfstudio",  # the same reader: the file's keys tell the two dialects apart
    "open3d": "lift3d.convert.open3d_rgbd",
    "panoptic-lifting": "lift3d.convert.panoptic_lifting",
    "scannet": "lift3d.convert.scannet",
}

# Files and folders a scene folder written by SceneWriter may hold. ``--overwrite`` removes exactly these
# (and nothing else the user may keep beside them): the reader discovers ``panoptic/<name>.png`` and
# ``gt/panoptic/<name>.png`` by name, so stale files from an earlier conversion would leak into the new one.
_SCENE_OUTPUTS = ("transforms.json", "panoptic.json", "images", "panoptic", "semantics", "instances",
                  "confidence", "depth", "masks", "gt", "sparse", "mvs")


@dataclass
class PanopticFrame:
    """2D panoptic labels of one frame, as :meth:`SceneWriter.add_frame` takes them.

    Attributes
    ----------
    panoptic : np.ndarray
        ``int64 [H, W]`` segment ids, 0 = void.
    segments : list of Segment
        One entry per non-zero id of ``panoptic`` (category and score).
    confidence : np.ndarray or None
        Optional ``float32 [H, W]`` per-pixel confidence in [0, 1].
    source : Path
        The file the labels came from (named in errors).
    """

    panoptic: np.ndarray
    segments: list[Segment]
    confidence: np.ndarray | None = None
    source: Path = Path(".")


@dataclass
class FrameInput:
    """Everything a source reader knows about one frame, before any pixel is read.

    Attributes
    ----------
    name : str
        Output frame name (file stem in the scene folder); unique per scene.
    image_path : Path
        The colour image.
    c2w_opencv : np.ndarray
        ``[4, 4]`` camera-to-world in **OpenCV** axes (x right, y down, looking down +z).
    pose_source : Path
        The file the pose came from (named when the pose is not rigid).
    intrinsics : tuple of float
        ``(fx, fy, cx, cy)`` in pixels of an image of size ``intrinsics_size``, lift3d convention (pixel
        centres at +0.5).
    intrinsics_size : tuple of int or None
        ``(w, h)`` the intrinsics refer to (None: the image's own size). When the image on disk has another
        size with the same aspect ratio, the intrinsics are scaled to it.
    distortion : dict
        Distortion coefficients by name (``k1 k2 p1 p2 k3`` or fisheye ``k1 k2 k3 k4``); empty for pinhole.
    labels : callable or None
        Returns the frame's :class:`PanopticFrame` pseudo-labels (called once, when the frame is written);
        None writes the frame without pseudo-labels, for ``lift3d label`` to add.
    gt : callable or None
        Returns ground-truth labels with scene-consistent segment ids, or None.
    depth_path : Path or None
        Optional depth image (uint16; ``depth_scale`` metres per unit).
    mask_path : Path or None
        Optional mask: non-zero pixels are **ignored** during training (Panoptic Lifting's ``invalid/``),
        unless ``mask_marks_valid``.
    mask_marks_valid : bool
        The mask's non-zero pixels are the ones to **train on** and zeros are ignored (nerfstudio's
        ``mask_path``).
    """

    name: str
    image_path: Path
    c2w_opencv: np.ndarray
    pose_source: Path
    intrinsics: tuple[float, float, float, float]
    intrinsics_size: tuple[int, int] | None
    labels: Callable[[], PanopticFrame] | None
    distortion: dict[str, float] = field(default_factory=dict)
    gt: Callable[[], PanopticFrame] | None = None
    depth_path: Path | None = None
    mask_path: Path | None = None
    mask_marks_valid: bool = False


@dataclass
class WriteOptions:
    """Options shared by every source (see ``lift3d convert --help``).

    ``depth_as_gt`` writes the source's depth maps as the frames' ``gt_depth_file_path`` (evaluation only)
    instead of ``depth_file_path`` (which training reads). ``frame_step`` keeps every N-th frame of the
    source, in its order, before the splits are made (:func:`every_nth`)."""

    downscale: int = 1
    frame_step: int = 1
    fix_poses: str | None = None
    """``--fix-poses``: a fix of :data:`lift3d.sfm.pose_check.FIXES` applied to every pose as the source stored it
    (``invert``, ``flip axes``, ``invert and flip axes``): a pose file written in another convention than its
    reader assumes."""
    pose_axes: str = "opencv"
    """The camera axes the source stores its poses in (``opengl`` for ``transforms.json`` files), for
    ``fix_poses`` and the check's advice."""
    check_poses: bool = True
    """Check the written poses against the images (:func:`lift3d.sfm.pose_check.check_pose_convention`)."""
    image_ext: str = ".png"
    depth_scale: float = 1e-3
    overwrite: bool = False
    progress: bool = True
    depth_as_gt: bool = False


def note(message: str) -> None:
    """Tell the user something worth knowing that is not an error (stderr, one line)."""
    print(f"lift3d convert: note: {message}", file=sys.stderr)


def distinct_color(index: int) -> tuple[int, int, int]:
    """A bright colour for category number ``index``; consecutive indices get well-separated hues."""
    hue = (index * 0.618033988749895) % 1.0  # golden-ratio steps spread hues evenly for any count
    r, g, b = colorsys.hsv_to_rgb(hue, 0.65, 0.95)
    return int(r * 255), int(g * 255), int(b * 255)


def parse_id_list(text: str | None, where: str) -> list[int] | None:
    """Parse ``--things 3,4,5`` (``none`` or an empty string means no thing classes)."""
    if text is None:
        return None
    text = text.strip()
    if text.lower() in ("", "none"):
        return []
    try:
        ids = [int(t) for t in text.replace(" ", ",").split(",") if t]
    except ValueError:
        raise InputError(where, f"expected comma-separated integer class ids (got {text!r})") from None
    if any(i < 1 for i in ids):
        raise InputError(where, "class ids must be >= 1 (0 is void)")
    return ids


def generic_categories(ids: Iterable[int], things: Sequence[int]) -> list[Category]:
    """Categories ``class_<id>`` for the given ids; ``isthing`` from ``things``."""
    thing_set = set(int(t) for t in things)
    return [Category(int(i), f"class_{int(i)}", int(i) in thing_set, distinct_color(k))
            for k, i in enumerate(sorted(set(int(i) for i in ids) - {0}))]


def every_nth(items: Sequence, step: int) -> list:
    """Frames 0, N, 2N, ... of a source (``--frame-step``): a video-rate capture's neighbours add little but
    time. Readers apply it to their frames in capture order, before :func:`split_every`.

    Examples
    --------
    >>> every_nth(list("abcdefg"), 3)
    ['a', 'd', 'g']
    """
    if step < 1:
        raise InputError("--frame-step", f"must be a positive integer (got {step})")
    return list(items)[::step]


def split_every(names: Sequence[str], test_every: int) -> dict[str, list[str]]:
    """nerfstudio's habit: every ``test_every``-th frame (0, N, 2N, ...) is held out for testing.

    ``test_every`` ≤ 0 keeps every frame for training (and no test split)."""
    if test_every <= 0 or len(names) < 2:
        return {"train": list(names)}
    test = [n for k, n in enumerate(names) if k % test_every == 0]
    train = [n for k, n in enumerate(names) if k % test_every != 0]
    return {"train": train, "test": test}


def read_matrix_txt(path: Path, what: str = "pose") -> np.ndarray:
    """Read a whitespace-separated matrix text file (ScanNet ``pose/*.txt``, ``intrinsic_color.txt``).

    Raises
    ------
    InputError
        When the file is missing, has non-numeric entries, or rows of different lengths.
    """
    if not path.is_file():
        raise InputError(path, "file not found")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot be read ({exc})") from exc
    rows = []
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            rows.append([float(t) for t in line.replace(",", " ").split()])
        except ValueError:
            raise InputError(path, f"line {lineno}: {what} entries must be numbers (got {line!r})") from None
    if not rows or len({len(r) for r in rows}) != 1:
        raise InputError(path, f"{what} must be a matrix with rows of equal length")
    return np.asarray(rows, dtype=np.float64)


def read_pose_txt(path: Path) -> np.ndarray | None:
    """A 4×4 (or 3×4) camera-to-world matrix from a text file; ``None`` when it is marked invalid.

    ScanNet writes ``-inf`` into every entry of a frame whose tracking failed; such frames are skipped by
    the callers rather than treated as malformed files."""
    m = read_matrix_txt(path, "pose")
    if m.shape == (3, 4):
        m = np.vstack([m, [0.0, 0.0, 0.0, 1.0]])
    if m.shape != (4, 4):
        raise InputError(path, f"pose must be a 4x4 camera-to-world matrix (got {m.shape[0]}x{m.shape[1]})")
    if not np.all(np.isfinite(m)):
        return None
    if not is_rigid(m, atol=1e-3):
        raise InputError(path, "pose is not a rigid transform (rotation must be orthonormal with det +1, "
                               "last row 0 0 0 1)")
    return m


def _resize(arr: np.ndarray, size: tuple[int, int], interpolation: int) -> np.ndarray:
    """``cv2.resize`` to ``(w, h)`` that keeps integer label maps exact (nearest neighbour on int32)."""
    if (arr.shape[1], arr.shape[0]) == tuple(size):
        return arr
    if interpolation == cv2.INTER_NEAREST and arr.dtype == np.int64:
        if arr.max(initial=0) < 2**31:
            return cv2.resize(arr.astype(np.int32), size, interpolation=cv2.INTER_NEAREST).astype(np.int64)
        # Ids past int32 (COCO panoptic ids go up to 256^3): index arithmetic instead of cv2.
        ys = np.minimum((np.arange(size[1]) + 0.5) * arr.shape[0] / size[1], arr.shape[0] - 1).astype(int)
        xs = np.minimum((np.arange(size[0]) + 0.5) * arr.shape[1] / size[0], arr.shape[1] - 1).astype(int)
        return arr[ys][:, xs]
    return cv2.resize(arr, size, interpolation=interpolation)


def _scaled_intrinsics(fr: FrameInput, w: int, h: int) -> tuple[float, float, float, float]:
    """The frame's intrinsics for an image of ``w × h`` (same aspect ratio as ``intrinsics_size``).

    With pixel centres at +0.5 the image corner is the origin, so scaling the image scales every intrinsic
    by the same factor (no half-pixel correction)."""
    fx, fy, cx, cy = fr.intrinsics
    if fr.intrinsics_size is None or tuple(fr.intrinsics_size) == (w, h):
        return fx, fy, cx, cy
    iw, ih = fr.intrinsics_size
    sx, sy = w / iw, h / ih
    # One pixel of rounding per side is fine (e.g. 1297 → 648 px); anything more means a cropped image.
    if abs(iw * sy - w) > 1.0 or abs(ih * sx - h) > 1.0:
        raise InputError(fr.image_path, f"image is {w}x{h} but its intrinsics are for {iw}x{ih} (a different "
                                        "aspect ratio: cropped?); pass the right intrinsics")
    return fx * sx, fy * sy, cx * sx, cy * sy


def _clear_outputs(out: Path, overwrite: bool) -> None:
    if out.exists() and not out.is_dir():
        raise InputError(out, "exists and is not a folder")
    if not out.exists():
        return
    ours = [out / n for n in _SCENE_OUTPUTS if (out / n).exists()]
    if not ours:
        return
    if not overwrite:
        raise InputError(out, f"already holds scene folder files ({', '.join(p.name for p in ours[:3])}); "
                              "pass --overwrite to replace them")
    for p in ours:
        if p.is_dir():
            shutil.rmtree(p)
        else:
            p.unlink()


def write_scene(
    out: str | Path,
    frames: Sequence[FrameInput],
    categories: Sequence[Category],
    *,
    camera_model: str = "PINHOLE",
    splits: dict[str, list[str]] | None = None,
    scene_box: tuple[str, np.ndarray] | None = None,
    options: WriteOptions | None = None,
    extra_meta: dict | None = None,
) -> Scene:
    """Write ``frames`` as a scene folder at ``out`` and read it back.

    Parameters
    ----------
    out : str or Path
        Output folder.
    frames : sequence of FrameInput
        The frames, in output order.
    categories : sequence of Category
        Label vocabulary (every category id the labels use must be in it); may be empty when no frame has
        labels.
    camera_model : str
        ``PINHOLE``, ``OPENCV`` or ``OPENCV_FISHEYE`` (one model for the whole scene).
    splits : dict, optional
        ``{"train": [frame names], "val": [...], "test": [...]}``; empty lists are left out.
    scene_box : (str, np.ndarray), optional
        ``("bounded" | "unbounded", aabb [2, 3])`` written as ``scene_box``.
    options : WriteOptions, optional
        Downscaling, image format, depth unit, overwrite, progress bars.
    extra_meta : dict, optional
        Extra top-level ``transforms.json`` keys (e.g. where the scene was converted from).

    Returns
    -------
    Scene
        The written folder, loaded with :func:`load_scene`.

    Raises
    ------
    InputError
        On any unreadable or inconsistent input, naming the file.
    """
    opts = options or WriteOptions()
    out = Path(out)
    if not frames:
        raise InputError(out, "nothing to convert: no frames found")
    names = [f.name for f in frames]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})[:3]
        raise InputError(frames[0].image_path.parent, f"several images share the file stem(s) {dup}; "
                                                       "frames are named by stem, so stems must be unique")
    if opts.downscale < 1:
        raise InputError("--downscale", "must be a positive integer")
    if opts.depth_as_gt and not any(f.depth_path is not None for f in frames):
        raise InputError("--depth-as-gt", "the source has no depth maps to keep for evaluation")
    _clear_outputs(out, opts.overwrite)

    cat_ids = {c.id for c in categories}
    file_paths: dict[str, str] = {}
    writer = SceneWriter(out, list(categories), image_ext=opts.image_ext, depth_unit_scale_factor=opts.depth_scale,
                         camera_model=camera_model, extra_meta=extra_meta)
    resized_labels = 0
    cropped: tuple[int, int, int] | None = None
    for fr in progress_bar(frames, desc="convert frames", unit="frame", disable=not opts.progress):
        image = read_rgb(fr.image_path)
        h, w = image.shape[:2]
        fx, fy, cx, cy = _scaled_intrinsics(fr, w, h)

        labels = fr.labels() if fr.labels is not None else None
        if labels is not None:
            _check_categories(labels, cat_ids)
        gt = fr.gt() if fr.gt is not None else None
        if gt is not None:
            _check_categories(gt, cat_ids)
        depth = read_depth(fr.depth_path, opts.depth_scale) if fr.depth_path is not None else None
        mask = None  # True = pixel left out of training
        if fr.mask_path is not None:
            mask = (read_label_map(fr.mask_path) > 0) != fr.mask_marks_valid

        # Labels predicted at another resolution (segmenters often run downscaled) are brought to the image
        # size with nearest neighbour, which keeps ids exact; depth likewise (ScanNet's depth is 640x480).
        for lab in (labels, gt):
            if lab is not None and lab.panoptic.shape != (h, w):
                resized_labels += 1
                lab.panoptic = _resize(lab.panoptic, (w, h), cv2.INTER_NEAREST)
                if lab.confidence is not None:
                    lab.confidence = _resize(lab.confidence.astype(np.float32), (w, h), cv2.INTER_LINEAR)
        if labels is not None and labels.confidence is not None and labels.confidence.shape != (h, w):
            labels.confidence = _resize(labels.confidence.astype(np.float32), (w, h), cv2.INTER_LINEAR)
        if depth is not None and depth.shape != (h, w):
            depth = _resize(depth, (w, h), cv2.INTER_NEAREST)
        if mask is not None and mask.shape != (h, w):
            mask = _resize(mask.astype(np.uint8), (w, h), cv2.INTER_NEAREST) > 0

        if opts.downscale > 1:
            # Each output pixel is one N x N block of every map, so labels and depth stay on the image's
            # pixel centres (lift3d.convert.downscale says how each kind of map is reduced).
            n = opts.downscale
            if w < n or h < n:
                raise InputError(fr.image_path, f"image is {w}x{h}, smaller than one --downscale {n} block")
            if (w % n or h % n) and not cropped:
                cropped = (w % n, h % n, n)
            image = downscale.block_mean(image, n)
            fx, fy, cx, cy = fx / n, fy / n, cx / n, cy / n
            for lab in (labels, gt):
                if lab is not None:
                    lab.panoptic = downscale.block_majority(lab.panoptic, n)
                    if lab.confidence is not None:
                        lab.confidence = downscale.block_mean(lab.confidence.astype(np.float32), n)
            if depth is not None:
                depth = downscale.block_median_depth(depth, n)
            if mask is not None:
                # The majority of the block decides; a tie goes to the smaller value, 0 = ignore.
                mask = downscale.block_majority((~mask).astype(np.uint8), n) == 0

        c2w_opencv = fr.c2w_opencv if opts.fix_poses is None else with_fix(fr.c2w_opencv[None], opts.fix_poses,
                                                                            opts.pose_axes)[0]
        c2w = opencv_to_opengl(c2w_opencv)
        if not is_rigid(c2w, atol=1e-3):
            raise InputError(fr.pose_source, f"pose of {fr.name!r} is not a rigid transform")
        confidence = None
        if labels is not None and labels.confidence is not None:
            confidence = np.clip(np.nan_to_num(labels.confidence.astype(np.float32), nan=0.0), 0.0, 1.0)
        file_paths[fr.name] = writer.add_frame(
            fr.name, image, c2w, (fx, fy, cx, cy),
            labels=None if labels is None else FramePseudoLabels(labels.panoptic, labels.segments,
                                                                 confidence=confidence),
            depth=None if opts.depth_as_gt else depth, distortion=fr.distortion or None,
            gt=FrameGroundTruth(None if gt is None else gt.panoptic, () if gt is None else gt.segments,
                                depth=depth if opts.depth_as_gt else None),
        )
        if mask is not None:
            # SceneWriter.add_frame has no mask argument yet; nerfstudio's mask_path convention is
            # 0 = ignore, so the "invalid" mask is inverted on the way out.
            rel = f"masks/{fr.name}.png"
            write_label_map(out / rel, np.where(mask, 0, 255).astype(np.uint16))
            writer.frames[-1]["mask_path"] = rel
    if resized_labels:
        note(f"{resized_labels} label maps were not at their image's size and were resized (nearest neighbour)")
    if cropped:
        note(f"--downscale {cropped[2]}: images lose their last {cropped[0]} column(s) and {cropped[1]} row(s) so "
             "that every output pixel is a whole block")

    if splits:
        lists = {k: [file_paths[n] for n in v if n in file_paths] for k, v in splits.items()}
        if not lists.get("train"):
            raise InputError(out, "the train split is empty after conversion")
        writer.set_splits(lists["train"], lists.get("val") or None, lists.get("test") or None)
    if scene_box is not None:
        writer.set_scene_box(scene_box[0], scene_box[1])
    writer.close()

    scene = load_scene(out)
    # Decode one frame completely: load_scene checks paths and JSON, this checks pixels and ids agree.
    scene.image(0)
    if scene.has_pseudo_labels:
        scene.pseudo_labels(0)
    if scene.frames[0].gt_panoptic_path is not None:
        scene.gt_labels(0)
    if opts.check_poses:
        _check_pose_convention(scene, frames[0].pose_source, opts)
    return scene


def _check_pose_convention(scene: Scene, pose_source: Path, opts: WriteOptions) -> None:
    """Stop with one line when the written poses fit the images only after a convention fix
    (:func:`lift3d.sfm.pose_check.check_pose_convention`; depth maps, or keypoints, of pairs of frames)."""
    def depth(i: int):
        frame = scene.frames[i]
        if frame.depth_path is not None:
            return scene.depth(i)
        return scene.gt_depth(i) if frame.gt_depth_path is not None else None

    check = check_pose_convention(scene.cameras, scene.split("train"), scene.image, depth, stored=opts.pose_axes)
    if check.likely_fix is None:
        if not check.fits:
            note(f"the poses fit the images poorly under every convention tried ({check.describe()})")
        return
    flag = check.likely_fix.replace(" ", "-")
    done = f" (after --fix-poses {opts.fix_poses.replace(' ', '-')})" if opts.fix_poses else ""
    raise InputError(pose_source, f"{FIX_MEANS[check.likely_fix]}{done} ({check.describe()}): convert again with "
                                  f"--fix-poses {flag} --overwrite (the scene written to {scene.root} has them as read)")


def _check_categories(labels: PanopticFrame, cat_ids: set[int]) -> None:
    unknown = sorted({s.category_id for s in labels.segments} - cat_ids)
    if unknown:
        raise InputError(labels.source, f"category ids {unknown[:5]} are not in the categories "
                                        "(pass --categories FILE with every id the labels use)")


def summary(scene: Scene) -> str:
    """One line describing a converted scene (printed by the CLI)."""
    n_things = len(scene.thing_ids)
    parts = [f"{len(scene)} frames"]
    if scene.has_pseudo_labels:
        parts.append(f"{len(scene.categories)} categories ({n_things} thing{'' if n_things == 1 else 's'})")
    else:
        parts.append("no pseudo-labels yet (lift3d label adds them; training needs them)")
    parts.append("splits " + ", ".join(f"{k} {len(scene.splits[k])}" for k in ("train", "val", "test")
                                       if k in scene.splits))
    if scene.has_gt:
        parts.append("ground truth")
    if scene.has_depth:
        parts.append("depth")
    if all(f.gt_depth_path is not None for f in scene.frames):
        parts.append("depth for evaluation only (gt_depth_file_path)")
    if scene.sparse_points_paths is not None:
        sparse = scene.sparse_points()
        parts.append(f"{len(sparse)} sparse points (median error {sparse.median_error:.2f} px)")
    return f"wrote {scene.root}: " + "; ".join(parts)
