"""The depth targets' sources that need no plane: triangulated points, plane-sweep depths, and the plane sweep's
depths on the pixels the labels call a thing (the planes hold stuff only)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from lift3d.data.scene import Scene
from lift3d.data.stereo import DenseDepth, SparsePoints
from lift3d.train.target_steps.state import TargetContext, TargetState, TargetStep, setting


@dataclass
class SparseObservations(TargetStep):
    """Every observation of a triangulated point in a frame that gets targets: the ray through its keypoint, with
    the point's z-depth and standard deviation. Records ``observations``."""

    name = "sparse-points"

    def apply(self, state: TargetState, context: TargetContext) -> dict[str, Any]:
        rows = sparse_rows(context.scene, context.sparse, context.targets_for)
        state.rows.append(rows)
        return {"observations": int(len(rows[0]))}


@dataclass
class PlaneSweepDepths(TargetStep):
    """Every plane-sweep depth of a frame that gets targets (source ``dense``). Records ``dense_coverage``: the
    share of those frames' pixels with a depth."""

    name = "plane-sweep"

    def apply(self, state: TargetState, context: TargetContext) -> dict[str, Any]:
        rows = dense_rows(context.scene, context.dense, context.targets_for)
        state.rows.append(rows)
        pixels = sum(int(context.scene.cameras.width[i]) * int(context.scene.cameras.height[i])
                     for i in context.targets_for)
        return {"dense_coverage": round(float(len(rows[0])) / max(1, pixels), 4)}


@dataclass
class PlaneSweepOnThings(TargetStep):
    """The plane sweep's depths at the pixels the labels call a thing: the planes give stuff only, and objects
    otherwise have the triangulated points alone. Records ``dense_on_things`` and ``dense_on_things_one_source``
    (of them, those one source view confirmed)."""

    name = "plane-sweep-on-things"
    enabled: bool = setting("plane_dense_things")

    def apply(self, state: TargetState, context: TargetContext) -> dict[str, Any]:
        scene, dense = context.scene, context.dense
        if not scene.thing_ids:
            return {}
        rows = dense_rows(scene, dense, context.targets_for)
        on_thing = np.zeros(len(rows[0]), bool)
        one_source = np.zeros(len(rows[0]), bool)
        support = dict(zip(dense.frame_names, dense.support)) if dense.support is not None else {}
        for i in np.unique(rows[0]):
            k = np.flatnonzero(rows[0] == i)
            sem = context.labels[int(i)]  # targets_for is a subset of the training frames
            r, c = rows[2][k].astype(np.int64), rows[1][k].astype(np.int64)
            on_thing[k] = np.isin(sem[r, c], scene.thing_ids)
            if scene.frames[int(i)].name in support:
                one_source[k] = np.asarray(support[scene.frames[int(i)].name])[r, c] == 1
        state.rows.append(tuple(a[on_thing] for a in rows))
        return {"dense_on_things": int(on_thing.sum()),
                "dense_on_things_one_source": int((on_thing & one_source).sum())}


def sparse_rows(scene: Scene, sparse: SparsePoints, targets_for: np.ndarray) -> tuple[np.ndarray, ...]:
    """Targets ``(frame, u, v, z, sigma, dense)`` of the observations in the frames of ``targets_for``, inside their
    image."""
    keep = np.isin(sparse.obs_frame, targets_for)
    f = sparse.obs_frame[keep].astype(np.int64)
    uv = sparse.obs_uv[keep].astype(np.float32)
    w, h = scene.cameras.width[f], scene.cameras.height[f]
    inside = (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] < w) & (uv[:, 1] < h)
    f, uv = f[inside], uv[inside]
    z, s = sparse.obs_depth[keep][inside], sparse.obs_sigma[keep][inside]
    # observations.npz puts pixel (c, r)'s centre at (c + .5, r + .5); rays put it at (c, r).
    return f, uv[:, 0] - 0.5, uv[:, 1] - 0.5, z.astype(np.float32), s.astype(np.float32), np.zeros(len(f), bool)


def dense_rows(scene: Scene, dense: DenseDepth, targets_for: np.ndarray) -> tuple[np.ndarray, ...]:
    """Targets ``(frame, u, v, z, sigma, dense)`` of every plane-sweep depth in the frames of ``targets_for``."""
    index = {f.name: k for k, f in enumerate(scene.frames)}
    wanted = set(int(i) for i in targets_for)
    out = []
    for name, d, s in zip(dense.frame_names, dense.depth, dense.sigma):
        i = index[name]
        if i not in wanted:
            continue
        r, c = np.nonzero(np.asarray(d) > 0)
        out.append((np.full(len(r), i, np.int64), c.astype(np.float32), r.astype(np.float32),
                    np.asarray(d)[r, c].astype(np.float32), np.asarray(s)[r, c].astype(np.float32),
                    np.ones(len(r), bool)))
    if not out:
        f = np.zeros(0, np.float32)
        return np.zeros(0, np.int64), f, f, f, f, np.zeros(0, bool)
    return tuple(np.concatenate(a) for a in zip(*out))
