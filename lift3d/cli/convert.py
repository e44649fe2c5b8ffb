"""``lift3d convert --from colmap|nerfstudio|open3d|panoptic-lifting|scannet SRC --out DIR``: other inputs
into a scene folder.

See ``docs/convert.md`` for the folder layouts each source expects and the conventions they follow.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lift3d.errors import InputError

EPILOG = """examples:
  lift3d convert --from colmap my_capture --predictions my_capture/m2f --out scenes/my_capture
  lift3d convert --from nerfstudio data/fox/transforms.json --predictions data/fox/m2f --out scenes/fox
  lift3d convert --from scannet scans/scene0423_02 --predictions preds/scene0423_02 \\
      --categories classes.json --out scenes/scene0423_02 --downscale 2
  lift3d convert --from panoptic-lifting data/replica/room_0 --out scenes/room_0
  lift3d convert --from open3d livingroom1 --intrinsic primesense --out scenes/livingroom1 --depth-as-gt
"""


def add_parser(subparsers: argparse._SubParsersAction, verb: str) -> argparse.ArgumentParser:
    """Create the ``convert`` sub-command."""
    p = subparsers.add_parser(
        verb,
        help="convert COLMAP, nerfstudio/instant-ngp, Open3D RGB-D, Panoptic Lifting or ScanNet-style inputs into a "
             "scene folder",
        description="Convert posed images plus 2D panoptic predictions from another layout into lift3d's "
                    "scene folder (transforms.json with OpenGL camera-to-world poses, COCO panoptic "
                    "pseudo-labels, optional ground truth and depth). The result is read back to check it.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--from", dest="source", required=True,
                   choices=["colmap", "nerfstudio", "instant-ngp", "open3d", "panoptic-lifting", "scannet"],
                   help="the layout of SRC (instant-ngp is the nerfstudio reader: one reader for both tools' "
                        "transforms.json)")
    p.add_argument("src", metavar="SRC", type=Path,
                   help="colmap: a sparse model folder or a workspace holding sparse/0, sparse or "
                        "colmap/sparse/0; nerfstudio: a transforms.json or the folder holding one; "
                        "open3d: the dataset folder (image/ or color/, depth/); "
                        "panoptic-lifting / scannet: the scene folder")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output scene folder")
    p.add_argument("--images", type=Path, metavar="DIR",
                   help="colmap: folder the image names in images.txt|bin are relative to (default: "
                        "SRC/images, else an images/ folder beside the model folder or up to three levels "
                        "above it)")
    p.add_argument("--predictions", type=Path, metavar="DIR",
                   help="colmap, nerfstudio (required), open3d, scannet: 2D panoptic predictions per image, matched by "
                        "file stem: COCO panoptic (panoptic.json + PNGs) or semantic/ + instance/ PNG folders; "
                        "without them open3d and scannet write a scene without pseudo-labels, for lift3d label")
    p.add_argument("--intrinsic", metavar="FILE|primesense",
                   help="open3d: an Open3D PinholeCameraIntrinsic JSON (width, height, intrinsic_matrix), or "
                        "'primesense' for Open3D's PrimeSense default (640x480, fx=fy=525, cx=319.5, cy=239.5) "
                        "(default: SRC/intrinsic.json)")
    p.add_argument("--poses", type=Path, metavar="FILE",
                   help="open3d: camera-to-world poses, a trajectory .log or an Open3D PoseGraph / "
                        "PinholeCameraTrajectory .json, paired with the colour frames in order (default: "
                        "SRC/trajectory.log, else SRC/scene/trajectory.log, else the only SRC/*/trajectory.log)")
    p.add_argument("--categories", type=Path, metavar="FILE",
                   help="JSON list of COCO panoptic categories {id, name, isthing, color} (or a COCO panoptic "
                        "JSON holding one); needed when the predictions carry none, unless --things is given")
    p.add_argument("--things", metavar="IDS",
                   help="comma-separated thing class ids for generic class_<id> categories, used when there "
                        "is no --categories and the predictions carry none ('none' = only stuff); "
                        "panoptic-lifting default: fg_classes of segmentation_data.pkl")
    p.add_argument("--test-every", type=int, default=8, metavar="N",
                   help="hold out every N-th frame (sorted by name) as the test split; 0 = train on all "
                        "(panoptic-lifting uses splits.json when present) (default: %(default)s)")
    p.add_argument("--labels-prefix", default="m2f", metavar="PREFIX",
                   help="panoptic-lifting: read pseudo-labels from PREFIX_semantics/ and PREFIX_instance/, "
                        "e.g. m2f_notta (default: %(default)s)")
    p.add_argument("--no-confidence", action="store_true",
                   help="panoptic-lifting: ignore the per-pixel confidence in m2f_probabilities/*.npz")
    p.add_argument("--no-gt", action="store_true",
                   help="panoptic-lifting: ignore rs_semantics/ + rs_instance/ ground truth")
    p.add_argument("--no-depth", action="store_true",
                   help="nerfstudio, open3d, panoptic-lifting, scannet: ignore the depth maps")
    p.add_argument("--depth-as-gt", action="store_true",
                   help="nerfstudio, open3d, panoptic-lifting, scannet: keep the depth maps for evaluation only "
                        "(gt_depth_file_path: lift3d eval scores rendered depth against them); training then uses "
                        "the images alone")
    p.add_argument("--depth-scale", type=float, default=1e-3, metavar="M",
                   help="metres per unit of the uint16 depth PNGs, in the input and the output "
                        "(default: %(default)s = millimetres)")
    p.add_argument("--intrinsics-size", metavar="WxH",
                   help="panoptic-lifting, scannet: image size intrinsic_color.txt refers to, when the colour "
                        "images were resized since (default: the images' own size)")
    p.add_argument("--scene-box", action="store_true",
                   help="colmap: write a bounded scene_box around the sparse points (points3D.txt|bin)")
    p.add_argument("--no-points", action="store_true",
                   help="colmap: do not keep points3D.txt|bin as the scene's sparse points (kept by default "
                        "as sparse/points3D.ply + sparse/observations.npz; see docs/scene-format.md)")
    p.add_argument("--downscale", type=int, default=1, metavar="N",
                   help="shrink images, labels and depth by N: each output pixel is one NxN block (mean colour, "
                        "majority label, median valid depth; intrinsics divided by N) (default: %(default)s)")
    p.add_argument("--frame-step", type=int, default=1, metavar="N",
                   help="keep every N-th frame of the source (in capture order; before --test-every splits what "
                        "is kept): a video-rate capture's neighbours add little but time (default: %(default)s)")
    p.add_argument("--image-format", choices=["png", "jpg"], default="png",
                   help="format of the written images (default: %(default)s, lossless)")
    p.add_argument("--fix-poses", choices=["invert", "flip-axes", "invert-and-flip-axes"], metavar="FIX",
                   help="the pose file holds another convention than the source's: invert (world-to-camera "
                        "matrices), flip-axes (the other camera axes: OpenGL for OpenCV or back), or both. The "
                        "conversion checks the poses against the images and names the fix when one is needed")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--overwrite", action="store_true",
                   help="replace a scene folder already at --out (only the files a scene folder holds)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Run ``lift3d convert``; returns the exit code (bad input raises :class:`InputError`)."""
    # here, not at module level: keeps `lift3d --help` cheap
    from lift3d.convert import WriteOptions, parse_id_list, summary
    from lift3d.convert.predictions import load_categories

    if args.test_every < 0:
        raise InputError("--test-every", "must be >= 0")
    if args.downscale < 1:
        raise InputError("--downscale", "must be a positive integer")
    if not args.depth_scale > 0:
        raise InputError("--depth-scale", "must be positive")
    categories = load_categories(args.categories) if args.categories is not None else None
    things = parse_id_list(args.things, "--things")
    if args.depth_as_gt and args.no_depth:
        raise InputError("--depth-as-gt", "keeps the depth maps that --no-depth leaves out: give one of them")
    options = WriteOptions(downscale=args.downscale, image_ext=f".{args.image_format}",
                           depth_scale=args.depth_scale, overwrite=args.overwrite, depth_as_gt=args.depth_as_gt,
                           frame_step=args.frame_step, progress=not args.quiet,
                           fix_poses=args.fix_poses.replace("-", " ") if args.fix_poses else None,
                           pose_axes="opengl" if args.source in ("nerfstudio", "instant-ngp") else "opencv")
    _reject_foreign_flags(args)

    if args.source == "colmap":
        # here, not at module level: keeps `lift3d --help` cheap
        from lift3d.convert import colmap

        if args.predictions is None:
            raise InputError("--predictions", "required with --from colmap (2D panoptic predictions per image)")
        scene = colmap.convert(args.src, args.out, predictions=args.predictions, images=args.images,
                               categories=categories, things=things, test_every=args.test_every,
                               scene_box=args.scene_box, keep_points=not args.no_points, options=options)
    elif args.source in ("nerfstudio", "instant-ngp"):
        # here, not at module level: keeps `lift3d --help` cheap
        from lift3d.convert import nerfstudio

        if args.predictions is None:
            raise InputError("--predictions", f"required with --from {args.source} (2D panoptic predictions per image)")
        scene = nerfstudio.convert(args.src, args.out, predictions=args.predictions, categories=categories,
                                   things=things, test_every=args.test_every, use_depth=not args.no_depth,
                                   options=options)
    elif args.source == "open3d":
        # here, not at module level: keeps `lift3d --help` cheap
        from lift3d.convert import open3d_rgbd

        scene = open3d_rgbd.convert(args.src, args.out, intrinsic=args.intrinsic, poses=args.poses,
                                    predictions=args.predictions, categories=categories, things=things,
                                    test_every=args.test_every, use_depth=not args.no_depth, options=options)
    elif args.source == "scannet":
        # here, not at module level: keeps `lift3d --help` cheap
        from lift3d.convert import scannet

        scene = scannet.convert(args.src, args.out, predictions=args.predictions, categories=categories,
                                things=things, test_every=args.test_every, use_depth=not args.no_depth,
                                intrinsics_size=scannet.parse_size(args.intrinsics_size), options=options)
    else:
        # here, not at module level: keeps `lift3d --help` cheap
        from lift3d.convert import panoptic_lifting
        from lift3d.convert.scannet import parse_size

        scene = panoptic_lifting.convert(
            args.src, args.out, categories=categories, things=things, labels_prefix=args.labels_prefix,
            use_confidence=not args.no_confidence, use_gt=not args.no_gt, use_depth=not args.no_depth,
            test_every=args.test_every, intrinsics_size=parse_size(args.intrinsics_size), options=options)
    print(summary(scene))
    return 0


# Flags that only one source reads: passing them to another is a mistake worth a clear message.
_ONLY_FOR = {
    "images": ("--images", {"colmap"}),
    "scene_box": ("--scene-box", {"colmap"}),
    "no_points": ("--no-points", {"colmap"}),
    "predictions": ("--predictions", {"colmap", "nerfstudio", "instant-ngp", "open3d", "scannet"}),
    "intrinsic": ("--intrinsic", {"open3d"}),
    "poses": ("--poses", {"open3d"}),
    "intrinsics_size": ("--intrinsics-size", {"scannet", "panoptic-lifting"}),
    "no_depth": ("--no-depth", {"nerfstudio", "instant-ngp", "open3d", "scannet", "panoptic-lifting"}),
    "depth_as_gt": ("--depth-as-gt", {"nerfstudio", "instant-ngp", "open3d", "scannet", "panoptic-lifting"}),
    "no_gt": ("--no-gt", {"panoptic-lifting"}),
    "no_confidence": ("--no-confidence", {"panoptic-lifting"}),
}


def _reject_foreign_flags(args: argparse.Namespace) -> None:
    for attr, (flag, sources) in _ONLY_FOR.items():
        value = getattr(args, attr)
        if value not in (None, False) and args.source not in sources:
            raise InputError(flag, f"is not used with --from {args.source} (only with {', '.join(sorted(sources))})")
    if args.labels_prefix != "m2f" and args.source != "panoptic-lifting":
        raise InputError("--labels-prefix", f"is not used with --from {args.source} (only with panoptic-lifting)")
