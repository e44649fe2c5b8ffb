"""``lift3d label``: 2D panoptic pseudo-labels for a scene folder from a real segmenter, or from depth.

Three sources, one writer:

* :func:`label_with_model` runs a Mask2Former panoptic model through Hugging Face ``transformers``
  (:mod:`lift3d.label.mask2former`, optional test-time augmentation from :mod:`lift3d.label.tta`);
* :func:`label_from_predictions` imports detectron2-style ``(panoptic_seg, segments_info)`` files made
  elsewhere (:mod:`lift3d.label.predictions`);
* :func:`label_geometric` needs no segmenter: structure-only labels (wall, floor, ceiling, object) from
  the frames' depth maps (:mod:`lift3d.label.geometric`).

The first two map the segmenter's classes onto the scene's vocabulary (:mod:`lift3d.label.classes`); all
write, per frame, ``panoptic/<name>.png`` (COCO panoptic PNG) and optionally ``confidence/<name>.png`` (16-bit, [0, 1]),
then ``panoptic.json`` (with per-segment ``score``) and ``transforms.json`` (frames get
``panoptic_file_path``/``confidence_file_path``, the top level gets ``categories``; everything else is kept).

Nothing in the scene changes until every frame is labelled: files are written to a staging folder inside
the scene and moved into place at the end (each move is an atomic rename), the JSON files last, each
written atomically. An error or Ctrl-C midway leaves the scene as it was. Ground truth (``gt/``) is never
touched; when the scene has some, the new vocabulary must keep the categories it uses (same id, name and
thing/stuff), otherwise evaluation would compare different classes.
"""

from __future__ import annotations

import io
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np

from lift3d.convert.predictions import load_categories, parse_categories
from lift3d.data.categories import Category
from lift3d.data.images import read_depth, read_rgb, write_label_map, write_panoptic_png
from lift3d.data.scene import Segment, cameras_from_transforms, load_scene, read_transforms
from lift3d.errors import InputError
from lift3d.label.classes import coco_sources, load_class_mapping, sources_from_categories, sources_from_labels
from lift3d.label.geometric import (GEOMETRIC_CATEGORIES, CAPTURE_POINTS, CAPTURE_SIDE, GeometricSettings,
                                    fit_structure, frame_geometry, label_frame)
from lift3d.label.predictions import convert_prediction, find_prediction, read_prediction
from lift3d.utils.atomic import write_bytes_atomic, write_json_atomic
from lift3d.utils.files import read_json
from lift3d.utils.progress import progress_bar

__all__ = ["label_with_model", "label_from_predictions", "label_geometric", "Mask2FormerSettings", "LabelScene",
           "read_label_scene", "FrameLabels"]

#: Staging folder inside the scene (removed at the end, or at the start of the next run after a crash).
STAGING_DIR = ".lift3d-label-staging"


@dataclass
class FrameLabels:
    """What is written for one frame.

    Attributes
    ----------
    panoptic : np.ndarray
        ``int64 [H, W]`` segment ids, 0 = void.
    segments : list of Segment
        One per non-zero id of ``panoptic`` (category ids of the new vocabulary, score in [0, 1]).
    confidence : np.ndarray or None
        ``float32 [H, W]`` per-pixel confidence in [0, 1] (multiplied by the segment score when training).
    probabilities : dict or None
        Arrays saved to ``probabilities/<name>.npz`` (TTA class probabilities and confidences).
    """

    panoptic: np.ndarray
    segments: list[Segment]
    confidence: np.ndarray | None = None
    probabilities: dict[str, np.ndarray] | None = None


@dataclass(frozen=True)
class Mask2FormerSettings:
    """How :func:`label_with_model` runs Mask2Former and what it writes (the ``Mask2Former options`` of
    ``lift3d label``).

    Attributes
    ----------
    threshold, overlap_threshold : float
        Mask2Former's panoptic inference thresholds (:class:`~lift3d.label.mask2former.Mask2FormerLabeler`).
    shortest_edge : int, optional
        Inference resolution override.
    tta : bool
        Test-time augmentation over ``tta_scales`` × (no flip, flip if ``tta_flip``).
    tta_scales : tuple of float
        Inference resolutions of the TTA passes, relative to the model's.
    tta_flip : bool
        Also horizontally flipped TTA passes.
    batch_size : int
        Frames per forward pass.
    confidence : bool
        Write per-pixel confidence maps.
    save_probabilities : bool
        Also write ``probabilities/<name>.npz`` with ``probability`` (``[H, W, K + 1]``, void first),
        ``confidence`` (TTA-averaged score × mask) and ``confidence_notta`` (Panoptic Lifting's layout).
    """

    threshold: float = 0.8
    overlap_threshold: float = 0.8
    shortest_edge: int | None = None
    tta: bool = False
    tta_scales: tuple[float, ...] = (0.75, 1.0, 1.25)
    tta_flip: bool = True
    batch_size: int = 1
    confidence: bool = True
    save_probabilities: bool = False


@dataclass
class LabelFrame:
    """One frame of the scene to label."""

    index: int
    name: str
    image_path: Path
    size: tuple[int, int] | None  # (H, W) transforms.json promises, when it says


@dataclass
class LabelScene:
    """A scene folder as ``label`` needs it: its ``transforms.json`` and frames (labels not required)."""

    root: Path
    meta: dict
    frames: list[LabelFrame]
    panoptic_json: Path
    gt_categories: dict[int, Category] = field(default_factory=dict)  # categories the GT uses, by id


def _int_or_none(value: Any) -> int | None:
    try:
        return int(value) if value is not None else None
    except (TypeError, ValueError):
        return None


def read_label_scene(root: str | Path) -> LabelScene:
    """Read what labelling needs from a scene folder; the scene may have no pseudo-labels yet.

    Raises
    ------
    InputError
        Missing folder or ``transforms.json``, frames without images, two frames with the same file stem.
    """
    root = Path(root)
    tpath, meta = read_transforms(root)
    frames: list[LabelFrame] = []
    names: dict[str, int] = {}
    for k, fr in enumerate(meta["frames"]):
        fp = fr.get("file_path") if isinstance(fr, dict) else None
        if not isinstance(fp, str) or not fp:
            raise InputError(tpath, f"frames[{k}].file_path: must be a non-empty path string")
        image = Path(fp) if os.path.isabs(fp) else root / fp
        if not image.is_file():
            raise InputError(image, f"file not found (from frames[{k}].file_path in transforms.json)")
        name = Path(fp).stem
        if name in names:
            raise InputError(tpath, f"frames[{k}]: file stem {name!r} also names frames[{names[name]}] "
                                    "(labels are named by stem)")
        names[name] = k
        h = _int_or_none(fr.get("h", meta.get("h")))
        w = _int_or_none(fr.get("w", meta.get("w")))
        frames.append(LabelFrame(k, name, image, (h, w) if h and w else None))
    pan_json = root / str(meta.get("panoptic_json", "panoptic.json"))
    return LabelScene(root, meta, frames, pan_json, _gt_categories(root, meta))


def _gt_categories(root: Path, meta: dict) -> dict[int, Category]:
    """The categories the ground truth uses (id → category as the scene defines it today)."""
    gt_json = root / "gt" / "panoptic.json"
    if not gt_json.is_file():
        return {}

    raw = read_json(gt_json)
    cats_raw = meta.get("categories") or (raw.get("categories") if isinstance(raw, dict) else None)
    where = root / "transforms.json" if meta.get("categories") else gt_json
    defined = {c.id: c for c in parse_categories(cats_raw, where)} if cats_raw else {}
    used: set[int] = set()
    for ann in raw.get("annotations", []) if isinstance(raw, dict) else []:
        for info in ann.get("segments_info", []) if isinstance(ann, dict) else []:
            cid = _int_or_none(info.get("category_id")) if isinstance(info, dict) else None
            if cid is not None:
                used.add(cid)
    return {cid: defined.get(cid, Category(cid, f"class_{cid}", False)) for cid in sorted(used)}


def check_gt_compatible(scene: LabelScene, categories: Sequence[Category]) -> None:
    """Refuse a vocabulary that would change what the ground truth's category ids mean."""
    if not scene.gt_categories:
        return
    new = {c.id: c for c in categories}
    problems = []
    for cid, old in scene.gt_categories.items():
        c = new.get(cid)
        if c is None:
            problems.append(f"{cid} {old.name!r} missing")
        elif c.name.casefold() != old.name.casefold() or c.isthing != old.isthing:
            problems.append(f"{cid} is {old.name!r} ({'thing' if old.isthing else 'stuff'}) in the GT but "
                            f"{c.name!r} ({'thing' if c.isthing else 'stuff'}) in the new labels")
    if problems:
        listed = "; ".join(problems[:3]) + ("; ..." if len(problems) > 3 else "")
        raise InputError(scene.root / "gt" / "panoptic.json",
                         f"the ground truth uses categories the new labels' vocabulary does not keep ({listed}): "
                         "pass --classes classes.json mapping the segmenter's classes onto the scene's categories "
                         "(same ids, names and thing/stuff)")


# --------------------------------------------------------------------------------------------- writing
def _check_frame(frame: LabelFrame, image: np.ndarray) -> None:
    if frame.size is not None and tuple(image.shape[:2]) != frame.size:
        h, w = frame.size
        raise InputError(frame.image_path, f"image is {image.shape[1]}x{image.shape[0]} but transforms.json says "
                                           f"w={w}, h={h}")


def _check_labels(frame: LabelFrame, labels: FrameLabels, image_shape: tuple[int, int],
                  categories: dict[int, Category]) -> None:
    """Internal consistency of what is about to be written (ids ↔ segments_info, sizes, ranges)."""
    if labels.panoptic.shape != image_shape:
        raise RuntimeError(f"{frame.name}: labels are {labels.panoptic.shape}, image is {image_shape}")
    listed = [s.id for s in labels.segments]
    present = set(np.unique(labels.panoptic).tolist()) - {0}
    if len(set(listed)) != len(listed) or present != set(listed):
        raise RuntimeError(f"{frame.name}: segment ids {sorted(present)} in the map but {sorted(listed)} listed")
    for s in labels.segments:
        if s.category_id not in categories or not 0.0 <= s.score <= 1.0:
            raise RuntimeError(f"{frame.name}: bad segment {s}")
    if labels.confidence is not None:
        c = labels.confidence
        if c.shape != image_shape or not np.all(np.isfinite(c)) or c.min(initial=0) < 0 or c.max(initial=0) > 1:
            raise RuntimeError(f"{frame.name}: confidence map out of [0, 1] or of the wrong size")


class _Staging:
    """Files written under ``<scene>/.lift3d-label-staging/`` and moved into place by :meth:`commit`."""

    def __init__(self, root: Path):
        self.root = root
        self.dir = root / STAGING_DIR
        if self.dir.exists():
            shutil.rmtree(self.dir)  # left by an interrupted run; nothing outside it was changed then
        self.files: list[str] = []

    def path(self, rel: str) -> Path:
        self.files.append(rel)
        return self.dir / rel

    def commit(self) -> None:
        for rel in self.files:
            final = self.root / rel
            final.parent.mkdir(parents=True, exist_ok=True)
            os.replace(self.dir / rel, final)
        shutil.rmtree(self.dir, ignore_errors=True)

    def discard(self) -> None:
        shutil.rmtree(self.dir, ignore_errors=True)


def write_labels(scene: LabelScene, categories: Sequence[Category],
                 labelled: Iterator[tuple[LabelFrame, np.ndarray, FrameLabels]], *, progress: bool = True,
                 labeller: dict | None = None) -> dict:
    """Write every frame's labels, then the JSON files; the scene is untouched unless all succeed.

    Parameters
    ----------
    scene : LabelScene
    categories : sequence of Category
        The new vocabulary (``transforms.json`` ``categories``).
    labelled : iterator
        ``(frame, image, labels)`` for every frame of ``scene``, in order.
    progress : bool
    labeller : dict, optional
        How the labels were made, written as ``transforms.json`` ``labeller``; without it an older
        ``labeller`` entry is removed (it described the labels being replaced).

    Returns
    -------
    dict
        Statistics: frames, segments, void fraction, mean score, what was written.
    """
    check_gt_compatible(scene, categories)
    cat_by_id = {c.id: c for c in categories}
    staging = _Staging(scene.root)
    annotations, images_json = [], []
    frames_meta = [dict(f) for f in scene.meta["frames"]]
    n_segments, void_px, total_px, scores = 0, 0, 0, []
    wrote_conf = wrote_probs = False
    done = 0
    try:
        bar = progress_bar(labelled, desc="label frames", total=len(scene.frames), unit="frame", disable=not progress)
        for frame, image, labels in bar:
            h, w = image.shape[:2]
            _check_labels(frame, labels, (h, w), cat_by_id)
            fr = frames_meta[frame.index]
            rel = f"panoptic/{frame.name}.png"
            write_panoptic_png(staging.path(rel), labels.panoptic)
            fr["panoptic_file_path"] = rel
            # The two-PNG layout would be shadowed by panoptic_file_path anyway; drop it so nobody reads it.
            fr.pop("semantic_file_path", None)
            fr.pop("instance_file_path", None)
            if labels.confidence is not None:
                rel_c = f"confidence/{frame.name}.png"
                write_label_map(staging.path(rel_c), np.round(np.clip(labels.confidence, 0.0, 1.0) * 65535.0))
                fr["confidence_file_path"] = rel_c
                wrote_conf = True
            else:
                fr.pop("confidence_file_path", None)  # it described the old labels
            if labels.probabilities is not None:
                buf = io.BytesIO()
                np.savez_compressed(buf, **labels.probabilities)
                write_bytes_atomic(staging.path(f"probabilities/{frame.name}.npz"), buf.getvalue())
                wrote_probs = True
            ids, counts = np.unique(labels.panoptic, return_counts=True)
            area = dict(zip(ids.tolist(), counts.tolist()))
            annotations.append({"image_id": frame.index, "file_name": f"{frame.name}.png",
                                "segments_info": [s.to_json(area.get(s.id, 0)) for s in labels.segments]})
            images_json.append({"id": frame.index, "file_name": os.path.basename(fr["file_path"]),
                                "width": int(w), "height": int(h)})
            n_segments += len(labels.segments)
            void_px += int(area.get(0, 0))
            total_px += int(h * w)
            scores.extend(s.score for s in labels.segments)
            done += 1
        if done != len(scene.frames):
            raise RuntimeError(f"labelled {done} of {len(scene.frames)} frames")
    except BaseException:
        staging.discard()
        raise
    cats_json = [c.to_json() for c in categories]
    meta = dict(scene.meta)
    meta["categories"] = cats_json
    meta["frames"] = frames_meta
    if labeller is not None:
        meta["labeller"] = labeller
    else:
        meta.pop("labeller", None)
    coco = {"images": images_json, "annotations": annotations, "categories": cats_json}
    staging.commit()
    write_json_atomic(scene.panoptic_json, coco)
    write_json_atomic(scene.root / "transforms.json", meta)
    load_scene(scene.root)  # the result must be a valid scene folder (metadata level; pixels checked above)
    return {
        "frames": done,
        "segments_per_frame": n_segments / max(done, 1),
        "void_fraction": void_px / max(total_px, 1),
        "mean_score": float(np.mean(scores)) if scores else None,
        "categories": len(categories),
        "confidence": wrote_conf,
        "probabilities": wrote_probs,
    }


def _frames_with_images(scene: LabelScene) -> Iterator[tuple[LabelFrame, np.ndarray]]:
    for frame in scene.frames:
        image = read_rgb(frame.image_path)
        _check_frame(frame, image)
        yield frame, image


# --------------------------------------------------------------------------------------------- sources
def label_with_model(scene_dir: str | Path, model: str | Path, settings: Mask2FormerSettings | None = None, *,
                     classes: str | Path | None = None, device: str = "auto", cache_dir: str | Path | None = None,
                     progress: bool = True, labeler: Any = None) -> dict:
    """Label every frame of a scene with a Mask2Former panoptic model.

    Parameters
    ----------
    scene_dir : str or Path
        The scene folder (``transforms.json`` + images; existing labels are replaced).
    model : str or Path
        Local ``save_pretrained`` folder or Hugging Face hub id (:func:`~lift3d.label.mask2former.load_mask2former`).
    settings : Mask2FormerSettings, optional
        Inference thresholds and resolution, test-time augmentation, batch size, and which maps are written
        (default: :class:`Mask2FormerSettings`'s).
    classes : str or Path, optional
        ``coco`` (default), ``scannet21`` or a ``classes.json`` (:mod:`lift3d.label.classes`).
    device : str
        ``auto``, ``cpu`` or ``cuda[:N]``.
    cache_dir : str or Path, optional
        Hugging Face cache to look in.
    progress : bool
    labeler : lift3d.label.mask2former.Mask2FormerLabeler, optional
        A ready labeler (then ``model``, ``classes``, ``device`` and the settings' thresholds and
        ``shortest_edge`` are unused).

    Returns
    -------
    dict
        Statistics of what was written (see :func:`write_labels`) plus ``seconds``, ``classes``, ``passes``.
    """
    # here, not at module level: only the model needs torch; this keeps `lift3d label --help` and --geometric
    # cheap (no torch import)
    from lift3d.label.mask2former import Mask2FormerLabeler, load_mask2former, load_mask2former_config
    from lift3d.label.tta import augmentations
    from lift3d.utils.device import resolve_device, set_threads

    s = Mask2FormerSettings() if settings is None else settings
    t0 = time.perf_counter()
    if s.batch_size < 1:
        raise InputError("--batch-size", f"must be at least 1 (got {s.batch_size})")
    scene = read_label_scene(scene_dir)
    if labeler is None:
        dev = resolve_device(device)
        if dev.type == "cpu":
            set_threads()
        config = load_mask2former_config(model, cache_dir=cache_dir)
        mapping = load_class_mapping(classes, sources_from_labels(config.id2label))
        check_gt_compatible(scene, mapping.categories)  # before loading hundreds of MB of weights
        net, processor = load_mask2former(model, device=dev, cache_dir=cache_dir, config=config)
        labeler = Mask2FormerLabeler(net, processor, mapping, threshold=s.threshold,
                                     overlap_threshold=s.overlap_threshold, shortest_edge=s.shortest_edge)
    check_gt_compatible(scene, labeler.mapping.categories)  # fail before minutes of inference
    try:
        augs = augmentations(tuple(s.tta_scales), s.tta_flip) if s.tta else augmentations()
    except ValueError as exc:
        raise InputError("--tta-scales", str(exc)) from None

    def labelled() -> Iterator[tuple[LabelFrame, np.ndarray, FrameLabels]]:
        batch: list[tuple[LabelFrame, np.ndarray]] = []
        for item in _frames_with_images(scene):
            batch.append(item)
            if len(batch) == s.batch_size or item[0] is scene.frames[-1]:
                preds = labeler.predict([im for _, im in batch], augs, keep_probabilities=s.save_probabilities)
                for (frame, image), p in zip(batch, preds):
                    probs = None
                    if s.save_probabilities:
                        probs = {"probability": p.probabilities.astype(np.float16),
                                 "confidence": p.confidence_tta.astype(np.float16),
                                 "confidence_notta": p.confidence_notta.astype(np.float16),
                                 "class_names": np.array(["void"] + [c.name for c in labeler.mapping.categories])}
                    yield frame, image, FrameLabels(p.panoptic, p.segments, p.confidence if s.confidence else None,
                                                    probs)
                batch = []

    report = write_labels(scene, labeler.mapping.categories, labelled(), progress=progress)
    report.update(seconds=time.perf_counter() - t0, classes=labeler.mapping.describe(), passes=[str(a) for a in augs],
                  source=str(model))
    return report


def label_from_predictions(scene_dir: str | Path, predictions_dir: str | Path, *, classes: str | Path | None = None,
                           prediction_categories: str | Path | None = None, progress: bool = True) -> dict:
    """Import detectron2-style ``(panoptic_seg, segments_info)`` files (:mod:`lift3d.label.predictions`).

    Parameters
    ----------
    scene_dir : str or Path
        The scene folder.
    predictions_dir : str or Path
        One ``<stem>.pt``/``.pth``/``.npz`` per frame, matched by the frame image's file stem.
    classes : str or Path, optional
        Target vocabulary (as for :func:`label_with_model`).
    prediction_categories : str or Path, optional
        COCO categories JSON naming the classes the files' ``category_id`` values refer to (default:
        detectron2's contiguous COCO panoptic ids 0..132).
    progress : bool

    Returns
    -------
    dict
        As :func:`write_labels`, plus ``seconds``, ``classes`` and ``source``.
    """
    t0 = time.perf_counter()
    scene = read_label_scene(scene_dir)
    pred_dir = Path(predictions_dir)
    if not pred_dir.is_dir():
        raise InputError(pred_dir, "predictions folder not found")
    if prediction_categories is not None:
        sources = sources_from_categories(load_categories(prediction_categories))
        file_ids = {s.id: s.index for s in sources}
    else:
        sources = coco_sources()
        file_ids = {s.index: s.index for s in sources}  # detectron2 writes contiguous ids
    mapping = load_class_mapping(classes, sources)
    check_gt_compatible(scene, mapping.categories)
    paths = {}
    for frame in scene.frames:  # every frame needs a prediction: check all before reading any pixel
        p = find_prediction(pred_dir, frame.name)
        if p is None:
            raise InputError(pred_dir, f"no prediction for frame {frame.name!r} (expected {frame.name}.pt, .pth "
                                       "or .npz; files are matched to images by file stem)")
        paths[frame.name] = p

    def labelled() -> Iterator[tuple[LabelFrame, np.ndarray, FrameLabels]]:
        for frame, image in _frames_with_images(scene):
            pred = read_prediction(paths[frame.name])
            seg, segments, conf = convert_prediction(pred, mapping, image.shape[:2], file_ids)
            yield frame, image, FrameLabels(seg, segments, conf)

    report = write_labels(scene, mapping.categories, labelled(), progress=progress)
    report.update(seconds=time.perf_counter() - t0, classes=mapping.describe(), passes=[], source=str(pred_dir))
    return report


#: ``depth_source`` choices of :func:`label_geometric` and the frame key each one reads.
DEPTH_SOURCES = {"depth": "depth_file_path", "gt_depth": "gt_depth_file_path"}


def _depth_paths(scene: LabelScene, depth_source: str) -> tuple[str, list[Path]]:
    """The frame key to read depth from and every frame's depth file; one-line errors when one is missing.

    ``auto`` takes the input depth (``depth_file_path``) when any frame has it, else the depth kept for
    evaluation (``gt_depth_file_path``); either way every frame must have it (the capture pass needs all
    of them to agree on the planes, and a frame cannot be labelled without depth)."""
    if depth_source not in ("auto", *DEPTH_SOURCES):
        raise InputError("--depth-source", f"{depth_source!r} is not one of auto, {', '.join(DEPTH_SOURCES)}")
    frames = scene.meta["frames"]
    if depth_source == "auto":
        depth_source = "depth" if any(DEPTH_SOURCES["depth"] in f for f in frames) else "gt_depth"
    key = DEPTH_SOURCES[depth_source]
    paths = []
    for frame, fr in zip(scene.frames, frames):
        rel = fr.get(key)
        if not isinstance(rel, str) or not rel:
            other = [(name, k) for name, k in DEPTH_SOURCES.items() if k != key and k in fr]
            has = f" (it has {other[0][1]}: pass --depth-source {other[0][0]})" if other else \
                " (nor any other depth map)"
            raise InputError(scene.root / "transforms.json",
                             f"frames[{frame.index}] ({frame.name}): no {key}{has}; --geometric labels every frame "
                             "from its depth map")
        path = Path(rel) if os.path.isabs(rel) else scene.root / rel
        if not path.is_file():
            raise InputError(path, f"file not found (from frames[{frame.index}].{key} in transforms.json)")
        paths.append(path)
    return key, paths


def geometric_vocabulary(scene: LabelScene) -> tuple[list[Category], dict[str, int]]:
    """The categories structure-only labels are written with, and the id of each of their classes.

    Without ground truth: :data:`~lift3d.label.geometric.GEOMETRIC_CATEGORIES` (wall 1, floor 2, ceiling 3,
    object 4). With ground truth, its ids must keep their meaning, so the scene's categories are kept and
    ``wall``, ``floor``, ``ceiling`` and ``object`` are matched to them by name (case-insensitive); a class
    the scene lacks is added with the next free id. A scene category of one of these names with the other
    thing/stuff flag is an error.
    """
    if not scene.gt_categories:
        return list(GEOMETRIC_CATEGORIES), {c.name: c.id for c in GEOMETRIC_CATEGORIES}
    where = scene.root / "transforms.json"
    raw = scene.meta.get("categories")
    if not raw:  # the GT JSON's own list, as _gt_categories reads it
        where = scene.root / "gt" / "panoptic.json"
        gt_json = read_json(where)
        raw = gt_json.get("categories") if isinstance(gt_json, dict) else None
    kept = {c.id: c for c in parse_categories(raw, where)} if raw else {}
    for cid, c in scene.gt_categories.items():
        kept.setdefault(cid, c)
    by_name = {c.name.casefold(): c for c in kept.values()}
    ids = {}
    for new in GEOMETRIC_CATEGORIES:
        old = by_name.get(new.name)
        if old is None:
            old = Category(max(kept, default=0) + 1, new.name, new.isthing, new.color)
            kept[old.id] = old
        elif old.isthing != new.isthing:
            kinds = ("stuff", "thing")
            raise InputError(where, f"category {old.id} {old.name!r} is {kinds[old.isthing]} in the scene, but "
                                    f"--geometric labels make {new.name} {kinds[new.isthing]}; the ground truth "
                                    "uses the scene's categories, so rename that category or label another way")
        ids[new.name] = old.id
    return sorted(kept.values(), key=lambda c: c.id), ids


def label_geometric(scene_dir: str | Path, settings: GeometricSettings | None = None, *, depth_source: str = "auto",
                    progress: bool = True) -> dict:
    """Structure-only labels from the frames' depth maps: wall, floor, ceiling and one ``object`` per
    depth-connected component (:mod:`lift3d.label.geometric`), no 2D segmenter.

    Parameters
    ----------
    scene_dir : str or Path
        The scene folder (``transforms.json``, images and a depth map for every frame; existing labels are
        replaced, and none are needed).
    settings : GeometricSettings, optional
        The thresholds (defaults: :class:`~lift3d.label.geometric.GeometricSettings`).
    depth_source : {"auto", "depth", "gt_depth"}
        Read ``depth_file_path`` or ``gt_depth_file_path``; ``auto`` prefers the input depth and falls back to
        the evaluation depth only when no frame has input depth.
    progress : bool

    Returns
    -------
    dict
        As :func:`write_labels`, plus ``seconds``, ``classes``, ``source``, ``labeller`` (what was recorded in
        ``transforms.json``) and ``class_shares`` (the share of all pixels each class got, void included).

    Examples
    --------
    >>> from lift3d.synth import SynthOptions, make_scene                    # doctest: +SKIP
    >>> make_scene("room", SynthOptions(n_views=8), progress=False)          # doctest: +SKIP
    >>> label_geometric("room", progress=False)["labeller"]["up"]            # doctest: +SKIP
    [0.0, 0.0, 1.0]
    """
    t0 = time.perf_counter()
    settings = settings or GeometricSettings()
    settings.check()
    scene = read_label_scene(scene_dir)
    tpath = scene.root / "transforms.json"
    cameras = cameras_from_transforms(scene.meta, tpath)
    unit = scene.meta.get("depth_unit_scale_factor", 1e-3)
    if not isinstance(unit, (int, float)) or not np.isfinite(unit) or unit <= 0:
        raise InputError(tpath, f"depth_unit_scale_factor: must be a positive number (got {unit!r})")
    key, depth_paths = _depth_paths(scene, depth_source)
    categories, ids = geometric_vocabulary(scene)
    check_gt_compatible(scene, categories)

    def depth_of(frame: LabelFrame) -> np.ndarray:
        path = depth_paths[frame.index]
        depth = read_depth(path, float(unit))
        w, h = int(cameras.width[frame.index]), int(cameras.height[frame.index])
        if depth.shape != (h, w):
            raise InputError(path, f"depth map is {depth.shape[1]}x{depth.shape[0]} but the image is {w}x{h}")
        return depth

    # Capture pass: a sample of every frame (the larger side read at about CAPTURE_SIDE pixels) for the up
    # direction and the planes.
    per_frame = max(2000, CAPTURE_POINTS // len(scene.frames))
    rng = np.random.default_rng(0)
    samples: list[tuple[np.ndarray, ...]] = []
    for frame in progress_bar(scene.frames, desc="fit planes", unit="frame", disable=not progress):
        depth = depth_of(frame)
        geom = frame_geometry(cameras, frame.index, depth, settings,
                              stride=max(1, int(np.ceil(max(depth.shape) / CAPTURE_SIDE))))
        idx = np.flatnonzero(geom.has_normal.ravel())
        if len(idx) > per_frame:
            idx = rng.choice(idx, per_frame, replace=False)
        samples.append((geom.points.reshape(-1, 3)[idx], geom.normals.reshape(-1, 3)[idx], geom.depth.ravel()[idx]))
    points, normals, depths = (np.concatenate(a) for a in zip(*samples))
    if len(points) == 0:
        raise InputError(scene.root, f"no frame has usable depth in its {key} maps (all zero?)")
    structure = fit_structure(points, normals, depths, cameras.c2w, settings)

    shares = np.zeros(len(GEOMETRIC_CATEGORIES) + 1)  # void, then GEOMETRIC_CATEGORIES' order

    def labelled() -> Iterator[tuple[LabelFrame, np.ndarray, FrameLabels]]:
        order = [0] + [ids[c.name] for c in GEOMETRIC_CATEGORIES]
        for frame, image in _frames_with_images(scene):
            geom = frame_geometry(cameras, frame.index, depth_of(frame), settings)
            panoptic, segments = label_frame(geom, structure, settings, ids)
            area = np.bincount(panoptic.ravel())
            for seg in segments:
                shares[order.index(seg.category_id)] += area[seg.id]
            shares[0] += area[0]
            yield frame, image, FrameLabels(panoptic, segments)

    labeller = {
        "method": "geometric", "structure_only": True, "depth": key, "categories": ids,
        "settings": settings.to_json(), **structure.to_json(),
    }
    report = write_labels(scene, categories, labelled(), progress=progress, labeller=labeller)
    names = ["void"] + [c.name for c in GEOMETRIC_CATEGORIES]
    report.update(seconds=time.perf_counter() - t0, source=f"depth maps ({key})", passes=[], labeller=labeller,
                  classes="structure-only: " + ", ".join(f"{n} {ids[n]}" for n in ids),
                  class_shares={n: float(v / max(shares.sum(), 1)) for n, v in zip(names, shares)})
    return report


def format_report(report: dict, scene_dir: str | Path) -> str:
    """A few summary lines for the CLI."""
    score = "n/a" if report["mean_score"] is None else f"{report['mean_score']:.3f}"
    written = ["panoptic/", "panoptic.json", "transforms.json (categories, frames)"]
    if report["confidence"]:
        written.insert(1, "confidence/")
    if report["probabilities"]:
        written.insert(1, "probabilities/")
    n_passes = len(report["passes"])
    passes = f", TTA {n_passes} passes ({', '.join(report['passes'])})" if n_passes > 1 else ""
    lines = []
    if "labeller" in report:
        lab = report["labeller"]
        kinds = [p["kind"] for p in lab["planes"]]
        shares = ", ".join(f"{k} {100 * v:.1f}%" for k, v in report["class_shares"].items())
        lines = [f"  up {(np.round(lab['up'], 3) + 0.0).tolist()} (from {lab['up_source']}); planes: "
                 f"{kinds.count('floor')} floor, {kinds.count('ceiling')} ceiling, {kinds.count('wall')} walls",
                 f"  pixels: {shares}"]
    return "\n".join([
        f"labelled {report['frames']} frames of {scene_dir} from {report['source']} "
        f"in {report['seconds']:.1f} s{passes}",
        f"  classes: {report['classes']}",
        f"  {report['segments_per_frame']:.1f} segments per frame, void {100 * report['void_fraction']:.1f}% "
        f"of pixels, mean segment score {score}",
        *lines,
        f"  wrote {', '.join(written)}",
    ])
