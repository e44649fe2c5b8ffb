"""Evaluation: metrics on plain numpy arrays (docs/metrics.md).

- :func:`pq_scene` — scene-level panoptic quality (PQ^scene of Panoptic Lifting)
- :func:`miou`, :func:`confusion_matrix` — semantic mIoU over GT-valid pixels
- :func:`psnr`, :func:`psnr_per_image` — image PSNR
- :func:`depth_error` — abs-rel / RMSE / MAE of depth maps
- :func:`points3d` — labelled point cloud vs GT points (point mIoU/PQ, Chamfer, F-score)
- :func:`evaluate_run` (with :class:`EvalOptions`), :func:`compute_2d_metrics`, :func:`time_render` — ``lift3d eval``
  on a run folder
"""

from lift3d.eval.metrics import confusion_matrix, depth_error, miou, pq_scene, psnr, psnr_per_image
from lift3d.eval.points3d import points3d
from lift3d.eval.evaluate import EvalOptions, compute_2d_metrics, evaluate_run, time_render

__all__ = ["pq_scene", "miou", "psnr", "psnr_per_image", "depth_error", "points3d", "confusion_matrix",
           "evaluate_run", "EvalOptions", "compute_2d_metrics", "time_render"]
