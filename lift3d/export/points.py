"""The export's points: a labelled point cloud that travels through the export's steps as one object, its crop box,
and the spacing and crumb size measured on it.

Examples
--------
>>> import numpy as np
>>> box = OrientedBox.from_params(center=(0, 0, 0), rotation=(0, 0, np.pi / 4), scale=(2, 1, 1))
>>> box.contains(np.array([[0.6, 0.6, 0.0], [0.6, -0.6, 0.0]])).tolist()
[True, False]
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from lift3d.errors import InputError


#: The per-point arrays of :class:`LabelledPoints`: what :meth:`~LabelledPoints.take` and
#: :meth:`~LabelledPoints.append` carry along (those that are set).
POINT_ARRAYS = ("xyz", "rgb", "semantic", "instance", "confidence", "channel", "filled", "dirs", "field_semantic",
                "field_channel")


@dataclass
class LabelledPoints:
    """A labelled point cloud in the export frame, and the points on their way there.

    :func:`~lift3d.export.pointcloud.extract_labelled_points` returns one; its steps
    (:mod:`lift3d.export.steps`) pass one on, each keeping a subset (:meth:`take`), adding points
    (:meth:`append`) or changing arrays. A per-point array that is not known yet (labels before the heads ran,
    instance ids before they are assigned) is None.

    Attributes
    ----------
    xyz : np.ndarray
        ``[N, 3]`` float32 positions (world units unless ``frame == "normalized"``); float64 on the way.
    rgb : np.ndarray
        ``[N, 3]`` uint8 colours.
    semantic : np.ndarray
        ``[N]`` int32 category ids (never 0 = void).
    instance : np.ndarray
        ``[N]`` int32 instance ids, contiguous ``1..K`` on thing classes, 0 on stuff.
    confidence : np.ndarray
        ``[N]`` float32 probability of the chosen class.
    frame : str
        ``world`` (the input poses' frame) or ``normalized`` (the field's coordinates).
    transform : np.ndarray
        ``4×4`` world ← normalised (``x_world = transform @ [x_normalized, 1]``).
    thresholds : dict
        The thresholds of the point source (density, opacity, visibility tolerance, ...) and the instance link
        radius.
    stats : dict
        Counts and timings of each stage.
    channel : np.ndarray, optional
        On the way: ``[N]`` the field's raw instance channel (0 on stuff), before instance ids are assigned.
    filled : np.ndarray, optional
        On the way: ``[N]`` bool, the point fills a hole of a thing's isosurface (it joins the instance it borders).
    dirs : np.ndarray, optional
        On the way: ``[N, 3]`` the direction a training view sees the point along (the colour head's input).
    field_semantic, field_channel : np.ndarray, optional
        ``[N]`` the field's own class and instance channel at the point (the heads' answer, what
        ``lift3d.load_run(...).query_points`` gives there), kept beside ``semantic`` / ``instance``, which the steps
        after the heads change.
    steps : list of dict
        What each step did (:meth:`lift3d.utils.steps.StepRecord.to_json`, with its settings): ``metadata.json``'s
        ``steps.points``.

    Examples
    --------
    >>> pts = LabelledPoints(np.zeros((3, 3)), semantic=np.array([1, 2, 3]))
    >>> both = pts.take(np.array([True, False, True])).append(pts.take([1]))
    >>> both.semantic.tolist(), both.rgb is None, len(both)
    ([1, 3, 2], True, 3)
    """

    xyz: np.ndarray
    rgb: np.ndarray | None = None
    semantic: np.ndarray | None = None
    instance: np.ndarray | None = None
    confidence: np.ndarray | None = None
    frame: str = "normalized"
    transform: np.ndarray = field(default_factory=lambda: np.eye(4))
    thresholds: dict[str, Any] = field(default_factory=dict)
    stats: dict[str, Any] = field(default_factory=dict)
    channel: np.ndarray | None = None
    filled: np.ndarray | None = None
    dirs: np.ndarray | None = None
    field_semantic: np.ndarray | None = None
    field_channel: np.ndarray | None = None
    steps: list[dict[str, Any]] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.xyz)

    def arrays(self) -> dict[str, np.ndarray]:
        """The per-point arrays that are set, by name."""
        return {k: getattr(self, k) for k in POINT_ARRAYS if getattr(self, k) is not None}

    def take(self, index) -> "LabelledPoints":
        """The points ``index`` selects (a boolean mask or indices), every per-point array alike."""
        return replace(self, **{k: a[index] for k, a in self.arrays().items()})

    def append(self, other: "LabelledPoints") -> "LabelledPoints":
        """These points followed by ``other``'s (``np.concatenate``: dtypes promote as NumPy does). Both must have
        the same per-point arrays set."""
        mine, theirs = self.arrays(), other.arrays()
        if set(mine) != set(theirs):
            raise ValueError(f"append: per-point arrays differ ({sorted(mine)} vs {sorted(theirs)})")
        return replace(self, **{k: np.concatenate([a, theirs[k]]) for k, a in mine.items()})

    def record(self, name: str) -> dict[str, Any] | None:
        """The record of the step ``name`` (see ``steps``), or None."""
        return next((r for r in self.steps if r["name"] == name), None)


@dataclass
class OrientedBox:
    """A crop box: ``center``, rotation matrix ``R`` (box axes as columns) and full side lengths ``scale``.

    nerfstudio's ``--obb-center/--obb-rotation/--obb-scale`` convention: the rotation is given as roll,
    pitch, yaw in radians about x, y, z, applied in that order (``R = Rz(yaw) Ry(pitch) Rx(roll)``).
    """

    center: np.ndarray
    R: np.ndarray
    scale: np.ndarray

    @classmethod
    def from_params(cls, center=(0.0, 0.0, 0.0), rotation=(0.0, 0.0, 0.0), scale=(2.0, 2.0, 2.0)) -> "OrientedBox":
        from scipy.spatial.transform import Rotation

        scale = np.asarray(scale, np.float64)
        if scale.shape != (3,) or not np.all(scale > 0):
            raise InputError("--obb-scale", f"needs three positive side lengths, got {np.asarray(scale).tolist()}")
        rot = Rotation.from_euler("xyz", np.asarray(rotation, np.float64)).as_matrix()
        return cls(np.asarray(center, np.float64), rot, scale)

    @classmethod
    def coerce(cls, obb) -> "OrientedBox":
        """Accept an :class:`OrientedBox`, an Open3D ``OrientedBoundingBox``, or a dict with ``center``,
        ``rotation`` (roll, pitch, yaw) and ``scale``."""
        if isinstance(obb, cls):
            return obb
        if isinstance(obb, dict):
            return cls.from_params(obb.get("center", (0, 0, 0)), obb.get("rotation", (0, 0, 0)),
                                   obb.get("scale", (2, 2, 2)))
        if hasattr(obb, "R") and hasattr(obb, "extent") and hasattr(obb, "center"):
            return cls(np.asarray(obb.center, np.float64), np.asarray(obb.R, np.float64),
                       np.asarray(obb.extent, np.float64))
        raise TypeError(f"obb: expected OrientedBox, dict or open3d OrientedBoundingBox, got {type(obb).__name__}")

    def contains(self, xyz: np.ndarray) -> np.ndarray:
        """``[N]`` bool: points inside (or on) the box."""
        local = (np.asarray(xyz, np.float64) - self.center) @ self.R
        return np.all(np.abs(local) <= self.scale / 2.0 + 1e-12, axis=1)


def default_crumb_points(link_radius: float, spacing: float) -> int:
    """Points on a patch ``link_radius`` on a side: uniform random points with median nearest-neighbour
    distance ``spacing`` have density ``ln 2 / (π spacing²)`` per unit area.

    Examples
    --------
    >>> default_crumb_points(0.1, 0.01)
    22
    """
    if spacing <= 0:
        return 0
    return int(round(math.log(2) / math.pi * (link_radius / spacing) ** 2))


def typical_spacing(xyz: np.ndarray, sample: int = 20000, seed: int = 0) -> float:
    """Median nearest-neighbour distance of a point cloud, estimated from a random subset.

    A random subset of ``n`` of ``N`` points sampled uniformly on a surface is ``√(N/n)`` times sparser, so
    its spacing is scaled back (exact in expectation for such samples, which is what the surface source
    draws).

    Examples
    --------
    For 100 000 uniform points on a unit square the expected median is ``√(ln 2 / (π · 100 000))``:

    >>> pts = np.c_[np.random.default_rng(0).random((100_000, 2)), np.zeros(100_000)]
    >>> round(float(typical_spacing(pts) / np.sqrt(np.log(2) / (np.pi * 100_000))), 1)
    1.0
    """
    from scipy.spatial import cKDTree

    n = len(xyz)
    if n < 2:
        return 0.0
    rng = np.random.default_rng(seed)
    sub = xyz if n <= sample else xyz[rng.choice(n, sample, replace=False)]
    d, _ = cKDTree(sub).query(sub, k=2, workers=-1)
    return float(np.median(d[:, 1])) * math.sqrt(len(sub) / n)
