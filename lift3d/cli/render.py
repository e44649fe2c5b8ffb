"""``lift3d render``: images of a trained run (rgb, depth, semantic, instance, panoptic) for a split or a
camera path."""

from __future__ import annotations

import argparse

HELP = "render a trained run's views (rgb, depth, semantic, instance, panoptic)"

DESCRIPTION = """\
Render a trained run's views into DIR/<output>/<frame stem>.png:
  rgb          8-bit RGB
  depth        16-bit PNG, z-depth in millimetres (0 = nothing hit or farther than 65.535 m) + depth_vis preview
  semantic     16-bit PNG of category ids (0 = void) + semantic_vis preview in the category colours
  instance     16-bit PNG of 3D instance ids + instance_vis preview: on things the id of the object in
               instances.json of `lift3d export --pointcloud` (default settings), 0 on stuff, void and
               thing pixels no exported object is near; --instances field: the field's channels 1..V
  panoptic     COCO panoptic PNG + DIR/panoptic.json (segments_info: id, category_id, area, bbox, score =
               mean confidence); segment id = category_id * 1000 + instance, the same in every frame
  confidence   16-bit PNG, probability of the chosen class x 65535
A camera path (--camera-path FILE.json) is a list of camera_to_world 4x4 matrices (OpenGL axes, the scene's
world frame) with fl_x/fl_y/cx/cy/w/h (or fov); see docs/metrics.md#camera-paths.

examples:
  lift3d render --run outputs/room0/fast/2026-11-22_101500 --split test --output-dir renders
  lift3d render --run RUN --outputs rgb panoptic --downscale 2 --output-dir previews
  lift3d render --run RUN --camera-path orbit.json --outputs rgb semantic --output-dir orbit
  lift3d render --run RUN --outputs instance --instances field --output-dir channels"""


def add_parser(subparsers, verb: str) -> argparse.ArgumentParser:
    """Register ``lift3d render`` on the CLI's subparsers."""
    # The output names live beside the renderer, which imports torch: here, not at module level, so that
    # `lift3d --help` stays cheap (see lift3d.cli.main).
    from lift3d.render.output import DEFAULT_OUTPUTS, OUTPUTS

    p = subparsers.add_parser(verb, help=HELP,
                              usage="lift3d render --run RUN [--split test | --camera-path FILE] "
                                    "[--outputs NAME ...] --output-dir DIR",
                              description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--run", required=True, metavar="RUN", help="run folder written by lift3d train")
    p.add_argument("--output-dir", required=True, metavar="DIR", help="where the images go (created)")
    p.add_argument("--split", default="test", choices=("train", "val", "test"),
                   help="frames of the scene to render (default: test)")
    p.add_argument("--camera-path", metavar="FILE", help="render these cameras instead of a split")
    p.add_argument("--outputs", nargs="+", default=list(DEFAULT_OUTPUTS), choices=OUTPUTS, metavar="NAME",
                   help=f"any of {', '.join(OUTPUTS)} (default: {' '.join(DEFAULT_OUTPUTS)})")
    p.add_argument("--no-previews", action="store_true",
                   help="do not add depth_vis / semantic_vis / instance_vis beside depth / semantic / instance")
    p.add_argument("--data", metavar="DIR", help="the scene folder, if it moved since training")
    p.add_argument("--downscale", type=int, default=1, metavar="N", help="render N times smaller images (default: 1)")
    p.add_argument("--min-segment-fraction", type=float, default=None, metavar="F",
                   help="thing segments under this fraction of a frame take the labels around them "
                        "(default: 0.001; 0 writes the raw argmax labels)")
    p.add_argument("--instances", default="export", choices=("export", "field"),
                   help="instance ids of thing pixels: the exported objects' (default; extracts the run's "
                        "labelled cloud first, a few seconds) or the field's channels")
    p.add_argument("--chunk-size", type=int, default=None, metavar="RAYS",
                   help="rays rendered at once (lower it when memory is short; default: the run's setting)")
    p.add_argument("--device", default="auto", metavar="DEV", help="auto, cpu or cuda[:N] (default: auto)")
    p.add_argument("--threads", type=int, default=None, metavar="N",
                   help="CPU threads (default: $LIFT3D_THREADS or every CPU)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Render, then print one line saying what was written where."""
    # here, not at module level: keeps `lift3d --help` cheap (torch)
    from lift3d.render.images import MIN_SEGMENT_FRACTION
    from lift3d.export.renders import FrameSettings, render_to_folder
    from lift3d.utils.device import set_threads

    set_threads(args.threads)
    res = render_to_folder(
        args.run, args.output_dir, args.outputs, split=args.split, camera_path=args.camera_path, data=args.data,
        frames=FrameSettings(args.downscale, args.chunk_size, MIN_SEGMENT_FRACTION if args.min_segment_fraction is None
                             else args.min_segment_fraction),
        device=args.device, previews=not args.no_previews, progress=not args.quiet, instances=args.instances,
    )
    what = f"camera path {args.camera_path}" if args.camera_path else f"split {args.split}"
    print(f"lift3d render: {len(res.stems)} frames of {what} ({res.size[1]}x{res.size[0]}) in {res.seconds:.1f} s "
          f"-> {res.output_dir} [{', '.join(res.outputs)}]"
          + (f"; {res.panoptic_json}" if res.panoptic_json else "")
          + (f"; instance ids: {res.instances_from}" if {"instance", "panoptic"} & set(res.outputs) else ""))
    return 0
