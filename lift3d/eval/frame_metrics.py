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


#: Most GT points :func:`lift3d.eval.evaluate.geometry_from_depth_block` back-projects (every pixel of a few small frames; every
#: k-th of many large ones).
DEPTH_GT_POINTS = 500_000


def depth_gt_points(scene: Scene, frames: Sequence[int], max_points: int = DEPTH_GT_POINTS) -> np.ndarray:
    """``[N, 3]`` world points of the ``frames``' depth maps (``gt_depth`` when every frame has one, else the
    input depth; 0 = no depth), every pixel, or an even pixel stride keeping at most ``max_points``."""
    reference = depth_reference(scene, frames)
    if reference is None:
        raise ValueError("depth_gt_points: not every frame has a depth map")
    pixels = sum(int(scene.cameras.width[i]) * int(scene.cameras.height[i]) for i in frames)
    stride = max(1, int(np.ceil(np.sqrt(pixels / max_points))))
    out = []
    for i in frames:
        d = scene.gt_depth(int(i)) if reference == "gt_depth" else scene.depth(int(i))
        vv, uu = np.mgrid[stride // 2:d.shape[0]:stride, stride // 2:d.shape[1]:stride]
        z = d[vv, uu]
        ok = np.isfinite(z) & (z > 0)
        out.append(scene.cameras.unproject(int(i), uu[ok], vv[ok], z[ok]))
    return np.concatenate(out) if out else np.zeros((0, 3))


def _describe_depth(m: dict, fmt: Callable[..., str]) -> str:
    d = m.get("depth")
    if not d:
        return "depth: no GT depth"
    return (f"depth abs-rel {fmt(d.get('abs_rel'))}, RMSE {fmt(d.get('rmse'))}, MAE {fmt(d.get('mae'))} "
            f"({fmt(100 * d['mae_of_diagonal'] if d.get('mae_of_diagonal') is not None else None, 2)} % of the "
            f"diagonal), off > 0.1: {fmt(d.get('share_over_0.1'))} ({d.get('n_valid')} px"
            f"{', vs GT depth maps' if d.get('reference') == 'gt_depth' else ''})")


@frame_metric("depth", describe=_describe_depth)
def _depth(scene: Scene, frames: Sequence[int], rendered: RenderedSplit) -> dict[str, Any]:
    """``depth``: ``abs_rel rmse mae share_over_0.1 n_valid`` over all valid pixels of all frames, the
    ``reference`` they were scored against (:func:`depth_reference`) and ``mae_of_diagonal`` (MAE over the
    diagonal of the reference depth back-projected: comparable across scene sizes); None without depth."""
    ref = depth_reference(scene, frames)
    if ref is None:
        return {"depth": None}
    read = scene.gt_depth if ref == "gt_depth" else scene.depth
    gd = np.concatenate([read(int(i)).ravel() for i in frames])
    pd = np.concatenate([np.asarray(d, np.float32).ravel() for d in rendered.depth])
    err = depth_error(pd, gd)
    gt = depth_gt_points(scene, frames, max_points=100_000)
    diagonal = float(np.linalg.norm(gt.max(0) - gt.min(0))) if len(gt) else float("nan")
    return {"depth": {**err, "reference": ref, "diagonal": diagonal,
                      "mae_of_diagonal": err["mae"] / diagonal if diagonal > 0 else float("nan")}}
