"""``lift3d bench``: measure the speed/accuracy trade of the presets, the paper's ablation and scaling."""

from __future__ import annotations

import argparse
from pathlib import Path

DESCRIPTION = """\
Train each preset on synthetic scenes and measure, in one run on this machine: training wall time and
peak memory, ms to render 2048 rays, PSNR, mIoU, PQ^scene/SQ/RQ (both min_area variants), 3D F-score and
point mIoU of the export, and the pseudo-label baseline; then the paper's ablation (Base, +S, +L_seg,
+L_feat, all) at equal wall time, and how step/render time and memory scale with resolution, views, V and U.

Writes OUT/results.json, OUT/results.csv, OUT/pareto.png, OUT/scaling.png, OUT/benchmarks.md and, from a
source checkout, regenerates docs/benchmarks.md. Resumable: finished measurements are cached in OUT/cache.
The full benchmark takes hours on 2 CPU cores; --quick runs tiny scenes in a few minutes (CI smoke test)."""


def _csv(kind):
    def parse(text: str):
        try:
            return tuple(kind(x) for x in text.split(",") if x)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a comma-separated list, got {text!r}") from None
    return parse


def add_parser(subparsers, verb: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(verb, help="measure the speed/accuracy trade across presets",
                              description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="bench_out", metavar="DIR", help="output folder (default: bench_out)")
    p.add_argument("--scenes", type=_csv(str), default=("indoor", "outdoor"), metavar="LIST",
                   help="synthetic scene kinds (default: indoor,outdoor)")
    p.add_argument("--presets", type=_csv(str), default=("fast", "balanced", "quality"), metavar="LIST",
                   help="presets in cost order (default: fast,balanced,quality)")
    p.add_argument("--seeds", type=_csv(int), default=(0,), metavar="LIST", help="seeds (default: 0)")
    p.add_argument("--no-hard", action="store_true", help="skip the indoor scene with --noise hard")
    p.add_argument("--no-rgb-only", action="store_true",
                   help="skip the indoor run without the scene's depth maps (the paper's RGB-only setting)")
    p.add_argument("--no-bounded", action="store_true",
                   help="skip the bounded-field run of the outdoor scene (unbounded vs bounded comparison)")
    p.add_argument("--no-ablation", action="store_true", help="skip the ablation")
    p.add_argument("--ablation-budget", type=float, default=300.0, metavar="S",
                   help="wall-time budget per ablation variant in seconds (default: 300)")
    p.add_argument("--no-scaling", action="store_true", help="skip the scaling measurements")
    p.add_argument("--no-export", action="store_true",
                   help="skip timing a 1M-point labelled export of the indoor run")
    p.add_argument("--no-profile", action="store_true",
                   help="skip the profile of one training step and one 2048-ray render")
    p.add_argument("--no-under-load", action="store_true",
                   help="skip timing a training step and a render beside one busy 2-thread process")
    p.add_argument("--reevaluate", action="store_true",
                   help="re-run the evaluation of cached preset runs and the export timing (after a change to the "
                        "eval or export code); training times and memory stay from the cache")
    p.add_argument("--quick", action="store_true", help="tiny scenes and few steps (a smoke test, minutes)")
    p.add_argument("--docs-dir", metavar="DIR",
                   help="also write benchmarks.md and its pictures here (default: the checkout's docs/ for a full "
                        "run, nothing for --quick)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    # here, not at module level: keeps `lift3d --help` cheap
    from lift3d.bench.runner import BenchConfig, run_benchmark

    docs = Path(args.docs_dir) if args.docs_dir else None
    if docs is None and not args.quick:
        checkout_docs = Path(__file__).resolve().parents[2] / "docs"
        docs = checkout_docs if checkout_docs.is_dir() else None
    cfg = BenchConfig(out=Path(args.out), scenes=args.scenes, presets=args.presets, seeds=args.seeds,
                      hard_noise=not args.no_hard, rgb_only=not args.no_rgb_only, bounded_check=not args.no_bounded,
                      ablation=not args.no_ablation,
                      ablation_budget=args.ablation_budget, scaling=not args.no_scaling, export=not args.no_export,
                      profile=not args.no_profile, under_load=not args.no_under_load,
                      reevaluate=args.reevaluate, quick=args.quick, docs_dir=docs)
    results = run_benchmark(cfg)
    print(f"wrote {cfg.out / 'results.json'}, {cfg.out / 'benchmarks.md'}"
          + (f" and {docs / 'benchmarks.md'}" if docs else ""))
    print(f"  {len(results['runs'])} preset runs, {len(results['ablation'])} ablation variants, "
          f"{len(results['scaling'])} scaling points")
    return 0
