"""``lift3d label``: 2D panoptic pseudo-labels for a scene from Mask2Former or from imported predictions."""

from __future__ import annotations

import argparse

from lift3d.errors import InputError

DESCRIPTION = """\
Write a scene's 2D panoptic pseudo-labels (panoptic/<name>.png, panoptic.json with per-segment scores,
optional confidence/<name>.png, and the categories in transforms.json), replacing existing ones; images,
poses and ground truth are untouched, and nothing changes unless every frame succeeds.

  --model PATH_OR_NAME    a Mask2Former panoptic checkpoint (Hugging Face transformers; pip install
                          'lift3d[label]'): a local save_pretrained folder or a hub id found in the Hugging
                          Face cache, e.g. facebook/mask2former-swin-large-coco-panoptic (get it on a machine
                          with network: huggingface-cli download facebook/mask2former-swin-large-coco-panoptic).
                          With HF_HUB_OFFLINE=1 nothing is ever downloaded.
  --from-predictions DIR  detectron2-style (panoptic_seg, segments_info) files, one <stem>.pt/.pth/.npz per
                          image, matched by file stem.

--classes maps the segmenter's classes onto the scene's vocabulary: coco (default, the 133 COCO panoptic
classes), scannet21 (21 ScanNet-style indoor classes) or a classes.json (docs/label.md); classes it leaves
out become void."""


def _scales(text: str) -> list[float]:
    try:
        values = [float(t) for t in text.replace(" ", ",").split(",") if t]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers (got {text!r})") from None
    if not values:
        raise argparse.ArgumentTypeError("give at least one scale")
    return values


def add_parser(subparsers, verb: str) -> argparse.ArgumentParser:
    """Register ``lift3d label`` on the CLI's subparsers."""
    p = subparsers.add_parser(
        verb, help="2D panoptic pseudo-labels from Mask2Former or imported predictions",
        description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--data", required=True, metavar="SCENE", help="scene folder (transforms.json + images)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--model", metavar="PATH_OR_NAME", help="Mask2Former panoptic checkpoint folder or hub id")
    src.add_argument("--from-predictions", metavar="DIR", help="folder of detectron2-style prediction files")
    p.add_argument("--classes", metavar="coco|scannet21|FILE", default=None,
                   help="target vocabulary: coco (default), scannet21 or a classes.json")
    p.add_argument("--prediction-categories", metavar="FILE", default=None,
                   help="with --from-predictions: COCO categories JSON giving what the files' category_id mean "
                        "(default: detectron2's contiguous COCO panoptic ids 0..132)")
    m = p.add_argument_group("Mask2Former options")
    m.add_argument("--tta", action="store_true",
                   help="test-time augmentation: average class probabilities and confidence over scales and flips")
    m.add_argument("--tta-scales", type=_scales, default=[0.75, 1.0, 1.25], metavar="S,S,...",
                   help="inference resolutions of the TTA passes, relative to the model's (default: 0.75,1,1.25)")
    m.add_argument("--no-tta-flip", action="store_true", help="no horizontally flipped TTA passes")
    m.add_argument("--batch-size", type=int, default=1, metavar="N", help="frames per forward pass (default: 1)")
    m.add_argument("--device", default="auto", help="auto, cpu or cuda[:N] (default: auto)")
    m.add_argument("--threshold", type=float, default=0.8,
                   help="drop queries whose class probability is not above this (default: 0.8)")
    m.add_argument("--overlap-threshold", type=float, default=0.8,
                   help="keep a query's segment only if it wins more than this fraction of its mask (default: 0.8)")
    m.add_argument("--shortest-edge", type=int, default=None, metavar="PX",
                   help="inference resolution (shortest side) instead of the model's own; smaller is faster")
    m.add_argument("--no-confidence", action="store_true", help="do not write per-pixel confidence maps")
    m.add_argument("--save-probabilities", action="store_true",
                   help="also write probabilities/<name>.npz (class probabilities and confidences, float16)")
    m.add_argument("--cache-dir", metavar="DIR", default=None, help="Hugging Face cache to look in")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Label the scene and print a short summary."""
    # here, not at module level: keeps `lift3d --help` cheap
    from lift3d.label import format_report, label_from_predictions, label_with_model

    if args.from_predictions is not None:
        if args.tta or args.save_probabilities:
            raise InputError("--from-predictions", "--tta and --save-probabilities need --model")
        report = label_from_predictions(args.data, args.from_predictions, classes=args.classes,
                                        prediction_categories=args.prediction_categories)
        print(format_report(report, args.data))
        return 0
    if args.prediction_categories is not None:
        raise InputError("--prediction-categories", "only applies to --from-predictions")
    report = label_with_model(
        args.data, args.model, classes=args.classes, tta=args.tta, tta_scales=args.tta_scales,
        tta_flip=not args.no_tta_flip, batch_size=args.batch_size, device=args.device, threshold=args.threshold,
        overlap_threshold=args.overlap_threshold, shortest_edge=args.shortest_edge,
        confidence=not args.no_confidence, save_probabilities=args.save_probabilities, cache_dir=args.cache_dir,
    )
    print(format_report(report, args.data))
    return 0
