"""What the depth-target steps share: the context they read, the state they change, and where their settings
come from.

Every setting of a step is an :class:`~lift3d.model.config.ImageDepthConfig` field (so a ``--image_depth.*``
flag and a ``config.yml`` entry): a step's dataclass field names it with :func:`setting`, which also takes its
default from there, and :meth:`TargetStep.from_config` reads them all.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Protocol

import numpy as np

from lift3d.data.scene import Scene
from lift3d.data.stereo import DenseDepth, SparsePoints
from lift3d.model.config import ImageDepthConfig
from lift3d.sfm.mvs import plane_fit_up
from lift3d.sfm.planes import StuffPlanes, floor_plane, height_above
from lift3d.utils.steps import Step

#: The metadata key of a step field that names its ImageDepthConfig field.
CONFIG_KEY = "image_depth"


def setting(name: str) -> Any:
    """A dataclass field read from ``ImageDepthConfig.<name>`` (the flag ``--image_depth.<name>``), whose default
    is that field's."""
    return field(default=ImageDepthConfig.__dataclass_fields__[name].default, metadata={CONFIG_KEY: name})


def from_config(cls: type, cfg: ImageDepthConfig) -> Any:
    """An instance of the dataclass ``cls`` with each :func:`setting` field read from ``cfg``."""
    return cls(**{f.name: getattr(cfg, f.metadata[CONFIG_KEY]) for f in dataclasses.fields(cls)
                  if CONFIG_KEY in f.metadata})


@dataclass
class TargetStep(Step):
    """A step of the depth targets: :meth:`apply` changes a :class:`TargetState` given a :class:`TargetContext`."""

    @classmethod
    def from_config(cls, cfg: ImageDepthConfig) -> "TargetStep":
        """The step with its settings from ``cfg``."""
        return from_config(cls, cfg)


@dataclass
class PlaneSettings:
    """Settings every plane step shares."""

    threshold: float = setting("plane_threshold")
    """Inlier distance of a plane and the unit of the steps' distances, as a share of the scene's diagonal."""
    stride: int = setting("plane_stride")
    """A target at every ``stride``-th pixel of each row and column."""
    boundary_rows: int = setting("plane_boundary_rows")
    """Rows of each class on either side of a label boundary."""
    height_percentile: float = setting("plane_height_percentile")
    """How high the points reach above the floor: this percentile of their heights."""
    directions_agree_deg: float = setting("plane_directions_agree_deg")
    """The room's wall directions are taken again over the walls within this many degrees of their mean."""

    @classmethod
    def from_config(cls, cfg: ImageDepthConfig) -> "PlaneSettings":
        return from_config(cls, cfg)


@dataclass
class TargetContext:
    """What the steps read; nothing changes it.

    Attributes
    ----------
    scene : Scene
    frames : np.ndarray
        ``int64`` the training frames: their points were triangulated, their labels vote.
    targets_for : np.ndarray
        ``int64`` the frames of ``frames`` without a depth map, which get targets.
    sparse : SparsePoints
        Triangulated points, observations indexed by scene frame.
    dense : DenseDepth or None
        Plane-sweep depth maps of ``frames`` (sources ``dense`` and ``planes``).
    labels : dict or None
        Frame → ``[H, W]`` semantic pseudo-labels of every frame of ``frames`` (source ``planes``).
    premises : frozenset of str
        The premises the scene shows (:mod:`lift3d.model.profiles`).
    plane : PlaneSettings
    """

    scene: Scene
    frames: np.ndarray
    targets_for: np.ndarray
    sparse: SparsePoints
    dense: DenseDepth | None = None
    labels: dict[int, np.ndarray] | None = None
    premises: frozenset[str] = frozenset()
    plane: PlaneSettings = field(default_factory=PlaneSettings)

    @cached_property
    def diag(self) -> float:
        """The scene's diagonal (world units; :func:`scene_diagonal`)."""
        return scene_diagonal(self.scene, self.sparse)

    @cached_property
    def _plane_fit_up(self) -> tuple[np.ndarray | None, float]:
        return plane_fit_up(self.scene.cameras)

    @cached_property
    def up(self) -> np.ndarray | None:
        """The world's up for the plane fit (:func:`lift3d.sfm.mvs.plane_fit_up`: level to the cameras' right axes,
        else their mean image-up axis), or None when the cameras do not agree on one."""
        return self._plane_fit_up[0]

    @cached_property
    def up_tolerance_deg(self) -> float:
        """How far the plane fit may turn :attr:`up` to its largest near-level plane
        (:func:`lift3d.sfm.mvs.plane_fit_up`)."""
        return self._plane_fit_up[1]

    @property
    def threshold(self) -> float:
        """The plane threshold in world units."""
        return self.plane.threshold * self.diag

    @property
    def stride(self) -> int:
        return max(1, int(self.plane.stride))


@dataclass
class ViewTargets:
    """One view's pixels on the plane grid whose class a plane holds, and the depths the steps give them.

    Attributes
    ----------
    frame : int
    rows, cols, classes : np.ndarray
        ``int64 [R]`` the pixels and their labels' classes.
    origins, directions : np.ndarray
        ``[R, 3]`` their rays (unit directions).
    t, plane : np.ndarray
        ``[R]`` distance along the ray to the plane it meets and that plane (``-1``: none).
    ok : np.ndarray
        ``bool [R]`` the pixel has a target there.
    enclosed : tuple or None
        ``(rows, cols, t, plane, directions)`` of pixels in segments a plane surrounds.
    standing : tuple or None
        ``(rows, cols, z, rms)`` of pixels on upright faces of things (z-depth and the face's residual).
    """

    frame: int
    rows: np.ndarray
    cols: np.ndarray
    classes: np.ndarray
    origins: np.ndarray
    directions: np.ndarray
    t: np.ndarray
    plane: np.ndarray
    ok: np.ndarray
    enclosed: tuple | None = None
    standing: tuple | None = None


class Refit(Protocol):
    """What fitted the planes, and can fit them again with more points
    (:class:`~lift3d.train.target_steps.plane_rules.FitPlanes`)."""

    def refit_with(self, state: "TargetState", context: TargetContext, points: tuple[np.ndarray, ...]) -> None:
        ...


@dataclass
class TargetState:
    """What the steps change: the rows of targets, and the stuff planes with what they were fitted to.

    The floor plane follows the planes: setting :attr:`planes` computes it once (:attr:`floor`).

    Attributes
    ----------
    rows : list of tuple
        Blocks of targets ``(frame int64, u, v, z, sigma float32, dense bool)``, in the order they are kept.
    up : np.ndarray or None
        The direction the floor is level to (set with the first planes).
    points, classes : np.ndarray or None
        ``[N, 3]`` the thinned points the planes are fitted to and ``[N]`` their classes.
    sightlines : (np.ndarray, np.ndarray) or None
        Camera centres and the points they see (every observation and plane-sweep depth).
    min_points : int
        Fewest points of a plane (from the stereo points).
    fit : Refit or None
        The step that fitted the planes (its ``refit_with`` fits them again with more points).
    views : list of ViewTargets
        The views whose pixels meet the planes.
    floor : (int, np.ndarray, float) or None
        ``(index, normal, offset)`` of the floor among :attr:`planes`, the normal up
        (:func:`lift3d.sfm.planes.floor_plane`).
    """

    rows: list = field(default_factory=list)
    up: np.ndarray | None = None
    points: np.ndarray | None = None
    classes: np.ndarray | None = None
    sightlines: tuple[np.ndarray, np.ndarray] | None = None
    min_points: int = 0
    fit: Refit | None = None
    views: list[ViewTargets] = field(default_factory=list)
    floor: tuple[int, np.ndarray, float] | None = field(default=None, init=False)
    _planes: StuffPlanes | None = field(default=None, init=False, repr=False)

    @property
    def planes(self) -> StuffPlanes | None:
        """The stuff planes (None before they are fitted, or when the scene has no stuff class)."""
        return self._planes

    @planes.setter
    def planes(self, planes: StuffPlanes | None) -> None:
        self._planes = planes
        self.floor = None if planes is None else floor_plane(planes, self.level_to)

    @property
    def level_to(self) -> np.ndarray | None:
        """The up the planes are level and upright to: the fit's refined up (the given one can be more than the
        floor test's 25° off it, and then no plane would be the floor), else :attr:`up`."""
        return self.up if self._planes is None or self._planes.up is None else self._planes.up

    def has_planes(self) -> bool:
        """Whether there is at least one plane."""
        return self._planes is not None and len(self._planes) > 0

    def height(self, context: TargetContext) -> float:
        """How high the points reach above the floor (0 without a floor)."""
        if self.floor is None:
            return 0.0
        return height_above(self.points, self.floor[1], self.floor[2], context.plane.height_percentile)


def scene_diagonal(scene: Scene, sparse: SparsePoints | None = None) -> float:
    """Length of the scene box's diagonal, else of the box around the cameras and the middle 90 % of the
    sparse points (world units)."""
    if scene.scene_box is not None:
        box = np.asarray(scene.scene_box.aabb, np.float64)
        return float(np.linalg.norm(box[1] - box[0]))
    pts = scene.cameras.centers
    if sparse is not None and len(sparse):
        lo, hi = np.percentile(sparse.xyz, [5, 95], axis=0)
        pts = np.r_[pts, lo[None], hi[None]]
    return float(np.linalg.norm(pts.max(0) - pts.min(0)))
