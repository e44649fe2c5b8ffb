"""Labelled geometry out of a trained run: what robot mapping consumes (docs/export.md).

Modules:

- :mod:`lift3d.export.pointcloud` — :func:`extract_labelled_points` (a source, then the steps);
- :mod:`lift3d.export.sources` — where the points come from (surface, tsdf, rays);
- :mod:`lift3d.export.steps` — the point steps in order (fills, heads, filters, label votes, stuff, instances), their
  flags and the premises they need;
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
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lift3d import __version__
from lift3d.data.ply import write_labelled_ply
from lift3d.errors import InputError
from lift3d.export import json_files
from lift3d.export.ground import floor_class_ids, map_frame, resolve_up
from lift3d.export.scene_graph import build_scene_graph, write_scene_graph_json
from lift3d.export.writers import ExportContext, ExportOptions, check_formats
from lift3d.utils.files import check_writable

if TYPE_CHECKING:  # torch-backed types, for annotations only (see the module docstring)
    from lift3d.data.scene import Scene
    from lift3d.export.pointcloud import PointSettings
    from lift3d.model.run import LoadedRun

__all__ = ["export_run", "extract_labelled_points", "LabelledPoints", "PointSettings", "MeshSettings",
           "benchmark_export", "ExportOptions"]


def __getattr__(name: str):
    if name in ("extract_labelled_points", "LabelledPoints", "PointSettings", "benchmark_export", "OrientedBox"):
        from lift3d.export import pointcloud  # on first use: keeps `import lift3d.export` cheap

        return getattr(pointcloud, name)
    raise AttributeError(f"module 'lift3d.export' has no attribute {name!r}")


@dataclass
class MeshSettings:
    """How ``mesh.ply`` is made (besides the density threshold, the refinement and the frame, which it shares with
    the points)."""

    resolution: int = 256
    """Grid cells per axis."""
    split_instances: bool = False
    """Also write ``instances/<id>_<class>.ply``, one sub-mesh per instance."""


def export_run(run: str | Path, output_dir: str | Path | None = None, *, pointcloud: bool = True,
               mesh: bool | MeshSettings = False, formats: tuple[str, ...] | list[str] = ("ply",), options=None,
               points: PointSettings | None = None, command: str | None = None, progress: bool = False,
               loaded: LoadedRun | None = None, scene: Scene | str | Path | None = None,
               **settings: Any) -> dict[str, Any]:
    """Export a trained run's labelled geometry into ``output_dir`` (every file written atomically).

    Parameters
    ----------
    run : str or Path
        Run folder.
    output_dir : str or Path, optional
        Destination (created); default ``<run>/export``.
    pointcloud : bool
        Export the points.
    mesh : bool or MeshSettings
        Export the mesh (True: at the default :class:`MeshSettings`).
    formats : sequence of str
        Names of :data:`lift3d.export.writers.WRITERS`: ``ply`` (``points.ply``), ``ply-cloudcompare``,
        ``pcd``, ``label`` (SemanticKITTI), ``ros2bag``, ``octomap``, ``nav2``. Optional libraries are checked
        before any work starts.
    options : lift3d.export.writers.ExportOptions, optional
        Settings of the format writers (ROS frame id, map resolution, up axis, floor classes, ...).
    points : lift3d.export.pointcloud.PointSettings, optional
        The point source, the steps and the profile (the frame, density threshold and refinement are the mesh's
        too); default from ``settings``.
    command : str, optional
        Recorded in ``metadata.json`` (default: this process's command line).
    progress : bool
    loaded : LoadedRun, optional
        The run, already loaded.
    scene : Scene or str or Path, optional
        Its scene, already loaded, or the scene folder when it moved since training.
    **settings
        ``device`` (load the run there), ``data`` (= ``scene`` as a folder), ``resolution`` and
        ``split_instances`` (:class:`MeshSettings`, with ``mesh=True``), and instead of ``points`` the keywords of
        :meth:`~lift3d.export.pointcloud.PointSettings.from_options` (``source``, ``num_points``, ``frame``,
        ``density_threshold``, ``refine_surface``, ``voxel_size``, ``obb``, ``min_points``, ``box_fill``,
        ``complete_corners``, ``profile`` ...).

    Returns
    -------
    dict
        Paths written, counts, thresholds and seconds.
    """
    # torch-backed modules load here, not at import: keeps `import lift3d.export` cheap
    from lift3d.export.instances import instance_records
    from lift3d.export.mesh import extract_labelled_mesh, match_instance_ids
    from lift3d.export.pointcloud import PointSettings, extract_labelled_points
    from lift3d.export.steps.options import keyword_settings
    from lift3d.model.run import load_run

    device = settings.pop("device", None)
    data = settings.pop("data", None)
    mesh_settings = mesh if isinstance(mesh, MeshSettings) else MeshSettings(
        **{k: settings.pop(k) for k in ("resolution", "split_instances") if k in settings})
    given = dict(settings)
    if points is None:
        points = PointSettings.from_options(**settings)
    elif settings:
        raise TypeError(f"export_run: give points or keyword settings, not both ({', '.join(settings)})")
    options = options if options is not None else ExportOptions()
    writers = check_formats(formats)  # unknown names and missing extras fail before any work
    if not pointcloud and not mesh:
        raise InputError("lift3d export", "nothing to export: give --pointcloud and/or --mesh")
    out = check_writable(output_dir if output_dir is not None else Path(run) / "export", folder=True)
    started = time.perf_counter()
    points.check()
    if loaded is None:
        loaded = load_run(run, device or "auto")
    if scene is None or isinstance(scene, (str, Path)):
        scene = loaded.scene(scene if scene is not None else data)
    frame = points.frame
    units = "normalized scene units (world units x scale)" if frame == "normalized" else \
        "world units of transforms.json (metres for lift3d synth scenes)"
    classes = json_files.class_table(scene.categories, loaded.labels.semantic_ids)
    names = {c["id"]: c["name"] for c in classes}
    # Options that depend on the scene are checked before the (long) extraction.
    up, up_reason = resolve_up(options.up, scene.cameras.c2w)
    # --z-up: the output frame turned so that up is +z; points and mesh are turned as they come out of extraction,
    # so that every file, the instances and the scene graph share one frame
    rotation = map_frame(up) if options.z_up else None
    floor_class_ids(classes, options.floor_classes)
    written: list[str] = []
    summary: dict[str, Any] = {"output_dir": str(out), "files": written}
    thresholds: dict[str, Any] = {}
    comments = [f"lift3d {__version__} export", f"frame {frame}", f"source run {loaded.run.path}"]
    pts = labelled = None
    view_depths: dict = {}  # the vote's renders of views without depth maps, done once for points and mesh
    if pointcloud:
        pts = extract_labelled_points(loaded, scene, points, progress=progress, view_depth_cache=view_depths,
                                      device=device)
        if rotation is not None:
            pts = dataclasses.replace(pts, xyz=(pts.xyz @ rotation.T).astype(pts.xyz.dtype))
        thresholds["points"] = pts.thresholds
        summary.update(points=len(pts), point_stats=pts.stats)
    if mesh:
        labelled = extract_labelled_mesh(loaded, scene, resolution=mesh_settings.resolution,
                                         density_threshold=points.source.density_threshold,
                                         refine_surface=points.source.refine_surface, frame=frame,
                                         min_points=points.step("instances").min_points,
                                         orient_stuff=points.step("stuff-orientation").enabled,
                                         view_vote=points.step("view-vote").enabled,
                                         view_depth_cache=view_depths, progress=progress)
        if rotation is not None:
            labelled.vertices = (labelled.vertices @ rotation.T).astype(labelled.vertices.dtype)
        if pts is not None:
            match_instance_ids(labelled, pts.xyz, pts.semantic, pts.instance)
        write_labelled_ply(out / "mesh.ply", labelled.vertices, rgb=labelled.rgb, semantic=labelled.semantic,
                           instance=labelled.instance, confidence=labelled.confidence, faces=labelled.faces,
                           comments=comments)
        written.append("mesh.ply")
        thresholds["mesh"] = labelled.thresholds
        summary.update(mesh_vertices=int(len(labelled.vertices)), mesh_faces=int(len(labelled.faces)))
        if mesh_settings.split_instances:
            written += _write_instance_meshes(out / "instances", labelled, names)
    if rotation is not None:
        up, up_reason = rotation @ up, f"{up_reason}; turned to +z (--z-up)"
    # Instances (and the scene graph) come from the points, or from the mesh vertices with --mesh alone.
    if pts is not None:
        geo = (pts.xyz, pts.semantic, pts.instance, pts.confidence)
        source, link = "points", pts.thresholds.get("instance_link_radius")
    else:
        geo = (labelled.vertices, labelled.semantic, labelled.instance, labelled.confidence)
        source, link = "mesh vertices", labelled.thresholds.get("instance_link_radius")
    transform = np.asarray(pts.transform if pts is not None else labelled.transform)
    # The export's own length scale (about two field grid cells), for map cells when the user gave none.
    voxel_size = points.step("voxel-downsample").voxel_size
    if voxel_size:
        default_resolution, resolution_reason = float(voxel_size), "--voxel-size"
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
        **({"rotation": rotation.tolist(),
            "rotation_note": f"x_output = rotation @ x_{frame} (--z-up: the {frame} frame turned so that up is +z)"}
           if rotation is not None else {}),
        "thresholds": thresholds,
        **({"premises": pts.stats["premises"], "steps": {"points": pts.steps}} if pts is not None else {}),
        "formats": {"names": [w.name for w in writers], "options": dataclasses.asdict(options),
                    "map_resolution": ctx.resolution,
                    "map_resolution_reason": resolution_reason, **ctx.notes},
        "source_run": {"path": str(Path(loaded.run.path).resolve()), "step": int(loaded.step),
                       "scene": str(scene.root.resolve())},
        "command": command if command is not None else " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "files": sorted(written + ["metadata.json"]),
        "options": {k: (list(v) if isinstance(v, tuple) else v if isinstance(v, (int, float, str, bool, type(None)))
                        else str(v)) for k, v in _options(points, keyword_settings(), given, device).items()},
        "counts": {k: summary[k] for k in ("points", "instances", "mesh_vertices", "mesh_faces") if k in summary},
    }
    json_files.write_metadata_json(out / "metadata.json", metadata)
    written.append("metadata.json")
    summary["seconds"] = time.perf_counter() - started
    return summary


def _options(points, keywords: dict[str, tuple[str, str]], given: dict[str, Any], device) -> dict[str, Any]:
    """``metadata.json``'s ``options``: the source's settings, the profile, and each step setting that has a Python
    keyword (its older flag's name) by that keyword, whatever way they were given."""
    out: dict[str, Any] = {**dataclasses.asdict(points.source), "profile": points.profile, "device": device}
    for key, (step, setting) in keywords.items():
        value = getattr(points.step(step), setting)
        if value is not None or key in given:
            out[key] = value
    return out


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
