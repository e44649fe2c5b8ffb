"""Pictures of labelled 3D geometry: instance- and class-coloured views side by side (PyVista).

``lift3d export`` writes ``points.ply`` / ``mesh.ply`` with per-vertex ``semantic`` and ``instance`` ids,
``classes.json`` (names and colours) and ``instances.json`` (boxes) beside them. This module turns such a
file, or arrays in memory, into a :class:`pyvista.Plotter` with two views sharing one camera:

* left, **instances**: every instance in its stable :func:`~lift3d.viz.palette.instance_color`, stuff in
  grey-ish tints of its class colour, optional boxes and ``id class`` labels per instance;
* middle, **classes**: class colours from the class table;
* right, a legend of the classes present.

Indoor scenes are closed rooms, so by default the stuff on the sides of the bounding box that face the
camera (near walls, the ceiling from above) is cut away (:func:`cutaway_mask`); instances are never cut.

Off-screen rendering is the default (headless machines); the same plotter opens a window with ``.show()``
when a display exists. :func:`save_views` writes one PNG per camera view, :func:`save_turntable` a GIF/MP4
orbit.

Why not ``pyvista.read(path)``: VTK's PLY reader drops the int32 label properties, so labels are always
read with :func:`lift3d.data.ply.read_labelled_ply` and attached to the PolyData here.

Examples
--------
>>> import numpy as np
>>> xyz = np.random.default_rng(0).uniform(0, 1, (200, 3))
>>> pl = plot_instances({"xyz": xyz, "semantic": np.full(200, 3), "instance": np.repeat([1, 2], 100)},
...                     PlotStyle(window_size=(320, 160)))
>>> pl.shape, pl.window_size  # instances | classes | legend
((1, 3), [320, 160])
>>> pl.close()
"""

from __future__ import annotations

import json

import math
import os
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from lift3d.data.categories import Category, as_class_table, read_class_table
from lift3d.data.ply import read_labelled_ply
from lift3d.errors import InputError
from lift3d.export.api import instances
from lift3d.utils.atomic import write_bytes_atomic
from lift3d.utils.geometry import plane_basis
from lift3d.viz.palette import (
    INSTANCE_NONE,
    classes_beside,
    color_to_float,
    instance_color,
    semantic_color,
    stuff_tint,
)

__all__ = [
    "VIEWS",
    "PlotStyle",
    "LabelledGeometry",
    "InstanceBox",
    "as_geometry",
    "read_instance_boxes",
    "instance_boxes",
    "plot_instances",
    "save_views",
    "save_turntable",
    "has_display",
    "auto_point_size",
]

#: Camera views :func:`plot_instances` knows. Axis views use a parallel projection (a floor plan for
#: ``top``), ``iso`` a perspective one from above a corner.
VIEWS = ("iso", "top", "bottom", "front", "back", "left", "right")

#: Background of the pictures (white prints well and keeps grey stuff readable).
BACKGROUND = (255, 255, 255)

# Elevation and azimuth (degrees) of the iso view. Steeper than the 35° of a true isometric view: indoor
# scenes have walls, and from higher up they hide less of the floor behind them.
_ISO_ELEVATION = 45.0
_ISO_AZIMUTH = -35.0
# Legends and instance labels list at most this many entries (a longer list is unreadable in a picture).
_MAX_LEGEND = 24
#: Picture size (pixels) of a view when its :class:`PlotStyle` gives none.
VIEW_WINDOW_SIZE = (1600, 800)
#: Picture size (pixels) of a turntable when its :class:`PlotStyle` gives none (small: a GIF grows with it).
TURNTABLE_WINDOW_SIZE = (960, 400)


@dataclass(frozen=True)
class PlotStyle:
    """How :func:`plot_instances`, :func:`save_views` and :func:`save_turntable` draw a labelled cloud or mesh
    (the "3D pictures" flags of ``lift3d plot``).

    Attributes
    ----------
    boxes : bool
        Draw a box and an ``id class`` label per instance (labels only in the instance view).
    window_size : (int, int) or None
        Picture size in pixels (views and legend together); None: :data:`VIEW_WINDOW_SIZE`, for a turntable
        :data:`TURNTABLE_WINDOW_SIZE`.
    point_size : float, optional
        Point size in pixels; default :func:`auto_point_size`. Ignored for meshes.
    hide : tuple of str or int
        Classes (names or ids) to leave out.
    cutaway : bool
        Cut away stuff on the bounding-box sides facing the camera (near walls, the ceiling from above;
        see :func:`cutaway_mask`) so the inside of a room is visible. Instances are never cut.
    up : str
        Up axis of the scene (``z`` for lift3d's synthetic scenes and most exports).
    legend : bool
        A panel on the right with the names and colours of the classes present.
    title : str, optional
        Text in the upper left corner of each view; default the file name.
    """

    boxes: bool = False
    window_size: tuple[int, int] | None = None
    point_size: float | None = None
    hide: tuple[str | int, ...] = ()
    cutaway: bool = True
    up: str = "z"
    legend: bool = True
    title: str | None = None


# ------------------------------------------------------------------------------------------ geometry in
@dataclass
class LabelledGeometry:
    """Points (or a triangle mesh) with per-vertex class and instance ids.

    Attributes
    ----------
    xyz : np.ndarray
        ``float32 [N, 3]`` positions.
    semantic : np.ndarray
        ``int32 [N]`` category ids (0 = void / unknown).
    instance : np.ndarray
        ``int32 [N]`` instance ids (0 on stuff).
    faces : np.ndarray or None
        ``int32 [M, 3]`` triangles; None for a point cloud.
    source : Path or None
        File it came from (for messages and default output names).
    """

    xyz: np.ndarray
    semantic: np.ndarray
    instance: np.ndarray
    faces: np.ndarray | None = None
    source: Path | None = None
    has_semantic: bool = True
    has_instance: bool = True

    @property
    def is_mesh(self) -> bool:
        return self.faces is not None and len(self.faces) > 0

    def subset(self, keep: np.ndarray) -> "LabelledGeometry":
        """Keep the vertices where ``keep`` is True; a mesh keeps the faces whose three vertices remain.

        Examples
        --------
        >>> g = LabelledGeometry(np.zeros((4, 3), np.float32), np.array([1, 1, 2, 2]), np.zeros(4, np.int32),
        ...                      faces=np.array([[0, 1, 2], [1, 2, 3], [0, 1, 3]]))
        >>> sub = g.subset(np.array([True, True, False, True]))
        >>> sub.faces.tolist(), sub.semantic.tolist()
        ([[0, 1, 2]], [1, 1, 2])
        """
        keep = np.asarray(keep, bool)
        faces = None
        if self.faces is not None:
            new_index = np.cumsum(keep) - 1
            kept_faces = self.faces[keep[self.faces].all(1)]
            faces = new_index[kept_faces].astype(np.int32)
        return LabelledGeometry(self.xyz[keep], self.semantic[keep], self.instance[keep], faces, self.source,
                                self.has_semantic, self.has_instance)

    def to_polydata(self):
        """A :class:`pyvista.PolyData` (vertices, or triangles) with ``semantic``/``instance`` point arrays."""
        import pyvista as pv

        if self.is_mesh:
            cells = np.hstack([np.full((len(self.faces), 1), 3, np.int64), self.faces.astype(np.int64)])
            poly = pv.PolyData(self.xyz.astype(np.float32), cells.ravel())
        else:
            poly = pv.PolyData(self.xyz.astype(np.float32))
        poly.point_data["semantic"] = self.semantic
        poly.point_data["instance"] = self.instance
        return poly


def _field(obj: Any, *names: str) -> Any:
    """The first of ``names`` that ``obj`` has (mapping key or attribute), else None."""
    for name in names:
        if isinstance(obj, Mapping):
            if name in obj and obj[name] is not None:
                return obj[name]
        elif getattr(obj, name, None) is not None:
            return getattr(obj, name)
    return None


def as_geometry(points_or_path: Any) -> LabelledGeometry:
    """Normalise what :func:`plot_instances` accepts into a :class:`LabelledGeometry`.

    Parameters
    ----------
    points_or_path : str, Path, dict, object, pyvista.PolyData or np.ndarray
        A labelled PLY file (``points.ply`` / ``mesh.ply``); a dict as returned by
        :func:`~lift3d.data.ply.read_labelled_ply` (``xyz``, ``semantic``, ``instance``, optional ``faces``);
        any object with those attributes (the export API's dataclasses); a PolyData with ``semantic`` /
        ``instance`` point arrays; or a bare ``[N, 3]`` array (drawn unlabelled).

    Returns
    -------
    LabelledGeometry
        Missing labels become zeros (``has_semantic`` / ``has_instance`` say so).

    Examples
    --------
    >>> g = as_geometry({"xyz": np.zeros((2, 3)), "instance": [0, 5]})
    >>> g.instance.tolist(), g.semantic.tolist(), g.has_semantic, g.is_mesh
    ([0, 5], [0, 0], False, False)
    """
    if isinstance(points_or_path, LabelledGeometry):
        return points_or_path
    source: Path | None = None
    if isinstance(points_or_path, (str, Path)):
        source = Path(points_or_path)
        obj: Any = read_labelled_ply(source)
    else:
        obj = points_or_path
    where = str(source) if source else "points"
    if type(obj).__module__.startswith("pyvista"):
        import pyvista as pv

        if isinstance(obj, pv.DataSet):
            faces = None
            if isinstance(obj, pv.PolyData) and obj.faces.size:
                tri = obj if obj.is_all_triangles else obj.triangulate()
                faces = tri.faces.reshape(-1, 4)[:, 1:]
            obj = {"xyz": np.asarray(obj.points), "faces": faces,
                   "semantic": obj.point_data.get("semantic"), "instance": obj.point_data.get("instance")}
    if isinstance(obj, np.ndarray):
        obj = {"xyz": obj}
    xyz = _field(obj, "xyz", "points", "positions")
    if xyz is None:
        raise InputError(where, "no point positions (expected 'xyz' [N, 3])")
    xyz = np.asarray(xyz, np.float32)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise InputError(where, f"positions must be [N, 3], got shape {list(xyz.shape)}")
    if not np.isfinite(xyz).all():
        raise InputError(where, "positions contain NaN or infinite values")
    n = len(xyz)
    labels = {}
    for name in ("semantic", "instance"):
        arr = _field(obj, name)
        if arr is not None:
            arr = np.asarray(arr).reshape(-1)
            if len(arr) != n:
                raise InputError(where, f"{name} has {len(arr)} values for {n} points")
            labels[name] = arr.astype(np.int32)
    faces = _field(obj, "faces", "triangles")
    if faces is not None:
        faces = np.asarray(faces, np.int64).reshape(-1, 3)
        if len(faces) and (faces.min() < 0 or faces.max() >= n):
            raise InputError(where, f"face indices outside 0..{n - 1}")
        faces = faces.astype(np.int32) if len(faces) else None
    return LabelledGeometry(xyz, labels.get("semantic", np.zeros(n, np.int32)),
                            labels.get("instance", np.zeros(n, np.int32)), faces, source,
                            "semantic" in labels, "instance" in labels)


# ------------------------------------------------------------------------------------------ boxes
@dataclass
class InstanceBox:
    """An oriented box around one instance: ``center + rotation @ (extent / 2 * [±1, ±1, ±1])``."""

    id: int
    class_id: int
    class_name: str
    center: np.ndarray  # [3]
    rotation: np.ndarray  # [3, 3], columns are the box axes
    extent: np.ndarray  # [3] full side lengths

    def corners(self) -> np.ndarray:
        """``[8, 3]`` corners; corner ``k`` has sign ``(-1)**bit`` of bits 0, 1, 2 of ``k`` along axis 0, 1, 2.

        Examples
        --------
        >>> b = InstanceBox(1, 3, "chair", np.zeros(3), np.eye(3), np.array([2.0, 4.0, 6.0]))
        >>> b.corners().min(0).tolist(), b.corners().max(0).tolist()
        ([-1.0, -2.0, -3.0], [1.0, 2.0, 3.0])
        """
        bits = np.array([[(k >> a) & 1 for a in range(3)] for k in range(8)], np.float64)
        local = (1.0 - 2.0 * bits) * (np.asarray(self.extent, np.float64) / 2.0)
        return np.asarray(self.center, np.float64) + local @ np.asarray(self.rotation, np.float64).T


# The 12 edges of a box as pairs of corner indices (corners differ in exactly one bit).
_BOX_EDGES = [(k, k | (1 << a)) for k in range(8) for a in range(3) if not k & (1 << a)]


def read_instance_boxes(path: str | Path) -> list[InstanceBox]:
    """Boxes of the instances in ``instances.json`` of ``lift3d export`` (read by
    :func:`lift3d.export.api.instances`, which also says what a record needs), in id order.

    Raises
    ------
    InputError
        Missing file, bad JSON, or a record without a usable box.
    """
    return [InstanceBox(r.id, r.class_id, r.class_name, r.obb.center, r.obb.rotation, r.obb.extent)
            for r in instances(path)]


def instance_boxes(geom: LabelledGeometry, classes: Sequence[Category] = ()) -> list[InstanceBox]:
    """Axis-aligned boxes of every instance id > 0, computed from the points (when no instances.json exists).

    The class of a box is the majority class of its points.

    Examples
    --------
    >>> g = as_geometry({"xyz": [[0, 0, 0], [1, 2, 3], [9, 9, 9]], "semantic": [4, 4, 1], "instance": [2, 2, 0]})
    >>> [(b.id, b.class_id, b.extent.tolist()) for b in instance_boxes(g)]
    [(2, 4, [1.0, 2.0, 3.0])]
    """
    names = {c.id: c.name for c in classes}
    boxes = []
    inst = geom.instance
    order = np.argsort(inst, kind="stable")
    ids, starts = np.unique(inst[order], return_index=True)
    ends = np.r_[starts[1:], len(order)]
    for inst_id, s, e in zip(ids, starts, ends):
        if inst_id <= 0:
            continue
        members = order[s:e]
        pts = geom.xyz[members].astype(np.float64)
        cls, votes = np.unique(geom.semantic[members], return_counts=True)
        cid = int(cls[np.argmax(votes)])
        lo, hi = pts.min(0), pts.max(0)
        boxes.append(InstanceBox(int(inst_id), cid, names.get(cid, f"class_{cid}"), (lo + hi) / 2, np.eye(3),
                                 hi - lo))
    return boxes


def _boxes_polydata(boxes: Sequence[InstanceBox]):
    """All box edges as one line PolyData with an ``rgb`` cell array in each box's instance colour."""
    import pyvista as pv

    corners = np.concatenate([b.corners() for b in boxes]).astype(np.float32)
    lines = np.array([[2, 8 * k + i, 8 * k + j] for k in range(len(boxes)) for i, j in _BOX_EDGES], np.int64)
    poly = pv.PolyData(corners, lines=lines.ravel())
    poly.cell_data["rgb"] = np.repeat(instance_color([b.id for b in boxes]), len(_BOX_EDGES), axis=0)
    return poly


# ------------------------------------------------------------------------------------------ cameras
def _axis(up: str) -> np.ndarray:
    """``'z'``, ``'-y'``, ... → unit vector."""
    up = up.strip().lower()
    sign = -1.0 if up.startswith("-") else 1.0
    name = up.lstrip("+-")
    if name not in ("x", "y", "z"):
        raise InputError("--up", f"expected x, y, z, -x, -y or -z, got {up!r}")
    v = np.zeros(3)
    v["xyz".index(name)] = sign
    return v


def up_beside(path: str | Path) -> tuple[str, str]:
    """The up axis an export recorded for ``path`` (``metadata.json`` in its folder: ``up.axis``, a signed
    unit axis), as ``x y z -x -y -z``, and where it came from; ``z`` when there is none.

    Examples
    --------
    >>> up_beside("/nonexistent/points.ply")
    ('z', 'no metadata.json beside the file: z')
    """
    meta_path = Path(path).parent / "metadata.json"
    try:
        axis = np.asarray(json.loads(meta_path.read_text(encoding="utf-8"))["up"]["axis"], float)
    except (OSError, ValueError, KeyError, TypeError):
        return "z", "no metadata.json beside the file: z"
    if axis.shape != (3,) or not np.isfinite(axis).all() or not np.abs(axis).max() > 0:
        return "z", f"{meta_path}: up.axis is not a 3-vector: z"
    k = int(np.argmax(np.abs(axis)))
    name = ("-" if axis[k] < 0 else "") + "xyz"[k]
    return name, f"{meta_path.name}: {name}"


def resolve_plot_up(up: str, path: str | Path | None) -> str:
    """``auto`` → the export's recorded up axis (:func:`up_beside`), else ``up`` itself."""
    if str(up).strip().lower() == "auto":
        return up_beside(path)[0] if path is not None else "z"
    _axis(up)
    return up


def view_camera(view: str, center: Sequence[float], radius: float, up: str = "z", *,
                azimuth: float | None = None, elevation: float | None = None) -> tuple[tuple, tuple, tuple]:
    """Camera ``(position, focal_point, view_up)`` looking at ``center`` from ``view``.

    The frame: ``up`` is the scene's up axis; *forward* is the horizontal axis a ``front`` camera looks
    along (+y for a z-up scene, -z for y-up, as OpenGL's "looking down -z"); *right* = forward × up. ``top``
    looks down with forward pointing up the picture (a floor plan: x right, y up for a z-up scene).

    Parameters
    ----------
    view : str
        One of :data:`VIEWS`, or ``orbit`` with ``azimuth`` / ``elevation``.
    center : sequence of float
        Focal point.
    radius : float
        Size of what must fit (the camera is placed at a distance that fits a sphere of this radius).
    up : str
        Up axis: ``x``, ``y``, ``z`` or their negatives.
    azimuth, elevation : float, optional
        Degrees; azimuth 0 is the front view, positive turns towards the right side.

    Examples
    --------
    >>> pos, focal, vup = view_camera("top", (0, 0, 0), 1.0)
    >>> np.round(pos, 3).tolist(), vup
    ([0.0, 0.0, 3.864], (0.0, 1.0, 0.0))
    >>> np.round(view_camera("front", (0, 0, 0), 1.0)[0], 3).tolist()
    [0.0, -3.864, 0.0]
    """
    u = _axis(up)
    # Forward: the first candidate axis not parallel to up.
    forward = next(c for c in (np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.0, 0.0]))
                   if abs(float(c @ u)) < 0.5)
    right = np.cross(forward, u)
    view_up = u
    if view == "iso" or view == "orbit":
        az = math.radians(_ISO_AZIMUTH if azimuth is None else azimuth)
        el = math.radians(_ISO_ELEVATION if elevation is None else elevation)
        direction = math.cos(el) * (math.cos(az) * -forward + math.sin(az) * right) + math.sin(el) * u
    elif view in ("top", "bottom"):
        direction = u if view == "top" else -u
        view_up = forward
    elif view in ("front", "back"):
        direction = -forward if view == "front" else forward
    elif view in ("left", "right"):
        direction = -right if view == "left" else right
    else:
        raise InputError("--views", f"unknown view {view!r} (choose from {', '.join(VIEWS)})")
    # Distance that fits a sphere of `radius` in VTK's default 30° view angle.
    distance = radius / math.sin(math.radians(15.0))
    position = np.asarray(center, float) + distance * direction / np.linalg.norm(direction)
    return (tuple(position.tolist()), tuple(float(c) for c in center), tuple(float(x) for x in view_up))


def _set_camera(renderer, view: str, center, radius: float, up: str, *, azimuth=None, elevation=None,
                distance: float | None = None) -> float:
    """Aim ``renderer``'s camera (axis views orthographic) and return its distance to the focal point.

    Without ``distance`` the camera zooms so that what is drawn fills the viewport (VTK's screen-space fit,
    tighter than the bounding sphere for flat rooms and streets); with it, the camera stays that far away
    (turntable frames keep one zoom instead of "breathing" as the fit changes with the angle).
    """
    position, focal, view_up = view_camera(view, center, radius, up, azimuth=azimuth, elevation=elevation)
    if distance is not None:
        direction = np.asarray(position) - np.asarray(focal)
        position = tuple((np.asarray(focal) + direction / np.linalg.norm(direction) * distance).tolist())
    renderer.camera.parallel_projection = view not in ("iso", "orbit")
    renderer.camera_position = (position, focal, view_up)
    renderer.camera.parallel_scale = radius
    if distance is None:
        renderer.ResetCameraScreenSpace(0.92)
    renderer.reset_camera_clipping_range()
    return float(renderer.camera.distance)


# ------------------------------------------------------------------------------------------ drawing
def auto_point_size(n_points: int, viewport_px: tuple[int, int]) -> float:
    """A point size (pixels) that covers surfaces without blobbing: about 1.6 × the mean spacing the points
    would have if spread over the viewport, clipped to 2..12.

    Examples
    --------
    >>> auto_point_size(50_000, (800, 600)), auto_point_size(100, (800, 600)), auto_point_size(10**7, (800, 600))
    (5.0, 12.0, 2.0)
    """
    area = float(viewport_px[0] * viewport_px[1])
    return float(np.clip(round(1.6 * math.sqrt(area / max(n_points, 1))), 2, 12))


def _resolve_hidden(hide: Iterable[str | int], classes: Sequence[Category], where: str = "--hide") -> set[int]:
    """Class names or ids → ids. Unknown names are an error (a typo must not silently hide nothing)."""
    by_name = {c.name.lower(): c.id for c in classes}
    out = set()
    for item in hide:
        text = str(item).strip()
        if not text:
            continue
        if text.lstrip("-").isdigit():
            out.add(int(text))
        elif text.lower() in by_name:
            out.add(by_name[text.lower()])
        else:
            known = ", ".join(sorted(by_name)) or "none: give class ids, or a class table with --classes"
            raise InputError(where, f"unknown class {text!r} (known: {known})")
    return out


def cutaway_mask(xyz: np.ndarray, instance: np.ndarray, direction: Sequence[float], *, up: str = "z",
                 margin: float = 0.05, facing: float = 0.3, sides: int = 72,
                 max_sample: int = 100_000) -> np.ndarray:
    """Which points to keep in a "dollhouse" cutaway: stuff near the sides of the scene that face the camera
    (the near walls, the ceiling from above) is cut, so the objects inside a room are visible.

    Only stuff (instance ≤ 0) is ever cut; every instance stays whole. The sides are the scene's top and bottom
    along ``up`` and its outline seen from above, taken as the supporting lines in ``sides`` horizontal
    directions: a room whose walls are not along the coordinate axes (a capture in its own world frame, a
    hexagonal room) has its near walls cut as well as a box along the axes. Each side lies at the 99.5th
    percentile of the points along its outward normal (a few outliers must not move the walls); it faces the
    camera when that normal has a dot product above ``facing`` with the viewing direction, and the stuff within
    ``margin`` of the points' extent along it is cut.

    Parameters
    ----------
    xyz : np.ndarray
        ``[N, 3]`` positions.
    instance : np.ndarray
        ``[N]`` instance ids (0 on stuff).
    direction : sequence of float
        From the scene towards the camera.
    up : str
        The scene's up axis (``x``, ``y``, ``z`` or their negatives).
    margin : float
        Thickness of the cut layer as a fraction of the extent along the side's normal.
    facing : float
        Minimum cosine between a side's normal and ``direction``.
    sides : int
        Horizontal directions of the outline's sides (every 360° / ``sides``).
    max_sample : int
        Most points the sides' percentiles are taken from (an even stride).

    Returns
    -------
    np.ndarray
        ``bool [N]``, True for points to draw.

    Examples
    --------
    >>> xyz = np.array([[0, 0, 0], [0, 0, 10], [0, 0, 5], [0, 0, 10.0]])
    >>> cutaway_mask(xyz, np.array([0, 0, 0, 7]), (0, 0, 1)).tolist()  # from above: the stuff "ceiling" goes
    [True, False, True, True]

    A square room turned 30° about the up axis, seen from outside its wall at +x' (its own x axis): that wall
    goes, the far one stays.

    >>> t = np.radians(30)
    >>> turn = np.array([[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, 1]])
    >>> walls = np.array([[2, 0, 1], [-2, 0, 1], [0, 0, 0], [1.9, 0, 1.0]]) @ turn.T
    >>> cutaway_mask(walls, np.array([0, 0, 0, 3]), turn @ [1, 0, 0.2]).tolist()
    [False, True, True, True]
    """
    xyz = np.asarray(xyz, np.float64)
    d = np.asarray(direction, np.float64)
    d = d / max(float(np.linalg.norm(d)), 1e-12)
    keep = np.ones(len(xyz), bool)
    if len(xyz) == 0:
        return keep
    u = _axis(up)
    a, b = plane_basis(u)  # two horizontal axes
    count = max(int(sides), 4)
    angles = 2 * np.pi * np.arange(count) / count
    normals = np.r_[u[None], -u[None], np.cos(angles)[:, None] * a + np.sin(angles)[:, None] * b]
    normals = normals[normals @ d > facing]
    if not len(normals):
        return keep
    stuff = np.asarray(instance) <= 0
    stride = max(1, -(-len(xyz) // max(int(max_sample), 1)))
    for n in normals:  # one side at a time: [N, sides] at once is hundreds of MB for a million points
        along = xyz @ n
        lo, hi = np.percentile(along[::stride], [0.5, 99.5])
        if hi > lo:
            keep &= ~(stuff & (along > hi - margin * (hi - lo)))
    return keep


def _swatch(rgb: Sequence[int]):
    """A unit square coloured ``rgb`` by a cell scalar: a legend symbol whose colour is independent of the
    (black) entry text. vtkLegendBoxActor colours text and symbol alike unless the symbol has scalars."""
    import pyvista as pv

    sq = pv.PolyData(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32), faces=[4, 0, 1, 2, 3])
    sq.cell_data.set_scalars(np.asarray([rgb], np.uint8), "rgb")
    return sq


def _add_legend(pl, items: Sequence[tuple[str, Sequence[int]]]) -> None:
    """Legend of ``(name, rgb)`` items, black text beside colour swatches, filling the active renderer."""
    shown = list(items[:_MAX_LEGEND])
    if len(items) > _MAX_LEGEND:
        shown.append((f"... {len(items) - _MAX_LEGEND} more", INSTANCE_NONE))
    # Each entry gets a fixed share of the panel height, so text keeps one size whatever the count.
    height = min(0.92, 0.045 * len(shown) + 0.01)
    # A leading space separates text from swatch (the legend box packs them edge to edge).
    legend = pl.add_legend([[f" {name}", "black"] for name, _ in shown], bcolor=None, border=False,
                           size=(0.95, height), loc="upper left", face="rectangle")
    for i, (_, rgb) in enumerate(shown):
        legend.SetEntrySymbol(i, _swatch(rgb))
    legend.SetScalarVisibility(True)


class InstanceFigure:
    """The instance | classes (| legend) figure of :func:`plot_instances`, re-aimable for turntables.

    Attributes
    ----------
    plotter : pyvista.Plotter
        Two linked 3D views (instances, classes) and, with ``legend``, a legend panel.
    geometry : LabelledGeometry
        What is drawn (after ``hide``).
    """

    def __init__(self, geom: LabelledGeometry, table: Sequence[Category], style: PlotStyle | None = None, *,
                 boxes: Sequence[InstanceBox] = (), off_screen: bool | None = True):
        import pyvista as pv

        style = PlotStyle() if style is None else style
        up, legend, title, point_size = style.up, style.legend, style.title or "", style.point_size

        self.geometry = geom
        self.up = up
        self.cutaway = style.cutaway
        self.boxes = list(boxes)
        lo, hi = geom.xyz.min(0).astype(float), geom.xyz.max(0).astype(float)
        self.center = (lo + hi) / 2.0
        self.radius = max(float(np.linalg.norm(hi - lo)) / 2.0, 1e-3)
        names = {c.id: c.name for c in table}
        thing = geom.instance > 0
        n_instances = int(len(np.unique(geom.instance[thing])))

        # Colours: instance view = vivid per-id colours on instances, grey-ish class tints on stuff.
        sem_rgb = semantic_color(geom.semantic, table)
        if geom.has_semantic:
            inst_rgb = stuff_tint(sem_rgb)
        else:
            inst_rgb = np.tile(np.asarray(INSTANCE_NONE, np.uint8), (len(geom.xyz), 1))
        inst_rgb[thing] = instance_color(geom.instance[thing])
        self._colors = (inst_rgb, sem_rgb)

        window_size = tuple(int(x) for x in (style.window_size or VIEW_WINDOW_SIZE))
        legend_items = []
        if legend and geom.has_semantic:
            legend_items = [(names.get(int(c), "void" if c <= 0 else f"class_{int(c)}"),
                             semantic_color(int(c), table)[0]) for c in np.unique(geom.semantic)]
        weights = [1.0, 1.0] + ([0.42] if legend_items else [])
        if off_screen is not False:
            prefer_headless_egl()
        self.plotter = pl = pv.Plotter(off_screen=off_screen, shape=(1, len(weights)), col_weights=weights,
                                       window_size=list(window_size), border=False)
        view_px = (int(window_size[0] / sum(weights)), window_size[1])
        if geom.is_mesh:
            self._style = dict(smooth_shading=True, lighting=True, ambient=0.35, diffuse=0.7, specular=0.0)
        else:
            size = point_size or auto_point_size(len(geom.xyz), view_px)
            # No lighting on points: each point's pixels carry exactly its palette colour (what tests and
            # colour pickers see); sphere impostors still read as round dots.
            self._style = dict(point_size=size, render_points_as_spheres=True, lighting=False, style="points")
        captions = (f"instances ({n_instances})", "classes")
        # VTK font sizes are absolute: scale captions with the picture so small GIFs stay readable.
        font_size = int(np.clip(window_size[1] / 55, 6, 12))
        for col in range(len(weights)):
            pl.subplot(0, col)
            pl.set_background(color_to_float(BACKGROUND))
            if col == 2:
                _add_legend(pl, legend_items)
                continue
            pl.add_text(f"{title}\n{captions[col]}".strip(), position="upper_left", font_size=font_size,
                        color="black")
            if col == 0 and self.boxes:
                pl.add_mesh(_boxes_polydata(self.boxes), scalars="rgb", rgb=True, line_width=2, lighting=False,
                            show_scalar_bar=False, name="boxes")
                up_vec = _axis(up)
                # Label above each box (its highest corner along up), so it does not cover the object.
                tops = np.array([b.center + up_vec * ((b.corners() - b.center) @ up_vec).max() for b in self.boxes])
                pl.add_point_labels(tops, [f"{b.id} {names.get(b.class_id, b.class_name)}" for b in self.boxes],
                                    font_size=max(font_size - 1, 6), bold=False, text_color="black",
                                    shape_color="white",
                                    shape_opacity=0.6, show_points=False, always_visible=True, margin=2)
        # One camera for both 3D views: they always show the same angle, and rotating one in a window
        # rotates the other (the legend panel keeps its own camera).
        pl.link_views([0, 1])
        self._drawn_keep: np.ndarray | None = None

    def set_view(self, view: str, *, azimuth: float | None = None, elevation: float | None = None,
                 distance: float | None = None) -> float:
        """Aim both views (and redo the cutaway for the new direction); returns the camera distance.

        ``distance`` fixes the camera's distance instead of fitting the drawing to the viewport.
        """
        position, focal, _ = view_camera(view, self.center, self.radius, self.up, azimuth=azimuth,
                                         elevation=elevation)
        direction = np.asarray(position) - np.asarray(focal)
        geom = self.geometry
        keep = (cutaway_mask(geom.xyz, geom.instance, direction, up=self.up) if self.cutaway
                else np.ones(len(geom.xyz), bool))
        if not keep.any():  # a cloud of nothing but stuff seen from its own side: show it uncut
            keep[:] = True
        redraw = self._drawn_keep is None or not np.array_equal(keep, self._drawn_keep)
        if redraw:
            sub = geom.subset(keep)
            poly = sub.to_polydata()
            poly.point_data["instance_rgb"] = self._colors[0][keep]
            poly.point_data["semantic_rgb"] = self._colors[1][keep]
        if redraw:
            for col, scalars in enumerate(("instance_rgb", "semantic_rgb")):
                self.plotter.subplot(0, col)
                # The same name replaces the previous actor (turntable frames re-cut the geometry).
                self.plotter.add_mesh(poly, scalars=scalars, rgb=True, show_scalar_bar=False, name="geometry",
                                      reset_camera=False, **self._style)
        self._drawn_keep = keep
        # Both views share one camera (link_views); fit it in the instance view, whose boxes and labels make
        # the larger drawing.
        return _set_camera(self.plotter.renderers[0], view, self.center, self.radius, self.up, azimuth=azimuth,
                           elevation=elevation, distance=distance)


def plot_instances(
    points_or_path: Any,
    style: PlotStyle | None = None,
    *,
    classes: Any = None,
    instances: str | Path | Sequence[InstanceBox] | None = None,
    view: str = "iso",
    off_screen: bool | None = True,
):
    """Instance-coloured and class-coloured views of labelled points or a mesh, side by side.

    Parameters
    ----------
    points_or_path : path, dict, object, PolyData or array
        What :func:`as_geometry` accepts (a labelled ``points.ply`` / ``mesh.ply``, arrays, the export API's
        dataclass).
    style : PlotStyle, optional
        Boxes, picture and point size, hidden classes, cutaway, up axis, legend and title (default:
        :class:`PlotStyle`'s).
    classes : path or class table, optional
        Names and colours of the class ids. Default: ``classes.json`` beside the file, if any; ids without a
        table get stable hash colours and ``class_<id>`` names.
    instances : path or list of InstanceBox, optional
        Boxes for ``style.boxes``. Default: ``instances.json`` beside the file, else boxes computed from the
        points (axis-aligned).
    view : str
        Camera, one of :data:`VIEWS`.
    off_screen : bool or None
        True renders without a window (PNG, GIF); False opens a window on ``show()``.

    Returns
    -------
    pyvista.Plotter
        Not shown yet: call ``.show()`` (window or notebook) or ``.screenshot(path)``; ``close()`` it after.

    Examples
    --------
    >>> import numpy as np
    >>> pts = {"xyz": np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]]), "semantic": [1, 2, 2], "instance": [0, 4, 4]}
    >>> pl = plot_instances(pts, PlotStyle(boxes=True, window_size=(300, 150)), view="top",
    ...                     classes=[{"id": 2, "name": "chair", "isthing": 1, "color": [200, 0, 0]}])
    >>> img = pl.screenshot(return_img=True); pl.close()
    >>> img.shape
    (150, 300, 3)
    """
    return _figure(points_or_path, style, classes=classes, instances=instances, view=view,
                   off_screen=off_screen).plotter


def _figure(points_or_path: Any, style: PlotStyle | None = None, *, classes: Any = None, instances: Any = None,
            view: str = "iso", off_screen: bool | None = True) -> InstanceFigure:
    """Build an :class:`InstanceFigure` aimed at ``view`` (the body of :func:`plot_instances`)."""
    style = PlotStyle() if style is None else style
    geom = as_geometry(points_or_path)
    if view not in VIEWS:
        raise InputError("--views", f"unknown view {view!r} (choose from {', '.join(VIEWS)})")
    _axis(style.up)  # validate before any work
    if classes is None and geom.source is not None:
        classes = classes_beside(geom.source)
    table = as_class_table(classes)
    hidden = _resolve_hidden(style.hide, table)
    if hidden:
        geom = geom.subset(~np.isin(geom.semantic, sorted(hidden)))
    if len(geom.xyz) == 0:
        raise InputError(geom.source or "points", "nothing to draw (no points" +
                         (" left after --hide)" if hidden else ")"))
    box_list: list[InstanceBox] = []
    if style.boxes:
        if instances is None and geom.source is not None and geom.source.with_name("instances.json").is_file():
            instances = geom.source.with_name("instances.json")
        if isinstance(instances, (str, Path)):
            box_list = read_instance_boxes(instances)
        elif instances is not None:
            box_list = list(instances)
        else:
            box_list = instance_boxes(geom, table)
        present = set(np.unique(geom.instance).tolist())
        box_list = [b for b in box_list if b.id in present]  # hidden classes take their boxes along
    if style.title is None:
        style = replace(style, title=_title(geom))
    fig = InstanceFigure(geom, table, style, boxes=box_list, off_screen=off_screen)
    fig.set_view(view)
    return fig


# ------------------------------------------------------------------------------------------ files out
def _png_bytes(img: np.ndarray) -> bytes:
    import imageio.v3 as iio

    return iio.imwrite("<bytes>", np.ascontiguousarray(img), extension=".png")


def _screenshot(pl) -> np.ndarray:
    img = pl.screenshot(None, return_img=True)
    return np.asarray(img)[..., :3]


def _with_files_beside(geom: LabelledGeometry, classes: Any, instances: Any = None, *,
                       boxes: bool = False) -> tuple[Any, Any]:
    """``classes`` and (for ``boxes``) ``instances``, with ``classes.json`` / ``instances.json`` beside the input
    read once, for every picture of it."""
    if classes is None and geom.source is not None:
        found = classes_beside(geom.source)
        classes = read_class_table(found) if found else None
    elif isinstance(classes, (str, Path)):
        classes = read_class_table(classes)
    if boxes and instances is None and geom.source is not None:
        beside = geom.source.with_name("instances.json")
        instances = read_instance_boxes(beside) if beside.is_file() else None
    elif isinstance(instances, (str, Path)):
        instances = read_instance_boxes(instances)
    return classes, instances


def save_views(points_or_path: Any, output_dir: str | Path, views: Sequence[str] = ("iso",),
               style: PlotStyle | None = None, *, classes: Any = None,
               instances: str | Path | Sequence[InstanceBox] | None = None, stem: str | None = None) -> list[Path]:
    """Write one PNG per view: ``<output_dir>/<stem>_<view>.png`` (instances | classes | legend).

    Parameters
    ----------
    points_or_path : path, dict, object, PolyData or array
        See :func:`as_geometry`. Read once for all views.
    output_dir : str or Path
        Created if needed.
    views : sequence of str
        Names from :data:`VIEWS`.
    style : PlotStyle, optional
        How to draw (as :func:`plot_instances`).
    classes, instances : optional
        As :func:`plot_instances`; read once for all views.
    stem : str, optional
        File name prefix; default the input file's stem (``points``), else ``points``.

    Returns
    -------
    list of Path
        The PNGs, in the order of ``views``; each written atomically.
    """
    for v in views:
        if v not in VIEWS:
            raise InputError("--views", f"unknown view {v!r} (choose from {', '.join(VIEWS)})")
    style = PlotStyle() if style is None else style
    geom = as_geometry(points_or_path)
    classes, instances = _with_files_beside(geom, classes, instances, boxes=style.boxes)
    stem = stem or (geom.source.stem if geom.source else "points")
    paths = []
    for v in views:
        fig = _figure(geom, style, classes=classes, instances=instances, view=v, off_screen=True)
        try:
            img = _screenshot(fig.plotter)
        finally:
            fig.plotter.close()
        path = Path(output_dir) / f"{stem}_{v}.png"
        write_bytes_atomic(path, _png_bytes(img))
        paths.append(path)
    return paths


def _title(geom: LabelledGeometry) -> str:
    name = geom.source.name if geom.source else ("mesh" if geom.is_mesh else "points")
    return f"{name}: {len(geom.xyz):,} {'vertices' if geom.is_mesh else 'points'}"


def save_turntable(points_or_path: Any, path: str | Path, style: PlotStyle | None = None, *, classes: Any = None,
                   instances: str | Path | Sequence[InstanceBox] | None = None, frames: int = 36, fps: int = 12,
                   elevation: float = 35.0) -> Path:
    """Orbit both views once around the scene's up axis and write a GIF (or MP4) through PyVista.

    Parameters
    ----------
    points_or_path : path, dict, object, PolyData or array
        See :func:`as_geometry`.
    path : str or Path
        ``.gif`` (PyVista's ``open_gif``, needs only imageio) or ``.mp4`` (``open_movie``, needs the
        ``imageio-ffmpeg`` package).
    style : PlotStyle, optional
        How to draw (as :func:`plot_instances`); without a ``window_size``, :data:`TURNTABLE_WINDOW_SIZE` keeps
        GIFs small.
    classes, instances : optional
        As :func:`plot_instances`.
    frames : int
        Frames per revolution.
    fps : int
        Playback speed.
    elevation : float
        Camera elevation in degrees.

    Returns
    -------
    Path
        The file, written under a temporary name and renamed when complete (never half-written).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise InputError(path, "a turntable is written as .gif or .mp4")
    if suffix == ".mp4":
        import importlib.util

        if importlib.util.find_spec("imageio_ffmpeg") is None:
            raise InputError("--turntable mp4", "MP4 needs the imageio-ffmpeg package (pip install "
                                                "imageio-ffmpeg); --turntable gif works without it")
    if frames < 2:
        raise InputError("--frames", f"a turntable needs at least 2 frames, got {frames}")
    style = PlotStyle() if style is None else style
    if style.window_size is None:
        style = replace(style, window_size=TURNTABLE_WINDOW_SIZE)
    geom = as_geometry(points_or_path)
    classes, instances = _with_files_beside(geom, classes, instances, boxes=style.boxes)
    fig = _figure(geom, style, classes=classes, instances=instances, view="iso", off_screen=True)
    pl = fig.plotter
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{suffix}")
    try:
        if suffix == ".gif":
            # Flat-coloured points need few colours; a 128-colour palette keeps the GIF small without banding.
            pl.open_gif(str(tmp), fps=fps, palettesize=128)
        else:
            pl.open_movie(str(tmp), framerate=fps)
        azimuths = [_ISO_AZIMUTH + 360.0 * k / frames for k in range(frames)]
        # One zoom for the whole orbit: the widest of the per-angle fits (no drawing happens in this pass).
        distance = max(fig.set_view("orbit", azimuth=a, elevation=elevation) for a in azimuths)
        for a in azimuths:
            fig.set_view("orbit", azimuth=a, elevation=elevation, distance=distance)
            pl.write_frame()
        pl.close()  # finalises the file
        os.replace(tmp, path)
    except BaseException:
        pl.close()
        tmp.unlink(missing_ok=True)
        raise
    return path


def _display_server_missing() -> bool:
    """True on a Linux/BSD machine with neither ``DISPLAY`` nor ``WAYLAND_DISPLAY`` set (no window can open)."""
    return sys.platform.startswith(("linux", "freebsd", "openbsd", "netbsd")) and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def prefer_headless_egl() -> bool:
    """On a headless Linux machine with EGL, render off-screen through EGL without probing X first.

    VTK (≥ 9.4) tries X, then EGL, then OSMesa; with no display the failed X attempt prints a "bad X server
    connection" warning although the picture then renders fine. When ``DISPLAY``/``WAYLAND_DISPLAY`` are
    unset, ``libEGL`` is installed and the user has not chosen a window class (``VTK_DEFAULT_OPENGL_WINDOW``),
    this selects ``vtkEGLRenderWindow`` for the render windows created from now on. Returns whether it did.
    """
    import ctypes.util

    if not sys.platform.startswith("linux") or os.environ.get("VTK_DEFAULT_OPENGL_WINDOW"):
        return False
    if not _display_server_missing() or not ctypes.util.find_library("EGL"):
        return False
    os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = "vtkEGLRenderWindow"
    return True


def has_display() -> bool:
    """Whether an interactive window can open: a display server on Linux/BSD, always on macOS/Windows.

    ``pyvista.system_supports_plotting()`` is not enough on its own: with VTK ≥ 9.4 it can answer True on a
    headless machine (EGL / OSMesa render off-screen fine, but no window can appear).
    """
    if _display_server_missing():
        return False
    try:
        import pyvista as pv

        return bool(pv.system_supports_plotting())
    except Exception:  # pragma: no cover - broken VTK install
        return False
