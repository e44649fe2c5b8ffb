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
    :data:`~lift3d.export.isosurface.UNBOUNDED_MAX_RADIUS` is skipped.
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
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lift3d.data.ply import write_labelled_ply
from lift3d.data.scene import Scene
from lift3d.errors import InputError
from lift3d.export.cleanup import clean_instances
from lift3d.export.fills import box_face_fill, thing_surface_fill
from lift3d.export.frames import check_frame, to_frame, world_from_normalized
from lift3d.export.instances import assign_instances, join_filled_instances, voxel_downsample_majority
from lift3d.export.isosurface import (
    choose_density_threshold,
    field_isosurface,
    lattice_resolution,
    point_surface_resolution,
    refine_to_rendered_surface,
)
from lift3d.export.points import LabelledPoints, OrientedBox, default_crumb_points, typical_spacing
from lift3d.export.stuff import complete_stuff_corners, orient_stuff_labels
from lift3d.export.views import vote_stuff_labels
from lift3d.export.visibility import CameraVisibility, normalized_cameras, train_frames, view_directions
from lift3d.export.tsdf import fuse_rendered_depth, sample_surface
from lift3d.field.encodings import uncontract
from lift3d.model.run import LoadedRun, load_run
from lift3d.sfm.mvs import scene_up
from lift3d.utils.device import resolve_device
from lift3d.utils.memory import peak_rss_mb

#: Rays source: keep rays whose accumulated opacity exceeds this (nerfstudio's rule).
RAY_OPACITY_THRESHOLD = 0.5
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


# ------------------------------------------------------------------------------------------ main entry
def resolve_point_source(source: str, loaded: LoadedRun, scene: Scene) -> tuple[str, str]:
    """The source ``auto`` stands for, and why: ``tsdf`` for an unbounded scene (a street) whose every training
    frame has a depth map, where the fused depth scored better in 3D (docs/benchmarks.md, "Export sources":
    F-score +0.06 on the reporting streets, +0.13 / +0.02 on two tuning streets; the isosurface reached 62–87 %
    of their GT points); ``surface`` everywhere else (rooms, and streets from images alone, where the fused
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
        (:func:`lift3d.export.isosurface.choose_density_threshold`).
    refine_surface : bool
        ``surface`` source: move the isosurface onto the rendered surface before sampling
        (:func:`lift3d.export.isosurface.refine_to_rendered_surface`; default on). Off: points lie exactly on
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
    check_frame(frame)
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



def _tsdf_points(loaded: LoadedRun, scene: Scene, num_points: int, progress: bool,
                 timings: dict[str, float]) -> dict[str, Any]:
    """Area-uniform samples on the TSDF fusion of the training views' rendered depth, labelled by the heads."""
    t = time.perf_counter()
    fused = fuse_rendered_depth(loaded, scene, progress=progress)
    timings["tsdf"] = time.perf_counter() - t
    if len(fused.faces) == 0:
        raise InputError(loaded.run.path, "the fused rendered depth has no surface (no training view renders an "
                                          f"opacity of {fused.info['min_opacity']} anywhere: train longer)")
    x, pick, bary = sample_surface(fused.vertices, fused.faces, num_points)
    rgb = (bary[:, :, None] * fused.colors[fused.faces[pick]].astype(np.float64)).sum(1)
    t = time.perf_counter()
    labels = loaded.model.query_labels(x.astype(np.float32), progress=progress)  # colour: the fused one
    timings["heads"] = time.perf_counter() - t
    return {"x": x, "labels": labels, "rgb": np.clip(rgb + 0.5, 0, 255).astype(np.uint8),
            "thresholds": {"tsdf": fused.info}, "link_radius_normalized": 4.0 * fused.voxel}


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


