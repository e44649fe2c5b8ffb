"""``lift3d export``: labelled point clouds, meshes and per-instance records from a trained run."""

from __future__ import annotations

import argparse

from lift3d.errors import InputError
from lift3d.export.writers import WRITERS, ExportOptions

DESCRIPTION = """\
Export a trained run's labelled geometry (docs/export.md) into --output-dir, every file atomically:
  mesh.ply         --mesh: density isosurface with per-vertex rgb, semantic, instance, confidence
  instances/       --mesh --split-instances: <id>_<class>.ply per instance
  instances.json   per instance: class, point count, centroid, axis-aligned and oriented box, confidence
  scene_graph.json objects, the stuff they stand on, relations on / next_to / inside the room
  classes.json     id, name, isthing, color;   metadata.json: frame, transform, units, thresholds, run
and per --format (default: ply):
{formats}

Point sources: 'auto' (default) is 'tsdf' for a street-like unbounded scene with a depth map in every training
frame and 'surface' otherwise. 'surface' samples the field's density isosurface where a training camera sees it
and runs the label heads at every point; 'rays' back-projects the rendered depth of training rays with
opacity > 0.5 (nerfstudio's way, slower). Coordinates are in the input poses' world frame unless
--frame normalized. See docs/export.md (how to load each format in ROS 2, OctoMap, Nav2, CloudCompare, PCL).

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
    p = subparsers.add_parser(
        verb, help="labelled point cloud / mesh / instances of a trained run",
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
    f.add_argument("--floor-classes", default="", metavar="LIST",
                   help="nav2 / scene graph: comma-separated walkable class names or ids (default: names with "
                        "floor, rug, road, sidewalk, grass, ground, ... in them)")
    f.add_argument("--height-band", type=float, nargs=2, metavar=("LOW", "HIGH"),
                   help="nav2: obstacles are non-floor points this high above the floor, output units (default: "
                        "0.1 1.8 world units)")
    g = p.add_argument_group("points")
    g.add_argument("--source", default="auto", choices=("auto", "surface", "tsdf", "rays"),
                   help="auto (default): tsdf for an unbounded scene with a depth map in every training frame, "
                        "surface otherwise; surface: sample the seen isosurface; tsdf: fuse the training views' "
                        "rendered depth into a TSDF and sample its surface; rays: back-project rendered depth")
    g.add_argument("--num-points", type=int, default=1_000_000, metavar="N",
                   help="points drawn before filtering (default: 1000000)")
    g.add_argument("--frame", default="world", choices=("world", "normalized"),
                   help="output coordinates (default: world, the input poses' frame)")
    g.add_argument("--density-threshold", type=float, metavar="SIGMA",
                   help="isosurface density (normalised units; default: fitted to the rendered depth)")
    g.add_argument("--no-refine-surface", dest="refine_surface", action="store_false",
                   help="keep points and mesh vertices on the exact isosurface instead of moving them onto the "
                        "rendered surface (default: refine)")
    g.add_argument("--no-box-fill", dest="box_fill", action="store_false",
                   help="bounded scenes: do not fill holes of the isosurface next to the scene box with the "
                        "training views' rendered surface (default: fill; docs/export.md)")
    g.add_argument("--no-thing-fill", dest="thing_fill", action="store_false",
                   help="bounded scenes: do not fill holes of the isosurface on things with the rendered surface "
                        "of the training views without a depth map (default: fill; docs/export.md)")
    g.add_argument("--min-confidence", type=float, default=0.0, metavar="P",
                   help="drop points whose class probability is below P (default: 0)")
    g.add_argument("--voxel-size", type=float, default=0.0, metavar="S",
                   help="one point per voxel of side S (output units) with majority-vote labels (default: off)")
    g.add_argument("--remove-outliers", action="store_true", help="Open3D statistical outlier removal")
    g.add_argument("--std-ratio", type=float, default=2.0, help="outlier removal threshold (default: 2.0)")
    g.add_argument("--obb-center", type=float, nargs=3, metavar=("X", "Y", "Z"), help="crop box centre")
    g.add_argument("--obb-rotation", type=float, nargs=3, metavar=("ROLL", "PITCH", "YAW"),
                   help="crop box rotation, radians (default: 0 0 0)")
    g.add_argument("--obb-scale", type=float, nargs=3, metavar=("SX", "SY", "SZ"), help="crop box side lengths")
    g.add_argument("--min-points", type=int, default=0, metavar="N",
                   help="instance fragments under N points take their surroundings' label (dropped when "
                        "isolated; default: 0 = keep all)")
    g.add_argument("--no-merge-fragments", dest="merge_fragments", action="store_false",
                   help="keep instances of one class apart even when one 2D segment covers them in the training "
                        "views (default: they merge; see docs/export.md)")
    g.add_argument("--no-orient-stuff", dest="orient_stuff", action="store_false",
                   help="keep the field's stuff labels where two stuff surfaces meet (default: a stuff point that "
                        "faces the way a neighbouring stuff class faces, and not the way its own class does, takes "
                        "that class; see docs/export.md)")
    g.add_argument("--no-complete-corners", dest="complete_corners", action="store_false",
                   help="keep the isosurface's rounded edges where walls, floor and ceiling meet (default: in a "
                        "bounded scene, stuff points near two stuff planes that meet are moved onto both, each "
                        "with its plane's class; see docs/export.md)")
    g.add_argument("--no-view-vote", dest="view_vote", action="store_false",
                   help="keep the field's labels everywhere (default: a point whose training views agree, in their "
                        "2D labels, that it is a stuff class takes that class: a chair's label does not spread onto "
                        "the floor around its legs; see docs/export.md)")
    g.add_argument("--crumb-points", type=int, default=None, metavar="N",
                   help="instances under N points fold into their neighbour (default: the points of a patch one "
                        "instance link radius on a side; 0 = keep all)")
    g.add_argument("--min-instance-confidence", type=float, default=None, metavar="P",
                   help="instances whose points' mean class probability is below P fold into their surroundings "
                        "(default: 0.7; 0 = keep all)")
    g.add_argument("--min-support-views", type=int, default=None, metavar="K",
                   help="instances that the 2D labels confirm as a thing in fewer than K training views fold into "
                        "their surroundings (default: 1; 0 = keep all)")
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

    # here, not at module level: keeps `lift3d --help` cheap
    from lift3d.export import export_run

    if not (args.pointcloud or args.mesh):
        raise InputError("lift3d export", "nothing to export: give --pointcloud and/or --mesh")
    if args.num_points < 1:
        raise InputError("--num-points", f"must be at least 1, got {args.num_points}")
    if args.min_points < 0:
        raise InputError("--min-points", f"must be >= 0, got {args.min_points}")
    if args.crumb_points is not None and args.crumb_points < 0:
        raise InputError("--crumb-points", f"must be >= 0, got {args.crumb_points}")
    if args.min_support_views is not None and args.min_support_views < 0:
        raise InputError("--min-support-views", f"must be >= 0, got {args.min_support_views}")
    # Clean-up settings the user gave; the rest keep extract_labelled_points' defaults.
    cleanup = {name: value for name, value in (("min_instance_confidence", args.min_instance_confidence),
                                               ("min_support_views", args.min_support_views)) if value is not None}
    if not 8 <= args.resolution <= 1024:
        raise InputError("--resolution", f"must be between 8 and 1024, got {args.resolution}")
    obb = None
    if args.obb_center is not None or args.obb_rotation is not None or args.obb_scale is not None:
        if args.obb_scale is None:
            raise InputError("--obb-scale", "a crop box needs its side lengths (--obb-scale SX SY SZ)")
        from lift3d.export.pointcloud import OrientedBox  # here: keeps `lift3d --help` cheap (torch)

        obb = OrientedBox.from_params(args.obb_center or (0, 0, 0), args.obb_rotation or (0, 0, 0), args.obb_scale)
    if args.map_resolution < 0:
        raise InputError("--map-resolution", f"must be > 0, got {args.map_resolution}")
    if args.height_band is not None and not args.height_band[1] > args.height_band[0]:
        raise InputError("--height-band", f"needs LOW < HIGH, got {args.height_band[0]} {args.height_band[1]}")
    from lift3d.utils.device import set_threads  # here: keeps `lift3d --help` cheap (torch)

    options = ExportOptions(pcd_ascii=args.pcd_ascii, frame_id=args.frame_id, map_resolution=args.map_resolution,
                            up=args.up, floor_classes=tuple(t.strip() for t in args.floor_classes.split(",")
                                                            if t.strip()),
                            height_band=tuple(args.height_band) if args.height_band else None)
    set_threads()
    summary = export_run(
        args.run, args.output_dir, pointcloud=args.pointcloud, mesh=args.mesh, formats=tuple(args.format),
        data=args.data, split_instances=args.split_instances, resolution=args.resolution,
        options=options, progress=not args.quiet,
        command=" ".join(["lift3d", *map(shlex.quote, sys.argv[1:])]) if sys.argv[1:] else None,
        source=args.source, num_points=args.num_points, frame=args.frame, density_threshold=args.density_threshold,
        refine_surface=args.refine_surface, min_confidence=args.min_confidence, voxel_size=args.voxel_size,
        remove_outliers=args.remove_outliers, std_ratio=args.std_ratio, obb=obb, min_points=args.min_points,
        merge_fragments=args.merge_fragments, crumb_points=args.crumb_points, orient_stuff=args.orient_stuff,
        view_vote=args.view_vote, box_fill=args.box_fill, thing_fill=args.thing_fill,
        complete_corners=args.complete_corners,
        **cleanup, device=args.device,
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
