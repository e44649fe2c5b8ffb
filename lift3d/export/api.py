"""Loading lift3d exports in downstream tools (robot mapping, planners, viewers).

Cheap to import: numpy and plyfile only (no torch, no Open3D). ``import lift3d`` re-exports
:func:`load_labelled_points` and :func:`instances`.

Examples
--------
>>> import lift3d, numpy as np, tempfile, os
>>> d = tempfile.mkdtemp()
>>> from lift3d.data.ply import write_labelled_ply
>>> write_labelled_ply(os.path.join(d, "points.ply"), np.zeros((3, 3)), semantic=np.array([1, 7, 7]),
...                    instance=np.array([0, 1, 1]), confidence=np.ones(3))
>>> pts = lift3d.load_labelled_points(d)          # a folder or the .ply itself
>>> pts.semantic.tolist(), {k: v.tolist() for k, v in pts.instance_indices().items()}
([1, 7, 7], {1: [1, 2]})
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lift3d.data.ply import read_labelled_ply
from lift3d.errors import InputError
from lift3d.export.writers.pcd import read_pcd


@dataclass(frozen=True)
class ClassInfo:
    """One row of ``classes.json``."""

    id: int
    name: str
    isthing: bool
    color: tuple[int, int, int]


@dataclass
class LabelledPointCloud:
    """A labelled point cloud as exported by ``lift3d export --pointcloud``.

    Attributes
    ----------
    xyz : np.ndarray
        ``[N, 3]`` float32 positions (frame and units in ``metadata``; world frame by default).
    rgb : np.ndarray or None
        ``[N, 3]`` uint8 colours.
    semantic : np.ndarray
        ``[N]`` int32 category ids (0 = void).
    instance : np.ndarray
        ``[N]`` int32 instance ids (0 = stuff / no instance).
    confidence : np.ndarray or None
        ``[N]`` float32 probability of the chosen class.
    classes : dict[int, ClassInfo]
        From ``classes.json`` beside the file (empty when absent).
    metadata : dict
        ``metadata.json`` beside the file (empty when absent).
    path : Path
    """

    xyz: np.ndarray
    rgb: np.ndarray | None
    semantic: np.ndarray
    instance: np.ndarray
    confidence: np.ndarray | None
    classes: dict[int, ClassInfo] = field(default_factory=dict)
    metadata: dict[str, Any] = field(default_factory=dict)
    path: Path | None = None

    def __len__(self) -> int:
        return len(self.xyz)

    def class_name(self, class_id: int) -> str:
        """Name of a category id (``void`` for 0, ``class_<id>`` when unknown)."""
        if class_id == 0:
            return "void"
        info = self.classes.get(int(class_id))
        return info.name if info else f"class_{int(class_id)}"

    def instance_indices(self) -> dict[int, np.ndarray]:
        """Point indices of every instance id > 0, in id order."""
        order = np.argsort(self.instance, kind="stable")
        ids, starts = np.unique(self.instance[order], return_index=True)
        ends = np.r_[starts[1:], len(order)]
        return {int(i): order[s:e] for i, s, e in zip(ids, starts, ends) if i > 0}

    def points_of(self, instance_id: int) -> np.ndarray:
        """``[K, 3]`` positions of one instance."""
        return self.xyz[self.instance == instance_id]


@dataclass(frozen=True)
class OrientedBox3D:
    """An oriented box: ``corners = center + rotation @ (extent / 2 · [±1, ±1, ±1])``."""

    center: np.ndarray  # [3]
    rotation: np.ndarray  # [3, 3], box axes as columns
    extent: np.ndarray  # [3] full side lengths

    def corners(self) -> np.ndarray:
        """``[8, 3]`` corners."""
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
        return self.center + (signs * self.extent / 2.0) @ self.rotation.T

    def contains(self, xyz: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """``[N]`` bool: points inside the box grown by ``margin``."""
        local = (np.asarray(xyz, np.float64) - self.center) @ self.rotation
        return np.all(np.abs(local) <= self.extent / 2.0 + margin, axis=1)


@dataclass(frozen=True)
class InstanceRecord:
    """One object of ``instances.json``.

    Attributes
    ----------
    id : int
        Instance id as in the point cloud's ``instance`` property.
    class_id, class_name
        Its category.
    count : int
        Number of exported points.
    centroid : np.ndarray
        ``[3]`` mean position.
    aabb : np.ndarray
        ``[2, 3]`` min and max corner.
    obb : OrientedBox3D
        Oriented bounding box (Open3D, PCA of the convex hull).
    mean_confidence : float
    """

    id: int
    class_id: int
    class_name: str
    count: int
    centroid: np.ndarray
    aabb: np.ndarray
    obb: OrientedBox3D
    mean_confidence: float = float("nan")


def _export_file(path: str | Path, name: str) -> Path:
    """``path`` itself, or ``path/name`` when ``path`` is an export folder."""
    p = Path(path)
    if p.is_dir():
        p = p / name
    if not p.is_file():
        raise InputError(p, "file not found")
    return p


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(path, f"not readable JSON ({exc})") from exc


def load_classes(path: str | Path) -> dict[int, ClassInfo]:
    """``classes.json`` as ``{id: ClassInfo}`` (a folder containing it also works)."""
    p = _export_file(path, "classes.json")
    raw = _read_json(p)
    rows = raw.get("classes", raw) if isinstance(raw, dict) else raw
    try:
        return {int(r["id"]): ClassInfo(int(r["id"]), str(r["name"]), bool(r["isthing"]),
                                        _rgb(r.get("color", (128, 128, 128)))) for r in rows}
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(p, f"classes need id, name, isthing ({exc})") from exc


def _rgb(color) -> tuple[int, int, int]:
    r, g, b = (int(c) for c in color)
    return r, g, b


def load_labelled_points(path: str | Path) -> LabelledPointCloud:
    """Load an exported labelled point cloud.

    Parameters
    ----------
    path : str or Path
        ``points.ply`` (or ``points.pcd``), or the export folder holding it. ``classes.json`` and
        ``metadata.json`` beside the file are read when present.

    Returns
    -------
    LabelledPointCloud
    """
    p = Path(path)
    if p.is_dir():
        p = p / ("points.ply" if (p / "points.ply").is_file() or not (p / "points.pcd").is_file() else "points.pcd")
    if not p.is_file():
        raise InputError(p, "file not found")
    if p.suffix.lower() == ".pcd":
        d = read_pcd(p)
        n = len(d["xyz"])
        data = {"xyz": d["xyz"], "rgb": d.get("rgb"), "semantic": d.get("label", np.zeros(n)).astype(np.int32),
                "instance": d.get("instance", np.zeros(n)).astype(np.int32),
                "confidence": d["confidence"].astype(np.float32) if "confidence" in d else None}
    else:
        d = read_labelled_ply(p)
        n = len(d["xyz"])
        if "semantic" not in d:
            raise InputError(p, "no 'semantic' vertex property: not a labelled point cloud")
        data = {"xyz": d["xyz"], "rgb": d.get("rgb"), "semantic": d["semantic"],
                "instance": d.get("instance", np.zeros(n, np.int32)), "confidence": d.get("confidence")}
    classes = load_classes(p.parent) if (p.parent / "classes.json").is_file() else {}
    metadata = _read_json(p.parent / "metadata.json") if (p.parent / "metadata.json").is_file() else {}
    return LabelledPointCloud(classes=classes, metadata=metadata, path=p, **data)


def instances(path: str | Path) -> list[InstanceRecord]:
    """Per-instance records from ``instances.json`` (or the export folder holding it), in id order.

    Examples
    --------
    >>> import tempfile, os, json
    >>> d = tempfile.mkdtemp()
    >>> rec = {"id": 1, "class_id": 7, "class_name": "chair", "count": 10, "centroid": [0, 0, 0],
    ...        "aabb": {"min": [-1, -1, -1], "max": [1, 1, 1]},
    ...        "obb": {"center": [0, 0, 0], "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "extent": [2, 2, 2]}}
    >>> _ = open(os.path.join(d, "instances.json"), "w").write(json.dumps({"instances": [rec]}))
    >>> [(r.id, r.class_name, r.obb.extent.tolist()) for r in instances(d)]
    [(1, 'chair', [2.0, 2.0, 2.0])]
    """
    p = _export_file(path, "instances.json")
    raw = _read_json(p)
    rows = raw.get("instances", []) if isinstance(raw, dict) else raw
    out = []
    try:
        for r in rows:
            obb = r["obb"]
            out.append(InstanceRecord(
                id=int(r["id"]), class_id=int(r["class_id"]), class_name=str(r.get("class_name", "")),
                count=int(r["count"]), centroid=np.asarray(r["centroid"], float),
                aabb=np.asarray([r["aabb"]["min"], r["aabb"]["max"]], float),
                obb=OrientedBox3D(np.asarray(obb["center"], float), np.asarray(obb["rotation"], float),
                                  np.asarray(obb["extent"], float)),
                mean_confidence=float(r.get("mean_confidence", float("nan"))),
            ))
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(p, f"malformed instance record ({exc!r})") from exc
    return sorted(out, key=lambda r: r.id)
