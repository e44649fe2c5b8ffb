"""Points of the training views' rendered surface where the density isosurface has a hole.

Two fills, both for bounded scenes and the ``surface`` source: next to the scene box (:func:`box_face_fill`: a wall
or ceiling the box hugs) and on things (:func:`thing_surface_fill`: an object few depth targets reached). Both keep
the rendered surface of the training views without a depth map (:func:`_fill_holes`) where it lies far enough
from every isosurface point.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from lift3d.data.scene import Scene
from lift3d.export.points import typical_spacing
from lift3d.export.views import rendered_depth, view_depths
from lift3d.export.visibility import train_frames, view_directions
from lift3d.model.run import LoadedRun

@dataclass(frozen=True)
class FillRules:
    """Where a fill keeps the rendered surface (:func:`_fill_holes`)."""

    spacings: float = 3.0
    """A rendered point fills a hole when it lies farther than this many point spacings (and the fill's gap) from
    every isosurface point; the kept points are thinned to one per point spacing."""
    smooth: float = 0.02
    """A rendered depth counts when it agrees with its 3 × 3 median to within this share (not an edge between two
    surfaces)."""
    smooth_slack: float = 0.0
    """… plus this (normalised units)."""


#: Surface source, bounded scenes: the rendered surface within this share of the box's diagonal of the box's
#: faces fills in where the isosurface has nothing (see :func:`box_face_fill`).
BOX_FILL_MARGIN = 0.01


def box_face_fill(loaded: LoadedRun, scene: Scene, x_surface: np.ndarray, cams, *, cache: dict | None = None,
                  margin: float = BOX_FILL_MARGIN, min_gap: float = 0.0, rules: FillRules = FillRules()
                  ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Points of the rendered surface next to a bounded scene's box where the isosurface has none.

    Rays stop at the scene box. A room's box hugs its walls, floor and ceiling, so the field need not build a
    surface there: the last centimetres before the box end the ray whatever the density. A wall or ceiling
    met by few depth targets then stays a soft layer below the isosurface's threshold, and its pixels render
    right while the isosurface has a hole (images-only tuning room 7: 0.74 of the ceiling's GT points within τ
    of the export; a reported room, 0.41). The training views' rendered surface (:func:`_fill_holes`)
    is kept where it lies within ``margin`` of the box's diagonal of a face of the box and more than three point
    spacings (and ``min_gap``) from every isosurface point, thinned to one per point spacing. ``min_gap`` keeps a
    dense export from covering again surface the isosurface has (the export passes two isosurface voxels, its
    instance link radius: at a million points three spacings are 1.7 cm, and a reported room's export took a
    quarter of its points from the fill, all but 0.5 % of them within two voxels of it).

    Parameters
    ----------
    x_surface : np.ndarray
        ``[N, 3]`` the isosurface points (normalised coordinates).
    cams : Cameras
        The training cameras in normalised coordinates (:func:`lift3d.export.visibility.normalized_cameras`).

    Returns
    -------
    (np.ndarray, np.ndarray, dict)
        ``[M, 3]`` points (normalised), ``[M, 3]`` the directions their views see them along, and the step's
        record for ``metadata.json``.
    """
    info: dict[str, Any] = {"rule": "rendered surface within a margin of the box, where the isosurface has no point",
                            "margin": float(margin)}
    lo, hi = loaded.norm.to_normalized(loaded.norm.aabb_world)
    near_face = margin * float(np.linalg.norm(hi - lo))

    def near_box(p: np.ndarray, *_) -> np.ndarray:
        return np.minimum(p - lo, hi - p).min(1) <= near_face

    return _fill_holes(loaded, scene, x_surface, cams, near_box, info, cache=cache, min_gap=min_gap,
                       rules=replace(rules, smooth_slack=0.25 * near_face))


def thing_surface_fill(loaded: LoadedRun, scene: Scene, x_surface: np.ndarray, cams, *, cache: dict | None = None,
                       min_gap: float = 0.0, rules: FillRules = FillRules()
                       ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Points of the rendered surface of things where the isosurface has none.

    Without depth maps an object's density often stays below the isosurface's threshold on the faces few depth
    targets reach, while its pixels render it in place: on images-only tuning rooms 10 and 22, 0.88 and 0.84 of
    the things' GT points lay within τ of the export (1.00 and 0.94 with this fill). A training view's rendered
    surface point is kept where the field labels it a thing class and the view's own 2D label at that pixel is
    the same class (without that, tuning room 22's precision fell 0.949 -> 0.914, with it 0.926, at the box fill's
    gap), more than three point spacings (and ``min_gap``) from every isosurface point, one per point spacing (as
    :func:`box_face_fill`). Stuff is not filled: the rendered surface of walls in an images-only field has layers
    in front of them (all of it on tuning room 10: precision 0.957 -> 0.842).

    Parameters and returns as :func:`box_face_fill`.
    """
    info: dict[str, Any] = {"rule": "rendered surface that the field and the view's 2D label both call one thing "
                                    "class, where the isosurface has no point"}
    things = np.asarray(sorted(scene.thing_ids), np.int64)

    def is_thing(p: np.ndarray, i: int, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        if not len(things) or not len(p):
            return np.zeros(len(p), bool)
        semantic = loaded.model.query_labels(p.astype(np.float32)).semantic
        return np.isin(semantic, things) & (scene.pseudo_labels(i).semantic[rows, cols] == semantic)

    return _fill_holes(loaded, scene, x_surface, cams, is_thing, info, cache=cache, min_gap=min_gap, rules=rules)


def _fill_holes(loaded: LoadedRun, scene: Scene, x_surface: np.ndarray, cams, where, info: dict[str, Any], *,
                cache: dict | None, min_gap: float, rules: FillRules) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """The training views' rendered surface (views without a depth map) where ``where(points, view, rows, cols)``
    (``[K, 3]`` normalised points, the view's index and their ``[K]`` pixel rows and columns at full resolution →
    ``[K] bool``) and more than three point spacings (and ``min_gap``) from every point of ``x_surface``, thinned
    to one per point spacing: ``(points, view directions, info)``. ``rules`` (:class:`FillRules`) holds the numbers.

    Each view is rendered (:func:`lift3d.export.views.rendered_depth`, shared with the label vote) and its depths
    back-projected where the opacity reaches one half and the depth agrees with its 3 × 3 median to within 2 %
    (``rules.smooth``, + ``rules.smooth_slack`` in normalised units): not an edge between two surfaces."""
    from scipy.ndimage import median_filter
    from scipy.spatial import cKDTree

    frames = [int(i) for i in train_frames(scene) if scene.frames[int(i)].depth_path is None]
    empty = np.zeros((0, 3))
    info = dict(info, views=len(frames), points=0)
    if not frames or len(x_surface) < 2:
        return empty, empty, info
    spacing = typical_spacing(x_surface)
    if spacing <= 0:
        return empty, empty, info
    gap = max(rules.spacings * spacing, float(min_gap))
    # these views without a depth map, at the downscale the label vote renders them at: one render each
    depths = view_depths(scene, frames, rendered_depth(loaded, scene, cache))
    scale = float(loaded.norm.scale)
    tree = cKDTree(x_surface)
    pts, dirs = [], []
    for i, (depth, ds) in depths.items():
        smooth = np.abs(depth - median_filter(depth, size=3)) <= rules.smooth * depth + rules.smooth_slack / scale
        r, c = np.nonzero((depth > 0) & smooth)
        if not len(r):
            continue
        off = (ds - 1) / 2.0  # the centre of a ds x ds block, as a pixel index
        p = cams.unproject(i, c * ds + off, r * ds + off, depth[r, c] * scale)
        keep = tree.query(p, distance_upper_bound=gap)[0] > gap
        keep[keep] = where(p[keep], i, (r * ds + ds // 2)[keep], (c * ds + ds // 2)[keep])
        pts.append(p[keep]), dirs.append(view_directions(p[keep], cams.centers[i]))
    if not pts or not sum(len(p) for p in pts):
        return empty, empty, info
    pts, dirs = np.concatenate(pts), np.concatenate(dirs)
    first = np.unique(np.floor(pts / spacing).astype(np.int64), axis=0, return_index=True)[1]
    info.update(points=int(len(first)), spacing=float(spacing), gap=float(gap),
                downscale=next(iter(depths.values()))[1])
    return pts[first], dirs[first], info
