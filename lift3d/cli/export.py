"""``lift3d export``: labelled point clouds, meshes and per-instance records from a trained run."""

from __future__ import annotations

import argparse

from lift3d.errors import InputError
from lift3d.export.writers import WRITERS, ExportOptions
from lift3d.model.profiles import CHOICES

HELP = "labelled point cloud / mesh / instances of a trained run"

DESCRIPTION = """\
Export a trained run's labelled geometry (docs/export.md) into --output-dir, every file atomically:
  mesh.ply         --mesh: density isosurface with per-vertex rgb, semantic, instance, confidence
  instances/       --mesh --split-instances: <id>_<class>.ply per instance
  instances.json   per instance: class, point count, centroid, axis-aligned and oriented box, confidence
  scene_graph.json objects, the stuff they stand on, relations on / next_to / inside the room
  classes.json     id, name, isthing, color;   metadata.json: frame, transform, units, thresholds, the
                   premises and the steps' records, run
and per --format (default: ply):
{formats}

Point sources: 'auto' (default) is 'tsdf' for a street-like unbounded scene with a depth map in every training
frame and 'surface' otherwise. 'surface' samples the field's density isosurface where a training camera sees it
and runs the label heads at every point; 'rays' back-projects the rendered depth of training rays with
opacity > 0.5 (nerfstudio's way, slower). Coordinates are in the input poses' world frame unless
--frame normalized. See docs/export.md (how to load each format in ROS 2, OctoMap, Nav2, CloudCompare, PCL).

Steps: the points then go through these steps in order, each where the scene shows the premises it needs
(--profile; the groups below say which): box-fill, thing-fill, heads, confidence-filter, frame-conversion, crop,
outlier-removal, voxel-downsample, link-radius, view-vote, stuff-orientation, stuff-corners, instances,
filled-join, instance-cleanup. Every setting of a step is a flag --<step>.<setting>; the older flags
(--voxel-size, --obb-*, --no-complete-corners, ...) set the same settings.

examples:
  lift3d export --run outputs/room0/fast/2026-11-22_101500 --pointcloud --output-dir export
  lift3d export --run RUN --pointcloud --mesh --format ply pcd label --min-points 200 --output-dir export
  lift3d export --run RUN --pointcloud --format ros2bag octomap nav2 --map-resolution 0.05 --output-dir map
  lift3d export --run RUN --pointcloud --voxel-size 0.05 --obb-center 0 0 1 --obb-scale 4 4 2 --output-dir crop"""


def _format_lines() -> str:
    return "\n".join(f"  {name:<16} {cls.help}" + (f" [extra: {cls.extra}]" if cls.extra else "")
                     for name, cls in WRITERS.items())


def add_parser(subparsers, verb: str) -> argparse.ArgumentParser:
    """Register ``lift3d export`` on the CLI's subparsers."""
    # The step flags come from the step classes, which import torch: here, not at module level, so that
    # `lift3d --help` stays cheap (see lift3d.cli.main)
    from lift3d.export.sources import SOURCES
    from lift3d.export.steps.options import add_step_flags

    p = subparsers.add_parser(
        verb, help=HELP,
        usage="lift3d export --run RUN (--pointcloud | --mesh) [--output-dir DIR] [options]",
        description=DESCRIPTION.format(formats=_format_lines()), formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--run", required=True, metavar="RUN", help="run folder (from lift3d train)")
    p.add_argument("--pointcloud", action="store_true", help="export points.ply (and --format files)")
    p.add_argument("--mesh", action="store_true", help="export mesh.ply (density isosurface)")
    p.add_argument("--output-dir", metavar="DIR", help="destination folder (default: RUN/export)")
    p.add_argument("--data", metavar="DIR", help="the scene folder, if it moved since training")
    p.add_argument("--format", nargs="+", default=["ply"], choices=tuple(WRITERS), metavar="FMT",
                   help=f"files to write: {' '.join(WRITERS)} (default: ply; see above)")
    f = p.add_argument_group("formats")
    f.add_argument("--pcd-ascii", action="store_true", help="pcd: write points.pcd as DATA ascii (default: binary)")
    f.add_argument("--frame-id", default="map", metavar="FRAME",
                   help="ros2bag (and nav2's map.yaml comment): header.frame_id (default: map)")
    f.add_argument("--map-resolution", type=float, default=0.0, metavar="S",
                   help="octomap voxel / nav2 cell side in output units (default: --voxel-size when given, else "
                        "about two field grid cells; recorded in metadata.json)")
    f.add_argument("--up", default="auto", metavar="AXIS",
                   help="the scene's up axis for nav2 and scene_graph.json: auto (from the training cameras), x, "
                        "y, z, -x, -y or -z (default: auto)")
    f.add_argument("--z-up", action="store_true",
                   help="write every file in the output frame turned so that the scene's up (--up) is +z, as ROS, "
                        "PCL and CloudCompare expect (a right-angle rotation, recorded in metadata.json)")
    f.add_argument("--floor-classes", default="", metavar="LIST",
                   help="nav2 / scene graph: comma-separated walkable class names or ids (default: names with "
                        "floor, rug, road, sidewalk, grass, ground, ... in them)")
    f.add_argument("--height-band", type=float, nargs=2, metavar=("LOW", "HIGH"),
                   help="nav2: obstacles are non-floor points this high above the floor, output units (default: "
                        "0.1 1.8 world units)")
    g = p.add_argument_group("points", "How the points are drawn; the steps after that each have a group below.")
    g.add_argument("--source", default="auto", choices=SOURCES,
                   help="auto (default): tsdf for an unbounded scene with a depth map in every training frame, "
                        "surface otherwise; surface: sample the seen isosurface; tsdf: fuse the training views' "
                        "rendered depth into a TSDF and sample its surface; rays: back-project rendered depth")
    g.add_argument("--num-points", type=int, default=1_000_000, metavar="N",
                   help="points drawn before the steps (default: 1000000)")
    g.add_argument("--density-threshold", type=float, metavar="SIGMA",
                   help="isosurface density (normalised units; default: fitted to the rendered depth)")
    g.add_argument("--no-refine-surface", dest="refine_surface", action="store_false",
                   help="keep points and mesh vertices on the exact isosurface instead of moving them onto the "
                        "rendered surface (default: refine)")
    g.add_argument("--profile", default="auto", choices=CHOICES,
                   help="the kind of scene, whose premises decide which steps run (auto, default: the run's, as "
                        "training recorded it; runs without one: manhattan-room when bounded, none otherwise); see "
                        "docs/export.md")
    add_step_flags(p)
    m = p.add_argument_group("mesh")
    m.add_argument("--resolution", type=int, default=256, metavar="R", help="grid cells per axis (default: 256)")
    m.add_argument("--split-instances", action="store_true", help="also write instances/<id>_<class>.ply")
    p.add_argument("--device", default=None, metavar="DEV", help="auto, cpu or cuda[:N] (default: auto)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Check the options, export, print a short summary."""
    import shlex
    import sys

    if not (args.pointcloud or args.mesh):
        raise InputError("lift3d export", "nothing to export: give --pointcloud and/or --mesh")
    # here, not at module level: keeps `lift3d --help` cheap (torch)
    from lift3d.export import MeshSettings, export_run
    from lift3d.export.pointcloud import PointSettings
    from lift3d.export.sources import SourceSettings
    from lift3d.export.steps.options import steps_from_args
    from lift3d.utils.device import set_threads

    points = PointSettings(SourceSettings(args.source, args.num_points, args.density_threshold, args.refine_surface),
                           steps_from_args(args), args.profile)
    points.check()
    if not 8 <= args.resolution <= 1024:
        raise InputError("--resolution", f"must be between 8 and 1024, got {args.resolution}")
    if args.map_resolution < 0:
        raise InputError("--map-resolution", f"must be > 0, got {args.map_resolution}")
    if args.height_band is not None and not args.height_band[1] > args.height_band[0]:
        raise InputError("--height-band", f"needs LOW < HIGH, got {args.height_band[0]} {args.height_band[1]}")
    options = ExportOptions(pcd_ascii=args.pcd_ascii, frame_id=args.frame_id, map_resolution=args.map_resolution,
                            up=args.up, floor_classes=tuple(t.strip() for t in args.floor_classes.split(",")
                                                            if t.strip()),
                            height_band=tuple(args.height_band) if args.height_band else None, z_up=args.z_up)
    set_threads()
    mesh = MeshSettings(args.resolution, args.split_instances) if args.mesh else False
    summary = export_run(
        args.run, args.output_dir, pointcloud=args.pointcloud, mesh=mesh, formats=tuple(args.format),
        options=options, points=points, progress=not args.quiet, scene=args.data, device=args.device,
        command=" ".join(["lift3d", *map(shlex.quote, sys.argv[1:])]) if sys.argv[1:] else None,
    )
    print(format_summary(summary))
    return 0


def format_summary(summary: dict) -> str:
    """A few lines: what was written where, how many points/instances, how long it took."""
    lines = [f"lift3d export: wrote {len(summary['files'])} files to {summary['output_dir']} in "
             f"{summary['seconds']:.1f} s"]
    if "points" in summary:
        lines.append(f"  points     {summary['points']:,} ({summary['point_stats'].get('source')}), "
                     f"{summary.get('instances', 0)} instances")
    if "mesh_vertices" in summary:
        lines.append(f"  mesh       {summary['mesh_vertices']:,} vertices, {summary['mesh_faces']:,} faces")
    lines.append("  files      " + " ".join(summary["files"]))
    return "\n".join(lines)
