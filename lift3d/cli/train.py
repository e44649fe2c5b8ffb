"""``lift3d train``: train a panoptic radiance field on a scene folder (or resume a run)."""

from __future__ import annotations

import argparse

from lift3d.train.config import PRESETS, add_config_flags, overrides_from_args

DESCRIPTION = """\
Train a panoptic radiance field (the paper's model S and losses) on a scene folder. Sizes the scene
determines (semantic classes U, instance channels V, bounded/unbounded, grid resolution) are derived and
written to the run folder's config.yml; every setting below overrides the preset.

Run folder: <output-dir>/<scene>/<preset>/<YYYY-MM-DD_HHMMSS>/ with config.yml, transform.json,
checkpoints/, log.jsonl. Checkpoints are atomic; `--resume RUN` continues from the newest readable one.

examples:
  lift3d train --data scenes/room0 --preset fast
  lift3d train --data scenes/room0 --preset quality --losses.feature 0 --optim.steps 20000
  lift3d train --resume outputs/room0/fast/2026-11-22_101500"""


def add_parser(subparsers, verb: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(verb, help="train a panoptic radiance field on a scene folder",
                              usage="lift3d train --data DIR [--preset NAME] [--output-dir DIR] [--resume RUN] [settings]",
                              description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", metavar="DIR", help="scene folder (see docs/scene-format.md)")
    p.add_argument("--preset", default="fast", metavar="NAME",
                   help=f"{', '.join(PRESETS)} or a YAML file of settings (default: fast)")
    p.add_argument("--output-dir", default="outputs", metavar="DIR", help="root of run folders (default: outputs)")
    p.add_argument("--device", default=None, metavar="DEV", help="auto, cpu or cuda[:N] (default: auto)")
    p.add_argument("--resume", metavar="RUN", help="continue a run folder from its newest checkpoint")
    p.add_argument("--steps", type=int, metavar="N", help="shortcut for --optim.steps")
    p.add_argument("--seed", type=int, metavar="N", help="shortcut for --trainer.seed")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_config_flags(p)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from lift3d.errors import InputError
    from lift3d.train.trainer import train

    overrides = overrides_from_args(args)
    if args.steps is not None:
        overrides.setdefault("optim", {})["steps"] = args.steps
    if args.seed is not None:
        overrides.setdefault("trainer", {})["seed"] = args.seed
    if args.device is not None:
        overrides.setdefault("trainer", {})["device"] = args.device
    if args.data is None and args.resume is None:
        raise InputError("--data", "give a scene folder (or --resume RUN)")
    train(args.data, preset=args.preset, output_dir=args.output_dir, overrides=overrides, resume=args.resume,
          progress=not args.quiet)
    return 0
