"""Which part of space the training cameras observe.

A dense grid starts with the same (opaque) density everywhere. Cells that no training ray crosses get no
gradient, so space behind every camera keeps that density: a novel view from there looks into fog, and
the export's isosurface wraps it. Like instant-NGP's marking of untrained cells, the field zeroes the
density of lattice cells outside every training camera's frustum (:class:`lift3d.field.space.SceneSpace`).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor
from torch.nn import functional as F


def observed_cells(space, cameras, frames, resolution: int, *, near: float, margin: float = 0.05,
                   dilate: int = 1, box: np.ndarray | None = None) -> Tensor:
    """``[R, R, R]`` bool: lattice cells whose centre some camera of ``frames`` sees (ignoring occlusion).

    Parameters
    ----------
    space : lift3d.field.space.SceneSpace
        Maps lattice cells to normalised scene points (contracted or not).
    cameras : lift3d.data.cameras.Cameras
        Cameras with poses in *normalised* coordinates.
    frames : sequence of int
        The training frames.
    resolution : int
        R, cells per axis.
    near : float
        Cells closer than this along a camera's axis are not seen by it (normalised units).
    margin : float
        Image bounds widened by this fraction of the image size per side, and ``dilate`` cells of dilation:
        a cell whose centre falls just outside every frustum may still be crossed by a ray near the image
        border. Marking too much only costs the fog it lets through; marking too little cuts surfaces.
    box : np.ndarray, optional
        ``[2, 3]`` min/max corners (normalised units) of the box the scene declares it lives in
        (``scene_box`` of a bounded scene): cells outside it are not observed either. The normalised cube
        is padded and cubic, so without this the space behind a room's walls and under its floor can hold
        fog that the export then reports as surface.

    """
    centers = space.cell_centers(resolution).reshape(-1, 3).numpy()
    seen = np.zeros(len(centers), bool)
    if box is not None:
        box = np.asarray(box, float)
        outside = ((centers < box[0]) | (centers > box[1])).any(1)
        seen[outside] = True  # "done": never tested against the cameras, cleared below
    for i in frames:
        i = int(i)
        todo = np.flatnonzero(~seen)
        if len(todo) == 0:
            break
        with np.errstate(all="ignore"):
            uv, z = cameras.project(i, centers[todo])
        w, h = float(cameras.width[i]), float(cameras.height[i])
        mw, mh = margin * w, margin * h
        inside = (z > near) & (uv[:, 0] >= -mw) & (uv[:, 0] <= w + mw) & (uv[:, 1] >= -mh) & (uv[:, 1] <= h + mh)
        seen[todo[inside]] = True
    if box is not None:
        seen[outside] = False
    grid = torch.from_numpy(seen.reshape(resolution, resolution, resolution))
    if dilate > 0:
        k = 2 * dilate + 1
        grid = F.max_pool3d(grid[None, None].float(), k, stride=1, padding=dilate)[0, 0] > 0
    return grid
