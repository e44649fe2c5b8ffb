"""Labelled geometry out of a trained run: what robot mapping consumes (docs/export.md).

Modules:

- :mod:`lift3d.export.pointcloud` — :func:`extract_labelled_points` (surface, tsdf or rays source, then the steps);
- :mod:`lift3d.export.points` — :class:`LabelledPoints` (the points the steps pass on), the crop box;
- :mod:`lift3d.export.isosurface` — density threshold, chunked density grid, isosurface and its refinement;
- :mod:`lift3d.export.visibility` — training frames and cameras, which camera sees a surface point;
- :mod:`lift3d.export.fills` — the rendered surface where the isosurface has a hole (box faces, things);
- :mod:`lift3d.export.frames` — world or normalised output coordinates;
- :mod:`lift3d.export.mesh` — :func:`~lift3d.export.mesh.extract_labelled_mesh`, the labelled isosurface;
- :mod:`lift3d.export.instances` — label heads at points, stable instance ids, per-instance records;
- :mod:`lift3d.export.writers` — the ``--format`` registry: one writer class per file format (PLY and its
  CloudCompare flavour, PCD, SemanticKITTI, ROS 2 bag, OctoMap, Nav2 map);
- :mod:`lift3d.export.json_files` — ``classes.json`` / ``instances.json`` / ``metadata.json``;
- :mod:`lift3d.export.scene_graph` — ``scene_graph.json`` (objects, the stuff they stand on, relations);
- :mod:`lift3d.export.ground` — the scene's up axis and its floor-like classes;
- :mod:`lift3d.export.renders` — :func:`~lift3d.export.renders.render_to_folder` (``lift3d render``), with the
  exported objects' ids in the instance images;
- :mod:`lift3d.export.api` — loading exports downstream (``lift3d.load_labelled_points``, ``lift3d.instances``).

:func:`export_run` is what ``lift3d export`` runs. Importing this package is cheap (``lift3d.load_labelled_points``
reads exports through it): the modules that need torch, Open3D or PyVista load only when a function needs
them.

Examples
--------
Export a run's labelled point cloud and mesh into a folder, then read it back::

    from lift3d.export import export_run
    summary = export_run("outputs/room0/fast/2026-11-22_101500", "export", pointcloud=True, mesh=True)
    import lift3d
    pts = lift3d.load_labelled_points("export/points.ply")
"""

from __future__ import annotations

import dataclasses
import re
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lift3d import __version__
from lift3d.data.ply import write_labelled_ply
from lift3d.errors import InputError
from lift3d.export import json_files
from lift3d.export.ground import floor_class_ids, resolve_up
from lift3d.export.scene_graph import build_scene_graph, write_scene_graph_json
from lift3d.export.writers import ExportContext, ExportOptions, check_formats
from lift3d.utils.files import check_writable

if TYPE_CHECKING:  # torch-backed types, for annotations only (see the module docstring)
    from lift3d.data.scene import Scene
    from lift3d.model.run import LoadedRun

__all__ = ["export_run", "extract_labelled_points", "LabelledPoints", "benchmark_export", "ExportOptions"]


def __getattr__(name: str):
    if name in ("extract_labelled_points", "LabelledPoints", "benchmark_export", "OrientedBox"):
        from lift3d.export import pointcloud  # on first use: keeps `import lift3d.export` cheap

        return getattr(pointcloud, name)
    raise AttributeError(f"module 'lift3d.export' has no attribute {name!r}")


def export_run(run: str | Path, output_dir: str | Path | None = None, *, pointcloud: bool = True, mesh: bool = False,
               formats: tuple[str, ...] | list[str] = ("ply",), data: str | Path | None = None,
               split_instances: bool = False, resolution: int = 256, options=None,
               command: str | None = None, progress: bool = False, loaded: LoadedRun | None = None,
               scene: Scene | None = None,
               **point_options: Any) -> dict[str, Any]:
    """Export a trained run's labelled geometry into ``output_dir`` (every file written atomically).

    Parameters
    ----------
    run : str or Path
        Run folder.
    output_dir : str or Path, optional
        Destination (created); default ``<run>/export``.
    pointcloud, mesh : bool
        What to export.
    formats : sequence of str
        Names of :data:`lift3d.export.writers.WRITERS`: ``ply`` (``points.ply``), ``ply-cloudcompare``,
        ``pcd``, ``label`` (SemanticKITTI), ``ros2bag``, ``octomap``, ``nav2``. Optional libraries are checked
        before any work starts.
    data : str or Path, optional
        The scene folder, when it moved since training.
    split_instances : bool
        With ``mesh``: also write ``instances/<id>_<class>.ply``, one sub-mesh per instance.
    resolution : int
        Mesh grid cells per axis.
    options : lift3d.export.writers.ExportOptions, optional
        Settings of the format writers (ROS frame id, map resolution, up axis, floor classes, ...).
    command : str, optional
        Recorded in ``metadata.json`` (default: this process's command line).
    loaded, scene : optional
        An already loaded run and scene (skips loading).
    **point_options
        Passed to :func:`~lift3d.export.pointcloud.extract_labelled_points` (``source``, ``num_points``,
        ``frame``, ``density_threshold``, ``refine_surface``, ``min_confidence``, ``voxel_size``,
        ``remove_outliers``, ``std_ratio``, ``obb``, ``min_points``, ``box_fill``, ``thing_fill``,
        ``complete_corners``, ``device``).

    Returns
    -------
    dict
        Paths written, counts, thresholds and seconds.
    """
    # torch-backed modules load here, not at import: keeps `import lift3d.export` cheap
    from lift3d.export.instances import instance_records
    from lift3d.export.mesh import extract_labelled_mesh, match_instance_ids
    from lift3d.export.pointcloud import extract_labelled_points
    from lift3d.model.run import load_run

    options = options if options is not None else ExportOptions()
    writers = check_formats(formats)  # unknown names and missing extras fail before any work
    if not pointcloud and not mesh:
        raise InputError("lift3d export", "nothing to export: give --pointcloud and/or --mesh")
    out = check_writable(output_dir if output_dir is not None else Path(run) / "export", folder=True)
    started = time.perf_counter()
    if loaded is None:
        loaded = load_run(run, point_options.get("device") or "auto")
    if scene is None:
        scene = loaded.scene(data)
    frame = point_options.get("frame", "world")
    units = "normalized scene units (world units x scale)" if frame == "normalized" else \
        "world units of transforms.json (metres for lift3d synth scenes)"
    classes = json_files.class_table(scene.categories, loaded.labels.semantic_ids)
    names = {c["id"]: c["name"] for c in classes}
    # Options that depend on the scene are checked before the (long) extraction.
    up, up_reason = resolve_up(options.up, scene.cameras.c2w)
    floor_class_ids(classes, options.floor_classes)
    written: list[str] = []
    summary: dict[str, Any] = {"output_dir": str(out), "files": written}
    thresholds: dict[str, Any] = {}
    comments = [f"lift3d {__version__} export", f"frame {frame}", f"source run {loaded.run.path}"]
    pts = labelled = None
    view_depths: dict = {}  # the vote's renders of views without depth maps, done once for points and mesh
    if pointcloud:
        pts = extract_labelled_points(loaded, scene, progress=progress, view_depth_cache=view_depths, **point_options)
        thresholds["points"] = pts.thresholds
        summary.update(points=len(pts), point_stats=pts.stats)
    if mesh:
        labelled = extract_labelled_mesh(loaded, scene, resolution=resolution,
                                         density_threshold=point_options.get("density_threshold"),
                                         refine_surface=point_options.get("refine_surface", True), frame=frame,
                                         min_points=point_options.get("min_points", 0),
                                         orient_stuff=point_options.get("orient_stuff", True),
                                         view_vote=point_options.get("view_vote", True),
                                         view_depth_cache=view_depths, progress=progress)
        if pts is not None:
            match_instance_ids(labelled, pts.xyz, pts.semantic, pts.instance)
        write_labelled_ply(out / "mesh.ply", labelled.vertices, rgb=labelled.rgb, semantic=labelled.semantic,
                           instance=labelled.instance, confidence=labelled.confidence, faces=labelled.faces,
                           comments=comments)
        written.append("mesh.ply")
        thresholds["mesh"] = labelled.thresholds
        summary.update(mesh_vertices=int(len(labelled.vertices)), mesh_faces=int(len(labelled.faces)))
        if split_instances:
            written += _write_instance_meshes(out / "instances", labelled, names)
    # Instances (and the scene graph) come from the points, or from the mesh vertices with --mesh alone.
    if pts is not None:
        geo = (pts.xyz, pts.semantic, pts.instance, pts.confidence)
        source, link = "points", pts.thresholds.get("instance_link_radius")
    else:
        geo = (labelled.vertices, labelled.semantic, labelled.instance, labelled.confidence)
        source, link = "mesh vertices", labelled.thresholds.get("instance_link_radius")
    transform = np.asarray(pts.transform if pts is not None else labelled.transform)
    # The export's own length scale (about two field grid cells), for map cells when the user gave none.
    if point_options.get("voxel_size"):
        default_resolution, resolution_reason = float(point_options["voxel_size"]), "--voxel-size"
    elif link:
        default_resolution, resolution_reason = float(link), "the instance link radius (about two field grid cells)"
    else:
        default_resolution, resolution_reason = _world_cell(transform, frame), "1/128 of the foreground box"
    if options.map_resolution:
        resolution_reason = "--map-resolution"
    records = instance_records(*geo, names)
    summary["instances"] = len(records)
    ctx = ExportContext(out=out, points=pts, mesh=labelled, classes=classes, records=records, frame=frame,
                        units=units, transform=transform, up=up, default_resolution=default_resolution,
                        options=options, comments=comments)
    graph = build_scene_graph(*geo, records, classes, up=up, contact=ctx.resolution,
                              floor_classes=options.floor_classes, world_length=ctx.world_length)
    for writer in writers:
        written += writer.write(ctx)
    json_files.write_instances_json(out / "instances.json", records, frame=frame, units=units, source=source)
    write_scene_graph_json(out / "scene_graph.json", graph, frame=frame, units=units)
    written += ["instances.json", "scene_graph.json"]
    json_files.write_classes_json(out / "classes.json", classes)
    written.append("classes.json")
    metadata = {
        "lift3d_version": __version__,
        "frame": frame,
        "transform": transform.tolist(),
        "transform_note": "x_world = transform @ [x_normalized, 1] (a similarity: uniform scale + translation)",
        "units": units,
        "up": {"axis": up.tolist(), "reason": up_reason},
        "thresholds": thresholds,
        "formats": {"names": [w.name for w in writers], "options": dataclasses.asdict(options),
                    "map_resolution": ctx.resolution,
                    "map_resolution_reason": resolution_reason, **ctx.notes},
        "source_run": {"path": str(Path(loaded.run.path).resolve()), "step": int(loaded.step),
                       "scene": str(scene.root.resolve())},
        "command": command if command is not None else " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "files": sorted(written + ["metadata.json"]),
        "options": {k: (v if isinstance(v, (int, float, str, bool, type(None))) else str(v))
                    for k, v in point_options.items()},
        "counts": {k: summary[k] for k in ("points", "instances", "mesh_vertices", "mesh_faces") if k in summary},
    }
    json_files.write_metadata_json(out / "metadata.json", metadata)
    written.append("metadata.json")
    summary["seconds"] = time.perf_counter() - started
    return summary


def _world_cell(transform, frame: str) -> float:
    """1/128 of the normalised foreground box's side ([-1, 1], so 2/256) in output units (a last resort)."""
    scale = 1.0 if frame == "normalized" else float(np.cbrt(abs(np.linalg.det(np.asarray(transform)[:3, :3]))))
    return 2.0 / 256 * scale


def _write_instance_meshes(folder: Path, labelled, names: dict[int, str]) -> list[str]:
    """``instances/<id>_<class>.ply``: the faces whose three vertices belong to one instance."""
    written = []
    face_instance = labelled.instance[labelled.faces]
    whole = (face_instance == face_instance[:, :1]).all(1)
    for inst in np.unique(labelled.instance[labelled.instance > 0]):
        faces = labelled.faces[whole & (face_instance[:, 0] == inst)]
        if len(faces) == 0:
            continue
        used = np.unique(faces)
        remap = np.full(len(labelled.vertices), -1, np.int64)
        remap[used] = np.arange(len(used))
        cls = int(np.bincount(labelled.semantic[used]).argmax())
        safe = re.sub(r"[^A-Za-z0-9_.-]+", "-", names.get(cls, f"class_{cls}"))
        name = f"{int(inst)}_{safe}.ply"
        write_labelled_ply(folder / name, labelled.vertices[used], rgb=labelled.rgb[used],
                           semantic=labelled.semantic[used], instance=labelled.instance[used],
                           confidence=labelled.confidence[used], faces=remap[faces])
        written.append(f"instances/{name}")
    return written
