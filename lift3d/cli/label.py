"""``lift3d label``: 2D panoptic pseudo-labels for a scene from Mask2Former, from imported predictions, or
structure-only labels from the depth maps (``--geometric``)."""

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
  --geometric             no segmenter: structure-only labels from every frame's depth map (wall, floor,
                          ceiling, and one generic "object" per depth-connected component; no semantic
                          object classes). The up direction, the planes and the settings are recorded in
                          transforms.json under "labeller".

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


def _vector(text: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(t) for t in text.replace(" ", ",").split(",") if t)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y,Z (got {text!r})") from None
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"expected three numbers X,Y,Z (got {text!r})")
    return values  # type: ignore[return-value]


#: --geometric settings: flag -> (GeometricSettings field, default shown in the help, metavar, help). Only
#: flags given are passed on, so GeometricSettings' own defaults apply; tests check the two agree. (Reading
#: them from the class here would load lift3d.label, scipy and OpenCV for every `lift3d --help`.)
GEOMETRIC_FLAGS = {
    "--level-angle": ("level_angle", 15.0, "DEG",
                      "normals within this angle of up/down are level, within it of horizontal vertical: which points "
                      "may form floor, ceiling and walls"),
    "--normal-angle": ("normal_angle", 40.0, "DEG", "a pixel joins a plane only if its normal is within this angle"),
    "--plane-distance": ("plane_distance", 0.02, "SHARE",
                         "a pixel joins a plane within this share of its depth from it (0.02: 4 cm at 2 m)"),
    "--min-plane-share": ("min_plane_share", 0.005, "SHARE",
                          "a floor, ceiling or wall needs this share of the capture's sampled depth points"),
    "--wall-max-behind": ("wall_max_behind", 0.1, "SHARE",
                          "a vertical plane is no wall when more points than this share of its own are seen behind "
                          "it above its top (a tall cabinet with the wall showing above it)"),
    "--depth-jump": ("depth_jump", 0.05, "SHARE",
                     "neighbours whose depths differ by more than this share are not connected (objects split there)"),
    "--min-object-share": ("min_object_share", 0.002, "SHARE",
                           "smallest object, as a share of the frame's pixels; smaller leftovers are void"),
    "--normal-window": ("normal_window", 0.01, "SHARE",
                        "normals are averaged over a window of this share of the image's larger side"),
    "--on-plane-share": ("on_plane_share", 0.5, "SHARE",
                         "a depth-connected component with this share of its pixels near a plane is part of it "
                         "(surfaces seen at grazing angles)"),
    "--leftover-band": ("leftover_band", 2.0, "BANDS",
                        "pieces too small to be objects join a plane within this many distance bands of it"),
}


def add_parser(subparsers, verb: str) -> argparse.ArgumentParser:
    """Register ``lift3d label`` on the CLI's subparsers."""
    p = subparsers.add_parser(
        verb, help="2D panoptic pseudo-labels from Mask2Former, imported predictions or depth (--geometric)",
        description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--data", required=True, metavar="SCENE", help="scene folder (transforms.json + images)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--model", metavar="PATH_OR_NAME", help="Mask2Former panoptic checkpoint folder or hub id")
    src.add_argument("--from-predictions", metavar="DIR", help="folder of detectron2-style prediction files")
    src.add_argument("--geometric", action="store_true",
                     help="structure-only labels (wall, floor, ceiling, object) from the depth maps, no segmenter")
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
    g = p.add_argument_group("--geometric options (thresholds relative to the scene; docs/label.md)")
    g.add_argument("--depth-source", choices=("auto", "depth", "gt_depth"), default="auto",
                   help="depth_file_path (depth) or gt_depth_file_path (gt_depth, kept for evaluation); auto: "
                        "the input depth when frames have it, else gt_depth (default: auto)")
    g.add_argument("--up", type=_vector, default=None, metavar="X,Y,Z",
                   help="the world's up direction, when known (default: estimated from the capture)")
    for flag, (_, default, metavar, text) in GEOMETRIC_FLAGS.items():
        g.add_argument(flag, type=float, default=None, metavar=metavar, help=f"{text} (default: {default:g})")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Label the scene and print a short summary."""
    # here, not at module level: keeps `lift3d --help` cheap
    from lift3d.label import format_report, label_from_predictions, label_geometric, label_with_model
    from lift3d.label import Mask2FormerSettings
    from lift3d.label.geometric import GeometricSettings

    given = {flag: getattr(args, name) for flag, (name, *_) in GEOMETRIC_FLAGS.items()
             if getattr(args, name) is not None}
    if args.up is not None:
        given["--up"] = args.up
    if args.depth_source != "auto":
        given["--depth-source"] = args.depth_source
    if args.geometric:
        for flag, used in (("--classes", args.classes), ("--prediction-categories", args.prediction_categories),
                           ("--tta", args.tta), ("--save-probabilities", args.save_probabilities)):
            if used:
                raise InputError(flag, "does not apply to --geometric (its classes are wall, floor, ceiling, object)")
        settings = GeometricSettings(up=args.up, **{GEOMETRIC_FLAGS[f][0]: v for f, v in given.items()
                                                    if f in GEOMETRIC_FLAGS})
        report = label_geometric(args.data, settings, depth_source=args.depth_source, progress=not args.quiet)
        print(format_report(report, args.data))
        return 0
    if given:
        raise InputError(next(iter(given)), "only applies to --geometric")
    if args.from_predictions is not None:
        if args.tta or args.save_probabilities:
            raise InputError("--from-predictions", "--tta and --save-probabilities need --model")
        report = label_from_predictions(args.data, args.from_predictions, classes=args.classes,
                                        prediction_categories=args.prediction_categories, progress=not args.quiet)
        print(format_report(report, args.data))
        return 0
    if args.prediction_categories is not None:
        raise InputError("--prediction-categories", "only applies to --from-predictions")
    settings = Mask2FormerSettings(
        threshold=args.threshold, overlap_threshold=args.overlap_threshold, shortest_edge=args.shortest_edge,
        tta=args.tta, tta_scales=tuple(args.tta_scales), tta_flip=not args.no_tta_flip, batch_size=args.batch_size,
        confidence=not args.no_confidence, save_probabilities=args.save_probabilities,
    )
    report = label_with_model(args.data, args.model, settings, classes=args.classes, device=args.device,
                              cache_dir=args.cache_dir, progress=not args.quiet)
    print(format_report(report, args.data))
    return 0
