"""Steps that keep a subset of the points or move them all: the views' surface, the sensor's surface, the
confidence filter, the output frame, the crop box, outlier removal and voxel down-sampling."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from lift3d.errors import InputError
from lift3d.export.frames import check_frame, to_frame
from lift3d.export.instances import voxel_downsample_majority
from lift3d.export.points import OrientedBox
from lift3d.export.steps.base import ExportStep, PointState, StepContext
from lift3d.export.views import rendered_depth, view_depths, views_on_surface
from lift3d.export.visibility import train_frames


def _on_views_surfaces(points, context: StepContext, depths: dict, tolerance_voxels: float, min_views: int):
    """``(keep, views, covered, tolerance)``: the points that at least ``min_views`` of the views' surfaces
    (:func:`lift3d.export.views.views_on_surface`) pass within ``tolerance_voxels`` voxels of, or that no view covers;
    the tolerance in world units."""
    # grid_link is two voxels of the source's grid (normalised units)
    tolerance = tolerance_voxels * 0.5 * context.grid_link / float(context.loaded.norm.scale)
    views, covered = views_on_surface(context.world(points), context.scene, depths, tolerance)
    return (views >= min_views) | (covered == 0), views, covered, tolerance


@dataclass
class ViewSurface(ExportStep):
    """Only the isosurface the training views render stays: a point goes when views render a surface at its pixel
    (the field's depth where a ray's opacity reaches 0.5) and fewer than ``min_views`` of those surfaces pass
    within ``tolerance_voxels`` isosurface voxels of it. The density isosurface also holds what no view renders:
    surface behind the one a view sees (a field that is not opaque at its first surface leaves density behind it,
    and the isosurface's holes let the visibility test see it) and floaters the rays pass through. A point at
    whose pixel no view renders an opaque surface stays: nothing says it is not there."""

    name = "view-surface"
    flags = {"enabled": "--no-view-surface"}
    needs_points = True
    tolerance_voxels: float = 1.0
    """How far from a view's rendered depth a point may lie, in voxels of the isosurface grid (the field's finest
    grid): the rendered depth and the isosurface of one good surface differ by about that much."""
    min_views: int = 1
    """Fewest views whose surface must pass through a point."""

    def check(self) -> None:
        if self.tolerance_voxels < 0 or self.min_views < 1:
            raise InputError("--view-surface.*", "tolerance-voxels must be >= 0 and min-views >= 1")

    def skip(self, state: PointState, context: StepContext) -> str | None:
        if context.source != "surface":
            return f"the {context.source} source draws the views' surfaces already"
        return super().skip(state, context)

    def apply(self, state: PointState, context: StepContext) -> dict:
        scene, p = context.scene, state.points
        depths = view_depths(scene, train_frames(scene), rendered_depth(context.loaded, scene, context.view_depth_cache),
                             own_depth=False)
        keep, views, covered, tolerance = _on_views_surfaces(p, context, depths, self.tolerance_voxels, self.min_views)
        state.points = p.take(keep)
        downscale = next(iter(depths.values()))[1] if depths else 1
        return {"removed": int((~keep).sum()), "views": len(depths), "downscale": int(downscale),
                "tolerance": round(tolerance, 5), "median_views": float(np.median(views)) if len(views) else 0.0}


@dataclass
class SensorSurface(ExportStep):
    """Only surface the depth sensor saw stays: a point goes when training frames' own depth maps cover its pixel
    and none of them passes within ``tolerance_voxels`` voxels of it. Where the scene has depth maps, they are
    better evidence than the field's rendered depth (``view-surface``): a field trained on them still holds surface
    the sensor never saw (the far side of a thin object; a wall seen through the holes the isosurface has in the
    chair in front of it), and the visibility test lets it through. A point no depth map covers (the sensor's
    holes: glass, dark or shiny surfaces, beyond its range) stays: nothing says it is not there. Frames whose depth
    is kept for evaluation only (``lift3d convert --depth-as-gt``) are never used."""

    name = "sensor-surface"
    flags = {"enabled": "--no-sensor-surface"}
    needs_points = True
    tolerance_voxels: float = 1.0
    """How far from a depth map's surface a point may lie, in voxels of the source's grid (the isosurface grid
    for ``surface``): the field's own resolution, as for ``view-surface`` (a depth camera's noise is below it
    within a few metres)."""
    min_views: int = 1
    """Fewest depth maps whose surface must pass through a point."""

    def check(self) -> None:
        if self.tolerance_voxels < 0 or self.min_views < 1:
            raise InputError("--sensor-surface.*", "tolerance-voxels must be >= 0 and min-views >= 1")

    def skip(self, state: PointState, context: StepContext) -> str | None:
        scene = context.scene
        if not any(scene.frames[int(i)].depth_path is not None for i in train_frames(scene)):
            return "no training frame has a depth map"
        return super().skip(state, context)

    def apply(self, state: PointState, context: StepContext) -> dict:
        scene, p = context.scene, state.points
        depths = view_depths(scene, train_frames(scene), None)  # the frames' own depth maps only
        keep, views, covered, tolerance = _on_views_surfaces(p, context, depths, self.tolerance_voxels, self.min_views)
        state.points = p.take(keep)
        return {"removed": int((~keep).sum()), "depth_maps": len(depths), "tolerance": round(tolerance, 5),
                "uncovered": int((covered == 0).sum()),
                "median_views": float(np.median(views)) if len(views) else 0.0}


@dataclass
class ConfidenceFilter(ExportStep):
    """Points whose chosen class has a lower probability than ``min_confidence`` are dropped."""

    name = "confidence-filter"
    flags = {"min_confidence": "--min-confidence"}
    min_confidence: float = 0.0
    """Drop points whose class probability is below this (0 = keep all)."""

    def check(self) -> None:
        if not 0.0 <= self.min_confidence <= 1.0:
            raise InputError("--min-confidence", f"must be in [0, 1], got {self.min_confidence}")

    def skip(self, state: PointState, context: StepContext) -> str | None:
        return None if self.min_confidence > 0 else "min_confidence 0: every point stays"

    def apply(self, state: PointState, context: StepContext) -> dict:
        p = state.points
        keep = p.confidence >= self.min_confidence
        state.points = p.take(keep)
        return {"removed": int(len(keep) - keep.sum())}


@dataclass
class FrameConversion(ExportStep):
    """The points move from the field's normalised coordinates into the output frame."""

    name = "frame-conversion"
    switchable = False
    flags = {"frame": "--frame"}
    frame: str = field(default="world", metadata={"choices": ("world", "normalized")})
    """Output coordinates: world (the input poses' frame) or normalized (the field's, the foreground box is
    [-1, 1]^3)."""

    def check(self) -> None:
        check_frame(self.frame)

    def apply(self, state: PointState, context: StepContext) -> dict:
        p = state.points
        state.points = replace(p, xyz=to_frame(p.xyz, context.transform, self.frame), frame=self.frame)
        return {"frame": self.frame}


@dataclass
class Crop(ExportStep):
    """Only the points inside an oriented box (output frame) stay: nerfstudio's ``--obb-*`` convention, rotation
    as roll, pitch, yaw in radians about x, y, z (``R = Rz(yaw) Ry(pitch) Rx(roll)``)."""

    name = "crop"
    flags = {"center": "--obb-center", "rotation": "--obb-rotation", "scale": "--obb-scale"}
    center: tuple[float, float, float] | None = None
    """Crop box centre (default 0 0 0)."""
    rotation: tuple[float, float, float] | None = None
    """Crop box rotation: roll, pitch, yaw in radians (default 0 0 0)."""
    scale: tuple[float, float, float] | None = None
    """Crop box side lengths: the box is used when they are given."""
    box: Any = field(default=None, metadata={"flag": False})
    """Python only (``obb=``): an OrientedBox, an Open3D OrientedBoundingBox or a dict with center, rotation, scale;
    used instead of the three settings above."""

    def oriented_box(self) -> OrientedBox | None:
        """The crop box, or None when no box is given."""
        if self.box is not None:
            return OrientedBox.coerce(self.box)
        if self.scale is None:
            return None
        return OrientedBox.from_params(self.center or (0, 0, 0), self.rotation or (0, 0, 0), self.scale)

    def check(self) -> None:
        if self.box is None and self.scale is None and (self.center is not None or self.rotation is not None):
            raise InputError("--obb-scale", "a crop box needs its side lengths (--obb-scale SX SY SZ)")
        self.oriented_box()  # checks the side lengths

    def skip(self, state: PointState, context: StepContext) -> str | None:
        return None if self.box is not None or self.scale is not None else "no crop box"

    def apply(self, state: PointState, context: StepContext) -> dict:
        box = self.oriented_box()
        inside = box.contains(state.points.xyz)
        state.points, state.crop = state.points.take(inside), box
        return {"box": {"center": box.center.tolist(), "R": box.R.tolist(), "scale": box.scale.tolist()},
                "removed": int(len(inside) - inside.sum())}


@dataclass
class OutlierRemoval(ExportStep):
    """Open3D's statistical outlier removal: a point goes when its mean distance to its neighbours is more than
    ``std_ratio`` standard deviations above the average."""

    name = "outlier-removal"
    flags = {"enabled": "--remove-outliers", "std_ratio": "--std-ratio"}
    enabled: bool = False
    neighbours: int = 20
    """Neighbours per point (nerfstudio and Open3D's tutorial use 20)."""
    std_ratio: float = 2.0
    """Outlier threshold in standard deviations."""

    def check(self) -> None:
        if self.std_ratio <= 0:
            raise InputError("--std-ratio", f"must be > 0, got {self.std_ratio}")

    def skip(self, state: PointState, context: StepContext) -> str | None:
        return None if len(state.points) > self.neighbours else "no more points than neighbours"

    def apply(self, state: PointState, context: StepContext) -> dict:
        import open3d as o3d

        p = state.points
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p.xyz))
        _, kept = cloud.remove_statistical_outlier(nb_neighbors=self.neighbours, std_ratio=float(self.std_ratio))
        state.points = p.take(np.sort(np.asarray(kept, np.int64)))
        return {"removed": len(p) - len(state.points)}


@dataclass
class VoxelDownsample(ExportStep):
    """One point per voxel: position and colour the voxel means, (class, instance channel) the majority, confidence
    the mean of the majority's points (:func:`lift3d.export.instances.voxel_downsample_majority`)."""

    name = "voxel-downsample"
    flags = {"voxel_size": "--voxel-size"}
    voxel_size: float = 0.0
    """Voxel side in output units (0 = off)."""

    def check(self) -> None:
        if self.voxel_size < 0 or not math.isfinite(self.voxel_size):
            raise InputError("--voxel-size", f"must be a finite size >= 0, got {self.voxel_size}")

    def skip(self, state: PointState, context: StepContext) -> str | None:
        return None if self.voxel_size > 0 else "voxel_size 0: every point stays"

    def apply(self, state: PointState, context: StepContext) -> dict:
        from scipy.spatial import cKDTree

        p = state.points
        state.voxel_size = float(self.voxel_size)
        if not len(p):
            return {"voxels": 0}
        xyz, rgb, semantic, channel, confidence = voxel_downsample_majority(p.xyz, p.rgb, p.semantic, p.channel,
                                                                            p.confidence, self.voxel_size)
        filled = p.filled[cKDTree(p.xyz).query(xyz)[1]] if p.filled.any() else np.zeros(len(xyz), bool)
        state.points = context.with_field_labels(replace(
            p, xyz=xyz, rgb=rgb, semantic=semantic, channel=channel, confidence=confidence, filled=filled,
            field_semantic=None if p.field_semantic is None else np.zeros(len(xyz), np.int32),
            field_channel=None if p.field_channel is None else np.zeros(len(xyz), np.int32)))
        return {"voxels": len(xyz)}
