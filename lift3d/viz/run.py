"""Pictures of a trained run: test views side by side with their labels, and the training curves.

:func:`plot_run` writes two PNGs into the output folder:

* ``views.png`` — one row per test view: the photo | the rendered colour (with its PSNR) | the 2D
  pseudo-label the run was trained on | the lifted panoptic labels rendered from the field | the ground
  truth (when the scene has it) | the rendered depth. Panoptic maps are colourised with
  :func:`~lift3d.viz.palette.panoptic_color`: class colour on stuff, the stable instance colour on things,
  black on void. Pseudo-label instance ids are per frame, so their colours change between rows; the
  lifted ids are the field's and the same object keeps its colour in every row.
* ``curves.png`` — every loss term, PSNR (training batches and held-out views) and mIoU / PQ^scene of the
  held-out evaluations over the steps, from the run's ``log.jsonl``.

Drawing is separate from rendering (:func:`collect_frames`), so the figures can be made from arrays.
matplotlib draws with the Agg backend: no display is needed.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from lift3d.data.categories import as_class_table
from lift3d.data.scene import Scene
from lift3d.errors import InputError
from lift3d.eval.metrics import psnr
from lift3d.model.run import LoadedRun, load_run
from lift3d.model.run_folder import RunFolder
from lift3d.render.images import render_frame
from lift3d.utils.atomic import write_bytes_atomic
from lift3d.utils.progress import progress_bar
from lift3d.viz.palette import color_to_float, panoptic_color, semantic_color

__all__ = ["FramePanels", "collect_frames", "pick_frames", "plot_frame_grid", "plot_curves", "plot_run",
           "training_series"]

#: Loss terms drawn in this order (any other numeric term of the log follows, alphabetically).
_LOSS_ORDER = ("total", "color", "semantic", "instance", "segment", "distill", "feature", "tv", "disparity")
#: Keys of training records that are not loss terms.
_NOT_LOSSES = {"step", "time", "psnr", "eval", "final", "lr"}


def _pyplot():
    """matplotlib's pyplot on the Agg backend (files only; never opens a window or needs a display)."""
    import sys

    import matplotlib

    if "matplotlib.pyplot" not in sys.modules:  # a notebook or script that chose its backend keeps it
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: str | Path, dpi: int = 100) -> Path:
    """Render a matplotlib figure to PNG bytes and write them atomically; closes the figure."""
    plt = _pyplot()
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=dpi, facecolor="white")
    finally:
        plt.close(fig)
    write_bytes_atomic(path, buf.getvalue())
    return Path(path)


# ------------------------------------------------------------------------------------------ frames
@dataclass
class FramePanels:
    """Everything one row of ``views.png`` shows (numpy arrays of one frame, all ``H × W``).

    Attributes
    ----------
    name : str
        Frame name (row label).
    image : np.ndarray
        ``uint8 [H, W, 3]`` photo.
    rendered : np.ndarray
        ``float [H, W, 3]`` rendered colour in [0, 1].
    depth : np.ndarray
        ``float [H, W]`` rendered depth (world units, 0 = nothing).
    pseudo : tuple of np.ndarray
        ``(semantic, instance)`` of the 2D pseudo-label.
    lifted : tuple of np.ndarray
        ``(semantic, instance)`` rendered from the field.
    gt : tuple of np.ndarray or None
        Ground-truth ``(semantic, instance)``.
    psnr : float or None
        PSNR of ``rendered`` against ``image``.
    """

    name: str
    image: np.ndarray
    rendered: np.ndarray
    depth: np.ndarray
    pseudo: tuple[np.ndarray, np.ndarray]
    lifted: tuple[np.ndarray, np.ndarray]
    gt: tuple[np.ndarray, np.ndarray] | None = None
    psnr: float | None = None


def pick_frames(indices: Sequence[int], n: int) -> list[int]:
    """``n`` frames spread evenly over ``indices`` (all of them when there are fewer).

    Examples
    --------
    >>> pick_frames([3, 5, 7, 9, 11, 13], 3)
    [3, 7, 13]
    >>> pick_frames([4], 3)
    [4]
    """
    indices = list(indices)
    if n <= 0 or not indices:
        return []
    if len(indices) <= n:
        return indices
    pos = np.round(np.linspace(0, len(indices) - 1, n)).astype(int)
    return [indices[p] for p in pos]


def _block_sample(arr: np.ndarray, d: int, shape: tuple[int, int]) -> np.ndarray:
    """The pixel at the centre of every ``d × d`` block (what ``render_frame(downscale=d)`` renders)."""
    if d == 1:
        return arr
    o = (d - 1) // 2
    return arr[o::d, o::d][: shape[0], : shape[1]]


def collect_frames(loaded: LoadedRun, scene: Scene, frames: Sequence[int], *, downscale: int = 1,
                   progress: bool = False) -> list[FramePanels]:
    """Render ``frames`` of a loaded run and gather photo, pseudo-label and GT beside each.

    Parameters
    ----------
    loaded : LoadedRun
        From :func:`~lift3d.model.run.load_run`.
    scene : Scene
        The run's scene (``loaded.scene()``).
    frames : sequence of int
        Frame indices.
    downscale : int
        Render every ``downscale``-th pixel block (reference maps are sampled at the same pixels).
    progress : bool
        Show a progress bar.
    """
    rays = loaded.rays(scene)
    out = []
    for i in progress_bar(list(frames), desc="render views", disable=not progress, unit="frame"):
        r = render_frame(loaded.model, rays, int(i), loaded.norm.scale, downscale=downscale)
        shape = r.rgb.shape[:2]
        image = _block_sample(scene.image(int(i)), downscale, shape)
        pseudo = scene.pseudo_labels(int(i))
        gt = scene.gt_labels(int(i)) if scene.has_gt else None
        if r.semantic is None:  # a model without label heads: show void rather than fail
            r.semantic = np.zeros(shape, np.int64)
            r.instance = np.zeros(shape, np.int64)
        out.append(FramePanels(
            name=scene.frames[int(i)].name,
            image=image,
            rendered=r.rgb,
            depth=r.depth,
            pseudo=(_block_sample(pseudo.semantic, downscale, shape), _block_sample(pseudo.instance, downscale, shape)),
            lifted=(r.semantic, r.instance if r.instance is not None else np.zeros(shape, np.int64)),
            gt=None if gt is None else (_block_sample(gt.semantic, downscale, shape),
                                        _block_sample(gt.instance, downscale, shape)),
            psnr=float(psnr(r.rgb, image.astype(np.float32) / 255.0)),
        ))
    return out


def plot_frame_grid(panels: Sequence[FramePanels], classes: Any, path: str | Path, *,
                    title: str | None = None, panel_inches: float = 2.3) -> Path:
    """Write the ``views.png`` grid: photo | render | pseudo-label | lifted | GT | depth, one row per frame.

    Parameters
    ----------
    panels : sequence of FramePanels
        Rows, e.g. from :func:`collect_frames`.
    classes : class table
        Anything :func:`~lift3d.data.categories.as_class_table` accepts (a scene's ``categories``, ``classes.json``).
    path : str or Path
        PNG to write (atomically).
    title : str, optional
        Figure title.
    panel_inches : float
        Size of one panel (the figure is 100 dpi).

    Returns
    -------
    Path

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> sem = np.array([[1, 1, 3, 3]] * 4); inst = np.where(sem == 3, 1, 0)
    >>> row = FramePanels("f0", np.zeros((4, 4, 3), np.uint8), np.zeros((4, 4, 3)), np.ones((4, 4)),
    ...                   (sem, inst), (sem, inst), None, 30.0)
    >>> table = [{"id": 1, "name": "wall", "isthing": 0, "color": [90, 90, 200]},
    ...          {"id": 3, "name": "chair", "isthing": 1}]
    >>> p = plot_frame_grid([row], table, os.path.join(tempfile.mkdtemp(), "views.png"))
    >>> p.stat().st_size > 0
    True
    """
    plt = _pyplot()
    from matplotlib.patches import Patch

    if not panels:
        raise InputError("--frames", "no frames to show")
    table = as_class_table(classes)
    has_gt = any(p.gt is not None for p in panels)
    columns = ["photo", "rendered", "2D pseudo-label", "lifted panoptic"] + (["ground truth"] if has_gt else []) + [
        "depth"]
    n_rows, n_cols = len(panels), len(columns)
    h, w = panels[0].image.shape[:2]
    aspect = h / max(w, 1)
    # Width: panels + the depth colour bar; height: panels + title and the class legend underneath.
    fig, axes = plt.subplots(n_rows, n_cols, squeeze=False,
                             figsize=(panel_inches * n_cols + 0.9, panel_inches * aspect * n_rows + 1.55))
    valid_depth = np.concatenate([p.depth[p.depth > 0].ravel() for p in panels] + [np.zeros(0)])
    # One depth range for every row (a colour means the same distance everywhere); percentiles ignore specks.
    near, far = (np.percentile(valid_depth, [2, 98]) if valid_depth.size else (0.0, 1.0))
    far = max(far, near + 1e-6)
    seen_classes: set[int] = set()
    depth_im = None
    for r, p in enumerate(panels):
        maps = [p.pseudo, p.lifted] + ([p.gt] if has_gt else [])
        for sem, _ in (m for m in maps if m is not None):
            seen_classes.update(int(c) for c in np.unique(sem) if c > 0)
        images = [p.image, np.clip(p.rendered, 0, 1)] + [
            panoptic_color(m[0], m[1], table) if m is not None else None for m in maps]
        for c, img in enumerate(images):
            ax = axes[r, c]
            if img is None:
                ax.text(0.5, 0.5, "no ground truth", ha="center", va="center", fontsize=9, transform=ax.transAxes)
            else:
                ax.imshow(img, interpolation="nearest")
        depth = np.where(p.depth > 0, p.depth, np.nan)
        depth_im = axes[r, -1].imshow(depth, cmap="turbo_r", vmin=near, vmax=far, interpolation="nearest")
        axes[r, -1].set_facecolor("black")
        for c, ax in enumerate(axes[r]):
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(columns[c], fontsize=10)
        axes[r, 0].set_ylabel(p.name, fontsize=9)
        if p.psnr is not None:
            axes[r, 1].set_xlabel(f"PSNR {p.psnr:.2f} dB", fontsize=8)
    fig.subplots_adjust(left=0.04, right=0.92, top=1 - 0.55 / fig.get_figheight(),
                        bottom=0.9 / fig.get_figheight(), wspace=0.04, hspace=0.12)
    if depth_im is not None:
        pos = axes[-1, -1].get_position()
        top = axes[0, -1].get_position()
        cax = fig.add_axes([pos.x1 + 0.008, pos.y0, 0.012, top.y1 - pos.y0])
        fig.colorbar(depth_im, cax=cax).set_label("depth (scene units)", fontsize=8)
    names = {c.id: c for c in table}
    handles = [Patch(facecolor=color_to_float(semantic_color(cid, table)[0]), edgecolor="none",
                     label=names[cid].name if cid in names else f"class_{cid}") for cid in sorted(seen_classes)]
    handles.append(Patch(facecolor="black", label="void"))
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 8), fontsize=8, frameon=False,
               title="class colours (things: one colour per instance id)", title_fontsize=8)
    if title:
        fig.suptitle(title, fontsize=11)
    return save_figure(fig, path)


# ------------------------------------------------------------------------------------------ curves
def training_series(records: Sequence[dict]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], str | None]:
    """Split ``log.jsonl`` records into training series and evaluation series, sorted by step.

    A step logged twice (a resumed run re-logs it) keeps its last record.

    Returns
    -------
    train : dict
        ``step`` and one array per numeric term (NaN where a record lacks it).
    evals : dict
        ``step``, ``psnr``, ``miou``, ``pq_scene``.
    against : str or None
        What the evaluations compared with (``gt`` or ``pseudo_labels``).

    Examples
    --------
    >>> t, e, against = training_series([{"step": 2, "total": 1.0, "psnr": 12.0},
    ...     {"step": 1, "total": 2.0, "psnr": 10.0}, {"step": 2, "eval": {"miou": 0.5, "against": "gt"}}])
    >>> t["step"].tolist(), t["total"].tolist(), e["miou"].tolist(), against
    ([1, 2], [2.0, 1.0], [0.5], 'gt')
    """
    train: dict[int, dict] = {}
    evals: dict[int, dict] = {}
    against = None
    for rec in records:
        if not isinstance(rec, dict) or "step" not in rec:
            continue
        step = int(rec["step"])
        if isinstance(rec.get("eval"), dict):
            evals[step] = rec["eval"]
            against = rec["eval"].get("against", against)
        else:
            train[step] = rec
    t_steps = sorted(train)
    keys = sorted({k for r in train.values() for k, v in r.items()
                   if k not in ("step", "time") and isinstance(v, (int, float)) and not isinstance(v, bool)})
    t_out = {"step": np.array(t_steps, np.int64)}
    for k in keys:
        t_out[k] = np.array([float(train[s].get(k, np.nan)) for s in t_steps], np.float64)
    e_steps = sorted(evals)
    e_out = {"step": np.array(e_steps, np.int64)}
    for k in ("psnr", "miou", "pq_scene"):
        e_out[k] = np.array([_num(evals[s].get(k)) for s in e_steps], np.float64)
    return t_out, e_out, against


def smooth(y: np.ndarray, window: int) -> np.ndarray:
    """Centred moving average that skips NaN (a term missing from some records) and keeps the length.

    Examples
    --------
    >>> smooth(np.array([1.0, 2.0, np.nan, 4.0, 5.0]), 3).tolist()
    [1.5, 1.5, 3.0, 4.5, 4.5]
    """
    y = np.asarray(y, np.float64)
    if window <= 1 or len(y) < 3:
        return y.copy()
    ok = np.isfinite(y)
    kernel = np.ones(window)
    total = np.convolve(np.where(ok, y, 0.0), kernel, mode="same")
    count = np.convolve(ok.astype(np.float64), kernel, mode="same")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def _num(x) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan


def plot_curves(records: Sequence[dict], path: str | Path, *, title: str | None = None) -> Path:
    """Write ``curves.png``: loss terms (log scale), PSNR, and held-out mIoU / PQ^scene over the steps.

    Parameters
    ----------
    records : sequence of dict
        ``log.jsonl`` records (``RunFolder.read_log()``).
    path : str or Path
        PNG to write (atomically).
    title : str, optional
        Figure title.

    Raises
    ------
    InputError
        The log holds no training record.

    Examples
    --------
    >>> import tempfile, os
    >>> log = [{"step": s, "total": 1 / s, "color": 0.5 / s, "psnr": 10 + s} for s in (1, 2, 3)]
    >>> log.append({"step": 3, "eval": {"psnr": 12.5, "miou": 0.4, "pq_scene": 0.3, "against": "gt"}})
    >>> plot_curves(log, os.path.join(tempfile.mkdtemp(), "curves.png")).suffix
    '.png'
    """
    plt = _pyplot()
    train, evals, against = training_series(records)
    if len(train["step"]) == 0:
        raise InputError("log.jsonl", "no training records yet (has the run started?)")
    fig, (ax_loss, ax_psnr, ax_lab) = plt.subplots(1, 3, figsize=(15, 4.2))
    steps = train["step"]
    losses = [k for k in _LOSS_ORDER if k in train] + sorted(k for k in train if k not in _LOSS_ORDER
                                                              and k not in _NOT_LOSSES and k != "step")
    cmap = plt.get_cmap("tab10")
    # Batch losses are noisy; a moving average over ~1/25 of the logged points shows the trend (the
    # window is named in the title so nobody mistakes it for the raw values).
    window = max(1, len(steps) // 25) | 1
    for n, k in enumerate(losses):
        y = smooth(train[k], window)
        ok = np.isfinite(y) & (y > 0)  # log scale: zero / negative terms cannot be drawn
        if not ok.any():
            continue
        style = dict(color="black", lw=2.0) if k == "total" else dict(color=cmap(n % 10), lw=1.2)
        ax_loss.plot(steps[ok], y[ok], label=k, **style)
    ax_loss.set_yscale("log")
    ax_loss.set_title("losses (total and weighted terms" +
                      (f", moving average of {window} logs)" if window > 1 else ")"), fontsize=10)
    ax_loss.legend(fontsize=7, ncol=2)

    if "psnr" in train:
        ax_psnr.plot(steps, train["psnr"], color="tab:blue", lw=0.8, alpha=0.35)
        ax_psnr.plot(steps, smooth(train["psnr"], max(window, 3)), color="tab:blue", lw=1.5,
                     label="training batches (moving average)")
    if np.isfinite(evals["psnr"]).any():
        ax_psnr.plot(evals["step"], evals["psnr"], "o-", color="tab:red", label="held-out views")
    ax_psnr.set_title("PSNR (dB)", fontsize=10)
    ax_psnr.legend(fontsize=8)

    who = {"gt": "ground truth", "pseudo_labels": "pseudo-labels"}.get(against or "", against or "")
    for key, label, color in (("miou", "mIoU", "tab:green"), ("pq_scene", "PQ$^{scene}$", "tab:purple")):
        y = evals[key]
        if np.isfinite(y).any():
            ax_lab.plot(evals["step"], y, "o-", color=color, label=label)
    ax_lab.set_ylim(0, 1)
    ax_lab.set_title("held-out labels" + (f" (vs {who})" if who else ""), fontsize=10)
    if np.isfinite(evals["miou"]).any() or np.isfinite(evals["pq_scene"]).any():
        ax_lab.legend(fontsize=8)
    else:
        ax_lab.text(0.5, 0.5, "no evaluation logged yet", ha="center", va="center", transform=ax_lab.transAxes)
    for ax in (ax_loss, ax_psnr, ax_lab):
        ax.set_xlabel("step")
        ax.grid(alpha=0.3)
        ax.set_xlim(0, max(int(steps.max()), int(evals["step"].max()) if len(evals["step"]) else 0) * 1.02 + 1)
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    return save_figure(fig, path)


# ------------------------------------------------------------------------------------------ the whole run
def plot_run(run: str | Path, output_dir: str | Path | None = None, *, frames: int = 3, split: str = "test",
             data: str | Path | None = None, device: str = "auto", downscale: int = 1,
             progress: bool = False) -> dict[str, Path]:
    """Write ``views.png`` and ``curves.png`` of a run folder.

    Parameters
    ----------
    run : str or Path
        Run folder written by ``lift3d train``.
    output_dir : str or Path, optional
        Default ``<run>/plots``.
    frames : int
        Number of views (spread evenly over the split).
    split : str
        ``test``, ``val`` or ``train``.
    data : str or Path, optional
        The scene folder, if it moved since training.
    device : str
        ``auto``, ``cpu`` or ``cuda[:N]``.
    downscale : int
        Render every ``downscale``-th pixel block (faster previews of large images).
    progress : bool
        Show a progress bar.

    Returns
    -------
    dict
        ``{"views": Path, "curves": Path}``.
    """
    if downscale < 1:
        raise InputError("--downscale", f"must be a positive integer (got {downscale})")
    if frames < 1:
        raise InputError("--frames", f"must be at least 1 (got {frames})")
    folder = RunFolder.open(run)
    out_dir = Path(output_dir) if output_dir else Path(run) / "plots"
    records = folder.read_log()
    loaded = load_run(run, device)
    scene = loaded.scene(data)
    indices = pick_frames(scene.split(split).tolist(), frames)
    if not indices:
        raise InputError("--split", f"the {split} split of {scene.root} has no frames")
    preset = getattr(loaded.cfg, "preset", "")
    head = f"{scene.name} · {preset} · step {loaded.step}".replace(" ·  ·", " ·")
    panels = collect_frames(loaded, scene, indices, downscale=downscale, progress=progress)
    views = plot_frame_grid(panels, scene.categories, out_dir / "views.png", title=f"{head} — {split} views")
    seconds = [r.get("time") for r in records if isinstance(r.get("time"), (int, float))]
    curve_title = head + (f" — {max(seconds):.0f} s of training" if seconds else "")
    curves = plot_curves(records, out_dir / "curves.png", title=curve_title)
    return {"views": views, "curves": curves}
