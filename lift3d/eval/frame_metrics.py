"""Metrics of rendered frames besides the panoptic labels, in a registry: PSNR, depth error.

Each entry computes its keys of ``metrics.json`` from the rendered frames and the scene (``None`` values
where the scene has no ground truth for it) and says how the ``lift3d eval`` table shows them.
:func:`lift3d.eval.evaluate.metrics_from_arrays` runs every entry; the panoptic labels (mIoU, PQ^scene and
the pseudo-label baseline) are :func:`lift3d.eval.evaluate.compute_2d_metrics`.

Adding a metric of rendered frames: its array function in :mod:`lift3d.eval.metrics`, and one function
here registered with :func:`frame_metric` (its ``metrics.json`` keys and its cell of the eval table).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from lift3d.eval.metrics import depth_error, psnr_per_image

if TYPE_CHECKING:  # annotations only: importing the metrics must not need torch
    from lift3d.data.scene import Scene
    from lift3d.eval.evaluate import RenderedSplit

#: ``compute(scene, frames, rendered) -> {metrics.json key: value}``
Compute = Callable[["Scene", Sequence[int], "RenderedSplit"], dict[str, Any]]
#: ``describe(metrics, fmt) -> str``: the table cell, numbers formatted with the table's ``fmt``
Describe = Callable[[dict, Callable[..., str]], str]


@dataclass(frozen=True)
class FrameMetric:
    """A registered metric: what computes its ``metrics.json`` keys, and its cell of the eval table."""

    name: str
    compute: Compute
    describe: Describe


#: Registered metrics, in the order of ``metrics.json`` and of the eval table's line.
FRAME_METRICS: dict[str, FrameMetric] = {}


def frame_metric(name: str, describe: Describe) -> Callable[[Compute], Compute]:
    """Register ``compute`` under ``name``; ``describe(metrics, fmt)`` is its cell of the eval table."""

    def register(compute: Compute) -> Compute:
        if name in FRAME_METRICS:
            raise ValueError(f"frame metric {name!r} is registered twice")
        FRAME_METRICS[name] = FrameMetric(name, compute, describe)
        return compute

    return register


def frame_psnrs(scene: Scene, rendered: RenderedSplit) -> list[float]:
    """PSNR of every rendered frame against its photo (RGB in [0, 1]); the scene's PSNR is their mean."""
    return [float(psnr_per_image(r[None], (scene.image(i).astype(np.float32) / 255.0)[None])[0])
            for i, r in zip(rendered.frames, rendered.rgb)]


@frame_metric("psnr", describe=lambda m, fmt: f"PSNR {fmt(m.get('psnr'), 2)} dB")
def _psnr(scene: Scene, frames: Sequence[int], rendered: RenderedSplit) -> dict[str, Any]:
    """``psnr``: mean of the per-frame PSNRs (``psnr_per_frame``)."""
    psnrs = frame_psnrs(scene, rendered)
    return {"psnr": float(np.mean(psnrs)), "psnr_per_frame": psnrs}


def depth_reference(scene: Scene, frames: Sequence[int]) -> str | None:
    """What rendered depth is scored against: the exact ``gt_depth_file_path`` maps when every frame has one
    (synthetic scenes, whose input depth may be noisy or absent), else the input ``depth_file_path``; None
    when some frame has neither."""
    if all(scene.frames[int(i)].gt_depth_path is not None for i in frames):
        return "gt_depth"
    if all(scene.frames[int(i)].depth_path is not None for i in frames):
        return "depth"
    return None


def _describe_depth(m: dict, fmt: Callable[..., str]) -> str:
    d = m.get("depth")
    if not d:
        return "depth: no GT depth"
    return (f"depth abs-rel {fmt(d.get('abs_rel'))}, RMSE {fmt(d.get('rmse'))}, MAE {fmt(d.get('mae'))} "
            f"({d.get('n_valid')} px{', vs GT depth maps' if d.get('reference') == 'gt_depth' else ''})")


@frame_metric("depth", describe=_describe_depth)
def _depth(scene: Scene, frames: Sequence[int], rendered: RenderedSplit) -> dict[str, Any]:
    """``depth``: ``abs_rel rmse mae n_valid`` over all valid pixels of all frames and the ``reference`` they
    were scored against (:func:`depth_reference`); None without depth to score against."""
    ref = depth_reference(scene, frames)
    if ref is None:
        return {"depth": None}
    read = scene.gt_depth if ref == "gt_depth" else scene.depth
    gd = np.concatenate([read(int(i)).ravel() for i in frames])
    pd = np.concatenate([np.asarray(d, np.float32).ravel() for d in rendered.depth])
    return {"depth": {**depth_error(pd, gd), "reference": ref}}
