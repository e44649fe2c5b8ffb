"""Planes of the stuff classes, fitted to triangulated points: depth where the images have too little texture.

Walls, floors and ceilings are most of an indoor view, and the part that photo-consistency pins down least:
docs/sfm.md measures 1–2 sparse observations per 1000 wall pixels and a few percent of dense coverage. They
are also planes. A handful of triangulated points that the 2D labels put on one wall fixes that wall's
plane, and then every pixel the labels call wall has a depth: where its ray first meets one of the scene's
stuff planes, provided that plane is of the pixel's class (a ray that meets the floor plane first cannot see
a wall; a furniture pixel the segmenter called wall gets no target when the plane it meets first disagrees).

1. **Each point's class**: the majority of the pseudo-label classes at its observations (at least
   ``min_share`` of them agree), so keypoints on an object's edge that the labels split go nowhere.
2. **Planes per stuff class**: sequential RANSAC (inliers within ``threshold`` of the plane), refined by a
   least-squares fit of the inliers, each plane kept when it holds ``min_points`` inliers spread over an
   area (not a line); the inliers leave and the next plane is searched among the rest.
3. **Extent**: the convex hull of a plane's inliers in its own 2D coordinates, grown by ``margin``. A ray
   meets the plane only inside it, so the plane of one wing of an L-shaped room does not cut through the
   other wing. (For a convex room the nearest plane a ray meets is the room's surface whatever the extent.)

The package holds one idea per module:

* :mod:`~lift3d.sfm.planes.model`: :class:`StuffPlanes` (planes, their classes, extent and margin, where rays
  first meet them) and the sight-line test a plane is put to (:func:`contradicted`);
* :mod:`~lift3d.sfm.planes.fit`: each point's class and the RANSAC fit (:func:`point_classes`,
  :func:`fit_planes`);
* :mod:`~lift3d.sfm.planes.label_lines`: where the labels put one class on another, in 3D (a wall's foot on the
  floor, the floor line, the ceiling's height);
* :mod:`~lift3d.sfm.planes.room_rules`: the priors of a room (wall directions, square walls, corner cutters,
  floor-line walls and their correction, the floor plane, how far a wall reaches);
* :mod:`~lift3d.sfm.planes.pixel_targets`: pixel targets past the first hit (enclosed segments, the other
  views' label support).

Everything is importable from ``lift3d.sfm.planes`` as before. The training's depth targets run these as
named steps (:mod:`lift3d.train.target_steps`); the export fits its stuff points with :func:`fit_planes`.

Examples
--------
Two walls of a box room, 40 points each; the ray from the middle looking along +x meets the wall x = 2:

>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> a = np.c_[np.full(40, 2.0), rng.uniform(-2, 2, 40), rng.uniform(0, 3, 40)]
>>> b = np.c_[rng.uniform(-2, 2, 40), np.full(40, 2.0), rng.uniform(0, 3, 40)]
>>> planes = fit_planes(np.r_[a, b], np.r_[np.full(40, 1), np.full(40, 1)], [1], threshold=0.02)
>>> len(planes)
2
>>> t, k = planes.first_hit(np.array([[0.0, 0.0, 1.5]]), np.array([[1.0, 0.0, 0.0]]))
>>> round(float(t[0]), 3), sorted(planes.classes[k[0]])
(2.0, [1])
"""

from lift3d.sfm.planes.fit import FitSettings, fit_planes, point_classes
from lift3d.sfm.planes.label_lines import (FloorLine, boundary_floor_hits, ceiling_boundary_points, ceiling_height,
                                           ceiling_plane, ceiling_points, floor_boundary_points, floor_line,
                                           label_boundary, level_ceiling_height, sloped_ceiling)
from lift3d.sfm.planes.model import StuffPlanes, contradicted, ray_plane_distance
from lift3d.sfm.planes.pixel_targets import enclosed_segments, label_support
from lift3d.sfm.planes.room_rules import (NewWalls, WallReach, add_walls, corner_cutters, correct_walls,
                                          floor_line_classes, floor_line_walls, floor_plane, height_above,
                                          most_walls_hold, settled_offset, square_walls, stretch_ids, wall_classes,
                                          wall_directions, wall_reach)

__all__ = ["StuffPlanes", "ray_plane_distance", "contradicted", "point_classes", "FitSettings", "fit_planes",
           "label_boundary", "boundary_floor_hits", "floor_boundary_points", "FloorLine", "floor_line",
           "ceiling_boundary_points", "ceiling_height", "ceiling_plane", "ceiling_points", "level_ceiling_height",
           "sloped_ceiling", "floor_plane", "height_above", "wall_classes", "floor_line_classes", "most_walls_hold",
           "wall_directions", "corner_cutters", "square_walls", "floor_line_walls", "correct_walls", "NewWalls",
           "add_walls", "settled_offset", "stretch_ids", "WallReach", "wall_reach", "enclosed_segments",
           "label_support"]
