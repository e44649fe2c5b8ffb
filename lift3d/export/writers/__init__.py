"""Export writers: one small class per ``lift3d export --format`` name, in a registry.

A writer turns the labelled geometry of one export (points and/or mesh, instance records, class table) into
the files of one format. ``lift3d export --format`` offers exactly the names registered here, so adding a
format is one module with an :class:`ExportWriter` subclass decorated with :func:`register`, plus its import
at the bottom of this file.

A writer whose library is an optional extra names it in :attr:`ExportWriter.extra` and
:attr:`ExportWriter.modules`; :func:`check_formats` imports those before any work starts, so a missing
extra is a one-line error naming ``pip install 'lift3d[<extra>]'`` instead of a traceback after the export.

Importing this package is cheap (numpy at most): heavy libraries load inside :meth:`ExportWriter.write`.

Examples
--------
>>> from lift3d.export.writers import WRITERS, get_writer
>>> "ply" in WRITERS and "pcd" in WRITERS
True
>>> get_writer("pcd").files
('points.pcd',)
>>> get_writer("obj")
Traceback (most recent call last):
...
lift3d.errors.InputError: --format: unknown format 'obj' (choose from ...)
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from lift3d.errors import InputError

__all__ = ["ExportContext", "ExportOptions", "ExportWriter", "WRITERS", "check_formats", "get_writer", "register"]


@dataclass
class ExportOptions:
    """Settings of the format writers (``lift3d export`` flags of the same names).

    Attributes
    ----------
    pcd_ascii : bool
        ``pcd``: write ``DATA ascii`` instead of binary.
    frame_id : str
        ``ros2bag``: the ``header.frame_id`` of every message.
    map_resolution : float
        ``octomap`` voxel / ``nav2`` cell side in output units; 0 = ``--voxel-size`` when given, else the
        export's instance link radius (about two field grid cells, recorded in ``metadata.json``).
    up : str
        The scene's up axis: ``auto`` (the mean up vector of the training cameras, snapped to the nearest
        axis) or one of ``x y z -x -y -z``. Used by ``nav2`` and ``scene_graph.json``.
    floor_classes : tuple of str
        Class names or ids that are walkable ground; empty = every class whose name contains a floor word
        (:data:`lift3d.export.ground.FLOOR_WORDS`).
    height_band : tuple of float or None
        ``nav2``: obstacles are non-floor points whose height above the floor lies in ``[low, high]``
        (output units); None = 0.1 to 1.8 world units.
    z_up : bool
        Every file in the output frame turned so that ``up`` is +z (a right-angle rotation,
        :func:`lift3d.export.ground.map_frame`, recorded as ``rotation`` in ``metadata.json``): ROS (REP 103),
        PCL's and CloudCompare's viewers and most maps take z as up.
    """

    pcd_ascii: bool = False
    frame_id: str = "map"
    map_resolution: float = 0.0
    up: str = "auto"
    floor_classes: tuple[str, ...] = ()
    height_band: tuple[float, float] | None = None
    z_up: bool = False


@dataclass
class ExportContext:
    """What one export hands every writer.

    Attributes
    ----------
    out : Path
        The export folder (exists and is writable).
    points : LabelledPoints or None
        ``--pointcloud``: ``xyz``, ``rgb``, ``semantic``, ``instance``, ``confidence`` arrays.
    mesh : LabelledMesh or None
        ``--mesh``: ``vertices``, ``faces`` and the same per-vertex arrays.
    classes : list of dict
        ``classes.json`` rows (``id``, ``name``, ``isthing``, ``color``).
    records : list of dict
        ``instances.json`` records.
    frame, units : str
        Output frame (``world`` or ``normalized``) and its units, as in ``metadata.json``.
    transform : np.ndarray
        ``4×4`` world ← normalised.
    up : np.ndarray
        ``[3]`` unit up vector in the output frame (a signed axis).
    default_resolution : float
        The export's own length scale (output units) for maps when the user gave none.
    options : ExportOptions
    comments : list of str
        Provenance lines for file headers.
    notes : dict
        Writers record the sizes they derived here (name → dict); saved under ``formats`` in
        ``metadata.json``.
    """

    out: Path
    points: Any
    mesh: Any
    classes: list[dict[str, Any]]
    records: list[dict[str, Any]]
    frame: str
    units: str
    transform: np.ndarray
    up: np.ndarray
    default_resolution: float
    options: ExportOptions = field(default_factory=ExportOptions)
    comments: list[str] = field(default_factory=list)
    notes: dict[str, Any] = field(default_factory=dict)

    @property
    def cloud(self) -> Any:
        """The points, else the mesh vertices as a point cloud (attributes ``xyz``, ``rgb``, ``semantic``,
        ``instance``, ``confidence``)."""
        if self.points is not None:
            return self.points
        from types import SimpleNamespace

        m = self.mesh
        return SimpleNamespace(xyz=m.vertices, rgb=m.rgb, semantic=m.semantic, instance=m.instance,
                               confidence=m.confidence)

    @property
    def world_length(self) -> float:
        """Output units per world unit (1 in the world frame; the normalisation scale otherwise)."""
        if self.frame == "world":
            return 1.0
        return float(1.0 / np.cbrt(abs(np.linalg.det(np.asarray(self.transform, float)[:3, :3]))))

    @property
    def resolution(self) -> float:
        """Map voxel / cell side: ``options.map_resolution`` or :attr:`default_resolution`."""
        return float(self.options.map_resolution or self.default_resolution)


class ExportWriter:
    """One export format. Subclasses set the class attributes and implement :meth:`write`.

    Attributes
    ----------
    name : str
        The ``--format`` name.
    help : str
        One line for ``--help`` and docs.
    files : tuple of str
        What it writes into the export folder (for ``--help``).
    extra : str or None
        The pip extra holding its libraries (``ros`` → ``pip install 'lift3d[ros]'``).
    modules : tuple of str
        Modules imported by :meth:`check` to prove the extra is installed.
    """

    name: ClassVar[str]
    help: ClassVar[str] = ""
    files: ClassVar[tuple[str, ...]] = ()
    extra: ClassVar[str | None] = None
    modules: ClassVar[tuple[str, ...]] = ()

    def check(self) -> None:
        """Raise a one-line :class:`InputError` when an optional library is missing."""
        for module in self.modules:
            try:
                importlib.import_module(module)
            except ImportError as exc:
                hint = f": pip install 'lift3d[{self.extra}]'" if self.extra else ""
                raise InputError("--format", f"{self.name} needs the {module.split('.')[0]} package{hint}") \
                    from exc

    def write(self, ctx: ExportContext) -> list[str]:
        """Write the files into ``ctx.out`` (atomically); return their paths relative to it."""
        raise NotImplementedError


#: ``--format`` name → writer class, in registration order.
WRITERS: dict[str, type[ExportWriter]] = {}


def register(cls: type[ExportWriter]) -> type[ExportWriter]:
    """Class decorator adding a writer to :data:`WRITERS` under ``cls.name``."""
    if cls.name in WRITERS and WRITERS[cls.name] is not cls:
        raise ValueError(f"export format {cls.name!r} is registered twice")
    WRITERS[cls.name] = cls
    return cls


def get_writer(name: str) -> ExportWriter:
    """An instance of the writer registered as ``name`` (an :class:`InputError` naming the choices)."""
    try:
        return WRITERS[name]()
    except KeyError:
        raise InputError("--format", f"unknown format {name!r} (choose from {' '.join(WRITERS)})") from None


def check_formats(names) -> list[ExportWriter]:
    """Writers for ``names`` (duplicates dropped), each checked for its optional libraries."""
    writers = [get_writer(n) for n in dict.fromkeys(names)]
    for w in writers:
        w.check()
    return writers


# The built-in formats register themselves on import (order = order in --help).
from lift3d.export.writers import ply as _ply  # noqa: E402,F401
from lift3d.export.writers import pcd as _pcd  # noqa: E402,F401
from lift3d.export.writers import semantickitti as _semantickitti  # noqa: E402,F401
from lift3d.export.writers import ros2bag as _ros2bag  # noqa: E402,F401
from lift3d.export.writers import octomap as _octomap  # noqa: E402,F401
from lift3d.export.writers import nav2 as _nav2  # noqa: E402,F401
