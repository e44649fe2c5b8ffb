"""The table ``lift3d eval`` prints: the lifted result beside the 2D pseudo-label baseline.

Layout (see docs/metrics.md, "Reading the eval table")::

    lift3d eval  run .../2026-11-22_101500  step 2500  split test (8 frames, 128x128)
                              lifted                 pseudo-labels
                              min_area 0.005  strict  min_area 0.005  strict
    mIoU                      0.812   0.776   0.728   0.693
    PQ^scene   all            ...
               things
               stuff
    SQ^scene   ...
    RQ^scene   ...
    PSNR 27.31 dB | depth abs-rel 0.031, RMSE 0.082 | ...
    3D (export.surface, 200000 points vs 54453 GT, tau 0.110): point mIoU ..., PQ ..., Chamfer ..., F-score ...
    render 2048 rays: 41.2 ms (median of 10, 1 thread, cpu)
"""

from __future__ import annotations

import math
from typing import Any

from lift3d.eval.frame_metrics import FRAME_METRICS

__all__ = ["format_eval_table", "fmt"]


def fmt(x: Any, digits: int = 3, width: int = 0) -> str:
    """A number for the table: fixed digits, ``-`` for missing / NaN, ``inf`` kept.

    Examples
    --------
    >>> fmt(0.12345), fmt(None), fmt(float("nan")), fmt(float("inf"))
    ('0.123', '-', '-', 'inf')
    """
    if x is None or (isinstance(x, float) and math.isnan(x)):
        s = "-"
    elif isinstance(x, float) and math.isinf(x):
        s = "inf" if x > 0 else "-inf"
    elif isinstance(x, int) and not isinstance(x, bool):
        s = str(x)
    else:
        s = f"{float(x):.{digits}f}"
    return s.rjust(width)


def _get(block: dict | None, key: str, part: str | None = None) -> Any:
    if not block:
        return None
    if part is not None:
        return (block.get(part) or {}).get(key)
    return block.get(key)


def format_eval_table(m: dict) -> str:
    """Render the metrics dict of :func:`lift3d.eval.evaluate.evaluate_run` as a plain-text table.

    Parameters
    ----------
    m : dict
        Metrics (NaN or None both show as ``-``).

    Returns
    -------
    str
        Lines without a trailing newline.
    """
    size = m.get("image_size") or [0, 0]
    lines = [f"lift3d eval  run {m.get('run')}  step {m.get('step')}  split {m.get('split')} "
             f"({m.get('frames')} frames, {size[0]}x{size[1]})"]
    both = m.get("frames_also_trained") or []
    for warning in m.get("warnings") or []:
        lines.append(f"WARNING: {warning}: {', '.join(both[:8])}{', ...' if len(both) > 8 else ''}")
    for note in m.get("notes") or []:
        lines.append(f"note: {note}")
    poses = m.get("poses") or {}
    err = poses.get("written_vs_true")
    if err and (err.get("rms_deg") or err.get("rms_translation")):
        where = ("their true poses (gt_transform_matrix)" if poses.get("scored_at") == "gt_transform_matrix"
                 else "their written poses (--no-true-poses)")
        lines.append(f"poses: {err.get('frames')} scored frames rendered from {where}; the written poses are off by "
                     f"{fmt(err.get('rms_deg'), 2)} deg and {fmt(err.get('rms_translation'))} (RMS, world units)")
    base = m.get("pseudo_labels")
    has_labels = m.get("miou") is not None or m.get("pq_scene") is not None
    w = 8
    if has_labels:
        lines.append(f"{'':22}{'lifted':^{2 * w}}  {'pseudo-labels':^{2 * w}}  {'lift - pseudo':^{2 * w}}")
        lines.append(f"{'min_area':22}" + (f"{'0.005':>{w}}{'strict':>{w}}  " * 3).rstrip())
        rows: list[tuple[str, str, str | None]] = [("mIoU", "miou", None)]
        for k, name in (("pq", "PQ^scene"), ("sq", "SQ^scene"), ("rq", "RQ^scene")):
            rows.append((f"{name}  all", f"{k}_scene", None))
            rows.append((f"{'':10}things", k, "things"))
            rows.append((f"{'':10}stuff", k, "stuff"))
        for label, key, part in rows:
            vals = []
            for src in (m, base):
                for suffix in ("", "_strict"):
                    vals.append(_get(src, key + suffix, part))
            deltas = [_delta(vals[0], vals[2]), _delta(vals[1], vals[3])]
            cells = [fmt(v, width=w) for v in vals[:2]], [fmt(v, width=w) for v in vals[2:]], \
                [_fmt_delta(v, w) for v in deltas]
            lines.append(f"{label:22}" + "  ".join("".join(c) for c in cells))
        nt = m.get("things") or {}
        ns = m.get("stuff") or {}
        lines.append(f"{'':22}classes scored: {nt.get('n', '-')} things + {ns.get('n', '-')} stuff "
                     f"(strict {nt.get('n_strict', '-')} + {ns.get('n_strict', '-')})")
        other = m.get("other_instances")
        if other:
            lines.append(f"{'':22}instance ids from {m.get('instances_from')}; from {other.get('instances_from')}: "
                         f"PQ^scene {fmt(other.get('pq_scene'))} (strict {fmt(other.get('pq_scene_strict'))}), "
                         f"things {fmt(_get(other, 'pq', 'things'))}")
    lines.append(" | ".join(metric.describe(m, fmt) for metric in FRAME_METRICS.values()))
    p = m.get("points3d")
    if p:
        lines.append(f"3D ({p.get('source')}, {p.get('n_pred')} points vs {p.get('n_gt')} GT, "
                     f"tau {fmt(p.get('tau'))}): "
                     f"point mIoU {fmt(p.get('miou'))} (strict {fmt(p.get('miou_strict'))}), PQ {fmt(p.get('pq'))} "
                     f"(strict {fmt(p.get('pq_strict'))}; SQ {fmt(p.get('sq'))}, RQ {fmt(p.get('rq'))}) | "
                     f"accuracy {fmt(p.get('accuracy'))}, completeness "
                     f"{fmt(p.get('completeness'))}, Chamfer {fmt(p.get('chamfer'))}, F-score {fmt(p.get('fscore'))} "
                     f"(P {fmt(p.get('precision'))}, R {fmt(p.get('recall'))}) | objects found "
                     f"{fmt(p.get('instance_recall'))} of {p.get('n_instances')}")
    if p and p.get("per_class"):
        lines.append("3D point IoU per class: " + ", ".join(f"{k} {fmt(v)}" for k, v in
                                                           sorted(p["per_class"].items(), key=lambda kv: kv[1])))
    if p and p.get("objects"):
        measured = [o for o in p["objects"] if o.get("points", SMALLEST_MIN_POINTS) >= SMALLEST_MIN_POINTS]
        small = measured[:SMALLEST_OBJECTS]
        lines.append(f"smallest {len(small)} GT objects of ≥ {SMALLEST_MIN_POINTS} GT points (size = largest side, "
                     "point IoU, found at > 0.5): " + ", ".join(
            f"{o['class']} {o['size']:.2f} m {fmt(o['iou'])}{'' if o['iou'] > 0.5 else ' (lost)'}" for o in small))
    g = m.get("geometry_from_depth")
    if g:
        lines.append(f"3D geometry ({g.get('source')}, {g.get('n_pred')} points vs {g.get('n_gt')} from the "
                     f"{g.get('frames')} frames' {g.get('reference')} maps, tau {fmt(g.get('tau'))}): accuracy "
                     f"{fmt(g.get('accuracy'))}, completeness {fmt(g.get('completeness'))}, Chamfer "
                     f"{fmt(g.get('chamfer'))}, F-score {fmt(g.get('fscore'))} (P {fmt(g.get('precision'))}, "
                     f"R {fmt(g.get('recall'))})")
        off = g.get("imprecise")
        if off:
            lines.append(f"3D points off the reference surface: {fmt(off.get('in_front'))} in front of it (floaters), "
                         f"{fmt(off.get('behind'))} behind it in every frame that sees their pixel, "
                         f"{fmt(off.get('unobserved'))} seen by no scored frame")
        if g.get("fscore_observed") is not None:
            lines.append(f"3D over the points a scored frame can judge: F-score {fmt(g['fscore_observed'])} "
                         f"(P {fmt(g['precision_observed'])})")
    t = m.get("render_timing")
    if t:
        th = t.get("threads")
        lines.append(f"render 2048 rays: {fmt(t.get('median_ms'), 1)} ms (median of {t.get('repeats')}, "
                     f"{th} thread{'s' if th != 1 else ''}, {t.get('device')})")
    return "\n".join(line.rstrip() for line in lines)


#: How many of the smallest GT objects the table lists with their recovery.
SMALLEST_OBJECTS = 5
#: Fewest GT points of an object the list counts: a street's far streetlight holds one or two GT points, whose
#: size reads 0.00 m and whose IoU says nothing.
SMALLEST_MIN_POINTS = 20


def _delta(a: Any, b: Any) -> float | None:
    if a is None or b is None:
        return None
    try:
        a, b = float(a), float(b)
    except (TypeError, ValueError):
        return None
    if math.isnan(a) or math.isnan(b):
        return None
    return a - b


def _fmt_delta(v: float | None, width: int) -> str:
    if v is None:
        return "-".rjust(width)
    return f"{v:+.3f}".rjust(width)
