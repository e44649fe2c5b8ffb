"""Where the export's points come from, before its steps (:mod:`lift3d.export.steps`) label and filter them.

``surface``
    Points sampled uniformly (by area) on the density isosurface of the field (:mod:`lift3d.export.isosurface`),
    keeping only surface that at least one training camera sees (:mod:`lift3d.export.visibility`), each with
    the direction from that camera (the colour head's input). The isosurface grid has the resolution of the
    field's finest grid (at least 128, at most 256 cells per axis): the density cannot change faster than that.
    Unbounded scenes are sampled in contracted space (so the foreground is dense and the background sparse, as
    pixels see it); far background beyond :data:`~lift3d.export.isosurface.UNBOUNDED_MAX_RADIUS` is skipped.
``tsdf``
    What the training views agree on: the rendered depth of every training view fused into a truncated signed
    distance volume (:mod:`lift3d.export.tsdf`; nerfstudio's ``ns-export tsdf``), its zero level set sampled
    uniformly by area; colour is the fused rendered colour.
``rays``
    nerfstudio's way: render expected depth for random training-camera rays (continuous pixel positions),
    back-project, keep rays whose opacity exceeds 0.5. Colour is the rendered colour. Slower (every point costs a
    rendered ray), and points follow the camera sampling rather than the surface.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from lift3d.data.scene import Scene
from lift3d.errors import InputError
from lift3d.export.isosurface import (
    choose_density_threshold,
    field_isosurface,
    lattice_resolution,
    point_surface_resolution,
    refine_to_rendered_surface,
)
from lift3d.export.points import LabelledPoints
from lift3d.export.tsdf import fuse_rendered_depth, sample_surface
from lift3d.export.visibility import CameraVisibility, normalized_cameras, train_frames, view_directions
from lift3d.field.encodings import uncontract
from lift3d.model.run import LoadedRun

#: Rays source: keep rays whose accumulated opacity exceeds this (nerfstudio's rule).
RAY_OPACITY_THRESHOLD = 0.5
#: Point sources of :func:`~lift3d.export.pointcloud.extract_labelled_points`, the default first.
SOURCES = ("auto", "surface", "tsdf", "rays")


@dataclass
class SourceSettings:
    """How the points are drawn (the flags of the same names)."""

    source: str = "auto"
    """auto, surface, tsdf or rays (:func:`resolve_point_source`)."""
    num_points: int = 1_000_000
    """Points drawn before the steps."""
    density_threshold: float | None = None
    """Isosurface density (normalised units); default fitted to the rendered depth."""
    refine_surface: bool = True
    """Move the isosurface onto the rendered surface before sampling."""

    def check(self) -> None:
        if self.source not in SOURCES:
            raise InputError("--source", f"unknown source {self.source!r} ({', '.join(SOURCES)})")
        if int(self.num_points) < 1:
            raise InputError("--num-points", f"must be at least 1, got {self.num_points}")


@dataclass
class DrawnPoints:
    """What a source drew: the points in normalised coordinates (``filled`` all False; ``dirs`` and ``rgb`` where
    the source has them), its thresholds for ``metadata.json``, its instance link radius (normalised units) and,
    for ``surface``, the training cameras in normalised coordinates."""

    points: LabelledPoints
    thresholds: dict[str, Any]
    grid_link: float
    cameras: Any = None


def draw_points(loaded: LoadedRun, scene: Scene, settings: SourceSettings, source: str, progress: bool,
                timings: dict[str, float]) -> DrawnPoints:
    """The points of ``source`` (resolved: not ``auto``); the seconds of its stages go to ``timings``."""
    draw = {"surface": _surface_points, "tsdf": _tsdf_points, "rays": _ray_points}[source]
    drawn = draw(loaded, scene, settings, progress, timings)
    drawn.points.filled = np.zeros(len(drawn.points), bool)
    return drawn


def resolve_point_source(source: str, loaded: LoadedRun, scene: Scene) -> tuple[str, str]:
    """The source ``auto`` stands for, and why: ``tsdf`` for an unbounded scene (a street) whose every training
    frame has a depth map, where the fused depth scored better in 3D
    (docs/notes/2026-11-29-benchmark-history.md, "Export sources":
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


def _surface_points(loaded: LoadedRun, scene: Scene, settings: SourceSettings, progress: bool,
                    timings: dict[str, float]) -> DrawnPoints:
    """Area-uniform samples on the seen part of the isosurface, each with the direction a camera sees it along."""
    model = loaded.model
    density_threshold = settings.density_threshold
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
    if settings.refine_surface:
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
    points_grid, pick, _ = sample_surface(surface.grid_vertices.astype(np.float64), surface.faces[seen],
                                          settings.num_points)
    x = uncontract(points_grid, surface.contraction) if surface.contraction != "none" else points_grid
    dirs = view_directions(x, cams.centers[seen_by[seen[pick]]])
    thresholds = {
        "density": tau, "density_rule": info, "surface_resolution": surface.resolution,
        "refine": surface.stats.get("refine", "off (points on the exact isosurface)"),
        "visibility": {"rule": "in a training camera's image, beyond its near plane, no isosurface between "
                               "camera and point", "occluder_tolerance": surface.voxel, "near": near},
    }
    # instances link across about two grid cells
    return DrawnPoints(LabelledPoints(x, dirs=dirs), thresholds, grid_link=2.0 * surface.voxel, cameras=cams)


def _tsdf_points(loaded: LoadedRun, scene: Scene, settings: SourceSettings, progress: bool,
                 timings: dict[str, float]) -> DrawnPoints:
    """Area-uniform samples on the TSDF fusion of the training views' rendered depth, with the fused colour."""
    t = time.perf_counter()
    fused = fuse_rendered_depth(loaded, scene, progress=progress)
    timings["tsdf"] = time.perf_counter() - t
    if len(fused.faces) == 0:
        raise InputError(loaded.run.path,
                         f"the fused rendered depth has no surface: {_why_no_fused_surface(fused.info)}")
    x, pick, bary = sample_surface(fused.vertices, fused.faces, settings.num_points)
    rgb = (bary[:, :, None] * fused.colors[fused.faces[pick]].astype(np.float64)).sum(1)
    return DrawnPoints(LabelledPoints(x, rgb=np.clip(rgb + 0.5, 0, 255).astype(np.uint8)), {"tsdf": fused.info},
                       grid_link=4.0 * fused.voxel)


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


def _ray_points(loaded: LoadedRun, scene: Scene, settings: SourceSettings, progress: bool,
                timings: dict[str, float]) -> DrawnPoints:
    """Back-projected expected depth of random training rays with opacity > 0.5, with the rendered colour."""
    model, num_points = loaded.model, settings.num_points
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
    field_voxel = 2.0 * (1.0 if model.bounded else 2.0) / lattice_resolution(model)
    points = LabelledPoints(x.astype(np.float64), rgb=np.concatenate(rgbs), dirs=np.concatenate(dirs_kept))
    return DrawnPoints(points, {"opacity": RAY_OPACITY_THRESHOLD, "rays_rendered": drawn},
                       grid_link=2.0 * field_voxel)
