"""``lift3d bench``: measure accuracy over several scenes, robustness to noise, the paper's ablation, speed."""

from __future__ import annotations

import argparse
from pathlib import Path

from lift3d.errors import InputError

DESCRIPTION = """\
Train on synthetic scenes and measure, in one run on this machine, with every accuracy row averaged over
scene seeds (mean ± standard deviation; default seeds 0,1,2, which no setting was tuned on):

  presets    indoor and outdoor x {RGB, RGB + sensor depth} x {moderate, view-correlated labels} at the first
             preset, the other presets for indoor RGB + depth: training time and peak memory, ms to render
             2048 rays, PSNR, mIoU, PQ^scene/SQ/RQ, 3D F-score and point mIoU of the export, objects found,
             instances exported, and the pseudo-label baseline
  curves     PQ^scene and mIoU (lifted and pseudo-labels) against label noise (clean, moderate, hard,
             view-correlated) and pose noise (0, 0.5 deg/2 cm, 1 deg/5 cm; scored at the true poses)
  ablation   the paper's Base, +S, +L_seg, +L_feat, all at equal steps and at equal time, each change tested
             seed by seed (significant or within noise)
  bounded    outdoor with a bounded field against the contracted one
  scaling    step/render time and memory against resolution, views, V and U
  export     time and memory of a 1M-point labelled export
  profile    where a training step and a render spend their time
  under-load a training step and a render alone and beside one busy 2-thread process

Writes OUT/results.json (per-seed values and the summary), OUT/results.csv, OUT/pareto.png,
OUT/noise_curves.png, OUT/scaling.png, OUT/benchmarks.md and, for a full run from a source checkout,
regenerates docs/benchmarks.md (a run narrowed by --only, --scenes, --seeds, ... leaves it alone unless
--docs-dir names where to write). Resumable: finished measurements are cached in OUT/cache. The full benchmark takes many
hours on 2 CPU cores: --plan lists every run with an estimated time (and trains nothing), --only runs some
sections; --quick runs tiny scenes (CI smoke test). A measurement that fails (training, evaluation, export)
becomes a row marked failed with its reason, the benchmark goes on, and the exit code is 1.

examples:
  lift3d bench --plan                                   # what the full run would do, and how long
  lift3d bench --only presets,curves --seeds 0,1,2
  lift3d bench --quick --scenes indoor --presets fast --seeds 100,101 --out /tmp/bench"""


def _csv(kind):
    def parse(text: str):
        try:
            return tuple(kind(x) for x in text.split(",") if x)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a comma-separated list, got {text!r}") from None
    return parse


#: Selection flags and the values of a full run: a run that narrows any of them writes the checkout's
#: docs/benchmarks.md only when --docs-dir asks for it (a partial page would replace the full one).
FULL_RUN = {"only": None, "scenes": ("indoor", "outdoor"), "presets": ("fast", "balanced"), "seeds": None,
            "noises": ("moderate", "view-correlated"), "inputs": ("rgb", "rgb+depth"), "ablation_variants": None,
            "ablation_modes": ("steps", "time"), "no_bounded": False, "no_ablation": False, "no_scaling": False,
            "no_export": False, "no_profile": False, "no_under_load": False}


def narrowed(args: argparse.Namespace) -> list[str]:
    """The selection flags of ``args`` that narrow the run below a full benchmark (``--scenes`` ...).

    >>> narrowed(argparse.Namespace(**{**FULL_RUN, "scenes": ("indoor",), "seeds": (0,)}))
    ['--scenes', '--seeds']
    >>> narrowed(argparse.Namespace(**{**FULL_RUN, "seeds": [0, 1, 2]}))   # the default seeds, spelt out
    []
    """
    from lift3d.bench.tables import REPORT_SEEDS  # here, not at module level: keeps `lift3d --help` cheap

    def full(key: str, value) -> bool:
        value = tuple(value) if isinstance(value, list) else value
        if key == "seeds" and value is not None:
            return value == tuple(REPORT_SEEDS)
        return value == FULL_RUN[key]
    return ["--" + k.replace("_", "-") for k in FULL_RUN if not full(k, getattr(args, k))]


def add_parser(subparsers, verb: str) -> argparse.ArgumentParser:
    from lift3d.bench.tables import QUICK_SEEDS, REPORT_SEEDS  # light module (no torch): keeps `lift3d --help` cheap

    p = subparsers.add_parser(verb, help="measure accuracy over scene seeds, noise robustness, ablation and speed",
                              description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="bench_out", metavar="DIR", help="output folder (default: bench_out)")
    p.add_argument("--plan", action="store_true",
                   help="list every training run with its cache status and estimated time, then stop")
    p.add_argument("--only", type=_csv(str), default=None, metavar="LIST",
                   help="run only these sections: presets, curves, ablation, bounded, scaling, export, profile, "
                        "under-load")
    p.add_argument("--scenes", type=_csv(str), default=FULL_RUN["scenes"], metavar="LIST",
                   help="synthetic scene kinds of the preset table (default: indoor,outdoor)")
    p.add_argument("--presets", type=_csv(str), default=FULL_RUN["presets"], metavar="LIST",
                   help="presets in cost order: the first makes every row, the others the indoor RGB + depth rows "
                        "(default: fast,balanced)")
    p.add_argument("--seeds", type=_csv(int), default=None, metavar="LIST",
                   help="scene seeds every row averages over (default: "
                        f"{','.join(map(str, REPORT_SEEDS))}; with --quick {','.join(map(str, QUICK_SEEDS))}: "
                        "seeds >= 5 are for tuning and smoke tests)")
    p.add_argument("--noises", type=_csv(str), default=FULL_RUN["noises"], metavar="LIST",
                   help="label noise of the preset table's scenes (default: moderate,view-correlated)")
    p.add_argument("--inputs", type=_csv(str), default=FULL_RUN["inputs"], metavar="LIST",
                   help="inputs of the preset table's rows: rgb (scenes without depth maps), rgb+depth "
                        "(default: both)")
    p.add_argument("--no-bounded", action="store_true",
                   help="skip the bounded-field runs of the outdoor scenes (unbounded vs bounded comparison)")
    p.add_argument("--no-ablation", action="store_true", help="skip the ablation")
    p.add_argument("--ablation-steps", type=int, default=1500, metavar="N",
                   help="steps of every variant in the equal-steps ablation (default: 1500, the fast preset's)")
    p.add_argument("--ablation-budget", type=float, default=600.0, metavar="S",
                   help="wall-time budget per variant in the equal-time ablation, seconds (default: 600)")
    p.add_argument("--ablation-modes", type=_csv(str), default=FULL_RUN["ablation_modes"], metavar="LIST",
                   help="ablations to run: steps (equal steps), time (equal wall time) or both (default: steps,time)")
    p.add_argument("--ablation-variants", type=_csv(str), default=None, metavar="LIST",
                   help="ablation variants to train, of base, base+S, base+S+L_seg, base+S+L_feat and all (default: "
                        "all five). The tables show the variants of this invocation: train some now and the rest "
                        "later, then run once more with all of them (finished runs come from the cache)")
    p.add_argument("--no-scaling", action="store_true", help="skip the scaling measurements")
    p.add_argument("--no-export", action="store_true",
                   help="skip timing a 1M-point labelled export of the indoor run")
    p.add_argument("--no-profile", action="store_true",
                   help="skip the profile of one training step and one 2048-ray render")
    p.add_argument("--no-under-load", action="store_true",
                   help="skip timing a training step and a render beside one busy 2-thread process")
    p.add_argument("--reevaluate", action="store_true",
                   help="re-run the evaluation of cached preset, curve and bounded runs and the export timing (after "
                        "a change to the eval or export code); training times and memory stay from the cache")
    p.add_argument("--quick", action="store_true", help="tiny scenes and few steps (a smoke test)")
    p.add_argument("--docs-dir", metavar="DIR",
                   help="also write benchmarks.md and its pictures here (default: the checkout's docs/ for a full "
                        "run; nothing for --quick or a run narrowed by --only, --scenes, --seeds, ...)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    # here, not at module level: keeps `lift3d --help` cheap
    from lift3d.bench.runner import ABLATION, SECTIONS, BenchConfig, plan_text, run_benchmark
    from lift3d.bench.tables import QUICK_SEEDS, REPORT_SEEDS

    switches = {"bounded": not args.no_bounded, "ablation": not args.no_ablation, "scaling": not args.no_scaling,
                "export": not args.no_export, "profile": not args.no_profile, "under-load": not args.no_under_load}
    if args.only is not None:
        unknown = [s for s in args.only if s not in SECTIONS]
        if unknown or not args.only:
            raise InputError("--only", f"{(unknown or [''])[0]!r} is not a section ({', '.join(SECTIONS)})")
        switches = {s: s in args.only for s in SECTIONS}
    docs = Path(args.docs_dir) if args.docs_dir else None
    partial = narrowed(args)
    if docs is None and not args.quick and not args.plan:
        checkout_docs = Path(__file__).resolve().parents[2] / "docs"
        if partial and checkout_docs.is_dir():
            print(f"a partial run ({' '.join(partial)}): {checkout_docs / 'benchmarks.md'} is left as it is "
                  "(--docs-dir DIR writes one)")
        elif checkout_docs.is_dir():
            docs = checkout_docs

    seeds = args.seeds if args.seeds is not None else (QUICK_SEEDS if args.quick else REPORT_SEEDS)
    cfg = BenchConfig(out=Path(args.out), scenes=args.scenes, presets=args.presets, seeds=seeds,
                      noises=args.noises, inputs=args.inputs, ablation_steps=args.ablation_steps,
                      ablation_budget=args.ablation_budget, ablation_modes=tuple(args.ablation_modes),
                      ablation_variants=tuple(ABLATION if args.ablation_variants is None else args.ablation_variants),
                      reevaluate=args.reevaluate, quick=args.quick,
                      docs_dir=docs, **{SECTIONS[s]: on for s, on in switches.items()})
    if args.plan:
        print(plan_text(cfg.check()))
        return 0
    results = run_benchmark(cfg)
    print(f"wrote {cfg.out / 'results.json'}, {cfg.out / 'benchmarks.md'}"
          + (f" and {docs / 'benchmarks.md'}" if docs else ""))
    curves = results.get("curves") or {}
    print(f"  {len(results['runs'])} preset-table runs, {sum(map(len, curves.values()))} noise-curve runs, "
          f"{len(results['ablation'])} ablation runs, {len(results['scaling'])} scaling points"
          + (f"; {len(results['skipped'])} runs could not be made (see benchmarks.md)" if results.get("skipped") else ""))
    failed = results.get("failed") or []
    for f in failed:
        print(f"  failed: {f['run']} ({', '.join(f['sections'])}): {f['stage']}: {f['reason']}")
    if failed:
        print(f"{len(failed)} measurement{'s' if len(failed) != 1 else ''} failed: their rows are marked failed in "
              "results.json, results.csv and benchmarks.md")
    return 1 if failed else 0
