"""Charts of ``lift3d bench``: the speed/accuracy trade of the presets and how cost scales.

``lift3d bench`` writes ``results.json``::

    {"machine": {...},
     "runs": [{"scene", "preset", "seed", "variant", "train_seconds", "peak_rss_mb",
               "render_ms_per_2048_rays", "psnr", "miou", "pq_scene", ..., "pseudo_labels": {"miou",
               "pq_scene", ...}}, ...],
     "scaling": [{"factor": "resolution" | "views" | "instance_channels" | "classes", "value": N,
                  "step_ms": x, "render_ms": y, "peak_rss_mb": z}, ...]}

and calls :func:`plot_pareto` and :func:`plot_scaling` (``lift3d plot --bench DIR`` draws the same from
the file):

* **Pareto plot** — PQ^scene, mIoU and PSNR (columns) against training time and against render time
  (rows). One marker shape per preset (mean over scenes and seeds, bars = ±1 standard deviation, faint
  dots = single runs), one colour per variant; the dashed staircase joins the presets no other preset
  beats on both axes; the horizontal line is the 2D pseudo-label baseline lifting has to beat.
* **Noise curves** — PQ^scene and mIoU (columns) of the lifted field and of its pseudo-labels against label
  noise and against pose noise (rows), mean over seeds with ±1 standard deviation and the single seeds.
* **Scaling plot** — log-log cost (ms per training step and per 2048 rendered rays; peak memory) against
  each factor, with the fitted exponent ``cost ∝ N^k`` in the legend.

Examples
--------
>>> results = {"runs": [{"preset": "fast", "train_seconds": 60, "pq_scene": 0.5},
...                     {"preset": "quality", "train_seconds": 600, "pq_scene": 0.6}]}
>>> plot_pareto(results, "pareto.png")  # doctest: +SKIP
>>> pareto_front([60, 600], [0.5, 0.6])  # both presets are on the front: each is best at its cost
[0, 1]
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from lift3d.errors import InputError
from lift3d.utils.files import read_json
from lift3d.viz.run import _pyplot, save_figure

__all__ = ["load_results", "plot_pareto", "plot_scaling", "plot_noise_curves", "pareto_front", "power_law_exponent"]

#: Presets in cost order; other preset names (YAML files) follow alphabetically.
PRESET_ORDER = ("fast", "balanced", "quality")
_MARKERS = ("o", "s", "D", "^", "v", "P", "X", "*", "<", ">")
#: (key, axis label, baseline key in ``pseudo_labels`` or None) of the Pareto plot's columns.
_METRICS = (("pq_scene", "PQ$^{scene}$", "pq_scene"), ("miou", "mIoU", "miou"), ("psnr", "PSNR (dB)", None))
#: (key, axis label) of the Pareto plot's rows.
_COSTS = (("train_seconds", "training time (s)"), ("render_ms_per_2048_rays", "render time (ms / 2048 rays)"))
_FACTOR_ORDER = ("resolution", "views", "instance_channels", "classes")
_FACTOR_LABEL = {"resolution": "image resolution (pixels per side)", "views": "training views",
                 "instance_channels": "instance channels V", "classes": "semantic classes"}


def load_results(results: dict | str | Path) -> tuple[dict, str]:
    """``results.json`` (a file, or a folder holding one) or an already-loaded dict, checked.

    Returns
    -------
    (dict, str)
        The results and the name to use in error messages.
    """
    where = "results"
    if isinstance(results, (str, Path)):
        path = Path(results)
        if path.is_dir():
            path = path / "results.json"
        where = str(path)
        results = read_json(path, missing="benchmark results not found (run `lift3d bench` first)")
    if not isinstance(results, dict):
        raise InputError(where, "expected a JSON object with 'runs' and 'scaling'")
    return results, where


def _num(x: Any) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return math.nan
    return v if math.isfinite(v) else math.nan


def pareto_front(x: Sequence[float], y: Sequence[float]) -> list[int]:
    """Indices of the points no other point beats on both axes (lower ``x`` cost, higher ``y`` quality),
    ordered by ``x``. NaN points are never on the front.

    Examples
    --------
    >>> pareto_front([1, 2, 3, 4], [0.5, 0.4, 0.7, 0.6])  # (2, 0.4) and (4, 0.6) are dominated
    [0, 2]
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.flatnonzero(np.isfinite(x) & np.isfinite(y))
    front, best = [], -math.inf
    # Sweep by cost (ties: better quality first); a point joins when it beats every cheaper point.
    for i in ok[np.lexsort((-y[ok], x[ok]))]:
        if y[i] > best:
            front.append(int(i))
            best = y[i]
    return front


def power_law_exponent(values: Sequence[float], costs: Sequence[float]) -> float:
    """Least-squares slope of ``log(cost)`` against ``log(value)``: ``k`` in ``cost ∝ value^k``.

    NaN when fewer than two positive points exist.

    Examples
    --------
    >>> round(power_law_exponent([1, 2, 4, 8], [3, 12, 48, 192]), 6)
    2.0
    """
    v, c = np.asarray(values, float), np.asarray(costs, float)
    ok = np.isfinite(v) & np.isfinite(c) & (v > 0) & (c > 0)
    if ok.sum() < 2 or np.ptp(np.log(v[ok])) == 0:
        return math.nan
    return float(np.polyfit(np.log(v[ok]), np.log(c[ok]), 1)[0])


def _machine_line(machine: Any) -> str:
    """One short line naming the machine (timings mean nothing without it)."""
    if not isinstance(machine, dict) or not machine:
        return ""
    parts = []
    for key in ("name", "cpu", "processor", "threads", "cores", "gpu", "device", "torch"):
        if machine.get(key) not in (None, ""):
            parts.append(f"{key} {machine[key]}" if key in ("threads", "cores", "torch") else str(machine[key]))
    if not parts:
        parts = [f"{k} {v}" for k, v in list(machine.items())[:4]]
    line = " · ".join(parts)
    return line if len(line) <= 110 else line[:107] + "..."


def _plain_log_ticks(ax, which: str = "x", ticks: Sequence[float] | None = None) -> None:
    """Readable log-axis labels: plain numbers (``300`` rather than ``3×10²``) at 1-2-5 steps, or at
    ``ticks`` (the measured values of a scaling series), and no crowded minor labels."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, LogLocator, NullFormatter

    axis = ax.xaxis if which == "x" else ax.yaxis
    axis.set_major_locator(FixedLocator(list(ticks)) if ticks is not None else LogLocator(subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


def _exponent_label(k: float) -> str:
    return f"  ∝ N^{round(k, 2) + 0.0:.2f}" if np.isfinite(k) else ""  # + 0.0: no "-0.00"


def _preset_key(name: str) -> tuple[int, str]:
    return (PRESET_ORDER.index(name) if name in PRESET_ORDER else len(PRESET_ORDER), name)


def plot_pareto(results: dict | str | Path, path: str | Path, *, title: str | None = None) -> Path:
    """Write the speed/accuracy chart: PQ^scene, mIoU, PSNR against training time and render time.

    Parameters
    ----------
    results : dict, str or Path
        ``results.json`` of ``lift3d bench`` (loaded, or its path / folder).
    path : str or Path
        PNG to write (atomically).
    title : str, optional
        Default: "speed / accuracy of the presets" and the machine.

    Returns
    -------
    Path

    Raises
    ------
    InputError
        No runs, or a run without a preset.

    Examples
    --------
    >>> plot_pareto("bench_out/results.json", "bench_out/pareto.png")  # doctest: +SKIP
    PosixPath('bench_out/pareto.png')
    """
    plt = _pyplot()
    results, where = load_results(results)
    runs = results.get("runs")
    if not isinstance(runs, list) or not runs:
        raise InputError(where, "'runs' is missing or empty (nothing to plot)")
    for k, r in enumerate(runs):
        if not isinstance(r, dict) or not r.get("preset"):
            raise InputError(where, f"runs[{k}].preset is missing")
    presets = sorted({str(r["preset"]) for r in runs}, key=_preset_key)
    # Runs are only compared within a scene (scene kind and noise): averaging different scenes would mix
    # their difficulty into the preset's point. Seeds of the same scene/preset/variant are averaged.
    scenes = sorted({_scene_label(r) for r in runs})
    default_variants = {"all", "default", "full"}
    marker = {p: _MARKERS[i % len(_MARKERS)] for i, p in enumerate(presets)}
    cmap = plt.get_cmap("tab10")
    color = {sc: cmap(i % 10) for i, sc in enumerate(scenes)}
    groups: dict[tuple[str, str, str], list[dict]] = {}
    for r in runs:
        groups.setdefault((_scene_label(r), str(r["preset"]), str(r.get("variant") or "default")), []).append(r)
    group_keys = sorted(groups, key=lambda g: (g[0], g[2], _preset_key(g[1])))

    fig, axes = plt.subplots(len(_COSTS), len(_METRICS), figsize=(14, 8), squeeze=False)
    for row, (cost_key, cost_label) in enumerate(_COSTS):
        for col, (metric, metric_label, base_key) in enumerate(_METRICS):
            ax = axes[row, col]
            curves: dict[tuple[str, str], tuple[list[float], list[float]]] = {}
            for g in group_keys:
                sc, preset, variant = g
                xs = np.array([_num(r.get(cost_key)) for r in groups[g]])
                ys = np.array([_num(r.get(metric)) for r in groups[g]])
                ok = np.isfinite(xs) & np.isfinite(ys)
                if not ok.any():
                    continue
                mx, my = float(xs[ok].mean()), float(ys[ok].mean())
                cx, cy = curves.setdefault((sc, variant), ([], []))
                cx.append(mx)
                cy.append(my)
                hollow = variant not in default_variants
                if ok.sum() > 1:  # single runs behind the mean, so the spread is visible
                    ax.scatter(xs[ok], ys[ok], marker=marker[preset], color=color[sc], alpha=0.25, s=18, lw=0)
                ax.errorbar(mx, my, xerr=float(xs[ok].std()) if ok.sum() > 1 else None,
                            yerr=float(ys[ok].std()) if ok.sum() > 1 else None, fmt=marker[preset],
                            color=color[sc], mfc="none" if hollow else color[sc], ms=9,
                            mec=color[sc] if hollow else "black", mew=1.5 if hollow else 0.6, capsize=3, lw=1)
                if col == 0:  # names once per row; the legend says the rest
                    ax.annotate(preset if not hollow else f"{preset} ({variant})", (mx, my),
                                textcoords="offset points", xytext=(6, 5), fontsize=8)
            for (sc, _variant), (cx, cy) in curves.items():
                front = pareto_front(cx, cy)
                if len(front) > 1:
                    ax.step(np.array(cx)[front], np.array(cy)[front], where="post", ls="--", color=color[sc],
                            lw=1, zorder=0)
            lines: dict[float, list[str]] = {}
            if base_key:
                # The baseline does not depend on the preset: one dotted line per scene, and one for scenes that
                # share their pseudo-labels (the same room with and without depth maps), named once.
                for sc in scenes:
                    vals = [_num((r.get("pseudo_labels") if isinstance(r.get("pseudo_labels"), dict) else {})
                                 .get(base_key)) for r in runs if _scene_label(r) == sc]
                    vals = [v for v in vals if np.isfinite(v)]
                    if vals:
                        lines.setdefault(round(float(np.mean(vals)), 4), []).append(sc)
                for k, (y, names) in enumerate(sorted(lines.items())):
                    ax.axhline(y, color="crimson", ls=":", lw=1.5)
                    if len(scenes) > 1:
                        # Neighbouring lines can be a few hundredths apart: names alternate below and above.
                        above = k % 2 == 1 or len(lines) == 1
                        ax.annotate(" · ".join(names), (1.0, y), xycoords=("axes fraction", "data"),
                                    xytext=(-3, 2 if above else -3), textcoords="offset points", ha="right",
                                    va="bottom" if above else "top", fontsize=7, color="crimson")
            xs_all = np.array([_num(r.get(cost_key)) for r in runs])
            xs_all = xs_all[np.isfinite(xs_all) & (xs_all > 0)]
            if xs_all.size and xs_all.max() / xs_all.min() > 5:
                ax.set_xscale("log")
                _plain_log_ticks(ax, "x")
            if metric in ("pq_scene", "miou"):
                lo = ax.get_ylim()[0]
                if lines:  # room for the name under the lowest baseline
                    lo = min(lo, min(lines) - 0.03 * (ax.get_ylim()[1] - lo) - 0.02)
                ax.set_ylim(max(0.0, min(lo, 0.0 if lo < 0.1 else lo)), min(1.0, ax.get_ylim()[1] + 0.05))
            ax.set_xlabel(cost_label)
            ax.set_ylabel(metric_label)
            ax.grid(alpha=0.3)
    # One legend for the figure: marker = preset, colour = scene, hollow = a non-default variant.
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], marker=marker[p], ls="", color="grey", mec="black", ms=8, label=p) for p in presets]
    handles += [Line2D([], [], marker="o", ls="", color=color[sc], ms=8, label=sc) for sc in scenes]
    others = sorted({g[2] for g in groups} - default_variants)
    handles += [Line2D([], [], marker="o", ls="", color="grey", mfc="none", mew=1.5, ms=8, label=v) for v in others]
    handles.append(Line2D([], [], ls="--", color="grey", label="Pareto front (per scene)"))
    handles.append(Line2D([], [], ls=":", color="crimson", lw=1.5, label="2D pseudo-labels"))
    # Up to 6 entries a row: with six scenes the names would run past the figure's edges in one row.
    rows = -(-len(handles) // 6)
    fig.legend(handles=handles, loc="upper center", ncol=-(-len(handles) // rows), fontsize=9, frameon=False,
               bbox_to_anchor=(0.5, 0.935))
    n_scenes = len(scenes)
    head = title or f"speed / accuracy of the presets ({len(runs)} runs, {n_scenes} scene{'s' * (n_scenes != 1)})"
    machine = _machine_line(results.get("machine"))
    fig.suptitle(head + (f"\n{machine}" if machine else ""), fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 0.9 - 0.03 * (rows - 1)))
    return save_figure(fig, path)


def _scene_label(run: dict) -> str:
    """``indoor``, ``indoor (view-correlated, RGB)``: the scene kind, and its label noise and inputs when they
    are not the default (moderate, RGB + depth)."""
    noise = run.get("noise")
    parts = [str(noise)] if noise and noise != "moderate" else []
    if run.get("inputs") and run["inputs"] != "RGB + depth":
        parts.append(str(run["inputs"]))
    return str(run.get("scene") or "scene") + (f" ({', '.join(parts)})" if parts else "")


#: x positions of the noise curves: label-noise presets and pose-noise levels, from none to most.
_LABEL_NOISE_ORDER = ("clean", "moderate", "hard", "view-correlated")


def _pose_key(run: dict) -> tuple[float, float]:
    p = run.get("pose_noise") or (0.0, 0.0)
    return float(p[0]), float(p[1])


def plot_noise_curves(results: dict | str | Path, path: str | Path, *, title: str | None = None) -> Path:
    """Write the robustness chart: PQ^scene and mIoU against label noise (top) and pose noise (bottom).

    Lines join the means over seeds (bars: ±1 standard deviation; faint dots: single seeds) of the lifted
    field (solid), of the same runs with pose refinement (dashed, pose row) and of the pseudo-labels the runs
    learned from (dotted).

    Parameters
    ----------
    results : dict, str or Path
        ``results.json`` of ``lift3d bench`` with ``curves.label_noise`` and/or ``curves.pose_noise`` run
        records (``noise``, ``pose_noise`` [deg, cm], ``variant``, ``seed``, ``miou``, ``pq_scene``,
        ``pseudo_labels``).
    path : str or Path
        PNG to write (atomically).

    Raises
    ------
    InputError
        No curve runs.
    """
    plt = _pyplot()
    results, where = load_results(results)
    curves = results.get("curves") if isinstance(results.get("curves"), dict) else {}
    label_runs = [r for r in curves.get("label_noise") or [] if isinstance(r, dict)]
    pose_runs = [r for r in curves.get("pose_noise") or [] if isinstance(r, dict)]
    if not label_runs and not pose_runs:
        raise InputError(where, "'curves' has no label_noise or pose_noise runs (nothing to plot)")
    metrics = (("pq_scene", "PQ$^{scene}$"), ("miou", "mIoU"))
    fig, axes = plt.subplots(2, 2, figsize=(11, 8), squeeze=False)

    def draw(ax, runs, xkey, levels, label_of, metric, series):
        for k, (name, select, value, style) in enumerate(series):
            dodge = 0.06 * (k - (len(series) - 1) / 2)  # series side by side, so equal values stay visible
            xs, means, stds = [], [], []
            for i, level in enumerate(levels):
                vals = np.array([_num(value(r, metric)) for r in runs if xkey(r) == level and select(r)])
                vals = vals[np.isfinite(vals)]
                if not vals.size:
                    continue
                ax.scatter(np.full(vals.size, i + dodge), vals, color=style["color"], alpha=0.25, s=16, lw=0)
                xs.append(i + dodge)
                means.append(vals.mean())
                stds.append(vals.std(ddof=1) if vals.size > 1 else 0.0)
            if xs:
                ax.errorbar(xs, means, yerr=stds, label=name, capsize=3, marker="o", ms=6, **style)
        ax.set_xticks(range(len(levels)))
        ax.set_xticklabels([label_of(v) for v in levels])
        ax.set_ylim(0.0, 1.0)
        ax.grid(alpha=0.3)

    lifted = lambda r, m: r.get(m)  # noqa: E731
    pseudo = lambda r, m: (r.get("pseudo_labels") or {}).get(m)  # noqa: E731
    plain = lambda r: r.get("variant", "all") != "pose-refinement"  # noqa: E731
    refined = lambda r: r.get("variant") == "pose-refinement"  # noqa: E731
    for col, (metric, label) in enumerate(metrics):
        ax = axes[0, col]
        if label_runs:
            present = {r.get("noise") for r in label_runs}
            levels = [n for n in _LABEL_NOISE_ORDER if n in present] + sorted(present - set(_LABEL_NOISE_ORDER) - {None})
            draw(ax, label_runs, lambda r: r.get("noise"), levels, str, metric,
                 [("lifted", lambda r: True, lifted, {"color": "tab:blue", "ls": "-"}),
                  ("2D pseudo-labels", lambda r: True, pseudo, {"color": "crimson", "ls": ":"})])
            ax.set_xlabel("label noise of the simulated segmenter")
        else:
            ax.text(0.5, 0.5, "not measured", ha="center", va="center", transform=ax.transAxes)
        ax.set_ylabel(label)
        ax = axes[1, col]
        if pose_runs:
            levels = sorted({_pose_key(r) for r in pose_runs})
            series = [("lifted", plain, lifted, {"color": "tab:blue", "ls": "-"})]
            if any(refined(r) for r in pose_runs):
                series.append(("lifted, pose refinement", refined, lifted, {"color": "tab:green", "ls": "--"}))
            series.append(("2D pseudo-labels", plain, pseudo, {"color": "crimson", "ls": ":"}))
            draw(ax, pose_runs, _pose_key, levels,
                 lambda v: "none" if not any(v) else f"{v[0]:g}° / {v[1]:g} cm", metric, series)
            ax.set_xlabel("pose noise of the training views (RMS rotation / translation)")
        else:
            ax.text(0.5, 0.5, "not measured", ha="center", va="center", transform=ax.transAxes)
        ax.set_ylabel(label)
    handles, names = [], []
    for ax in axes.ravel():
        for h, n in zip(*ax.get_legend_handles_labels()):
            if n not in names:
                handles.append(h)
                names.append(n)
    fig.legend(handles, names, loc="upper center", ncol=len(names), fontsize=9, frameon=False,
               bbox_to_anchor=(0.5, 0.935))
    seeds = sorted({r.get("seed") for r in label_runs + pose_runs if r.get("seed") is not None})
    head = title or f"robustness to label noise and pose noise (mean ± std over seeds {', '.join(map(str, seeds))})"
    machine = _machine_line(results.get("machine"))
    fig.suptitle(head + (f"\n{machine}" if machine else ""), fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 0.9))
    return save_figure(fig, path)


def plot_scaling(results: dict | str | Path, path: str | Path, *, title: str | None = None) -> Path:
    """Write the log-log scaling chart: ms per step, ms per 2048 rays and peak memory against each factor.

    Parameters
    ----------
    results : dict, str or Path
        ``results.json`` of ``lift3d bench`` (loaded, or its path / folder).
    path : str or Path
        PNG to write (atomically).
    title : str, optional
        Default: "how cost scales" and the machine.

    Returns
    -------
    Path

    Raises
    ------
    InputError
        No ``scaling`` entries, or an entry without ``factor`` / ``value``.

    Examples
    --------
    >>> plot_scaling("bench_out", "bench_out/scaling.png")  # doctest: +SKIP
    PosixPath('bench_out/scaling.png')
    """
    plt = _pyplot()
    results, where = load_results(results)
    entries = results.get("scaling")
    if not isinstance(entries, list) or not entries:
        raise InputError(where, "'scaling' is missing or empty (nothing to plot)")
    by_factor: dict[str, list[dict]] = {}
    for k, e in enumerate(entries):
        if not isinstance(e, dict) or "factor" not in e or not np.isfinite(_num(e.get("value"))):
            raise InputError(where, f"scaling[{k}] needs a 'factor' and a numeric 'value'")
        by_factor.setdefault(str(e["factor"]), []).append(e)
    factors = sorted(by_factor, key=lambda f: (_FACTOR_ORDER.index(f) if f in _FACTOR_ORDER else 99, f))
    fig, axes = plt.subplots(2, len(factors), figsize=(4.2 * len(factors) + 0.6, 7), squeeze=False)
    series = (("step_ms", "training step", "tab:blue", "o"), ("render_ms", "render 2048 rays", "tab:orange", "s"))
    for col, factor in enumerate(factors):
        rows = sorted(by_factor[factor], key=lambda e: _num(e["value"]))
        values = np.array([_num(e["value"]) for e in rows])
        ax_t, ax_m = axes[0, col], axes[1, col]
        for key, label, color, mk in series:
            costs = np.array([_num(e.get(key)) for e in rows])
            ok = np.isfinite(costs) & (costs > 0) & (values > 0)
            if ok.any():
                k = power_law_exponent(values[ok], costs[ok])
                ax_t.plot(values[ok], costs[ok], marker=mk, color=color, label=label + _exponent_label(k))
        mem = np.array([_num(e.get("peak_rss_mb")) for e in rows])
        ok = np.isfinite(mem) & (mem > 0) & (values > 0)
        if ok.any():
            k = power_law_exponent(values[ok], mem[ok])
            ax_m.plot(values[ok], mem[ok], marker="D", color="tab:green", label="peak memory" + _exponent_label(k))
        for ax, ylabel in ((ax_t, "ms"), (ax_m, "peak RSS (MB)")):
            if ax.lines:
                ax.set_xscale("log")
                ax.set_yscale("log")
                _plain_log_ticks(ax, "x", ticks=values[values > 0])
                _plain_log_ticks(ax, "y")
                ax.legend(fontsize=8)
            else:
                ax.text(0.5, 0.5, "not measured", ha="center", va="center", transform=ax.transAxes)
            ax.set_xlabel(_FACTOR_LABEL.get(factor, factor))
            ax.set_ylabel(ylabel)
            ax.grid(alpha=0.3, which="both")
        ax_t.set_title(_FACTOR_LABEL.get(factor, factor).split(" (")[0], fontsize=10)
    machine = _machine_line(results.get("machine"))
    head = title or "how cost scales (log-log; exponent k of cost ∝ N^k)"
    fig.suptitle(head + (f"\n{machine}" if machine else ""), fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 0.94))
    return save_figure(fig, path)
