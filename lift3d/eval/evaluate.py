"""``lift3d eval``: every metric of docs/metrics.md for a trained run, beside the pseudo-label baseline.

The pipeline is split so that each stage can be used (and tested) on its own:

1. :func:`render_split` renders the frames of a split (rgb, z-depth, semantic, instance);
2. :func:`gt_labels` / :func:`pseudo_labels` read the scene's GT and 2D pseudo-labels of those frames;
3. :func:`compute_2d_metrics` scores any prediction arrays against GT arrays (mIoU, PQ^scene with
   ``min_area`` 0.005 and, as ``*_strict``, 0.0; things / stuff split) -- the lifted prediction and the
   pseudo-labels go through the very same function;
4. :func:`metrics_from_arrays` assembles the 2D part of ``metrics.json`` (PSNR, depth errors, 2D labels,
   the ``pseudo_labels`` block);
5. :func:`points3d_block` scores a labelled point cloud of the run against ``gt/points.ply``;
6. :func:`time_render` measures the milliseconds to render 2048 rays;
7. :func:`evaluate_run` does all of it and writes ``metrics.json`` (NaN / inf written as ``null``).

The metric functions themselves live in :mod:`lift3d.eval.metrics` and :mod:`lift3d.eval.points3d`.
"""

from __future__ import annotations

import json
import math
import statistics
import time
from dataclasses import dataclass, replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Iterable, NamedTuple, Sequence

import numpy as np
import torch

from lift3d import __version__
from lift3d.data.scene import Scene
from lift3d.errors import InputError
from lift3d.eval.frame_metrics import FRAME_METRICS, depth_gt_points, depth_reference
from lift3d.eval.metrics import miou, pq_scene
from lift3d.eval.points3d import geometry3d, points3d
from lift3d.export.instances import INSTANCE_SOURCES, check_instance_source, frame_instance_ids
from lift3d.export.pointcloud import SOURCES, extract_labelled_points
from lift3d.model.run import LoadedRun, load_run
from lift3d.render.images import MIN_SEGMENT_FRACTION, check_min_segment_fraction, render_frame, surface_depth
from lift3d.utils.atomic import write_text_atomic
from lift3d.utils.files import check_writable
from lift3d.utils.progress import progress_bar

__all__ = [
    "MIN_AREA",
    "MIN_AREA_STRICT",
    "LabelStack",
    "RenderedSplit",
    "compute_2d_metrics",
    "render_split",
    "gt_labels",
    "pseudo_labels",
    "metrics_from_arrays",
    "points3d_block",
    "points_from_rendered_depth",
    "time_render",
    "evaluate_run",
    "EvalOptions",
    "json_safe",
    "write_metrics",
    "trained_frames_warning",
    "scoring_poses",
]

#: Class-area filter of the published PQ^scene / mIoU numbers, and the strict variant (no filter).
MIN_AREA = 0.005
MIN_AREA_STRICT = 0.0
#: The point source the 3D block scores by default: the export's default.
DEFAULT_SOURCE = SOURCES[0]
#: Keys of a 2D metrics block (the lifted result and the ``pseudo_labels`` baseline share them).
_PQ_KEYS = ("pq", "sq", "rq")
#: Field channels that keep their own id under ``--instances export`` (a thing class the export has no
#: object of) are shifted by this, so they never collide with an exported object's id.
FIELD_CHANNEL_OFFSET = 1 << 20


class LabelStack(NamedTuple):
    """Panoptic labels of a set of frames: semantic (category ids, 0 = void) and instance ids.

    Each array is flat (the pixels of all frames concatenated, so frames may differ in size) or F×H×W.
    """

    semantic: np.ndarray
    instance: np.ndarray


@dataclass
class RenderedSplit:
    """Rendered frames, one array per frame (frames may differ in size)."""

    frames: list[int]
    rgb: list[np.ndarray]  # [H, W, 3] float32 in [0, 1]
    depth: list[np.ndarray]  # [H, W] float32 z-depth, world units (0 = nothing hit)
    semantic: list[np.ndarray]  # [H, W] category ids
    instance: list[np.ndarray]  # [H, W] instance ids, 0 on stuff
    confidence: list[np.ndarray]  # [H, W] probability of the chosen class
    #: [H, W] z-depth where the opacity reaches 0.5 (0 where it never does), world units; None: not rendered
    median_depth: list[np.ndarray] | None = None

    def labels(self) -> LabelStack:
        """The rendered labels as one flat :class:`LabelStack`."""
        return _concat(self.semantic, self.instance)


def _concat(sem: Sequence[np.ndarray], inst: Sequence[np.ndarray]) -> LabelStack:
    # int32 halves the memory of int64 stacks; the metric functions accept any integer dtype.
    return LabelStack(np.concatenate([np.asarray(s, np.int32).ravel() for s in sem]),
                      np.concatenate([np.asarray(i, np.int32).ravel() for i in inst]))


# --------------------------------------------------------------------------------------- 2D metrics
def compute_2d_metrics(preds, gts, things: Iterable[int], stuff: Iterable[int]) -> dict:
    """mIoU and PQ^scene (both ``min_area`` variants) of predicted labels against GT labels.

    Parameters
    ----------
    preds, gts : LabelStack or (semantic, instance) pair
        Integer arrays of the same shape (flat pixel lists or F×H×W stacks). GT instance ids must be
        scene-consistent; predicted ones are taken as given (per-frame ids score as such).
    things, stuff : iterable of int
        Thing and stuff category ids (disjoint, no 0).

    Returns
    -------
    dict
        ``miou``, ``pq_scene``, ``sq_scene``, ``rq_scene`` at ``min_area`` 0.005 and the same keys with
        suffix ``_strict`` at ``min_area`` 0; ``things`` and ``stuff`` blocks with ``pq sq rq n`` and
        ``pq_strict sq_strict rq_strict n_strict``; ``n_classes`` / ``n_classes_strict`` (classes PQ
        averaged over); ``per_class`` (str(category id) → ``pq sq rq tp fp fn iou``, ``min_area`` 0.005);
        ``per_class_iou_strict`` (str(category id) → ``iou gt_pixels`` for every class with a GT pixel,
        ``min_area`` 0).
        NaN where a mean is over no class (written as null in JSON).

    Examples
    --------
    >>> sem = np.array([1, 1, 2, 2]); inst = np.array([0, 0, 5, 5])
    >>> r = compute_2d_metrics((sem, inst), (sem, inst), things=[2], stuff=[1])
    >>> r["pq_scene"], r["miou_strict"], r["things"]["pq"]
    (1.0, 1.0, 1.0)
    """
    ps, pi = (np.asarray(a) for a in preds)
    gs, gi = (np.asarray(a) for a in gts)
    if ps.shape != gs.shape or pi.shape != gi.shape or ps.shape != pi.shape:
        raise ValueError(f"compute_2d_metrics: prediction {ps.shape}/{pi.shape} and GT {gs.shape}/{gi.shape} differ")
    things, stuff = sorted(int(c) for c in things), sorted(int(c) for c in stuff)
    # One confusion-matrix size for both variants, covering every id either side uses.
    n_cls = 1 + max(int(ps.max(initial=0)), int(gs.max(initial=0)))
    out: dict[str, Any] = {"things": {}, "stuff": {}}
    per_class: dict[str, dict] = {}
    for min_area, suffix in ((MIN_AREA, ""), (MIN_AREA_STRICT, "_strict")):
        mi = miou(ps, gs, min_area=min_area, num_classes=n_cls)
        pq = pq_scene(ps, pi, gs, gi, things, stuff, min_area=min_area)
        out["miou" + suffix] = mi["miou"]
        for k in _PQ_KEYS:
            out[f"{k}_scene{suffix}"] = pq[k]
        out["n_classes" + suffix] = pq["n_classes"]
        for part in ("things", "stuff"):
            for k in _PQ_KEYS:
                out[part][k + suffix] = pq[part][k]
            out[part]["n" + suffix] = pq[part]["n"]
        if not suffix:
            iou = mi["per_class_iou"]
            for cid, c in pq["per_class"].items():
                per_class[str(cid)] = {k: c[k] for k in ("pq", "sq", "rq", "tp", "fp", "fn")}
                per_class[str(cid)]["iou"] = float(iou[cid]) if cid < len(iou) else float("nan")
        else:
            # every class the GT shows, however small: its IoU and how many GT pixels it has
            gt_pixels = mi["confusion"].sum(axis=1)
            out["per_class_iou_strict"] = {
                str(c): {"iou": float(mi["per_class_iou"][c]), "gt_pixels": int(gt_pixels[c])}
                for c in things + stuff if c < len(gt_pixels) and gt_pixels[c] > 0}
    out["per_class"] = per_class
    return out


# --------------------------------------------------------------------------------------- inputs
def render_split(loaded: LoadedRun, scene: Scene, frames: Sequence[int], *, chunk_size: int | None = None,
                 progress: bool = True, min_segment_fraction: float = MIN_SEGMENT_FRACTION) -> RenderedSplit:
    """Render ``frames`` of ``scene`` at full resolution with the run's model.

    Parameters
    ----------
    loaded : LoadedRun
        From :func:`lift3d.model.run.load_run` (or a run being trained).
    scene : Scene
        The run's scene (same world frame as at training).
    frames : sequence of int
        Frame indices.
    chunk_size : int, optional
        Rays per rendering chunk.
    progress : bool
        Show a progress bar.
    min_segment_fraction : float
        Thing segments under this fraction of a frame take their surroundings' labels
        (:func:`lift3d.render.images.merge_small_segments`; 0 scores the raw argmax labels).
    """
    rays = loaded.rays(scene)
    out = RenderedSplit(list(map(int, frames)), [], [], [], [], [], median_depth=[])
    for i in progress_bar(out.frames, desc="eval: render", disable=not progress, unit="frame"):
        r = render_frame(loaded.model, rays, i, loaded.norm.scale, chunk_size=chunk_size,
                         min_segment_fraction=min_segment_fraction)
        h, w = r.rgb.shape[:2]
        sem = r.semantic if r.semantic is not None else np.zeros((h, w), np.int64)
        inst = r.instance if r.instance is not None else np.zeros((h, w), np.int64)
        conf = r.confidence if r.confidence is not None else np.ones((h, w), np.float32)
        out.rgb.append(r.rgb)
        out.depth.append(r.depth)
        out.median_depth.append(r.median_depth)
        out.semantic.append(sem)
        out.instance.append(inst)
        out.confidence.append(conf)
    return out


def with_export_instances(rendered: RenderedSplit, scene: Scene, points, things: Iterable[int]) -> RenderedSplit:
    """``rendered`` with each thing pixel's instance id taken from an exported labelled cloud.

    Every pixel of a thing class is lifted to the world along its ray by its rendered median z-depth (where the
    opacity reaches 0.5, as the export's isosurface does; the expected depth where the render has none) and takes the id
    of the nearest exported point of its class (:func:`lift3d.export.instances.frame_instance_ids`), so
    that one object has one id in every view and the same id as in the export's ``instances.json``. The
    export groups the field's instance channels in 3D (connected components, fragments merged where the
    training views' 2D segments say they are one object, crumbs folded), which the per-pixel argmax over
    channels cannot do. Pixels with no depth, or of a class the cloud has no object of, keep their channel
    plus :data:`FIELD_CHANNEL_OFFSET`.

    Parameters
    ----------
    rendered : RenderedSplit
        Frames rendered from ``scene``'s cameras (depth in world units).
    scene : Scene
        The scene whose cameras rendered them (world frame of ``points``).
    points
        The export's cloud: ``xyz`` (world frame), ``semantic``, ``instance``
        (:func:`lift3d.export.pointcloud.extract_labelled_points`).
    things : iterable of int
        Thing category ids.
    """
    things = list(things)
    instance = []
    for k, i in enumerate(rendered.frames):
        field = np.where(rendered.instance[k] > 0, rendered.instance[k] + FIELD_CHANNEL_OFFSET, 0).astype(np.int64)
        depth = surface_depth(rendered.depth[k], rendered.median_depth[k] if rendered.median_depth else None)
        ids = frame_instance_ids(scene.cameras, i, rendered.semantic[k], depth, points.xyz,
                                 points.semantic, points.instance, things)
        instance.append(np.where(ids > 0, ids, field))
    return replace(rendered, instance=instance)


def gt_labels(scene: Scene, frames: Sequence[int]) -> LabelStack:
    """GT panoptic labels (scene-consistent instance ids) of ``frames``, flat."""
    labs = [scene.gt_labels(int(i)) for i in frames]
    return _concat([x.semantic for x in labs], [x.instance for x in labs])


def pseudo_labels(scene: Scene, frames: Sequence[int]) -> LabelStack:
    """The scene's 2D pseudo-labels of ``frames``, flat, with their per-frame instance ids as given."""
    labs = [scene.pseudo_labels(int(i)) for i in frames]
    return _concat([x.semantic for x in labs], [x.instance for x in labs])


def _has_gt_panoptic(scene: Scene, frames: Sequence[int]) -> bool:
    return all(scene.frames[int(i)].gt_panoptic_path is not None for i in frames)


def trained_frames_warning(scene: Scene, frames: Sequence[int]) -> tuple[list[str], list[str]]:
    """The scored ``frames`` that are also training frames (their names), and a warning about them (or none)."""
    train = set(int(i) for i in scene.split("train"))
    both = [scene.frames[int(i)].name for i in frames if int(i) in train]
    if not both:
        return [], []
    return both, [f"{len(both)} of the {len(frames)} scored frames are also training frames: their numbers "
                  "measure fitting, not generalisation (see frames_also_trained)"]


def scoring_poses(scene: Scene, frames: Sequence[int], true_poses: bool = True) -> tuple[Scene, dict]:
    """The scene whose cameras the scored ``frames`` are rendered from, and the ``poses`` block of
    ``metrics.json``.

    Frames with a true pose (``gt_transform_matrix``, written by ``lift3d synth --pose-noise``) are rendered
    from it when ``true_poses`` is on: their images were taken there, so a view rendered from the noisy
    written pose would be scored against a photo of somewhere else and pose noise would be charged twice.
    Training frames keep the poses the field was trained with.

    Returns
    -------
    (Scene, dict)
        The scene to render from, and ``{"scored_at": "gt_transform_matrix" | "transform_matrix",
        "true_pose_frames": n, "written_vs_true": {"frames", "rms_deg", "rms_translation"} or None}``
        (the written poses' error against the true ones, world units).
    """
    err = scene.pose_error(frames)
    use = bool(true_poses and err is not None)
    block = {"scored_at": "gt_transform_matrix" if use else "transform_matrix",
             "true_pose_frames": 0 if err is None else int(err["frames"]), "written_vs_true": err}
    return (scene.at_true_poses(frames) if use else scene), block


# --------------------------------------------------------------------------------------- assembling
def _empty_2d_block() -> dict:
    block: dict[str, Any] = {}
    for suffix in ("", "_strict"):
        block["miou" + suffix] = None
        for k in _PQ_KEYS:
            block[f"{k}_scene{suffix}"] = None
    block["things"] = {k + s: None for s in ("", "_strict") for k in _PQ_KEYS}
    block["stuff"] = {k + s: None for s in ("", "_strict") for k in _PQ_KEYS}
    return block


def metrics_from_arrays(scene: Scene, frames: Sequence[int], rendered: RenderedSplit, *,
                        with_baseline: bool = True) -> dict:
    """The 2D part of ``metrics.json`` from rendered frames: labels and baseline, and every registered
    metric of rendered frames (:mod:`lift3d.eval.frame_metrics`: PSNR, depth errors).

    Parameters
    ----------
    scene : Scene
        Source of GT images, GT labels, GT depth and pseudo-labels.
    frames : sequence of int
        The frames ``rendered`` holds, in the same order.
    rendered : RenderedSplit
        The prediction (any source: a render, or arrays built by hand).
    with_baseline : bool
        Also score the pseudo-labels (``pseudo_labels`` block).

    Returns
    -------
    dict
        ``psnr`` (mean of per-frame PSNRs, RGB in [0, 1]), the keys of :func:`compute_2d_metrics` (None
        without GT panoptic), ``depth`` (``abs_rel rmse mae n_valid`` over all valid pixels of all frames and
        ``reference``: ``gt_depth`` when the scene has exact depth for evaluation, else ``depth``; None without
        either), ``pseudo_labels`` (2D keys of the pseudo-labels, or None), ``gt``
        (which GT exists) and ``notes`` (human-readable remarks).
    """
    frames = [int(i) for i in frames]
    if list(rendered.frames) != frames:
        raise ValueError("metrics_from_arrays: rendered frames differ from frames")
    notes: list[str] = []
    out: dict[str, Any] = {}
    for metric in FRAME_METRICS.values():
        out.update(metric.compute(scene, frames, rendered))

    has_pan = _has_gt_panoptic(scene, frames)
    out["gt"] = {"panoptic": has_pan, "depth": depth_reference(scene, frames) is not None,
                 "points": scene.gt_points_path is not None}
    if has_pan:
        gts = gt_labels(scene, frames)
        things, stuff = scene.thing_ids, scene.stuff_ids
        out.update(compute_2d_metrics(rendered.labels(), gts, things, stuff))
        if with_baseline:
            base = compute_2d_metrics(pseudo_labels(scene, frames), gts, things, stuff)
            out["pseudo_labels"] = base
        else:
            out["pseudo_labels"] = None
    else:
        notes.append(f"no GT panoptic labels for the frames of this split in {scene.root}: "
                     "only PSNR (and depth / 3D where their GT exists) is computed, no pseudo-label baseline")
        out.update(_empty_2d_block())
        out["pseudo_labels"] = None
    out["notes"] = notes
    return out


# --------------------------------------------------------------------------------------- 3D
def points_from_rendered_depth(loaded: LoadedRun, scene: Scene, num_points: int = 200_000,
                               frames: Sequence[int] | None = None, min_opacity: float = 0.5, seed: int = 0,
                               progress: bool = False) -> SimpleNamespace:
    """Labelled points from back-projected rendered depth (a cross-check of the export's surface points).

    Every frame of ``frames`` (default: all frames of the scene, training views included) is rendered at a
    downscale that gives roughly ``num_points`` rays in total; pixels whose opacity is at least
    ``min_opacity`` are lifted to the world along their ray by the rendered z-depth and keep the rendered
    semantic / instance labels and confidence. A random subset of ``num_points`` is returned.

    Returns
    -------
    types.SimpleNamespace
        ``xyz`` (float64 [N, 3], world frame), ``semantic``, ``instance`` (int64 [N]), ``confidence``
        (float32 [N]) -- the fields of the export module's labelled points.
    """
    frames = list(range(len(scene))) if frames is None else [int(i) for i in frames]
    cams = scene.cameras
    total = float(sum(int(cams.width[i]) * int(cams.height[i]) for i in frames))
    ds = max(1, int(math.floor(math.sqrt(total / max(num_points, 1)))))
    rays = loaded.rays(scene)
    parts: list[tuple[np.ndarray, ...]] = []
    for i in progress_bar(frames, desc="eval: points from depth", disable=not progress, unit="frame"):
        r = render_frame(loaded.model, rays, i, loaded.norm.scale, downscale=ds)
        h, w = r.depth.shape
        vv, uu = np.mgrid[0:h, 0:w]
        # The same pixel positions as RayGenerator.image_rays: centre of each ds×ds block.
        off = (ds - 1) / 2.0
        ok = (r.opacity >= min_opacity) & (r.depth > 0)
        if not ok.any():
            continue
        z = r.depth[ok].astype(np.float64)
        xyz = cams.unproject(i, uu[ok] * ds + off, vv[ok] * ds + off, z)
        sem = r.semantic[ok] if r.semantic is not None else np.zeros(len(z), np.int64)
        inst = r.instance[ok] if r.instance is not None else np.zeros(len(z), np.int64)
        conf = r.confidence[ok] if r.confidence is not None else np.ones(len(z), np.float32)
        parts.append((xyz, sem.astype(np.int64), inst.astype(np.int64), conf.astype(np.float32)))
    if not parts:
        return SimpleNamespace(xyz=np.zeros((0, 3)), semantic=np.zeros(0, np.int64), instance=np.zeros(0, np.int64),
                               confidence=np.zeros(0, np.float32))
    xyz, sem, inst, conf = (np.concatenate(a) for a in zip(*parts))
    if len(xyz) > num_points:
        keep = np.sort(np.random.default_rng(seed).choice(len(xyz), num_points, replace=False))
        xyz, sem, inst, conf = xyz[keep], sem[keep], inst[keep], conf[keep]
    return SimpleNamespace(xyz=xyz, semantic=sem, instance=inst, confidence=conf)


def points3d_block(loaded: LoadedRun, scene: Scene, num_points: int = 200_000, progress: bool = True,
                   source: str = DEFAULT_SOURCE, points=None) -> dict | None:
    """3D metrics of the run's labelled points against ``gt/points.ply`` (None when there is no 3D GT).

    ``points``, when given, is the cloud to score, already extracted with ``source`` and ``num_points``.

    Returns
    -------
    dict or None
        ``miou pq sq rq`` (point labels, ``min_area`` 0.005 as in 2D) and ``miou_strict pq_strict sq_strict
        rq_strict`` (``min_area`` 0), ``accuracy completeness chamfer`` (world units),
        ``precision recall fscore`` at ``tau`` (1 % of the GT bounding-box diagonal), ``tau``, ``n_pred``,
        ``n_gt``, ``instance_recall`` (share of GT objects with ≥ 500 points found as one instance with point
        IoU > 0.5) and ``n_instances``, ``n_gt_objects`` (every GT thing instance, however small),
        ``n_pred_instances`` (distinct thing instances among the scored
        points: what the export offers), ``source`` (``export.<source>``: the export's points from ``source``,
        by default the export's default), ``num_points``.
    """
    gt = scene.gt_points()
    if gt is None:
        return None
    pts = points if points is not None else extract_labelled_points(loaded, scene, source=source,
                                                                    num_points=num_points)
    r = points3d(np.asarray(pts.xyz, np.float64), np.asarray(pts.semantic).astype(np.int64),
                 np.asarray(pts.instance).astype(np.int64), gt["xyz"], np.asarray(gt["semantic"]).astype(np.int64),
                 np.asarray(gt["instance"]).astype(np.int64), things=scene.thing_ids, stuff=scene.stuff_ids,
                 min_area=MIN_AREA)
    keys = ("miou", "pq", "sq", "rq", "miou_strict", "pq_strict", "sq_strict", "rq_strict", "min_area", "accuracy",
            "completeness", "chamfer", "precision", "recall", "fscore", "tau", "n_pred", "n_gt", "instance_recall",
            "n_instances")
    block = {k: r[k] for k in keys}
    # Objects the export offers (distinct thing instances among the scored points), beside the GT objects
    # scored (n_instances): an export that splits furniture into pieces finds objects but offers too many.
    pred_inst = np.asarray(pts.instance)
    block["n_pred_instances"] = int(len(np.unique(pred_inst[pred_inst > 0])))
    # Every GT object (n_instances counts only those with >= 500 GT points, the ones instance_recall scores).
    gt_sem, gt_inst = np.asarray(gt["semantic"]).astype(np.int64), np.asarray(gt["instance"]).astype(np.int64)
    on_thing = np.isin(gt_sem, list(scene.thing_ids)) & (gt_inst != 0)
    block["n_gt_objects"] = int(len(np.unique(np.stack([gt_sem[on_thing], gt_inst[on_thing]], 1), axis=0)))
    block.update(source=f"export.{pts.stats.get('source', source)}", num_points=int(num_points))
    # Per class (strict: every class present) and per GT object with its size: a small thing lost does not move
    # the mean much, but it is what a robot reaches for.
    names = {c.id: c.name for c in scene.categories}
    block["per_class"] = {names.get(c, str(c)): round(v, 4) for c, v in points3d_per_class(r).items()}
    block["objects"] = [{**o, "class": names.get(o["class_id"], str(o["class_id"]))} for o in r["objects"]]
    return block


def points3d_per_class(r: dict) -> dict[int, float]:
    """Point IoU per class id (void left out) of a :func:`lift3d.eval.points3d.points3d` result: every class the
    GT or the prediction has (the ``min_area`` filter drops classes from the mean only)."""
    iou = np.asarray(r["miou_detail"]["per_class_iou"], float)
    return {int(c): float(iou[c]) for c in range(1, len(iou)) if np.isfinite(iou[c])}


def geometry_from_depth_block(points, scene: Scene, frames: Sequence[int]) -> dict:
    """Geometry of the run's exported points against the scored frames' depth maps back-projected (a real
    capture's depth kept for evaluation, ``lift3d convert --depth-as-gt``): accuracy, completeness, chamfer,
    precision, recall and F-score at ``tau`` = 1 % of the GT points' bounding-box diagonal
    (:func:`lift3d.eval.points3d.geometry3d`), where the points off the reference lie (:func:`where_off_surface`)
    and the precision and F-score over the points it can judge (:func:`observed_scores`); no labels (depth carries
    none)."""
    gt = depth_gt_points(scene, frames)
    if not len(gt):
        raise InputError(scene.root / "transforms.json", "the scored frames' depth maps hold no depth")
    tau = 0.01 * float(np.linalg.norm(gt.max(0) - gt.min(0)))
    xyz = np.asarray(points.xyz, np.float64)
    block = geometry3d(xyz, gt, tau)
    block.pop("_gt_to_pred")
    off = block.pop("_pred_to_gt") > tau
    imprecise = where_off_surface(xyz[off], scene, frames, tau, total=len(xyz))
    block.update(reference=depth_reference(scene, frames), frames=len(frames),
                 source=f"export.{points.stats.get('source', DEFAULT_SOURCE)}", imprecise=imprecise,
                 **observed_scores(block["precision"], block["recall"], imprecise["unobserved"]))
    return block


def observed_scores(precision: float, recall: float, unobserved: float) -> dict[str, float | None]:
    """``precision_observed`` and ``fscore_observed``: precision over the exported points that the reference can
    judge (within tau of it, or covered by some scored frame's depth), and the F-score with it. A point no scored
    frame sees is neither right nor wrong against depth maps of those frames only (DTU's observation mask; a
    capture's train views see more than its test views).

    Examples
    --------
    >>> observed_scores(0.883, 0.994, 0.059)
    {'precision_observed': 0.9384, 'fscore_observed': 0.9654}
    """
    judged = 1.0 - unobserved
    if judged <= 0:
        return {"precision_observed": None, "fscore_observed": None}
    p = min(1.0, precision / judged)
    f = 2 * p * recall / (p + recall) if p + recall > 0 else 0.0
    return {"precision_observed": round(p, 4), "fscore_observed": round(f, 4)}


def where_off_surface(xyz: np.ndarray, scene: Scene, frames: Sequence[int], tau: float, *, total: int) -> dict:
    """Where the points that miss the reference surface (farther than ``tau`` from every depth point) lie, seen
    from the scored frames, as shares of ``total`` points: ``in_front`` of the surface in some frame (floaters, or a
    surface rendered too near: they would hide what the camera saw), else ``behind`` it in every frame whose depth
    covers their pixel (a surface placed too far, or one that is hidden in the capture), else ``unobserved`` (no
    scored frame's depth covers them). The three add up to 1 - precision.

    Examples
    --------
    >>> from lift3d.data.cameras import Cameras
    >>> from types import SimpleNamespace
    >>> cams = Cameras(c2w=np.eye(4)[None], fx=2.0, fy=2.0, cx=2.0, cy=2.0, width=4, height=4)
    >>> scene = SimpleNamespace(cameras=cams, frames=[SimpleNamespace(gt_depth_path="d")],
    ...                         gt_depth=lambda i: np.full((4, 4), 2.0, np.float32))
    >>> pts = np.array([[0.0, 0, -1], [0.0, 0, -3], [0.0, 0, 5]])  # OpenGL camera: it looks down -z
    >>> where_off_surface(pts, scene, [0], tau=0.1, total=4)
    {'in_front': 0.25, 'behind': 0.25, 'unobserved': 0.25}
    """
    front = np.zeros(len(xyz), bool)
    covered = np.zeros(len(xyz), bool)
    reference = depth_reference(scene, frames)
    for i in frames:
        depth = scene.gt_depth(int(i)) if reference == "gt_depth" else scene.depth(int(i))
        uv, z = scene.cameras.project(int(i), xyz)
        col, row = np.floor(np.nan_to_num(uv, nan=-1.0)).astype(np.int64).T
        inside = (z > 0) & (col >= 0) & (col < depth.shape[1]) & (row >= 0) & (row < depth.shape[0])
        seen_z = np.zeros(len(xyz))
        seen_z[inside] = depth[row[inside], col[inside]]
        inside &= np.isfinite(seen_z) & (seen_z > 0)
        covered |= inside
        front |= inside & (z < seen_z - tau)
    share = (lambda m: round(float(m.sum()) / total, 4)) if total else (lambda m: 0.0)
    return {"in_front": share(front), "behind": share(covered & ~front), "unobserved": share(~covered)}


# --------------------------------------------------------------------------------------- speed
def time_render(loaded: LoadedRun, n_rays: int = 2048, repeats: int = 10, *, warmup: int = 2, scene: Scene | None = None,
                frame: int | None = None) -> dict:
    """Milliseconds to render ``n_rays`` rays of a test view with rgb + depth + semantic + instance.

    ``loaded.model.render_chunked(..., chunk_size=n_rays)`` (one chunk, no gradients, label probabilities
    included) is timed ``repeats`` times after ``warmup`` untimed runs; the rays are spread evenly over the
    view's pixels so they hit what the camera sees.

    Parameters
    ----------
    loaded : LoadedRun
    n_rays : int
        Rays per render (2048 in every published number).
    repeats : int
        Timed runs (at least 1; 10 or more for a stable median).
    warmup : int
        Untimed runs first (allocator, caches, lazy initialisation).
    scene : Scene, optional
        Default ``loaded.scene()``.
    frame : int, optional
        View to use; default the first test frame.

    Returns
    -------
    dict
        ``median_ms``, ``all_ms`` (list), ``threads`` (``torch.get_num_threads()`` during the runs),
        ``n_rays``, ``repeats``, ``warmup``, ``device``, ``frame``.
    """
    if repeats < 1 or n_rays < 1:
        raise ValueError("time_render: repeats and n_rays must be positive")
    scene = loaded.scene() if scene is None else scene
    if frame is None:
        test = scene.split("test")
        frame = int(test[0]) if len(test) else 0
    o, d, _, _ = loaded.rays(scene).image_rays(int(frame))
    # Evenly spread pixel indices; views with fewer pixels than n_rays repeat them.
    idx = torch.as_tensor(np.resize(np.linspace(0, len(o) - 1, min(n_rays, len(o))).round().astype(np.int64), n_rays),
                          device=o.device)
    o, d = o[idx].contiguous(), d[idx].contiguous()
    model = loaded.model
    was_training = model.training
    model.eval()
    cuda = o.device.type == "cuda"

    def once() -> float:
        if cuda:
            torch.cuda.synchronize(o.device)
        t0 = time.perf_counter()
        model.render_chunked(o, d, with_labels=True, chunk_size=n_rays)
        if cuda:
            torch.cuda.synchronize(o.device)
        return (time.perf_counter() - t0) * 1000.0

    try:
        for _ in range(max(0, warmup)):
            once()
        all_ms = [once() for _ in range(repeats)]
    finally:
        if was_training:
            model.train()
    return {"median_ms": float(statistics.median(all_ms)), "all_ms": all_ms, "threads": int(torch.get_num_threads()),
            "n_rays": int(n_rays), "repeats": int(repeats), "warmup": int(warmup), "device": str(o.device),
            "frame": scene.frames[int(frame)].name}


# --------------------------------------------------------------------------------------- JSON
def json_safe(obj: Any) -> Any:
    """``obj`` with numpy types turned into Python ones and NaN / ±inf into None (valid strict JSON).

    Examples
    --------
    >>> json_safe({"a": float("nan"), "b": [np.float32(1.5), np.inf], "c": np.int64(3)})
    {'a': None, 'b': [1.5, None], 'c': 3}
    """
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [json_safe(v) for v in obj.tolist()]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_metrics(metrics: dict, path: str | Path) -> Path:
    """Write ``metrics`` as strict JSON (NaN / inf as null), atomically."""
    text = json.dumps(json_safe(metrics), indent=2, allow_nan=False) + "\n"
    write_text_atomic(path, text)
    return Path(path)


# --------------------------------------------------------------------------------------- the whole eval
@dataclass(frozen=True)
class EvalOptions:
    """What :func:`evaluate_run` scores and how (the ``lift3d eval`` flags of the same names).

    Attributes
    ----------
    split : str
        ``test`` (default), ``val`` or ``train``.
    with_points3d : bool
        Compute the 3D block when ``gt/points.ply`` exists (without it, the export's geometry against the
        scored frames' depth maps).
    num_points : int
        Size of the labelled point cloud scored in 3D.
    points_source : str
        Which export source makes that cloud (``surface``, ``tsdf``, ``rays``; default: the export's).
    timing_repeats : int
        Timed repeats of :func:`time_render` (0 skips the timing).
    chunk_size : int, optional
        Rays per rendering chunk for the split renders.
    true_poses : bool
        Render scored frames that have a true pose (``gt_transform_matrix``) from it rather than from their
        written ``transform_matrix`` (:func:`scoring_poses`); the 3D block is unaffected (it is the export's
        point cloud, built from the training views).
    min_segment_fraction : float
        Thing segments under this fraction of a rendered frame take their surroundings' labels before scoring
        (:func:`lift3d.render.images.merge_small_segments`; 0 scores the raw argmax labels). Recorded in
        ``metrics.json``.
    instances : {"export", "field"}
        Where the rendered frames' instance ids come from: the exported cloud's objects (default;
        :func:`with_export_instances`; the cloud is the one the 3D block scores, extracted once), or the argmax
        of the field's instance head (the paper's rule). Both are scored when there is GT: the other one's
        PQ^scene goes to ``metrics["other_instances"]``.
    """

    split: str = "test"
    with_points3d: bool = True
    num_points: int = 200_000
    points_source: str = DEFAULT_SOURCE
    timing_repeats: int = 10
    chunk_size: int | None = None
    true_poses: bool = True
    min_segment_fraction: float = MIN_SEGMENT_FRACTION
    instances: str = INSTANCE_SOURCES[0]


def evaluate_run(
    run_path: str | Path,
    options: EvalOptions | None = None,
    *,
    data: str | Path | None = None,
    device: str = "auto",
    json_path: str | Path | None = None,
    write: bool = True,
    progress: bool = True,
) -> dict:
    """Evaluate a trained run: render the split, score it and its pseudo-label baseline, time rendering.

    Parameters
    ----------
    run_path : str or Path
        Run folder written by ``lift3d train``.
    options : EvalOptions, optional
        The split, the 3D block and its point cloud, the timing, the poses and instance ids scored (default:
        :class:`EvalOptions`'s).
    data : str or Path, optional
        Scene folder, when it is not where the run's config says.
    device : str
        ``auto``, ``cpu`` or ``cuda[:N]``.
    json_path : str or Path, optional
        Also write the metrics here.
    write : bool
        Write ``metrics.json`` into the run folder.
    progress : bool
        Progress bars.

    Returns
    -------
    dict
        The content of ``metrics.json`` (see docs/metrics.md), with NaN still as float NaN.

    Raises
    ------
    InputError
        Missing / corrupt run folder or checkpoint, missing scene, unwritable output (named in the message).
    """
    o = EvalOptions() if options is None else options
    split, with_points3d, num_points, points_source = o.split, o.with_points3d, o.num_points, o.points_source
    min_segment_fraction, instances = o.min_segment_fraction, o.instances
    if json_path is not None:
        check_writable(json_path)
    start = time.perf_counter()
    loaded = load_run(run_path, device)
    if write:
        check_writable(loaded.run.metrics_path)
    scene = loaded.scene(data)
    frames = [int(i) for i in scene.split(split)]
    if not frames:
        raise InputError(scene.root / "transforms.json", f"split {split!r} has no frames")

    check_instance_source(instances)
    scored_scene, poses = scoring_poses(scene, frames, o.true_poses)
    check_min_segment_fraction(min_segment_fraction)
    rendered = render_split(loaded, scored_scene, frames, chunk_size=o.chunk_size, progress=progress,
                            min_segment_fraction=min_segment_fraction)
    render_timing = None
    if o.timing_repeats > 0:
        # Timed before the export and the 3D metrics: their NumPy/SciPy thread pools keep the cores busy for a
        # while after they return (a 2048-ray render timed right after them took 39 instead of 33 ms; 34.5 ms
        # a second later).
        render_timing = time_render(loaded, n_rays=2048, repeats=o.timing_repeats, scene=scored_scene,
                                    frame=frames[0])

    things = [c for c in scene.thing_ids if c in set(loaded.labels.thing_ids)] if loaded.model.has_instances else []
    points = None
    want_points3d = with_points3d and scene.gt_points_path is not None
    # Without 3D GT, the scored frames' depth maps (kept for evaluation, or the input's) say where the
    # surfaces are: the export's geometry is scored against them.
    want_depth_geometry = (with_points3d and scene.gt_points_path is None
                           and depth_reference(scene, frames) is not None)
    export_failed = None
    if want_points3d or want_depth_geometry or things:  # (both instance sources are scored: the export's cloud is needed for either)
        try:
            points = extract_labelled_points(loaded, scene, source=points_source, num_points=num_points)
        except InputError as exc:  # e.g. a field with no surface yet: the 3D block cannot do without it
            if want_points3d or want_depth_geometry:
                raise
            export_failed = str(exc)
    field_rendered = rendered
    if points is None:
        things = []  # no export to take ids from: the head's ids, and nothing to compare them with
    if instances == "export" and things:
        rendered = with_export_instances(rendered, scored_scene, points, things)
    metrics: dict[str, Any] = {
        "run": str(Path(run_path).resolve()),
        "step": int(loaded.step),
        "split": split,
        "frames": len(frames),
        "frame_names": [scene.frames[i].name for i in frames],
        "image_size": [int(rendered.rgb[0].shape[1]), int(rendered.rgb[0].shape[0])],
        "data": str(scene.root.resolve()),
        "lift3d_version": __version__,
        "min_area": MIN_AREA,
        "min_segment_fraction": float(min_segment_fraction),
        "poses": poses,
    }
    if things:
        metrics["instances_from"] = instances
    elif not loaded.model.has_instances:
        metrics["instances_from"] = "none (no instance head)"
    else:
        metrics["instances_from"] = f"field (no export: {export_failed})" if export_failed else "field"
    metrics.update(metrics_from_arrays(scene, frames, rendered))
    metrics["other_instances"] = None
    if things and metrics["gt"]["panoptic"]:
        other = with_export_instances(field_rendered, scored_scene, points, things) if instances == "field" \
            else field_rendered
        m = compute_2d_metrics(other.labels(), gt_labels(scene, frames), scene.thing_ids, scene.stuff_ids)
        metrics["other_instances"] = {
            "instances_from": "field" if instances == "export" else "export",
            **{k: m[k] for k in ("pq_scene", "sq_scene", "rq_scene", "pq_scene_strict")},
            "things": m["things"], "stuff": m["stuff"]}
    del rendered, field_rendered
    metrics["frames_also_trained"], metrics["warnings"] = trained_frames_warning(scene, frames)
    metrics["render_ms_per_2048_rays"] = render_timing["median_ms"] if render_timing else None
    metrics["render_timing"] = render_timing

    metrics["points3d"] = None
    if want_points3d:
        metrics["points3d"] = points3d_block(loaded, scene, num_points=num_points, progress=progress,
                                             source=points_source, points=points)
    elif want_depth_geometry:
        metrics["geometry_from_depth"] = geometry_from_depth_block(points, scene, frames)
        metrics["notes"].append(f"no gt/points.ply: 3D geometry only, against the {split} frames' "
                                f"{depth_reference(scene, frames)} maps back-projected")
    elif scene.gt_points_path is None:
        metrics["notes"].append("no gt/points.ply: no 3D metrics")

    metrics["device"] = str(loaded.device)
    metrics["seconds"] = time.perf_counter() - start

    if write:
        write_metrics(metrics, loaded.run.metrics_path)
    if json_path is not None:
        write_metrics(metrics, json_path)
    return metrics
