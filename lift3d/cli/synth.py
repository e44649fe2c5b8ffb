"""``lift3d synth``: write a synthetic labelled scene with simulated 2D segmenter noise."""

from __future__ import annotations

import argparse

DESCRIPTION = """\
Write a synthetic scene folder (DESIGN.md section 1): posed images, GT panoptic maps, depth and 3D points,
and the 2D panoptic pseudo-labels of a simulated noisy segmenter (per-frame ids, missed/merged/split
instances, class confusion, boundary errors, abstention, spurious segments, scores; see docs/synth.md).
indoor: a furnished room (bounded); outdoor: a long street with sky (unbounded). The same arguments give the
same files byte for byte; the noise level changes only the pseudo-labels."""


def add_parser(subparsers, verb: str) -> argparse.ArgumentParser:
    """Register ``lift3d synth`` on the CLI's subparsers."""
    p = subparsers.add_parser(
        verb, help="write a synthetic labelled scene with simulated 2D segmenter noise",
        description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--out", required=True, metavar="DIR", help="output scene folder (created)")
    p.add_argument("--kind", default="indoor", choices=("indoor", "outdoor"), help="scene kind (default: indoor)")
    p.add_argument("--seed", type=int, default=0, help="random seed of layout, cameras and noise (default: 0)")
    p.add_argument("--noise", default="moderate", choices=("clean", "moderate", "hard"),
                   help="simulated segmenter error level (default: moderate)")
    p.add_argument("--views", type=int, default=60, metavar="N", help="number of views (default: 60)")
    p.add_argument("--width", type=int, default=128, help="image width in pixels (default: 128)")
    p.add_argument("--height", type=int, default=128, help="image height in pixels (default: 128)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Build the scene and print a short summary with the noise statistics."""
    # here, not at module level: keeps `lift3d --help` cheap
    from lift3d.synth import make_scene

    report = make_scene(args.out, kind=args.kind, seed=args.seed, noise=args.noise, n_views=args.views,
                        width=args.width, height=args.height, progress=True)
    print(format_summary(report))
    return 0


def format_summary(report: dict) -> str:
    """A few lines: what was written, the content and the simulated segmenter's error statistics."""
    c, n = report["content"], report["noise"]
    rates, counts = n["rates"], n["counts"]

    def pct(x) -> str:
        return "n/a" if x is None else f"{100 * x:.1f}%"

    lines = [
        f"wrote {report['kind']} scene to {report['out']} in {report['seconds']:.1f} s: {report['n_views']} views "
        f"{report['width']}x{report['height']} (train {report['splits']['train']}, val {report['splits']['val']}, "
        f"test {report['splits']['test']})",
        f"  content: {c['n_things']} objects of {c['n_thing_classes']} thing classes, extent {c['extent_m']:.1f} m"
        + (f" = {c['extent_over_baseline']}x the camera baseline ({c['camera_baseline_m']:.2f} m)"
           if c["scene_box"]["type"] == "unbounded" else "")
        + f", scene box {c['scene_box']['type']}, {c['gt_points']} GT points",
        f"  noise '{n['name']}': missed {counts['missed']}/{counts['gt_things']} things ({pct(rates['missed'])}), "
        f"confused {counts['confused']}/{counts['confusion_eligible']} segments ({pct(rates['confused'])}), "
        f"merged {counts['merged']}/{counts['merge_considered']} touching pairs ({pct(rates['merged'])}), "
        f"split {counts['split']}/{counts['split_eligible']} ({pct(rates['split'])})",
        f"    boundary shifted {pct(rates['boundary_shifted'])} of segments, void rings {pct(rates['boundary_void'])}, "
        f"{rates['abstain_blobs_per_frame']:.2f} void blobs and {rates['spurious_per_frame']:.2f} spurious "
        f"segments per frame; void pixels {pct(n['pixels']['void_fraction'])}",
        f"    scores: correct {n['mean_score']['correct']}, corrupted {n['mean_score']['corrupted']}; pseudo-label "
        f"semantic accuracy {pct(n['pixels']['semantic_accuracy'])}, mIoU {n['semantic_miou']:.3f} "
        f"(strict {n['semantic_miou_strict']:.3f})",
        f"  noise statistics: {report['paths']['noise_stats']}",
    ]
    return "\n".join(lines)
