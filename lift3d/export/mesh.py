"""The labelled mesh (``lift3d export --mesh``): the density isosurface (:mod:`lift3d.export.isosurface`) with
labels queried at every vertex, and its instance ids matched to a point cloud's.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from lift3d.data.scene import Scene
from lift3d.export.frames import check_frame, length_to_frame, to_frame, world_from_normalized
from lift3d.export.instances import assign_instances
from lift3d.export.isosurface import (
    FieldSurface,
    choose_density_threshold,
    field_isosurface,
    point_surface_resolution,
    refine_to_rendered_surface,
)
from lift3d.export.stuff import orient_stuff_labels
from lift3d.export.views import vote_stuff_labels
from lift3d.export.visibility import normalized_cameras, train_frames, view_directions
from lift3d.model.run import LoadedRun
from lift3d.utils.device import resolve_device


# ------------------------------------------------------------------------------------------ labelled mesh
@dataclass
class LabelledMesh:
    """A triangle mesh with per-vertex labels, in the export frame."""

    vertices: np.ndarray  # [V, 3] float32
    faces: np.ndarray  # [M, 3] int64
    rgb: np.ndarray  # [V, 3] uint8
    semantic: np.ndarray  # [V] int32
    instance: np.ndarray  # [V] int32
    confidence: np.ndarray  # [V] float32
    frame: str
    transform: np.ndarray  # 4x4 world <- normalised
    thresholds: dict[str, Any]
    stats: dict[str, Any] = field(default_factory=dict)


def extract_labelled_mesh(loaded: LoadedRun, scene: Scene, *, resolution: int = 256, density_threshold: float | None = None,
                          refine_surface: bool = True, frame: str = "world", min_points: int = 0,
                          orient_stuff: bool = True, view_vote: bool = True, view_depth_cache: dict | None = None,
                          device=None, progress: bool = False) -> LabelledMesh:
    """The density isosurface with labels queried at every vertex.

    Vertex colour is the colour head seen from the nearest training camera. Instances follow
    :func:`lift3d.export.instances.assign_instances` on the vertices (link radius two grid cells), so ids
    are contiguous and ordered by vertex count; :func:`match_instance_ids` re-numbers them to agree with a
    point cloud exported from the same run.

    Parameters
    ----------
    loaded : LoadedRun
    scene : Scene
    resolution : int
        Grid cells per axis (default 256).
    density_threshold : float, optional
        Overrides :func:`choose_density_threshold`.
    refine_surface : bool
        Move the vertices onto the rendered surface (:func:`refine_to_rendered_surface`; default on).
    frame : {"world", "normalized"}
    min_points : int
        Instance fragments with fewer vertices are relabelled (see ``assign_instances``).
    orient_stuff : bool
        Stuff vertices take the class their surface's orientation says, as the point cloud's do
        (:func:`lift3d.export.stuff.orient_stuff_labels`, over the same distance; default on).
    view_vote : bool
        Vertices take the stuff class the training views' 2D labels agree on, as the point cloud's do
        (:mod:`lift3d.export.views`; default on).
    view_depth_cache : dict, optional
        The renders of that step, shared with the point cloud's (:func:`lift3d.export.views.rendered_depth`).
    device : str, optional
        Move the model to this device first.
    """
    check_frame(frame)
    if device is not None:
        loaded.model.to(resolve_device(device))
    model = loaded.model
    if density_threshold is None:
        tau, info = choose_density_threshold(loaded, scene)
    else:
        tau = float(density_threshold)
        info = {"rule": "set by the user (--density-threshold)", "value": tau}
    surface = field_isosurface(model, tau, resolution, progress=progress)
    if refine_surface:
        surface = refine_to_rendered_surface(model, surface)
    cams = normalized_cameras(loaded, scene)
    centers = cams.centers[train_frames(scene)]
    dirs = np.zeros((0, 3), np.float32)
    if len(surface.vertices):
        _, nearest = cKDTree(centers).query(surface.vertices.astype(np.float64), workers=-1)
        dirs = view_directions(surface.vertices, centers[nearest])
    labels = model.query_labels(surface.vertices, dirs, progress=progress, desc="label vertices")
    transform = world_from_normalized(loaded.norm)
    xyz = to_frame(surface.vertices, transform, frame)
    grid_step_out = length_to_frame(_normalized_voxel(surface), loaded.norm, frame)
    semantic = labels.semantic
    channel = labels.channel
    thresholds: dict[str, Any] = {}
    if view_vote and len(xyz):
        # As the point cloud's step (lift3d.export.views), within half of the point cloud's grid cell.
        point_voxel_world = _normalized_voxel(surface) * surface.resolution / point_surface_resolution(model) \
            / float(loaded.norm.scale)
        semantic, channel, thresholds["view_vote"] = vote_stuff_labels(
            to_frame(surface.vertices, transform, "world"), semantic, channel, loaded, scene, train_frames(scene),
            abs_tolerance=0.5 * point_voxel_world, depth_cache=view_depth_cache)
    if orient_stuff:
        # The point cloud's distance (two link radii of its grid: four of its cells), whatever this mesh's
        # resolution, so that points and mesh label an edge alike.
        point_cell = grid_step_out * surface.resolution / point_surface_resolution(model)
        semantic, thresholds["stuff_orientation"] = orient_stuff_labels(xyz, semantic, scene.stuff_ids,
                                                                        radius=4.0 * point_cell)
    assignment = assign_instances(xyz, semantic, channel, link_radius=2.0 * grid_step_out,
                                  min_points=min_points)
    faces = surface.faces
    keep = assignment.keep
    if not keep.all():
        faces = faces[keep[faces].all(-1)]
        remap = np.cumsum(keep) - 1
        faces = remap[faces]
    thresholds.update(density=tau, density_rule=info, resolution=surface.resolution,
                      refine=surface.stats.get("refine", "off (vertices on the exact isosurface)"))
    return LabelledMesh(
        vertices=xyz[keep].astype(np.float32), faces=faces.astype(np.int64), rgb=labels.rgb[keep],
        semantic=assignment.semantic[keep], instance=assignment.instance[keep],
        confidence=labels.confidence[keep], frame=frame, transform=transform, thresholds=thresholds,
        stats={**surface.stats, "instances": assignment.stats},
    )


def match_instance_ids(mesh: LabelledMesh, xyz: np.ndarray, semantic: np.ndarray, instance: np.ndarray) -> None:
    """Re-number mesh instances (in place) to the point-cloud instance they overlap most.

    Every mesh vertex votes for the instance of its nearest point when that point has the same class; a
    mesh instance takes the id with most votes if no other mesh instance took it already, else (and when it
    has no votes) a new id after the point cloud's largest.
    """
    if not len(mesh.vertices) or not len(xyz) or mesh.instance.max(initial=0) == 0:
        return
    _, nn = cKDTree(np.asarray(xyz, np.float64)).query(mesh.vertices.astype(np.float64), workers=-1)
    vote = np.where(semantic[nn] == mesh.semantic, instance[nn], 0)
    mesh_ids = np.unique(mesh.instance[mesh.instance > 0])
    sizes = np.array([(mesh.instance == m).sum() for m in mesh_ids])
    taken: set[int] = set()
    next_id = int(np.max(instance, initial=0)) + 1
    new_of: dict[int, int] = {}
    for m in mesh_ids[np.argsort(-sizes, kind="stable")]:  # larger mesh instances choose first
        votes = vote[(mesh.instance == m) & (vote > 0)]
        choice = 0
        if len(votes):
            ids, counts = np.unique(votes, return_counts=True)
            for cand in ids[np.argsort(-counts, kind="stable")]:
                if int(cand) not in taken:
                    choice = int(cand)
                    break
        if choice == 0:
            choice, next_id = next_id, next_id + 1
        taken.add(choice)
        new_of[int(m)] = choice
    lut = np.zeros(int(mesh.instance.max()) + 1, np.int32)
    for m, c in new_of.items():
        lut[m] = c
    mesh.instance = lut[mesh.instance]


def _normalized_voxel(surface: FieldSurface) -> float:
    """Grid cell size in normalised units near the foreground (contraction is the identity there)."""
    return surface.voxel
