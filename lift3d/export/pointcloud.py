"""Labelled point clouds from a trained panoptic field (``lift3d export --pointcloud``).

Three sources of 3D points, all labelled by running the field's semantic and instance heads *at the points*
(once per point, in chunks; no rays are rendered for them):

``surface`` (default)
    Points sampled uniformly (by area) on the density isosurface of the field (threshold and grid: see
    :mod:`lift3d.export.mesh`), keeping only surface that at least one training camera sees: in its
    frustum, in front of it, and not hidden behind the surface that camera sees. The colour head is
    evaluated along the direction from that camera. The isosurface grid has the resolution of the field's
    finest grid (at least 128, at most 256 cells per axis): the density cannot change faster than that.
    Unbounded scenes are sampled in contracted space (so the foreground is dense and the background
    sparse, as pixels see it) and written in world coordinates; far background beyond
    :data:`~lift3d.export.mesh.UNBOUNDED_MAX_RADIUS` is skipped.
    In a bounded scene, where the isosurface has a hole next to the scene box (a wall or ceiling the box
    hugs: rays end at the box whatever the density), the training views' rendered surface fills it
    (:func:`box_face_fill`).
``tsdf``
    What the training views agree on: the rendered depth of every training view fused into a truncated
    signed distance volume (:mod:`lift3d.export.tsdf`; nerfstudio's ``ns-export tsdf``), its zero level set
    sampled uniformly by area; colour is the fused rendered colour.
``rays``
    nerfstudio's way: render expected depth for random training-camera rays (continuous pixel positions),
    back-project, keep rays whose opacity exceeds 0.5. Colour is the rendered colour. Slower (every point
    costs a rendered ray), and points follow the camera sampling rather than the surface.

``num_points`` is the number of points drawn *before* the optional filters, applied in this order:
``min_confidence`` → frame conversion → ``obb`` crop → statistical outlier removal (Open3D) → voxel
down-sampling with majority-vote labels → instance ids (:func:`lift3d.export.instances.assign_instances`:
connected components of one (class, channel), fragments under ``min_points`` relabelled to their
surroundings or dropped when isolated, contiguous ids ordered by size then position) → instance clean-up
(:mod:`lift3d.export.cleanup`: fragments that one 2D segment covers in the training views merge, crumbs
under ``crumb_points`` fold into their neighbour).

Examples
--------
>>> import numpy as np
>>> box = OrientedBox.from_params(center=(0, 0, 0), rotation=(0, 0, np.pi / 4), scale=(2, 1, 1))
>>> box.contains(np.array([[0.6, 0.6, 0.0], [0.6, -0.6, 0.0]])).tolist()
[True, False]
"""

from __future__ import annotations

import math
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lift3d.data.ply import write_labelled_ply
from lift3d.data.scene import Scene
from lift3d.errors import InputError
from lift3d.export.cleanup import clean_instances
from lift3d.export.instances import assign_instances, join_filled_instances, voxel_downsample_majority
from lift3d.export.stuff import complete_stuff_corners, orient_stuff_labels
from lift3d.export.views import rendered_depth, view_depths, vote_stuff_labels
from lift3d.export.mesh import (
    CameraVisibility,
    _check_frame,
    choose_density_threshold,
    field_isosurface,
    lattice_resolution,
    normalized_cameras,
    point_surface_resolution,
    refine_to_rendered_surface,
    to_frame,
    train_frames,
    view_directions,
    world_from_normalized,
)
from lift3d.export.tsdf import fuse_rendered_depth, sample_surface
from lift3d.field.encodings import uncontract
from lift3d.model.run import LoadedRun, load_run
from lift3d.sfm.mvs import scene_up
from lift3d.utils.device import resolve_device
from lift3d.utils.memory import peak_rss_mb

#: Rays source: keep rays whose accumulated opacity exceeds this (nerfstudio's rule).
RAY_OPACITY_THRESHOLD = 0.5
#: Surface source, bounded scenes: the rendered surface within this share of the box's diagonal of the box's
#: faces fills in where the isosurface has nothing (see :func:`box_face_fill`).
BOX_FILL_MARGIN = 0.01
#: Point sources of :func:`extract_labelled_points`, the default first.
SOURCES = ("auto", "surface", "tsdf", "rays")
#: Statistical outlier removal: neighbours per point (nerfstudio and Open3D's tutorial use 20).
OUTLIER_NEIGHBOURS = 20
#: Instances whose points' mean class probability is lower fold into their surroundings. A thing the field
#: learned from a spurious 2D segment in one or two views (a chair painted on a wall) keeps the wall in its
#: class distribution: on tuning scene 100 such instances had a mean class probability of 0.61-0.66, every
#: instance on a real object 0.78-0.93.
MIN_INSTANCE_CONFIDENCE = 0.7
#: Instances need the majority of their visible points on one 2D thing segment in this many of the clean-up's
#: voting views (:func:`lift3d.export.cleanup.clean_instances`). One: on tuning scene 5, asking for two or three
#: folded real objects that few views see (a toy plane on the floor in 1 of 1 voting view, a ball in 2 of 5).
MIN_SUPPORT_VIEWS = 1


# ------------------------------------------------------------------------------------------ results
@dataclass
class LabelledPoints:
    """A labelled point cloud in the export frame.

    Attributes
    ----------
    xyz : np.ndarray
        ``[N, 3]`` float32 positions (world units unless ``frame == "normalized"``).
    rgb : np.ndarray
        ``[N, 3]`` uint8 colours.
    semantic : np.ndarray
        ``[N]`` int32 category ids (never 0 = void).
    instance : np.ndarray
        ``[N]`` int32 instance ids, contiguous ``1..K`` on thing classes, 0 on stuff.
    confidence : np.ndarray
        ``[N]`` float32 probability of the chosen class.
    frame : str
        ``world`` (the input poses' frame) or ``normalized`` (the field's coordinates).
    transform : np.ndarray
        ``4×4`` world ← normalised (``x_world = transform @ [x_normalized, 1]``).
    thresholds : dict
        Every threshold the export used (density, opacity, confidence, visibility tolerance, link radius...).
    stats : dict
        Counts and timings of each stage.
    """

    xyz: np.ndarray
    rgb: np.ndarray
    semantic: np.ndarray
    instance: np.ndarray
    confidence: np.ndarray
    frame: str
    transform: np.ndarray
    thresholds: dict[str, Any]
    stats: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.xyz)


@dataclass
class OrientedBox:
    """A crop box: ``center``, rotation matrix ``R`` (box axes as columns) and full side lengths ``scale``.

    nerfstudio's ``--obb-center/--obb-rotation/--obb-scale`` convention: the rotation is given as roll,
    pitch, yaw in radians about x, y, z, applied in that order (``R = Rz(yaw) Ry(pitch) Rx(roll)``).
    """

    center: np.ndarray
    R: np.ndarray
    scale: np.ndarray

    @classmethod
    def from_params(cls, center=(0.0, 0.0, 0.0), rotation=(0.0, 0.0, 0.0), scale=(2.0, 2.0, 2.0)) -> "OrientedBox":
        from scipy.spatial.transform import Rotation

        scale = np.asarray(scale, np.float64)
        if scale.shape != (3,) or not np.all(scale > 0):
            raise InputError("--obb-scale", f"needs three positive side lengths, got {np.asarray(scale).tolist()}")
        rot = Rotation.from_euler("xyz", np.asarray(rotation, np.float64)).as_matrix()
        return cls(np.asarray(center, np.float64), rot, scale)

    @classmethod
    def coerce(cls, obb) -> "OrientedBox":
        """Accept an :class:`OrientedBox`, an Open3D ``OrientedBoundingBox``, or a dict with ``center``,
        ``rotation`` (roll, pitch, yaw) and ``scale``."""
        if isinstance(obb, cls):
            return obb
        if isinstance(obb, dict):
            return cls.from_params(obb.get("center", (0, 0, 0)), obb.get("rotation", (0, 0, 0)),
                                   obb.get("scale", (2, 2, 2)))
        if hasattr(obb, "R") and hasattr(obb, "extent") and hasattr(obb, "center"):
            return cls(np.asarray(obb.center, np.float64), np.asarray(obb.R, np.float64),
                       np.asarray(obb.extent, np.float64))
        raise TypeError(f"obb: expected OrientedBox, dict or open3d OrientedBoundingBox, got {type(obb).__name__}")

    def contains(self, xyz: np.ndarray) -> np.ndarray:
        """``[N]`` bool: points inside (or on) the box."""
        local = (np.asarray(xyz, np.float64) - self.center) @ self.R
        return np.all(np.abs(local) <= self.scale / 2.0 + 1e-12, axis=1)


# ------------------------------------------------------------------------------------------ main entry
def resolve_point_source(source: str, loaded: LoadedRun, scene: Scene) -> tuple[str, str]:
    """The source ``auto`` stands for, and why: ``tsdf`` for an unbounded scene (a street) whose every training
    frame has a depth map, where the fused depth scored better in 3D (docs/notes/2026-11-29-benchmark-history.md,
    "Export sources": F-score +0.06 on the reporting streets, +0.13 / +0.02 on two tuning streets; the isosurface
    reached 62–87 % of their GT points); ``surface`` everywhere else (rooms, and streets from images alone, where the fused
    rendered depth is haze). Any other source is returned as given."""
    if source not in SOURCES:
        raise InputError("--source", f"unknown source {source!r} ({', '.join(SOURCES)})")
    if source != "auto":
        return source, "given"
    depth_everywhere = all(scene.frames[int(i)].depth_path is not None for i in train_frames(scene))
    if not loaded.model.bounded and depth_everywhere:
        return "tsdf", "auto: an unbounded scene with a depth map in every training frame"
    return "surface", ("auto: a bounded scene" if loaded.model.bounded
                       else "auto: an unbounded scene without depth maps in every training frame")


def extract_labelled_points(loaded: LoadedRun, scene: Scene, *, source: str = "auto", num_points: int = 1_000_000,
                            frame: str = "world", density_threshold: float | None = None,
                            refine_surface: bool = True, min_confidence: float = 0.0, voxel_size: float = 0.0,
                            remove_outliers: bool = False, std_ratio: float = 2.0, obb=None, min_points: int = 0,
                            merge_fragments: bool = True, crumb_points: int | None = None,
                            min_instance_confidence: float = MIN_INSTANCE_CONFIDENCE,
                            min_support_views: int = MIN_SUPPORT_VIEWS, orient_stuff: bool = True,
                            view_vote: bool = True, view_depth_cache: dict | None = None, box_fill: bool = True,
                            thing_fill: bool = True, complete_corners: bool = True, device=None,
                            progress: bool = False) -> LabelledPoints:
    """A labelled point cloud of a trained run (see the module docstring for the sources and filters).

    Parameters
    ----------
    loaded : LoadedRun
        From :func:`lift3d.model.run.load_run`.
    scene : Scene
        The run's scene (``loaded.scene()``): training cameras decide visibility and ray origins.
    source : {"auto", "surface", "tsdf", "rays"}
        ``auto`` (default): :func:`resolve_point_source`.
    num_points : int
        Points drawn before filtering (default one million).
    frame : {"world", "normalized"}
        Output coordinates: the input poses' frame (default), or the field's normalised frame.
    density_threshold : float, optional
        Isosurface density (normalised units); default chosen from the field
        (:func:`lift3d.export.mesh.choose_density_threshold`).
    refine_surface : bool
        ``surface`` source: move the isosurface onto the rendered surface before sampling
        (:func:`lift3d.export.mesh.refine_to_rendered_surface`; default on). Off: points lie exactly on
        ``σ = τ``.
    min_confidence : float
        Drop points whose chosen class has a lower probability.
    voxel_size : float
        > 0: one point per voxel of this size (output units) with majority-vote labels.
    remove_outliers : bool
        Open3D statistical outlier removal (20 neighbours, ``std_ratio``).
    std_ratio : float
    obb : OrientedBox or open3d.geometry.OrientedBoundingBox or dict, optional
        Keep only points inside this box (output frame).
    min_points : int
        Instance fragments with fewer points are relabelled to their surroundings (dropped when isolated).
    merge_fragments : bool
        Merge instances of one class that one 2D pseudo-label segment covers in the training views that see
        both (:mod:`lift3d.export.cleanup`; default on).
    crumb_points : int, optional
        Instances with fewer points fold into their neighbour (or are dropped when isolated). Default: the
        points of a patch one instance link radius on a side, from the cloud's point density (a piece the
        field's grid cannot resolve as an object); 0 keeps every instance.
    min_instance_confidence : float
        Instances whose points' mean class probability is below this fold into their surroundings as crumbs
        do (default :data:`MIN_INSTANCE_CONFIDENCE`; 0 keeps them).
    min_support_views : int
        Instances that the 2D pseudo-labels confirm as a thing (most of their visible points on one 2D thing
        segment) in fewer training views fold into their surroundings as crumbs do (default
        :data:`MIN_SUPPORT_VIEWS`; 0 keeps them).
    orient_stuff : bool
        Stuff points whose surface faces the way a neighbouring stuff class faces, and not the way their own
        class does, take that class (:func:`lift3d.export.stuff.orient_stuff_labels`: ceiling is not wall
        where the two meet; default on).
    complete_corners : bool
        Bounded scenes: stuff points within two instance link radii of two stuff planes that meet (a wall and the
        ceiling, two walls) are replaced by their projections onto each of them, which take the plane's class
        (:func:`lift3d.export.stuff.complete_stuff_corners`: the isosurface's rounded edge becomes two surfaces
        that meet; default on).
    view_vote : bool
        Points take the class that the 2D labels of the training views seeing them agree on, where they agree
        (:mod:`lift3d.export.views`: a chair's label no longer spreads onto the floor around its legs; views
        without a depth map are rendered for the visibility test; default on).
    view_depth_cache : dict, optional
        Those renders are kept in it and reused (:func:`lift3d.export.views.rendered_depth`): pass the same
        dict to :func:`lift3d.export.mesh.extract_labelled_mesh` of the same run and scene.
    box_fill : bool
        ``surface`` source, bounded scenes: where the isosurface has a hole next to the scene box (a wall or
        ceiling the box hugs), the training views' rendered surface fills it (:func:`box_face_fill`; default on).
    thing_fill : bool
        ``surface`` source, bounded scenes: where the isosurface has no point on a thing the training views without
        a depth map render, their rendered surface fills it (:func:`thing_surface_fill`; default on).
    device : str, optional
        Move the model to this device first (``cpu``, ``cuda``, ``auto``).
    progress : bool

    Returns
    -------
    LabelledPoints
    """
    _check_frame(frame)
    requested = source
    source, source_rule = resolve_point_source(source, loaded, scene)
    if int(num_points) < 1:
        raise InputError("--num-points", f"must be at least 1, got {num_points}")
    if voxel_size < 0 or not math.isfinite(voxel_size):
        raise InputError("--voxel-size", f"must be a finite size >= 0, got {voxel_size}")
    if not 0.0 <= min_confidence <= 1.0:
        raise InputError("--min-confidence", f"must be in [0, 1], got {min_confidence}")
    if std_ratio <= 0:
        raise InputError("--std-ratio", f"must be > 0, got {std_ratio}")
    if not 0.0 <= min_instance_confidence <= 1.0:
        raise InputError("--min-instance-confidence", f"must be in [0, 1], got {min_instance_confidence}")
    if int(min_support_views) < 0:
        raise InputError("--min-support-views", f"must be >= 0, got {min_support_views}")
    if device is not None:
        loaded.model.to(resolve_device(device))
    timings: dict[str, float] = {}
    start = time.perf_counter()
    if view_depth_cache is None:
        view_depth_cache = {}  # the box fill and the label vote render the same views
    if source == "surface":
        cand = _surface_points(loaded, scene, int(num_points), density_threshold, progress, timings,
                               refine=refine_surface, box_fill=box_fill, thing_fill=thing_fill,
                               view_depth_cache=view_depth_cache)
    elif source == "tsdf":
        cand = _tsdf_points(loaded, scene, int(num_points), progress, timings)
    else:
        cand = _ray_points(loaded, scene, int(num_points), progress, timings)
    stats: dict[str, Any] = {"source": source, "drawn": int(len(cand["x"]))}
    thresholds = dict(cand["thresholds"])
    if requested == "auto":
        thresholds["source"] = {"source": source, "rule": source_rule}
    labels = cand["labels"]
    xyz_norm = cand["x"]
    rgb = cand["rgb"] if cand.get("rgb") is not None else labels.rgb
    keep = np.ones(len(xyz_norm), bool)
    if min_confidence > 0:
        keep &= labels.confidence >= min_confidence
        thresholds["min_confidence"] = float(min_confidence)
    stats["after_confidence"] = int(keep.sum())
    transform = world_from_normalized(loaded.norm)
    xyz = to_frame(xyz_norm[keep], transform, frame)
    rgb, semantic, channel, confidence = rgb[keep], labels.semantic[keep], labels.channel[keep], labels.confidence[keep]
    # points that fill holes of things' isosurface (thing_fill) join the instances they border
    filled = cand["filled"][keep] if cand.get("filled") is not None else np.zeros(len(xyz), bool)
    if obb is not None:
        box = OrientedBox.coerce(obb)
        inside = box.contains(xyz)
        xyz, rgb, semantic, channel, confidence, filled = (a[inside] for a in (xyz, rgb, semantic, channel,
                                                                                confidence, filled))
        thresholds["obb"] = {"center": box.center.tolist(), "R": box.R.tolist(), "scale": box.scale.tolist()}
        stats["after_obb"] = int(len(xyz))
    if remove_outliers and len(xyz) > OUTLIER_NEIGHBOURS:
        import open3d as o3d

        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
        _, kept = cloud.remove_statistical_outlier(nb_neighbors=OUTLIER_NEIGHBOURS, std_ratio=float(std_ratio))
        kept = np.sort(np.asarray(kept, np.int64))
        xyz, rgb, semantic, channel, confidence, filled = (a[kept] for a in (xyz, rgb, semantic, channel,
                                                                              confidence, filled))
        thresholds["outliers"] = {"nb_neighbors": OUTLIER_NEIGHBOURS, "std_ratio": float(std_ratio)}
        stats["after_outliers"] = int(len(xyz))
    if voxel_size > 0 and len(xyz):
        from scipy.spatial import cKDTree

        before, before_filled = xyz, filled
        xyz, rgb, semantic, channel, confidence = voxel_downsample_majority(xyz, rgb, semantic, channel, confidence,
                                                                            voxel_size)
        filled = before_filled[cKDTree(before).query(xyz)[1]] if before_filled.any() else np.zeros(len(xyz), bool)
        thresholds["voxel_size"] = float(voxel_size)
        stats["after_voxel"] = int(len(xyz))
    scale_out = 1.0 if frame == "normalized" else 1.0 / float(loaded.norm.scale)
    # Instances link across gaps of about two grid cells, 1.5 point spacings (sparse clouds) or one voxel.
    link = max(cand["link_radius_normalized"] * scale_out, 1.5 * typical_spacing(xyz), voxel_size)
    if view_vote and len(xyz):
        t = time.perf_counter()
        xyz_world = xyz if frame == "world" else to_frame(xyz, transform, "world")
        # A view sees a point within half a grid cell (plus a share of its depth) of the view's depth there.
        semantic, channel, thresholds["view_vote"] = vote_stuff_labels(
            xyz_world, semantic, channel, loaded, scene, train_frames(scene),
            abs_tolerance=0.25 * cand["link_radius_normalized"] / float(loaded.norm.scale),
            depth_cache=view_depth_cache)
        timings["view_vote"] = time.perf_counter() - t
    if orient_stuff:
        t = time.perf_counter()
        # Two link radii: about the width over which the label grid's cells blur an edge between two surfaces.
        semantic, thresholds["stuff_orientation"] = orient_stuff_labels(xyz, semantic, scene.stuff_ids,
                                                                        radius=2.0 * link)
        timings["stuff_orientation"] = time.perf_counter() - t
    if complete_corners and loaded.norm.bounded and len(xyz):
        t = time.perf_counter()
        n_before = len(xyz)
        xyz, rgb, semantic, channel, confidence, filled, thresholds["stuff_corners"] = _complete_corners(
            loaded, scene, frame, link, xyz, rgb, semantic, channel, confidence, filled)
        # The projections honour the crop box and the voxel size: none outside the box, one point per voxel.
        keep = box.contains(xyz) if obb is not None else np.ones(len(xyz), bool)
        if voxel_size > 0:
            first = np.zeros(len(xyz), bool)
            first[np.unique(np.floor(xyz / voxel_size).astype(np.int64), axis=0, return_index=True)[1]] = True
            keep &= first
        if not keep.all():
            xyz, rgb, semantic, channel, confidence, filled = (a[keep] for a in (xyz, rgb, semantic, channel,
                                                                                  confidence, filled))
        stats["after_corners"] = int(len(xyz))
        thresholds["stuff_corners"]["points_before"] = int(n_before)
        timings["stuff_corners"] = time.perf_counter() - t
    t = time.perf_counter()
    assignment = assign_instances(xyz, semantic, channel, link_radius=link, min_points=int(min_points))
    k = assignment.keep
    timings["instances"] = time.perf_counter() - t
    thresholds["instance_link_radius"] = float(link)
    thresholds["min_points"] = int(min_points)
    xyz, rgb, confidence = xyz[k], rgb[k], confidence[k]
    semantic, instance = assignment.semantic[k], assignment.instance[k]
    if filled[k].any():
        # a filled patch lies at least a link radius from the isosurface it completes: three link radii reach it
        instance, joined = join_filled_instances(xyz, semantic, instance, filled[k], radius=3.0 * link)
        stats["filled_instances_joined"] = joined
    t = time.perf_counter()
    if crumb_points is None:
        crumb_points = default_crumb_points(link, typical_spacing(xyz))
    elif crumb_points < 0:
        raise InputError("--crumb-points", f"must be >= 0, got {crumb_points}")
    xyz_world = xyz if frame == "world" else to_frame(xyz, transform, "world")
    semantic, instance, kept, cleanup = clean_instances(
        xyz, xyz_world, semantic, instance, cameras=scene.cameras, frames=train_frames(scene),
        segments_of=lambda f: scene.pseudo_labels(f).instance, link_radius=link, crumb_points=int(crumb_points),
        merge=merge_fragments, min_support_views=int(min_support_views), confidence=confidence,
        min_confidence=float(min_instance_confidence))
    timings["instance_cleanup"] = time.perf_counter() - t
    thresholds["instance_cleanup"] = cleanup
    stats.update(points=int(kept.sum()), instances=assignment.stats, instance_cleanup=cleanup, seconds=timings,
                 total_seconds=time.perf_counter() - start)
    return LabelledPoints(
        xyz=np.asarray(xyz[kept], np.float32), rgb=np.asarray(rgb[kept], np.uint8),
        semantic=np.asarray(semantic[kept], np.int32), instance=np.asarray(instance[kept], np.int32),
        confidence=np.asarray(confidence[kept], np.float32), frame=frame, transform=transform, thresholds=thresholds,
        stats=stats,
    )


#: Inlier distance of the planes :func:`lift3d.export.stuff.complete_stuff_corners` fits, as a share of the scene
#: box's diagonal (4 cm in a 10 m room). 0.2 % and 0.8 % gave point mIoU within 0.005 of it on each tuning run,
#: neither better on all.
CORNER_PLANE_THRESHOLD = 0.004


def _complete_corners(loaded: LoadedRun, scene: Scene, frame: str, link: float, xyz, rgb, semantic, channel,
                      confidence, filled) -> tuple:
    """:func:`lift3d.export.stuff.complete_stuff_corners` on the export's arrays (output frame): corner points
    are replaced by their projections, which carry their point's colour, instance channel and confidence."""
    lo, hi = np.asarray(loaded.norm.aabb_world, np.float64)
    diag = float(np.linalg.norm(hi - lo)) * (float(loaded.norm.scale) if frame == "normalized" else 1.0)
    up = scene_up(scene.cameras[np.asarray(train_frames(scene))])  # as the training's plane fit
    # Two link radii: the width over which the isosurface rounds an edge, as orient_stuff_labels' radius.
    keep, source, new_xyz, new_semantic, info = complete_stuff_corners(
        xyz, semantic, scene.stuff_ids, radius=2.0 * link, threshold=CORNER_PLANE_THRESHOLD * diag, up=up)
    if not len(source):
        return xyz, rgb, semantic, channel, confidence, filled, info
    return (np.r_[xyz[keep], new_xyz.astype(xyz.dtype)], np.r_[rgb[keep], rgb[source]],
            np.r_[semantic[keep], new_semantic.astype(semantic.dtype)], np.r_[channel[keep], channel[source]],
            np.r_[confidence[keep], confidence[source]], np.r_[filled[keep], filled[source]], info)


def default_crumb_points(link_radius: float, spacing: float) -> int:
    """Points on a patch ``link_radius`` on a side: uniform random points with median nearest-neighbour
    distance ``spacing`` have density ``ln 2 / (π spacing²)`` per unit area.

    Examples
    --------
    >>> default_crumb_points(0.1, 0.01)
    22
    """
    if spacing <= 0:
        return 0
    return int(round(math.log(2) / math.pi * (link_radius / spacing) ** 2))


def typical_spacing(xyz: np.ndarray, sample: int = 20000, seed: int = 0) -> float:
    """Median nearest-neighbour distance of a point cloud, estimated from a random subset.

    A random subset of ``n`` of ``N`` points sampled uniformly on a surface is ``√(N/n)`` times sparser, so
    its spacing is scaled back (exact in expectation for such samples, which is what the surface source
    draws).

    Examples
    --------
    For 100 000 uniform points on a unit square the expected median is ``√(ln 2 / (π · 100 000))``:

    >>> pts = np.c_[np.random.default_rng(0).random((100_000, 2)), np.zeros(100_000)]
    >>> round(float(typical_spacing(pts) / np.sqrt(np.log(2) / (np.pi * 100_000))), 1)
    1.0
    """
    from scipy.spatial import cKDTree

    n = len(xyz)
    if n < 2:
        return 0.0
    rng = np.random.default_rng(seed)
    sub = xyz if n <= sample else xyz[rng.choice(n, sample, replace=False)]
    d, _ = cKDTree(sub).query(sub, k=2, workers=-1)
    return float(np.median(d[:, 1])) * math.sqrt(len(sub) / n)


# ------------------------------------------------------------------------------------------ sources
def _surface_points(loaded: LoadedRun, scene: Scene, num_points: int, density_threshold, progress: bool,
                    timings: dict[str, float], refine: bool = True, box_fill: bool = True, thing_fill: bool = True,
                    view_depth_cache: dict | None = None) -> dict[str, Any]:
    """Area-uniform samples on the seen part of the isosurface, labelled by the heads."""
    model = loaded.model
    t = time.perf_counter()
    if density_threshold is None:
        tau, info = choose_density_threshold(loaded, scene)
    else:
        if not density_threshold > 0:
            raise InputError("--density-threshold", f"must be > 0, got {density_threshold}")
        tau, info = float(density_threshold), {"rule": "set by the user (--density-threshold)",
                                                "value": float(density_threshold)}
    timings["threshold"] = time.perf_counter() - t
    t = time.perf_counter()
    surface = field_isosurface(model, tau, point_surface_resolution(loaded.model), progress=progress)
    timings["isosurface"] = time.perf_counter() - t
    if len(surface.faces) == 0:
        raise InputError(loaded.run.path, f"the field has no surface at density {tau:.4g} (train longer, or pass a "
                                          "lower --density-threshold)")
    if refine:
        t = time.perf_counter()
        surface = refine_to_rendered_surface(model, surface)
        timings["refine"] = time.perf_counter() - t
    t = time.perf_counter()
    cams = normalized_cameras(loaded, scene)
    near = float(loaded.cfg.sampling.near_plane)
    visibility = CameraVisibility(cams, train_frames(scene), surface.vertices, surface.faces, near=near,
                                  tolerance=surface.voxel)
    tri = surface.vertices[surface.faces].astype(np.float64)  # [M, 3, 3]
    # Flying edges orients triangles consistently: this cross product points to lower density (outwards).
    outward = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    seen_by = visibility.first_seen_by(tri.mean(1), outward)
    seen = np.flatnonzero(seen_by >= 0)
    timings["visibility"] = time.perf_counter() - t
    if len(seen) == 0:
        raise InputError(loaded.run.path, "no part of the isosurface is seen by a training camera")
    # Area in grid space: uniform in contracted space for unbounded scenes (see module docstring).
    points_grid, pick, _ = sample_surface(surface.grid_vertices.astype(np.float64), surface.faces[seen], num_points)
    x = uncontract(points_grid, surface.contraction) if surface.contraction != "none" else points_grid
    dirs = view_directions(x, cams.centers[seen_by[seen[pick]]])
    link = 2.0 * surface.voxel  # instances link across about two grid cells
    fill_info: dict[str, Any] = {}
    if model.bounded and box_fill:
        t = time.perf_counter()
        fx, fdirs, fill_info = box_face_fill(loaded, scene, x, cams, cache=view_depth_cache, min_gap=link)
        x, dirs = np.r_[x, fx], np.r_[dirs, fdirs]
        timings["box_fill"] = time.perf_counter() - t
    things_info: dict[str, Any] = {}
    filled = np.zeros(len(x), bool)
    if model.bounded and thing_fill:
        # not in unbounded scenes (streets): there it cost point mIoU (outdoor seeds 0 and 2: -0.02 to -0.05) and
        # objects found (a filled patch joined a neighbouring car), and took 50-60 s more
        t = time.perf_counter()
        # half the box fill's gap (one isosurface voxel): a thing's holes narrower than the link radius get filled
        # too (nine tuning runs: point mIoU +0.011 on average over the full gap, F-score -0.002); the patches
        # join their object's instance below
        fx, fdirs, things_info = thing_surface_fill(loaded, scene, x, cams, cache=view_depth_cache,
                                                    min_gap=0.5 * link)
        x, dirs = np.r_[x, fx], np.r_[dirs, fdirs]
        filled = np.r_[np.zeros(len(x) - len(fx), bool), np.ones(len(fx), bool)]
        timings["thing_fill"] = time.perf_counter() - t
    t = time.perf_counter()
    labels = model.query_labels(x.astype(np.float32), dirs, progress=progress)
    timings["heads"] = time.perf_counter() - t
    thresholds = {
        "density": tau, "density_rule": info, "surface_resolution": surface.resolution,
        "refine": surface.stats.get("refine", "off (points on the exact isosurface)"),
        "visibility": {"rule": "in a training camera's image, beyond its near plane, no isosurface between "
                               "camera and point", "occluder_tolerance": surface.voxel, "near": near},
    }
    if fill_info:
        thresholds["box_fill"] = fill_info
    if things_info:
        thresholds["thing_fill"] = things_info
    return {"x": x, "labels": labels, "rgb": None, "thresholds": thresholds, "filled": filled,
            "link_radius_normalized": link,
            "surface": {"faces": int(len(surface.faces)), "seen_faces": int(len(seen)), **surface.stats}}


def box_face_fill(loaded: LoadedRun, scene: Scene, x_surface: np.ndarray, cams, *, cache: dict | None = None,
                  margin: float = BOX_FILL_MARGIN, min_gap: float = 0.0) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Points of the rendered surface next to a bounded scene's box where the isosurface has none.

    Rays stop at the scene box. A room's box hugs its walls, floor and ceiling, so the field need not build a
    surface there: the last centimetres before the box end the ray whatever the density. A wall or ceiling
    met by few depth targets then stays a soft layer below the isosurface's threshold, and its pixels render
    right while the isosurface has a hole (images-only tuning room 7: 0.74 of the ceiling's GT points within τ
    of the export; a reported room, 0.41). The training views' rendered surface (:func:`_fill_holes`)
    is kept where it lies within ``margin`` of the box's diagonal of a face of the box and more than three point
    spacings (and ``min_gap``) from every isosurface point, thinned to one per point spacing. ``min_gap`` keeps a
    dense export from covering again surface the isosurface has (the export passes two isosurface voxels, its
    instance link radius: at a million points three spacings are 1.7 cm, and a reported room's export took a
    quarter of its points from the fill, all but 0.5 % of them within two voxels of it).

    Parameters
    ----------
    x_surface : np.ndarray
        ``[N, 3]`` the isosurface points (normalised coordinates).
    cams : Cameras
        The training cameras in normalised coordinates (:func:`lift3d.export.mesh.normalized_cameras`).

    Returns
    -------
    (np.ndarray, np.ndarray, dict)
        ``[M, 3]`` points (normalised), ``[M, 3]`` the directions their views see them along, and the step's
        record for ``metadata.json``.
    """
    info: dict[str, Any] = {"rule": "rendered surface within a margin of the box, where the isosurface has no point",
                            "margin": float(margin)}
    lo, hi = loaded.norm.to_normalized(loaded.norm.aabb_world)
    near_face = margin * float(np.linalg.norm(hi - lo))

    def near_box(p: np.ndarray, *_) -> np.ndarray:
        return np.minimum(p - lo, hi - p).min(1) <= near_face

    return _fill_holes(loaded, scene, x_surface, cams, near_box, info, cache=cache, min_gap=min_gap,
                       smooth_slack=0.25 * near_face)


def thing_surface_fill(loaded: LoadedRun, scene: Scene, x_surface: np.ndarray, cams, *,
                       cache: dict | None = None, min_gap: float = 0.0) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Points of the rendered surface of things where the isosurface has none.

    Without depth maps an object's density often stays below the isosurface's threshold on the faces few depth
    targets reach, while its pixels render it in place: on images-only tuning rooms 10 and 22, 0.88 and 0.84 of
    the things' GT points lay within τ of the export (1.00 and 0.94 with this fill). A training view's rendered
    surface point is kept where the field labels it a thing class and the view's own 2D label at that pixel is
    the same class (without that, tuning room 22's precision fell 0.949 -> 0.914, with it 0.926, at the box fill's
    gap), more than three point spacings (and ``min_gap``) from every isosurface point, one per point spacing (as
    :func:`box_face_fill`). Stuff is not filled: the rendered surface of walls in an images-only field has layers
    in front of them (all of it on tuning room 10: precision 0.957 -> 0.842).

    Parameters and returns as :func:`box_face_fill`.
    """
    info: dict[str, Any] = {"rule": "rendered surface that the field and the view's 2D label both call one thing "
                                    "class, where the isosurface has no point"}
    things = np.asarray(sorted(scene.thing_ids), np.int64)

    def is_thing(p: np.ndarray, i: int, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        if not len(things) or not len(p):
            return np.zeros(len(p), bool)
        semantic = loaded.model.query_labels(p.astype(np.float32)).semantic
        return np.isin(semantic, things) & (scene.pseudo_labels(i).semantic[rows, cols] == semantic)

    return _fill_holes(loaded, scene, x_surface, cams, is_thing, info, cache=cache, min_gap=min_gap)


def _fill_holes(loaded: LoadedRun, scene: Scene, x_surface: np.ndarray, cams, where, info: dict[str, Any], *,
                cache: dict | None, min_gap: float, smooth_slack: float = 0.0
                ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """The training views' rendered surface (views without a depth map) where ``where(points, view, rows, cols)``
    (``[K, 3]`` normalised points, the view's index and their ``[K]`` pixel rows and columns at full resolution →
    ``[K] bool``) and more than three point spacings (and ``min_gap``) from every point of ``x_surface``, thinned
    to one per point spacing: ``(points, view directions, info)``.

    Each view is rendered (:func:`lift3d.export.views.rendered_depth`, shared with the label vote) and its depths
    back-projected where the opacity reaches one half and the depth agrees with its 3 × 3 median to within 2 %
    (+ ``smooth_slack`` in normalised units): not an edge between two surfaces."""
    from scipy.ndimage import median_filter
    from scipy.spatial import cKDTree

    frames = [int(i) for i in train_frames(scene) if scene.frames[int(i)].depth_path is None]
    empty = np.zeros((0, 3))
    info = dict(info, views=len(frames), points=0)
    if not frames or len(x_surface) < 2:
        return empty, empty, info
    spacing = typical_spacing(x_surface)
    if spacing <= 0:
        return empty, empty, info
    gap = max(3.0 * spacing, float(min_gap))
    # these views without a depth map, at the downscale the label vote renders them at: one render each
    depths = view_depths(scene, frames, rendered_depth(loaded, scene, cache))
    scale = float(loaded.norm.scale)
    tree = cKDTree(x_surface)
    pts, dirs = [], []
    for i, (depth, ds) in depths.items():
        smooth = np.abs(depth - median_filter(depth, size=3)) <= 0.02 * depth + smooth_slack / scale
        r, c = np.nonzero((depth > 0) & smooth)
        if not len(r):
            continue
        off = (ds - 1) / 2.0  # the centre of a ds x ds block, as a pixel index
        p = cams.unproject(i, c * ds + off, r * ds + off, depth[r, c] * scale)
        keep = tree.query(p, distance_upper_bound=gap)[0] > gap
        keep[keep] = where(p[keep], i, (r * ds + ds // 2)[keep], (c * ds + ds // 2)[keep])
        pts.append(p[keep]), dirs.append(view_directions(p[keep], cams.centers[i]))
    if not pts or not sum(len(p) for p in pts):
        return empty, empty, info
    pts, dirs = np.concatenate(pts), np.concatenate(dirs)
    first = np.unique(np.floor(pts / spacing).astype(np.int64), axis=0, return_index=True)[1]
    info.update(points=int(len(first)), spacing=float(spacing), gap=float(gap),
                downscale=next(iter(depths.values()))[1])
    return pts[first], dirs[first], info


def _tsdf_points(loaded: LoadedRun, scene: Scene, num_points: int, progress: bool,
                 timings: dict[str, float]) -> dict[str, Any]:
    """Area-uniform samples on the TSDF fusion of the training views' rendered depth, labelled by the heads."""
    t = time.perf_counter()
    fused = fuse_rendered_depth(loaded, scene, progress=progress)
    timings["tsdf"] = time.perf_counter() - t
    if len(fused.faces) == 0:
        raise InputError(loaded.run.path,
                         f"the fused rendered depth has no surface: {_why_no_fused_surface(fused.info)}")
    x, pick, bary = sample_surface(fused.vertices, fused.faces, num_points)
    rgb = (bary[:, :, None] * fused.colors[fused.faces[pick]].astype(np.float64)).sum(1)
    t = time.perf_counter()
    labels = loaded.model.query_labels(x.astype(np.float32), progress=progress)  # colour: the fused one
    timings["heads"] = time.perf_counter() - t
    return {"x": x, "labels": labels, "rgb": np.clip(rgb + 0.5, 0, 255).astype(np.uint8),
            "thresholds": {"tsdf": fused.info}, "link_radius_normalized": 4.0 * fused.voxel}


def _why_no_fused_surface(info: dict[str, Any]) -> str:
    """Why the training views' fused depth holds no surface, from :func:`fuse_rendered_depth`'s ``info``.

    Examples
    --------
    >>> _why_no_fused_surface({"min_opacity": 0.5, "opaque_pixels": 0, "fused_pixels": 0})
    'no training view renders an opacity of 0.5 anywhere: train longer'
    >>> _why_no_fused_surface({"min_opacity": 0.5, "opaque_pixels": 900, "fused_pixels": 0, "cube_half_width": 4.0,
    ...                        "median_opaque_depth": 160.4})  # doctest: +NORMALIZE_WHITESPACE
    'the training views are opaque only beyond the fused cube (median depth 160 normalised units; the cube reaches
    4), so the field has no foreground surface yet: train longer, or export with --source surface'
    """
    if not info.get("opaque_pixels"):
        return f"no training view renders an opacity of {info['min_opacity']} anywhere: train longer"
    if not info.get("fused_pixels"):
        return (f"the training views are opaque only beyond the fused cube (median depth "
                f"{info['median_opaque_depth']:.0f} normalised units; the cube reaches {info['cube_half_width']:g}), "
                "so the field has no foreground surface yet: train longer, or export with --source surface")
    return (f"{info['fused_pixels']} opaque pixels of the training views lie in the fused cube, but their depths do "
            "not agree on a surface: train longer, or export with --source surface")


def _ray_points(loaded: LoadedRun, scene: Scene, num_points: int, progress: bool,
                timings: dict[str, float]) -> dict[str, Any]:
    """Back-projected expected depth of random training rays with opacity > 0.5, labelled by the heads."""
    model = loaded.model
    rays = loaded.rays(scene)
    frames = train_frames(scene)
    rng = np.random.default_rng(0)
    xs, rgbs, dirs_kept = [], [], []
    have, drawn, keep_rate = 0, 0, 1.0
    t = time.perf_counter()
    for _ in range(4):  # a few rounds: opaque rays are a fraction of all rays
        need = num_points - have
        if need <= 0:
            break
        n = int(min(max(need / max(keep_rate, 0.05), 1024), 4 * num_points))
        frame = frames[rng.integers(0, len(frames), n)]
        u = torch.from_numpy(rng.random(n) * scene.cameras.width[frame] - 0.5)
        v = torch.from_numpy(rng.random(n) * scene.cameras.height[frame] - 0.5)
        o, d, _ = rays.rays(torch.from_numpy(frame), u, v)
        out = model.render_chunked(o, d, with_labels=False, progress=progress)
        opacity = out["opacity"].cpu()
        ok = (opacity > RAY_OPACITY_THRESHOLD).nonzero().squeeze(1)[:need]
        depth = out["depth"].cpu()[ok] / opacity[ok]
        o, d = o.cpu()[ok], d.cpu()[ok]
        xs.append((o + d * depth[:, None]).numpy())
        rgbs.append((out["rgb"].cpu()[ok].clamp(0, 1) * 255 + 0.5).to(torch.uint8).numpy())
        dirs_kept.append(d.numpy())
        drawn += n
        have += len(ok)
        keep_rate = max(have / drawn, 1e-3)
    timings["render"] = time.perf_counter() - t
    x = np.concatenate(xs) if xs else np.zeros((0, 3), np.float32)
    if len(x) == 0:
        raise InputError(loaded.run.path, "no training ray reaches opacity 0.5: the field is empty")
    t = time.perf_counter()
    labels = model.query_labels(x, np.concatenate(dirs_kept), progress=progress)
    timings["heads"] = time.perf_counter() - t
    field_voxel = 2.0 * (1.0 if model.bounded else 2.0) / lattice_resolution(model)
    return {"x": x.astype(np.float64), "labels": labels, "rgb": np.concatenate(rgbs),
            "thresholds": {"opacity": RAY_OPACITY_THRESHOLD, "rays_rendered": drawn},
            "link_radius_normalized": 2.0 * field_voxel}


# ------------------------------------------------------------------------------------------ benchmark
def benchmark_export(run_path, num_points: int = 1_000_000, output_dir=None) -> dict[str, float]:
    """Time a labelled point-cloud export of ``run_path``: extraction plus writing ``points.ply``.

    Importing Open3D and PyVista (``import_seconds``) and loading the checkpoint and the scene
    (``load_seconds``) are timed separately and not included in ``seconds``. ``peak_rss_mb`` is the
    process's peak resident memory so far (it includes whatever ran before in the same process: call it in
    a fresh process for a clean figure).

    Returns
    -------
    dict
        ``seconds``, ``peak_rss_mb``, ``load_seconds``, ``import_seconds``, ``extract_seconds``,
        ``write_seconds``, ``points``, ``threads`` (torch intra-op threads), ``stages`` (seconds per
        extraction stage).
    """
    t0 = time.perf_counter()
    import open3d  # noqa: F401  (library import time is process start-up, reported apart)
    import pyvista  # noqa: F401

    t_import = time.perf_counter() - t0
    t0 = time.perf_counter()
    loaded = load_run(run_path, "cpu")
    scene = loaded.scene()
    t1 = time.perf_counter()
    pts = extract_labelled_points(loaded, scene, num_points=num_points)
    t2 = time.perf_counter()
    if output_dir is not None:
        Path(output_dir).mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=output_dir) as tmp:
        write_labelled_ply(Path(tmp) / "points.ply", pts.xyz, rgb=pts.rgb, semantic=pts.semantic,
                           instance=pts.instance, confidence=pts.confidence)
        t3 = time.perf_counter()
    return {"seconds": t3 - t1, "peak_rss_mb": peak_rss_mb(), "load_seconds": t1 - t0, "import_seconds": t_import,
            "extract_seconds": t2 - t1, "write_seconds": t3 - t2, "points": int(len(pts)),
            "threads": torch.get_num_threads(), "stages": pts.stats.get("seconds", {})}


