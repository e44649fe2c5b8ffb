"""``lift3d demo``: the main job in one command, on a built-in synthetic scene."""

from __future__ import annotations

import argparse

DESCRIPTION = """\
Synthesise a labelled scene, train a panoptic radiance field on its noisy 2D pseudo-labels (fast preset),
evaluate it on held-out views beside the pseudo-labels (2D and 3D), export the labelled point cloud and
mesh, draw the pictures, and print a summary of where everything is. About 10-15 minutes on 2 CPU cores
(--quick: a tiny scene, about a minute)."""


def add_parser(subparsers, verb: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(verb, help="the main job on a built-in synthetic scene",
                              description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--kind", default="indoor", choices=("indoor", "outdoor"), help="scene kind (default: indoor)")
    p.add_argument("--preset", default="fast", metavar="NAME", help="training preset (default: fast)")
    p.add_argument("--output-dir", default="demo_out", metavar="DIR", help="output folder (default: demo_out)")
    p.add_argument("--seed", type=int, default=0, help="scene and training seed (default: 0)")
    p.add_argument("--quick", action="store_true", help="tiny scene and few steps: checks the pipeline in a minute")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    # here, not at module level: keeps `lift3d --help` cheap
    from lift3d.demo import run_demo

    run_demo(args.output_dir, kind=args.kind, preset=args.preset, seed=args.seed, quick=args.quick)
    return 0
