"""``lift3d eval``: 2D and 3D metrics of a trained run, beside the 2D pseudo-label baseline."""

from __future__ import annotations

import argparse

from lift3d.errors import InputError

DESCRIPTION = """\
Render the split, score it against the scene's ground truth and print one table: the lifted result next to
the scene's own 2D pseudo-labels (the baseline lifting has to beat), with a things/stuff split.

  2D   mIoU and PQ^scene / SQ / RQ at min_area 0.005 (published numbers) and 0 (suffix _strict), PSNR,
       depth errors when the scene has GT depth
  3D   when gt/points.ply exists: the run's labelled surface points against the GT points (point mIoU,
       point PQ with the same two min_area variants, accuracy, completeness, Chamfer, F-score at
       tau = 1 % of the GT box diagonal)
  speed  ms to render 2048 rays (rgb+depth+semantic+instance), median of 10 after 2 warm-up runs

Instance ids of the rendered frames are the exported objects' (--instances export, the default): each thing
pixel takes the id of the nearest point of its class in the labelled cloud the 3D block scores, the id
instances.json gives that object. --instances field scores the argmax of the field's instance head
(Panoptic Lifting's rule). Both are scored; the other source's PQ^scene is printed under the table.

Frames whose true pose is known (gt_transform_matrix beside a noisy transform_matrix, as lift3d synth
--pose-noise writes) are rendered from the true pose (--no-true-poses: from the written one).

Writes <run>/metrics.json (and --json FILE) atomically; NaN / inf are written as null. Without GT panoptic
labels only PSNR (plus depth / 3D where their GT exists) is computed. Definitions: docs/metrics.md.

examples:
  lift3d eval --run outputs/room0/fast/2026-11-22_101500
  lift3d eval --run RUN --split val --json results/room0.json
  lift3d eval --run RUN --data /new/place/of/room0 --no-points3d"""


def add_parser(subparsers, verb: str) -> argparse.ArgumentParser:
    """Register ``lift3d eval`` on the CLI's subparsers."""
    p = subparsers.add_parser(verb, help="2D and 3D metrics of a trained run vs. the pseudo-label baseline",
                              usage="lift3d eval --run RUN [--split test] [--json FILE] [--data DIR]",
                              description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--run", required=True, metavar="RUN", help="run folder written by lift3d train")
    p.add_argument("--split", default="test", choices=("train", "val", "test"), help="frames to score (default: test)")
    p.add_argument("--json", metavar="FILE", help="also write the metrics to FILE")
    p.add_argument("--data", metavar="DIR", help="the scene folder, if it moved since training")
    p.add_argument("--no-points3d", action="store_true", help="skip the 3D metrics")
    p.add_argument("--no-true-poses", action="store_true",
                   help="render the scored frames from their written transform_matrix even when the scene also "
                        "gives their true pose (gt_transform_matrix, e.g. lift3d synth --pose-noise); by default "
                        "views are scored where their images were taken")
    p.add_argument("--num-points", type=int, default=200_000, metavar="N",
                   help="points of the labelled cloud scored against gt/points.ply (default: 200000)")
    p.add_argument("--timing-repeats", type=int, default=10, metavar="N",
                   help="timed renders of 2048 rays (median reported; 0 = skip; default: 10)")
    p.add_argument("--chunk-size", type=int, default=None, metavar="RAYS", help="rays rendered at once")
    p.add_argument("--min-segment-fraction", type=float, default=None, metavar="F",
                   help="thing segments under this fraction of a rendered frame take the labels around them "
                        "before scoring (default: 0.001; 0 scores the raw argmax labels)")
    p.add_argument("--instances", default="export", choices=("export", "field"),
                   help="instance ids of the renders: the exported objects' (default) or the instance head's "
                        "argmax")
    p.add_argument("--device", default="auto", metavar="DEV", help="auto, cpu or cuda[:N] (default: auto)")
    p.add_argument("--threads", type=int, default=None, metavar="N",
                   help="CPU threads (default: $LIFT3D_THREADS or every CPU)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Evaluate, print the table, say where the metrics went."""
    # here, not at module level: keeps `lift3d --help` cheap
    from lift3d.eval.evaluate import EvalOptions, evaluate_run
    from lift3d.eval.report import format_eval_table
    from lift3d.render.images import MIN_SEGMENT_FRACTION
    from lift3d.utils.device import set_threads

    if args.num_points < 1:
        raise InputError("--num-points", f"must be positive (got {args.num_points})")
    if args.timing_repeats < 0:
        raise InputError("--timing-repeats", f"must be 0 or more (got {args.timing_repeats})")
    if args.chunk_size is not None and args.chunk_size < 1:
        raise InputError("--chunk-size", f"must be a positive number of rays (got {args.chunk_size})")
    set_threads(args.threads)
    options = EvalOptions(split=args.split, with_points3d=not args.no_points3d, num_points=args.num_points,
                          timing_repeats=args.timing_repeats, chunk_size=args.chunk_size,
                          true_poses=not args.no_true_poses,
                          min_segment_fraction=MIN_SEGMENT_FRACTION if args.min_segment_fraction is None
                          else args.min_segment_fraction, instances=args.instances)
    m = evaluate_run(args.run, options, data=args.data, device=args.device, json_path=args.json,
                     progress=not args.quiet)
    print(format_eval_table(m))
    where = f"{m['run']}/metrics.json" + (f" and {args.json}" if args.json else "")
    print(f"wrote {where}")
    return 0
