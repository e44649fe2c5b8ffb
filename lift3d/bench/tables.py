"""The accuracy sections of ``docs/benchmarks.md``, written from the results: seed-averaged rows, the noise
curves' tables, the ablation with paired differences — and the sentences about them, so no number in the
page is typed by hand.

:func:`summarize` groups the per-seed run records of ``results.json`` into rows (mean ± standard deviation
over the seeds, per-seed values kept) and compares variants seed by seed (:mod:`lift3d.bench.stats`); the
``*_markdown`` functions turn that into Markdown lines.
"""

from __future__ import annotations

from typing import Any, Callable, Iterable, Sequence

from lift3d.bench.stats import fmt_diff, fmt_pm, mean_std, paired_difference

#: Scene seeds reserved for reported numbers; tuning uses seeds from TUNING_SEEDS_FROM on (never 0-4).
REPORT_SEEDS = (0, 1, 2)
TUNING_SEEDS_FROM = 5
#: Default seeds of ``lift3d bench --quick`` (a smoke test: it never trains on the reserved seeds).
QUICK_SEEDS = (100, 101)


def _p3(key: str) -> Callable[[dict], Any]:
    return lambda r: (r.get("points3d") or {}).get(key)


def _pl(key: str) -> Callable[[dict], Any]:
    return lambda r: (r.get("pseudo_labels") or {}).get(key)


def _minus(a: Callable[[dict], Any], b: Callable[[dict], Any]) -> Callable[[dict], Any]:
    def get(r: dict) -> Any:
        x, y = a(r), b(r)
        return None if x is None or y is None else float(x) - float(y)
    return get


#: Per-run values a row averages: name → how to read it from a run record.
METRICS: dict[str, Callable[[dict], Any]] = {
    "steps": lambda r: r.get("steps"),
    "train_seconds": lambda r: r.get("train_seconds"),
    "peak_rss_mb": lambda r: r.get("peak_rss_mb"),
    "render_ms": lambda r: r.get("render_ms_per_2048_rays"),
    "psnr": lambda r: r.get("psnr"),
    "miou": lambda r: r.get("miou"),
    "pq_scene": lambda r: r.get("pq_scene"),
    "sq_scene": lambda r: r.get("sq_scene"),
    "rq_scene": lambda r: r.get("rq_scene"),
    "pseudo_miou": _pl("miou"),
    "pseudo_pq_scene": _pl("pq_scene"),
    # The lifted result's margin over its own pseudo-labels, per seed (a paired difference).
    "lift_miou": _minus(lambda r: r.get("miou"), _pl("miou")),
    "lift_pq_scene": _minus(lambda r: r.get("pq_scene"), _pl("pq_scene")),
    "fscore_3d": _p3("fscore"),
    "miou_3d": _p3("miou"),
    "miou_3d_strict": _p3("miou_strict"),
    "objects_found_3d": _p3("instance_recall"),
    "gt_objects_3d": _p3("n_instances"),
    "instances_exported_3d": _p3("n_pred_instances"),
}
#: Ablation steps: variant → the variant it adds one component to (the paper's Table 6 reading).
ABLATION_COMPARE = {"base+S": "base", "base+S+L_seg": "base+S", "base+S+L_feat": "base+S", "all": "base+S"}
_ABLATION_METRICS = (("miou", "mIoU", 0), ("pq_scene", "PQ^scene", 1), ("psnr", "PSNR", 2))


# ------------------------------------------------------------------------------------------ grouping
def group_rows(records: Iterable[dict], keys: Sequence[str]) -> list[dict]:
    """Records with equal ``keys`` become one row (in order of first appearance).

    Returns
    -------
    list of dict
        ``key`` (the keys' values), ``seeds``, ``n``, ``inputs`` (what the runs trained on, as they say),
        ``metrics`` (name → ``mean std n per_seed``), ``records``.

    Examples
    --------
    >>> rows = group_rows([{"scene": "indoor", "seed": 0, "miou": 0.5}, {"scene": "indoor", "seed": 1, "miou": 0.7}],
    ...                   ["scene"])
    >>> rows[0]["n"], round(rows[0]["metrics"]["miou"]["mean"], 3)
    (2, 0.6)
    """
    groups: dict[tuple, list[dict]] = {}
    for r in records:
        groups.setdefault(tuple(_hashable(r.get(k)) for k in keys), []).append(r)
    rows = []
    for key, recs in groups.items():
        metrics = {}
        for name, get in METRICS.items():
            per_seed = {r["seed"]: get(r) for r in recs}
            m, s, n = mean_std(per_seed.values())
            metrics[name] = {"mean": m, "std": s, "n": n,
                             "per_seed": {str(k): v for k, v in per_seed.items() if v is not None}}
        inputs = sorted({str(r.get("inputs")) for r in recs if r.get("inputs")})
        rows.append({"key": dict(zip(keys, key)), "seeds": sorted(r["seed"] for r in recs), "n": len(recs),
                     "inputs": " / ".join(inputs) or "–", "metrics": metrics, "records": recs})
    return rows


def _hashable(v: Any) -> Any:
    return tuple(v) if isinstance(v, list) else v


def compare(a: dict, b: dict, metric: str) -> dict:
    """Paired difference ``a − b`` of one metric between two rows, seed by seed."""
    get = METRICS[metric]
    return paired_difference({r["seed"]: get(r) for r in a["records"]}, {r["seed"]: get(r) for r in b["records"]})


def summarize(results: dict) -> dict:
    """Rows and comparisons of every accuracy section (stored in ``results.json`` as ``summary``; the
    records keep the per-seed values). Run records are not repeated here."""
    def strip(rows: list[dict]) -> list[dict]:
        return [{k: v for k, v in row.items() if k != "records"} for row in rows]

    curves = results.get("curves") or {}
    out: dict[str, Any] = {
        "runs": strip(group_rows(results.get("runs", []), ("scene", "noise", "scene_depth", "preset", "variant"))),
        "label_noise": strip(group_rows(curves.get("label_noise", []), ("noise",))),
        "pose_noise": strip(group_rows(curves.get("pose_noise", []), ("pose_noise", "variant"))),
        "parameterisation": strip(group_rows(results.get("parameterisation", []), ("variant",))),
        "ablation": strip(group_rows(results.get("ablation", []), ("mode", "variant"))),
        "ablation_steps": ablation_steps(results.get("ablation", [])),
        "pose_noise_cost": pose_noise_cost(curves.get("pose_noise", [])),
    }
    return out


def ablation_steps(records: list[dict]) -> list[dict]:
    """Each ablation step (a variant against the one it adds to), per mode: paired differences of mIoU,
    PQ^scene and PSNR over the seeds, and whether each is significant."""
    rows = {(r["key"]["mode"], r["key"]["variant"]): r for r in group_rows(records, ("mode", "variant"))}
    out = []
    for mode in dict.fromkeys(m for m, _ in rows):
        for name, ref in ABLATION_COMPARE.items():
            if (mode, name) in rows and (mode, ref) in rows:
                out.append({"mode": mode, "variant": name, "against": ref,
                            **{k: compare(rows[mode, name], rows[mode, ref], k) for k, _, _ in _ABLATION_METRICS}})
    return out


def pose_noise_cost(records: list[dict]) -> list[dict]:
    """What each pose-noise level costs against no pose noise (same variant, paired by seed), and what pose
    refinement changes at each level (against no refinement): PQ^scene, mIoU, PSNR, 3D F-score."""
    rows = group_rows(records, ("pose_noise", "variant"))
    by = {(tuple(r["key"]["pose_noise"]), r["key"]["variant"]): r for r in rows}
    out = []
    for (pose, variant), row in by.items():
        entry = {"pose_noise": list(pose), "variant": variant}
        zero = by.get(((0.0, 0.0), variant))
        if zero is not None and any(pose):
            entry["vs_no_noise"] = {k: compare(row, zero, k) for k in ("pq_scene", "miou", "psnr", "fscore_3d")}
        plain = by.get((pose, "all"))
        if plain is not None and variant != "all":
            entry["vs_no_refinement"] = {k: compare(row, plain, k) for k in ("pq_scene", "miou", "psnr", "fscore_3d")}
        out.append(entry)
    return out


# ------------------------------------------------------------------------------------------ Markdown
def seed_note(seeds: Sequence[int]) -> str:
    """The sentence under the page title saying which seeds the numbers average and whether any was tuned on."""
    seeds = sorted(int(s) for s in seeds)
    listed = ", ".join(map(str, seeds))
    head = (f"Accuracy rows are the **mean ± standard deviation over scene seeds {listed}** (n = {len(seeds)} unless "
            "a row says otherwise; per-seed values in `results.json` and `results.csv`); each seed is a different "
            "synthetic scene (`lift3d synth`: room or street, textures, objects, camera path, label and sensor noise). ")
    if all(s < TUNING_SEEDS_FROM for s in seeds):
        return head + (f"These seeds were **not used for tuning**: every default was tuned on seeds ≥ {TUNING_SEEDS_FROM}.")
    return head + (f"**Seeds ≥ {TUNING_SEEDS_FROM} are tuning seeds**: these are development numbers, not a held-out "
                   "measurement.")


def _cell(row: dict, name: str, nd: int = 3) -> str:
    m = row["metrics"][name]
    return fmt_pm(m["mean"], m["std"], nd)


def _n_note(row: dict, n_seeds: int) -> str:
    return "" if row["n"] == n_seeds else f" (n={row['n']})"


def _labels(noise: str) -> str:
    return {"view-correlated": "view-corr."}.get(noise, noise)


def presets_markdown(results: dict) -> list[str]:
    """The preset table (mean ± std over seeds), the lifting margins, and sentences about both."""
    rows = group_rows(results["runs"], ("scene", "noise", "scene_depth", "preset", "variant"))
    n_seeds = len(results.get("seeds") or {r["seed"] for r in results["runs"]})
    lines = [
        "",
        "## How good: accuracy over scenes and seeds",
        "",
        "Test views of synthetic scenes (`lift3d synth`; indoor rooms and outdoor streets, label noise `moderate` "
        "(independent errors) or `view-correlated` (a segmenter that repeats its mistakes from similar "
        "viewpoints, with scores that say little; [synth.md](synth.md))). *Lifted* is the trained field; *(2D)* "
        "is the same metric on the pseudo-labels it learned from (per-frame ids as given). PQ^scene and mIoU at "
        "`min_area` 0.005. Render: median ms for 2048 rays with rgb, depth, semantic and instance. *Inputs*: what "
        "the run trained on, as it records it — `RGB + depth` with the scenes' sensor-like depth maps (noise "
        "growing with depth, holes); for the same scenes written without depth maps (`lift3d synth --depth "
        "none`) `RGB` (the paper's setting) or `RGB + SfM points` when depth from the images supervises the "
        "geometry ([sfm.md](sfm.md)). 3D metrics score the exported point cloud against `gt/points.ply` at "
        "τ = 1 % of its diagonal; *objects found* is the share of GT objects one exported instance covers with "
        "point IoU > 0.5 (of how many), *instances* how many thing instances the export holds.",
        "",
        "| scene | labels | inputs | preset | train s | peak MB | render ms | PSNR | mIoU lifted (2D) | "
        "PQ^scene lifted (2D) | 3D F-score | 3D mIoU | objects found | instances |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        k, mt = row["key"], row["metrics"]
        gt_obj = mt["gt_objects_3d"]["mean"]
        lines.append(
            f"| {k['scene']} | {_labels(k['noise'])} | {row['inputs']} | {k['preset']}{_n_note(row, n_seeds)} | "
            f"{_cell(row, 'train_seconds', 0)} | {_cell(row, 'peak_rss_mb', 0)} | {_cell(row, 'render_ms', 1)} | "
            f"{_cell(row, 'psnr', 2)} | {_cell(row, 'miou')} ({fmt_pm(mt['pseudo_miou']['mean'], None)}) | "
            f"{_cell(row, 'pq_scene')} ({fmt_pm(mt['pseudo_pq_scene']['mean'], None)}) | {_cell(row, 'fscore_3d')} | "
            f"{_cell(row, 'miou_3d')} | {_cell(row, 'objects_found_3d', 2)}"
            f"{f' of {gt_obj:.0f}' if gt_obj is not None else ''} | {_cell(row, 'instances_exported_3d', 0)} |")
    lines += [
        "",
        "**What lifting adds over its own pseudo-labels** (lifted − 2D on the same test views, seed by seed: "
        "mean ± standard error; *significant* when the mean is more than 2 standard errors from 0):",
        "",
        "| scene | labels | inputs | preset | Δ mIoU | Δ PQ^scene |",
        "|---|---|---|---|---|---|",
    ]
    for row in rows:
        k = row["key"]
        cells = []
        for name in ("lift_miou", "lift_pq_scene"):
            d = _self_diff(row, name)
            cells.append(fmt_diff(d) + (" significant" if d["significant"] else ""))
        lines.append(f"| {k['scene']} | {_labels(k['noise'])} | {row['inputs']} | {k['preset']} | {cells[0]} | {cells[1]} |")
    lines += [""] + _presets_prose(rows)
    return lines


def _self_diff(row: dict, name: str) -> dict:
    """A per-seed margin (already a difference) as a paired difference against 0."""
    per_seed = {r["seed"]: METRICS[name](r) for r in row["records"]}
    return paired_difference(per_seed, {s: 0.0 for s in per_seed})


def _presets_prose(rows: list[dict]) -> list[str]:
    out = []
    first = rows[0]["key"]["preset"] if rows else None
    at_first = [r for r in rows if r["key"]["preset"] == first]
    # 1. Margins over the pseudo-labels.
    for name, label in (("lift_miou", "mIoU"), ("lift_pq_scene", "PQ^scene")):
        diffs = [(r, _self_diff(r, name)) for r in at_first]
        up = [r for r, d in diffs if d["significant"] and d["mean"] > 0]
        down = [r for r, d in diffs if d["significant"] and d["mean"] < 0]
        text = (f"At `{first}`, lifting raises {label} over its pseudo-labels significantly in {len(up)} of "
                f"{len(diffs)} rows")
        if down:
            text += "; it lowers it significantly in " + ", ".join(_row_name(r) for r in down)
        if len(diffs) > 1:
            lo = min(diffs, key=lambda x: x[1]["mean"] if x[1]["mean"] is not None else 9.0)
            hi = max(diffs, key=lambda x: x[1]["mean"] if x[1]["mean"] is not None else -9.0)
            if lo[1]["mean"] is not None:
                text += (f" (margins from {lo[1]['mean']:+.3f} for {_row_name(lo[0])} to {hi[1]['mean']:+.3f} for "
                         f"{_row_name(hi[0])})")
        out.append(f"- {text}.")
    # 2. What depth maps buy, per scene and label noise.
    by = {(r["key"]["scene"], r["key"]["noise"], r["key"]["scene_depth"]): r for r in at_first}
    for (scene, noise, depth), row in by.items():
        if depth != "sensor" or (scene, noise, "none") not in by:
            continue
        rgb = by[(scene, noise, "none")]
        f_rgb, f_d = rgb["metrics"]["fscore_3d"]["mean"], row["metrics"]["fscore_3d"]["mean"]
        pq = compare(row, rgb, "pq_scene")
        if f_rgb is None or f_d is None:
            continue
        out.append(f"- {scene}, {noise} labels: with depth maps the export's 3D F-score is {f_d:.3f} against "
                   f"{f_rgb:.3f} from {rgb['inputs']} (mean over seeds); PQ^scene changes by {fmt_diff(pq)}"
                   f"{_significance(pq)}.")
    return out


def _against_first(rows: list[dict]) -> list[tuple[dict, dict]]:
    """Each row of a further preset with the first preset's row of the same scene, labels and inputs."""
    first = rows[0]["key"]["preset"] if rows else None
    at_first = [r for r in rows if r["key"]["preset"] == first]
    pairs = []
    for row in rows:
        if row["key"]["preset"] == first:
            continue
        ref = next((r for r in at_first if all(r["key"][k] == row["key"][k] for k in ("scene", "noise", "scene_depth",
                                                                                      "variant"))), None)
        if ref is not None:
            pairs.append((row, ref))
    return pairs


def _trade_sentence(row: dict, ref: dict) -> str:
    """A further preset against the first on one row: paired differences, and the training time it costs."""
    t, t0 = row["metrics"]["train_seconds"]["mean"], ref["metrics"]["train_seconds"]["mean"]
    parts = [f"{label} {fmt_diff(compare(row, ref, k), nd)}{_significance(compare(row, ref, k))}"
             for k, label, nd in (("psnr", "PSNR", 2), ("pq_scene", "PQ^scene", 3), ("miou", "mIoU", 3),
                                  ("fscore_3d", "3D F-score", 3), ("miou_3d", "point mIoU", 3))]
    return (f"`{row['key']['preset']}` against `{ref['key']['preset']}` ({_row_name(row, preset=False)}, paired by "
            "seed): " + ", ".join(parts) + (f", for {t / t0:.1f}× the training time" if t and t0 else ""))


def preset_choice_markdown(results: dict) -> list[str]:
    """The page's first section: which preset to use, with each preset's cost and accuracy on the indoor
    RGB + depth rows (the rows every preset has) and what the further presets buy over the first."""
    rows = group_rows(results.get("runs", []), ("scene", "noise", "scene_depth", "preset", "variant"))
    lines = ["", "## Which preset to use", "",
             "`fast` is the default (the demo's preset, and the one the benchmark measures on every scene): use it to "
             "check a capture end to end and on CPUs. `balanced` and `quality` train longer for more colour and "
             "geometry; [presets.md](presets.md) says what each setting of a preset buys. Measured here (means over "
             "the seeds; the tables below have the spread):", ""]
    shown = [r for r in rows if r["key"]["scene"] == "indoor" and r["key"]["scene_depth"] == "sensor"
             and r["key"]["variant"] == "all"]
    for row in shown:
        mt, k = row["metrics"], row["key"]
        lines.append(f"- `{k['preset']}`, indoor, {k['noise']} labels, {row['inputs']}: trains in "
                     f"{fmt_pm(mt['train_seconds']['mean'], None, 0)} s, renders 2048 rays in "
                     f"{fmt_pm(mt['render_ms']['mean'], None, 1)} ms, PQ^scene {fmt_pm(mt['pq_scene']['mean'], None)}, "
                     f"3D F-score {fmt_pm(mt['fscore_3d']['mean'], None)}, point mIoU "
                     f"{fmt_pm(mt['miou_3d']['mean'], None)}.")
    for row, ref in _against_first(rows):
        lines.append(f"- {_trade_sentence(row, ref)}.")
    measured = {r["key"]["preset"] for r in rows}
    missing = [p for p in ("fast", "balanced", "quality") if p not in measured]
    if missing:
        them = "it" if len(missing) == 1 else "them"
        lines.append(f"- Not measured in this benchmark: {', '.join(f'`{p}`' for p in missing)} "
                     f"(`lift3d bench --presets fast,{','.join(missing)}` adds {them}).")
    return lines


def preset_trade_markdown(results: dict, picture: str | None) -> list[str]:
    """The speed/accuracy trade: every preset row's training time against its accuracy, and the further presets
    against the first seed by seed."""
    rows = group_rows(results.get("runs", []), ("scene", "noise", "scene_depth", "preset", "variant"))
    lines = ["", "## The speed/accuracy trade", "",
             "Training time against PQ^scene and 3D F-score for every row of the preset table (means over the "
             "seeds). Timings move with the machine and its load: compare them within one benchmark run."]
    if picture:
        lines += ["", f"![speed/accuracy]({picture})"]
    lines += ["", "| scene | labels | inputs | preset | train s | render ms | PQ^scene | 3D F-score |",
              "|---|---|---|---|---|---|---|---|"]
    for row in rows:
        k = row["key"]
        lines.append(f"| {k['scene']} | {_labels(k['noise'])} | {row['inputs']} | {k['preset']} | "
                     f"{_cell(row, 'train_seconds', 0)} | {_cell(row, 'render_ms', 1)} | {_cell(row, 'pq_scene')} | "
                     f"{_cell(row, 'fscore_3d')} |")
    pairs = _against_first(rows)
    if pairs:
        lines += [""] + [f"- {_trade_sentence(row, ref)}." for row, ref in pairs]
    return lines


#: Thing classes the test views show with fewer GT pixels are left out of the per-class table: over 12 test
#: views of 128² a class of a few dozen pixels swings between IoU 0 and 0.5 with a handful of them.
PER_CLASS_MIN_PIXELS = 300


def per_class_markdown(results: dict) -> list[str]:
    """Per-class IoU of the thing classes on the test views: the indoor rows of the first preset, each class's
    mean over the seeds whose test views show it with at least :data:`PER_CLASS_MIN_PIXELS` pixels."""
    runs = [r for r in results.get("runs", []) if r.get("thing_iou") and r.get("scene") == "indoor"]
    if not runs:
        return []
    first = results["runs"][0]["preset"]
    rows = group_rows([r for r in runs if r["preset"] == first], ("noise", "scene_depth"))
    names = sorted({name for r in runs for name, c in r["thing_iou"].items() if c["gt_pixels"] >= PER_CLASS_MIN_PIXELS})
    if not names:
        return []
    lines = ["", "### Per-class IoU of the thing classes", "",
             f"Indoor rows of `{first}`; each class's IoU on the test views (every class the GT views show, however "
             f"small: `per_class_iou_strict` in `metrics.json`), the mean over the seeds whose test views show it with "
             f"at least {PER_CLASS_MIN_PIXELS} pixels (n = how many). Smaller classes are left out: a few dozen "
             "pixels swing between IoU 0 and 0.5.", "",
             "| thing class | " + " | ".join(f"{_labels(r['key']['noise'])}, {r['inputs']}" for r in rows) + " |",
             "|---|" + "---|" * len(rows)]
    for name in names:
        cells = []
        for row in rows:
            vals = [r["thing_iou"][name]["iou"] for r in row["records"]
                    if name in r["thing_iou"] and r["thing_iou"][name]["gt_pixels"] >= PER_CLASS_MIN_PIXELS]
            m, _, n = mean_std(vals)
            cells.append("–" if m is None else f"{m:.2f} (n={n})")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def _significance(d: dict) -> str:
    if d.get("significant") is None:
        return ""
    return " (significant)" if d["significant"] else " (within noise)"


def _row_name(row: dict, preset: bool = True) -> str:
    k = row["key"]
    name = f"{k['scene']} {k['noise']} {row['inputs']}"
    return name + (f" `{k['preset']}`" if preset else "")


def _pose_label(pose: Sequence[float]) -> str:
    return "none" if not any(pose) else f"{pose[0]:g}°/{pose[1]:g} cm"


def curves_markdown(results: dict, picture: str | None) -> list[str]:
    """The noise curves: picture, tables and sentences."""
    curves = results.get("curves") or {}
    n_seeds = len(results.get("seeds") or [])
    lines = [
        "",
        "### Label noise and pose noise",
        "",
        "Indoor scenes, the first preset, RGB + sensor depth, the same seeds. *Label noise*: the simulated "
        "segmenter from `clean` (GT classes and masks, per-frame ids) through `moderate` and `hard` (independent "
        "errors, `hard` doubling every rate) to `view-correlated` (`moderate` plus mistakes repeated from a range "
        "of viewpoints, scores loosely related to correctness). *Pose noise*: the training poses are off by the "
        "given RMS rotation and translation per frame (`lift3d synth --pose-noise`); test views are scored at "
        "their true poses (`gt_transform_matrix`, see [metrics.md](metrics.md)). Lines are means over the seeds, "
        "bars ± one standard deviation, faint dots single seeds.",
    ]
    if picture:
        lines += ["", f"![PQ^scene and mIoU against label noise and pose noise]({picture})"]
    label_rows = group_rows(curves.get("label_noise", []), ("noise",))
    if label_rows:
        lines += ["", "| labels | mIoU lifted | mIoU 2D | PQ^scene lifted | PQ^scene 2D | Δ PQ^scene (lifted − 2D) |",
                  "|---|---|---|---|---|---|"]
        for row in label_rows:
            lines.append(f"| {row['key']['noise']}{_n_note(row, n_seeds)} | {_cell(row, 'miou')} | "
                         f"{_cell(row, 'pseudo_miou')} | {_cell(row, 'pq_scene')} | {_cell(row, 'pseudo_pq_scene')} | "
                         f"{fmt_diff(_self_diff(row, 'lift_pq_scene'))} |")
        lines += [""] + _label_prose(label_rows)
    pose = curves.get("pose_noise", [])
    if pose:
        rows = group_rows(pose, ("pose_noise", "variant"))
        costs = {(tuple(c["pose_noise"]), c["variant"]): c for c in pose_noise_cost(pose)}
        lines += ["", "| pose noise | pose refinement | PSNR | mIoU | PQ^scene | 3D F-score | PQ^scene vs no pose noise |",
                  "|---|---|---|---|---|---|---|"]
        for row in rows:
            k = row["key"]
            c = costs.get((tuple(k["pose_noise"]), k["variant"]), {})
            vs = c.get("vs_no_noise", {}).get("pq_scene")
            lines.append(f"| {_pose_label(k['pose_noise'])}{_n_note(row, n_seeds)} | "
                         f"{'on' if k['variant'] == 'pose-refinement' else 'off'} | {_cell(row, 'psnr', 2)} | "
                         f"{_cell(row, 'miou')} | {_cell(row, 'pq_scene')} | {_cell(row, 'fscore_3d')} | "
                         f"{fmt_diff(vs) + _significance(vs) if vs else '–'} |")
        lines += [""] + _pose_prose(list(costs.values()))
    return lines


def _label_prose(rows: list[dict]) -> list[str]:
    by = {r["key"]["noise"]: r for r in rows}
    out = []
    order = [n for n in ("clean", "moderate", "hard", "view-correlated") if n in by]
    if len(order) >= 2:
        a, b = by[order[0]], by[order[-1]]
        for k, label in (("miou", "mIoU"), ("pq_scene", "PQ^scene")):
            la, lb = a["metrics"][k]["mean"], b["metrics"][k]["mean"]
            pa, pb = a["metrics"]["pseudo_" + k]["mean"], b["metrics"]["pseudo_" + k]["mean"]
            if None in (la, lb, pa, pb):
                continue
            out.append(f"- From `{order[0]}` to `{order[-1]}` labels, {label} of the pseudo-labels goes from {pa:.3f} "
                       f"to {pb:.3f} ({pb - pa:+.3f}) and of the lifted field from {la:.3f} to {lb:.3f} "
                       f"({lb - la:+.3f}).")
    for n in order:
        d = _self_diff(by[n], "lift_pq_scene")
        if d["mean"] is not None:
            word = ("above" if d["mean"] > 0 else "below") if d["significant"] else "within noise of"
            out.append(f"- `{n}`: lifted PQ^scene is {word} its pseudo-labels' ({fmt_diff(d)}).")
    return out


def _pose_prose(costs: list[dict]) -> list[str]:
    out = []
    for c in costs:
        vs = (c.get("vs_no_noise") or {}).get("pq_scene")
        if vs and vs["mean"] is not None:
            refine = " with pose refinement" if c["variant"] == "pose-refinement" else ""
            spread = (f"paired over {vs['n']} seeds, standard error {vs['se']:.3f}" if vs["se"] is not None
                      else "one seed")
            out.append(f"- {_pose_label(c['pose_noise'])} of pose noise{refine} costs {-vs['mean']:.3f} PQ^scene "
                       f"against none ({spread}){_significance(vs)}.")
        ref = (c.get("vs_no_refinement") or {}).get("pq_scene")
        if ref and ref["mean"] is not None:
            where = f"At {_pose_label(c['pose_noise'])}" if any(c["pose_noise"]) else "Without pose noise"
            out.append(f"- {where}, pose refinement changes PQ^scene by {fmt_diff(ref)}{_significance(ref)}.")
    return out


def ablation_markdown(results: dict, paper: dict[str, tuple[float, float, float]]) -> list[str]:
    """The ablation at equal steps and equal time: mean ± std per variant, then each step's paired
    difference with its significance and the paper's direction."""
    records = results["ablation"]
    rows = group_rows(records, ("mode", "variant"))
    n_seeds = len(results.get("seeds") or [])
    budget = next((r.get("budget_seconds") for r in records if r.get("budget_seconds")), None)
    steps = next((r.get("steps") for r in records if r.get("mode") == "steps"), None)
    modes = []
    if steps is not None:
        modes.append(f"*equal steps*: every variant trains {steps} steps")
    if budget is not None:
        modes.append(f"*equal time*: every variant trains {budget:.0f} s (the learning-rate schedule follows the "
                     "budget), so a cheaper variant takes more steps")
    lines = [
        "",
        "### Ablation: the paper's Table 6 on our rooms",
        "",
        "Base = a plain NeRF MLP field with the semantic and instance losses; S = the voxel-grid model; L_seg = "
        "segment consistency; L_feat = the perceptual prior. RGB only, as in the paper, `moderate` labels; "
        + "; ".join(modes) + ".",
    ]
    for mode, title in (("steps", "equal steps"), ("time", "equal time")):
        mode_rows = [r for r in rows if r["key"]["mode"] == mode]
        if not mode_rows:
            continue
        lines += ["", f"**{title}**", "", "| variant | steps | train s | PSNR | mIoU | PQ^scene | SQ | RQ | "
                  "paper mIoU / PQ / PSNR |", "|---|---|---|---|---|---|---|---|---|"]
        for row in mode_rows:
            v = row["key"]["variant"]
            lines.append(f"| {v}{_n_note(row, n_seeds)} | {_cell(row, 'steps', 0)} | {_cell(row, 'train_seconds', 0)} | "
                         f"{_cell(row, 'psnr', 2)} | {_cell(row, 'miou')} | {_cell(row, 'pq_scene')} | "
                         f"{_cell(row, 'sq_scene')} | {_cell(row, 'rq_scene')} | "
                         f"{' / '.join(str(x) for x in paper[v]) if v in paper else '–'} |")
    steps_ = ablation_steps(records)
    if steps_:
        lines += ["", "**Each step, seed by seed** (variant − the variant it adds to: mean ± standard error over the "
                  "seeds). *Ours*: `agrees` / `**opposite**` when the change is significant (more than 2 standard "
                  "errors from 0) and goes the paper's way or the other way, `within noise` when it is not; "
                  "*paper* is the direction of the same change in the paper's Table 6.", "",
                  "| step | mode | Δ mIoU | Δ PQ^scene | Δ PSNR | paper (mIoU, PQ, PSNR) | ours (mIoU, PQ, PSNR) |",
                  "|---|---|---|---|---|---|---|"]
        for s in steps_:
            ours, theirs = [], []
            for key, _, i in _ABLATION_METRICS:
                t = paper[s["variant"]][i] - paper[s["against"]][i] if s["variant"] in paper and s["against"] in paper else None
                theirs.append("–" if t is None else ("up" if t > 0 else "down"))
                ours.append(_verdict(s[key], t))
            lines.append(f"| {s['against']} → {s['variant']} | equal {s['mode']} | {fmt_diff(s['miou'])} | "
                         f"{fmt_diff(s['pq_scene'])} | {fmt_diff(s['psnr'], 2)} | {', '.join(theirs)} | "
                         f"{', '.join(ours)} |")
        lines += [""] + _ablation_prose(steps_, paper)
    return lines


def _verdict(d: dict, paper_change: float | None) -> str:
    if d.get("significant") is None:
        return "–"
    if not d["significant"]:
        return "within noise"
    if paper_change is None:
        return "up" if d["mean"] > 0 else "down"
    return "agrees" if (d["mean"] > 0) == (paper_change > 0) else "**opposite**"


def _ablation_prose(steps: list[dict], paper: dict) -> list[str]:
    out = []
    for mode in dict.fromkeys(s["mode"] for s in steps):
        agree, opposite, noise = [], [], []
        for s in (x for x in steps if x["mode"] == mode):
            for key, label, i in _ABLATION_METRICS:
                t = paper[s["variant"]][i] - paper[s["against"]][i] if s["variant"] in paper and s["against"] in paper else None
                v = _verdict(s[key], t)
                name = f"{s['variant']} ({label})"
                (agree if v == "agrees" else opposite if v == "**opposite**" else noise if v == "within noise" else []
                 ).append(name)
        text = f"- Equal {mode}: {_changes(len(agree))} the paper's way significantly"
        if opposite:
            text += f"; {_changes(len(opposite))} the other way significantly: " + ", ".join(opposite)
        if noise:
            text += f"; {len(noise)} {'is' if len(noise) == 1 else 'are'} within noise: " + ", ".join(noise)
        out.append(text + ".")
    return out


def _changes(n: int) -> str:
    return f"{n} change goes" if n == 1 else f"{n} changes go"


def parameterisation_markdown(results: dict) -> list[str]:
    """Bounded against contracted (unbounded) field on the outdoor scenes."""
    rows = group_rows(results["parameterisation"], ("variant",))
    n_seeds = len(results.get("seeds") or [])
    lines = [
        "",
        "### Unbounded vs bounded space (outdoor)",
        "",
        "The same preset and seeds on the outdoor scenes (moderate labels, RGB + depth), once with the contracted "
        "field that covers all of space (the default for scenes whose cameras look out of their box) and once "
        "bounded to the normalised scene box (`field.contraction: none`).",
        "",
        "| field | steps | train s | PSNR | mIoU | PQ^scene | 3D F-score |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        name = "unbounded (contracted)" if row["key"]["variant"] == "all" else row["key"]["variant"]
        lines.append(f"| {name}{_n_note(row, n_seeds)} | {_cell(row, 'steps', 0)} | {_cell(row, 'train_seconds', 0)} | "
                     f"{_cell(row, 'psnr', 2)} | {_cell(row, 'miou')} | {_cell(row, 'pq_scene')} | "
                     f"{_cell(row, 'fscore_3d')} |")
    by = {r["key"]["variant"]: r for r in rows}
    if "all" in by and "bounded" in by:
        parts = [f"{label} {fmt_diff(compare(by['all'], by['bounded'], k))}{_significance(compare(by['all'], by['bounded'], k))}"
                 for k, label in (("psnr", "PSNR"), ("pq_scene", "PQ^scene"), ("fscore_3d", "3D F-score"))]
        lines += ["", "The contraction changes " + ", ".join(parts) + " (unbounded − bounded, seed by seed)."]
    return lines
