"""``lift3d train``: train a panoptic radiance field on a scene folder (or resume a run)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lift3d.cli.main import one_line
from lift3d.errors import InputError, Lift3DError

HELP = "train a panoptic radiance field on a scene folder"

DESCRIPTION = """\
Train a panoptic radiance field (the paper's model S and losses) on a scene folder. Sizes the scene
determines (semantic classes U, instance channels V, bounded/unbounded, grid resolution) are derived and
written to the run folder's config.yml; every setting below overrides the preset. A setting's default
names the built-in presets' values where they differ from the plain default ("else": a --preset YAML file
that does not set it) and the bounded/unbounded scene defaults of configs/indoor.yaml and outdoor.yaml,
which apply after the preset (docs/presets.md).

Run folder: <output-dir>/<scene>/<preset>/<YYYY-MM-DD_HHMMSS>/ with config.yml, transform.json,
checkpoints/, log.jsonl. Checkpoints are atomic; `--resume RUN` continues from the newest readable one.

examples:
  lift3d train --data scenes/room0 --preset fast
  lift3d train --data scenes/room0 --preset quality --losses.feature 0 --optim.steps 20000
  lift3d train --resume outputs/room0/fast/2026-11-22_101500
  lift3d train --data scenes/*              several scenes, one run each, one after another
  lift3d train --data scenes.txt --scene-index $SLURM_ARRAY_TASK_ID   one scene of a list per array job
  torchrun --nproc_per_node 2 -m lift3d train --data scenes/room0   data-parallel (docs/scaling.md)"""


def add_parser(subparsers, verb: str) -> argparse.ArgumentParser:
    # The flags come from the run configuration, which imports torch: here, not at module level, so that
    # `lift3d --help` stays cheap (see lift3d.cli.main).
    from lift3d.model.config import PRESETS, add_config_flags

    p = subparsers.add_parser(verb, help=HELP,
                              usage="lift3d train --data DIR [DIR ...] [--preset NAME] [--output-dir DIR] [--resume RUN] [settings]",
                              description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", nargs="+", metavar="DIR",
                   help="scene folder (see docs/scene-format.md); several folders, or a text file listing one "
                        "folder per line, train one after another, each as its own run")
    p.add_argument("--scene-index", type=int, metavar="N",
                   help="with several scenes, train only the N-th (0-based), e.g. a job array's task id")
    p.add_argument("--preset", default="fast", metavar="NAME",
                   help=f"{', '.join(PRESETS)} or a YAML file of settings (default: fast)")
    p.add_argument("--output-dir", default="outputs", metavar="DIR", help="root of run folders (default: outputs)")
    p.add_argument("--device", default=None, metavar="DEV", help="auto, cpu or cuda[:N] (default: auto)")
    p.add_argument("--resume", metavar="RUN", help="continue a run folder from its newest checkpoint")
    p.add_argument("--steps", type=int, metavar="N", help="shortcut for --optim.steps")
    p.add_argument("--seed", type=int, metavar="N", help="shortcut for --trainer.seed")
    p.add_argument("--profile", metavar="NAME",
                   help="shortcut for --data.profile: auto (decided from the scene), manhattan-room, room, open, "
                        "outdoor or object")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_config_flags(p)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    # here, not at module level: keeps `lift3d --help` cheap (torch)
    from lift3d.model.config import overrides_from_args
    from lift3d.train.trainer import train

    overrides = overrides_from_args(args)
    if args.steps is not None:
        overrides.setdefault("optim", {})["steps"] = args.steps
    if args.seed is not None:
        overrides.setdefault("trainer", {})["seed"] = args.seed
    if args.profile is not None:
        overrides.setdefault("data", {})["profile"] = args.profile
    if args.device is not None:
        overrides.setdefault("trainer", {})["device"] = args.device
    if args.data is None and args.resume is None:
        raise InputError("--data", "give a scene folder (or --resume RUN)")
    if args.resume is not None:
        train(None, output_dir=args.output_dir, overrides=overrides, resume=args.resume, progress=not args.quiet)
        return 0
    scenes = scene_list(args.data)
    if args.scene_index is not None:
        if not 0 <= args.scene_index < len(scenes):
            raise InputError("--scene-index", f"{args.scene_index} is out of range for {len(scenes)} scene(s)")
        scenes = [scenes[args.scene_index]]
    if len(scenes) == 1:
        train(scenes[0], preset=args.preset, output_dir=args.output_dir, overrides=overrides,
              progress=not args.quiet)
        return 0
    return train_many(scenes, args.preset, args.output_dir, overrides, progress=not args.quiet)


def scene_list(entries: list[str]) -> list[Path]:
    """Scene folders from ``--data``: folders as given; a file is a list of folders, one per line (blank lines
    and ``#`` comments skipped, relative paths relative to the list file)."""
    scenes: list[Path] = []
    for entry in entries:
        path = Path(entry)
        if path.is_dir():
            scenes.append(path)
        elif path.is_file():
            try:
                lines = path.read_text().splitlines()
            except (OSError, UnicodeDecodeError) as exc:
                raise InputError(path, f"cannot read the scene list: {exc}") from None
            listed = [ln.strip() for ln in lines if ln.strip() and not ln.strip().startswith("#")]
            if not listed:
                raise InputError(path, "the scene list is empty")
            for item in listed:
                folder = Path(item) if Path(item).is_absolute() else path.parent / item
                if not folder.is_dir():
                    raise InputError(path, f"lists {item!r}, which is not a folder")
                scenes.append(folder)
        else:
            raise InputError(path, "no such scene folder or scene list")
    return scenes


def train_many(scenes: list[Path], preset: str, output_dir: str, overrides: dict, progress: bool) -> int:
    """Train each scene as its own run. A scene that fails is reported and skipped; exit code 2 if any did."""
    from lift3d.train.trainer import train  # here, not at module level: keeps `lift3d --help` cheap (torch)

    failed = []
    for k, scene in enumerate(scenes):
        print(f"lift3d train: scene {k + 1}/{len(scenes)}: {scene}", flush=True)
        try:
            train(scene, preset=preset, output_dir=output_dir, overrides=overrides, progress=progress)
        except Lift3DError as exc:
            print(f"lift3d train: error: {one_line(str(exc))}", file=sys.stderr, flush=True)
            failed.append(scene)
    if failed:
        print(f"lift3d train: {len(failed)} of {len(scenes)} scene(s) failed: {', '.join(map(str, failed))}",
              file=sys.stderr)
        return 2
    return 0
