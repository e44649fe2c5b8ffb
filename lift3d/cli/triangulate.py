"""``lift3d triangulate``: geometry from the images of a scene folder (sparse points, optionally dense depth)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

HELP = "sparse points (and --dense depth maps) from a scene's images and poses"

DESCRIPTION = """\
Triangulate sparse 3D points from the images of a scene folder with its known poses (SIFT features, matches
checked against the epipolar geometry of the poses, tracks over >= 3 views, multi-view triangulation with
outlier removal and a depth sigma per observation) and, with --dense, plane-sweep stereo depth maps with a
per-pixel sigma. The results go into the scene folder and are referenced from transforms.json:

  sparse/points3D.ply        points: x y z, rgb, error (px), track_length (opens in CloudCompare)
  sparse/observations.npz    per observation: frame, pixel (u, v), point, depth, sigma
  mvs/depth/<name>.png       --dense: z-depth, uint16 in depth_unit_scale_factor units, 0 = none
  mvs/sigma/<name>.png       --dense: its standard deviation, same encoding
  mvs/support/<name>.png     --dense: source views that confirmed each depth (uint8)

Too little texture or baseline is a warning in the summary, never an error. Formats and measured accuracy:
docs/scene-format.md, docs/sfm.md.

examples:
  lift3d triangulate --data scenes/room
  lift3d triangulate --data scenes/room --dense --split all
  lift3d triangulate --data scenes/room --out /tmp/room_sfm --features.detector orb"""

SECTIONS = ("features", "pairs", "matching", "tracks", "dense")


def add_parser(subparsers, verb: str) -> argparse.ArgumentParser:
    """Register ``lift3d triangulate``."""
    # The flags come from the configuration dataclasses (lift3d.sfm loads OpenCV and scipy, the flags
    # machinery torch): here, not at module level, so that `lift3d --help` stays cheap (see lift3d.cli.main).
    from lift3d.model.config import add_config_flags
    from lift3d.sfm.config import SfmConfig

    p = subparsers.add_parser(verb, help=HELP,
                              description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter,
                              usage="lift3d triangulate --data DIR [--dense] [--split NAME] [--out DIR] [settings]")
    p.add_argument("--data", required=True, type=Path, metavar="DIR", help="scene folder (docs/scene-format.md)")
    p.add_argument("--dense", action="store_true", help="also compute plane-sweep depth and sigma maps")
    p.add_argument("--split", default="train", choices=("train", "val", "test", "all"),
                   help="frames to use (default: train, so held-out views stay out of the geometry)")
    p.add_argument("--out", type=Path, metavar="DIR",
                   help="write the files into DIR (same layout) instead of the scene folder, and leave "
                        "transforms.json untouched")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    # One --<section>.<field-name> flag per SfmConfig setting, by the run configuration's flags machinery.
    add_config_flags(p, SfmConfig(), SECTIONS)
    p.set_defaults(func=run)
    return p


def config_from_args(args: argparse.Namespace):
    """The :class:`~lift3d.sfm.config.SfmConfig` the flags describe (checked), and the overrides as a nested
    dict (recorded with the result)."""
    # here, not at module level: keeps `lift3d --help` cheap (torch, OpenCV)
    from lift3d.model.config import overrides_from_args, update_dataclass
    from lift3d.sfm.config import SfmConfig

    overrides = overrides_from_args(args)
    cfg = update_dataclass(SfmConfig(), overrides, "command line") if overrides else SfmConfig()
    return cfg.check(), overrides


def run(args: argparse.Namespace) -> int:
    """Run the pipeline, write the results, print the summary."""
    # here, not at module level: keeps `lift3d --help` cheap (OpenCV features, scipy graph routines)
    from lift3d.data.scene import load_scene
    from lift3d.data.stereo import write_mvs_depth, write_sparse_points
    from lift3d.sfm import plane_sweep_scene, triangulate_scene
    from lift3d.sfm.sparse import default_frames

    cfg, overrides = config_from_args(args)
    scene = load_scene(args.data)
    frames = default_frames(scene, args.split)
    progress = not args.quiet
    t0 = time.perf_counter()
    sparse = triangulate_scene(scene, frames, cfg, progress=progress)
    sparse.info["split"] = args.split
    if overrides:
        sparse.info["settings"] = overrides
    sparse_s = time.perf_counter() - t0
    dense = None
    if args.dense:
        t0 = time.perf_counter()
        dense = plane_sweep_scene(scene, frames, cfg, sparse=sparse, progress=progress)
        dense.info["split"] = args.split
        dense_s = time.perf_counter() - t0
    out = args.out if args.out is not None else scene.root
    if args.out is not None:
        _write_detached(out, sparse, dense, scene.depth_unit_scale_factor)
    else:
        write_sparse_points(out, sparse)
        if dense is not None:
            write_mvs_depth(out, dense, scene.depth_unit_scale_factor)
    print(summary(sparse, sparse_s, dense, dense_s if dense is not None else None, out))
    for w in sparse.info.get("warnings", []) + (dense.info.get("warnings", []) if dense is not None else []):
        print(f"lift3d triangulate: warning: {w}", file=sys.stderr)
    return 0


def _write_detached(out: Path, sparse, dense, unit_scale: float) -> None:
    """The same files in another folder, with a small JSON standing in for transforms.json's entries."""
    # here, not at module level: keeps `lift3d --help` cheap (as in run)
    from lift3d.data.stereo import write_mvs_maps, write_sparse_points_files
    from lift3d.utils.atomic import write_json_atomic

    entry = write_sparse_points_files(out, sparse)
    record: dict[str, Any] = {"sparse_points": entry}
    if dense is not None:
        record["mvs_depth"] = write_mvs_maps(out, dense, unit_scale)
    write_json_atomic(out / "triangulation.json", record)


def summary(sparse, sparse_s: float, dense, dense_s: float | None, out: Path) -> str:
    """The printed summary: counts, errors, dropped points by reason, seconds, where the files went."""
    info = sparse.info
    dropped = ", ".join(f"{k} {v}" for k, v in info.get("dropped", {}).items())
    lines = [f"lift3d triangulate: {info.get('frames', 0)} views ({info.get('keypoints_median', 0)} keypoints "
             f"per view, median), {info.get('pairs', 0)} view pairs, {info.get('matches', 0)} matches"]
    if len(sparse):
        lines.append(f"  sparse: {len(sparse)} points, median reprojection error {sparse.median_error:.2f} px, "
                     f"median track length {float(_median(sparse.track_length)):.0f}, "
                     f"{len(sparse.obs_point)} observations; {sparse_s:.1f} s")
    else:
        lines.append(f"  sparse: no points; {sparse_s:.1f} s")
    lines.append(f"  dropped: {dropped}")
    if dense is not None:
        lines.append(f"  dense: {len(dense)} depth maps, {100 * dense.coverage:.1f} % of pixels have a depth; "
                     f"{dense_s:.1f} s")
    lines.append(f"  wrote {out}/sparse/" + (f" and {out}/mvs/" if dense is not None else ""))
    return "\n".join(lines)


def _median(x) -> float:
    return float(np.median(x)) if len(x) else 0.0
