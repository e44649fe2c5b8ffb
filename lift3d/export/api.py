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

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lift3d.data.categories import Category, read_class_table
from lift3d.data.ply import read_labelled_ply
from lift3d.errors import InputError
from lift3d.export.writers.pcd import read_pcd
from lift3d.utils.files import read_json


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
    field_semantic, field_instance : np.ndarray or None
        ``[N]`` int32 the field's own class and instance channel at each point, before the export's steps
        relabelled it (what ``lift3d.load_run(...).query_points`` gives there; docs/api.md); None in files
        without them.
    classes : dict[int, Category]
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
    classes: dict[int, Category] = field(default_factory=dict)
    field_semantic: np.ndarray | None = None
    field_instance: np.ndarray | None = None
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
                "instance": d.get("instance", np.zeros(n, np.int32)), "confidence": d.get("confidence"),
                "field_semantic": d.get("field_semantic"), "field_instance": d.get("field_instance")}
    classes_path, metadata_path = p.parent / "classes.json", p.parent / "metadata.json"
    classes = {c.id: c for c in read_class_table(classes_path)} if classes_path.is_file() else {}
    metadata = read_json(metadata_path) if metadata_path.is_file() else {}
    return LabelledPointCloud(classes=classes, metadata=metadata, path=p, **data)


def instances(path: str | Path) -> list[InstanceRecord]:
    """Per-instance records from ``instances.json`` (or the export folder holding it), in id order.

    The file is a dict with an ``instances`` list (what ``lift3d export`` writes) or the list itself. Each
    record needs ``id`` and a box: ``obb`` (``center``, ``rotation`` or ``R``, ``extent``) and/or ``aabb``
    (``min``, ``max``), each made from the other when absent. ``class_id`` (or ``semantic``), ``class_name``,
    ``count``, ``centroid`` and ``mean_confidence`` default to 0, ``class_<id>``, 0, the box centre and NaN.

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
    raw = read_json(p)
    rows = raw.get("instances") if isinstance(raw, dict) else raw
    if not isinstance(rows, list):
        raise InputError(p, "expected a list of instance records (or an 'instances' list)")
    out = []
    for k, r in enumerate(rows):
        try:
            out.append(_instance_record(r))
        except (AttributeError, KeyError, TypeError, ValueError) as exc:
            raise InputError(p, f"instances[{k}]: not an instance record with an obb or aabb ({exc})") from None
    return sorted(out, key=lambda r: r.id)


def _instance_record(r: dict) -> InstanceRecord:
    obb, aabb = r.get("obb"), r.get("aabb")
    if obb:
        box = OrientedBox3D(np.asarray(obb["center"], float), np.asarray(obb.get("rotation", obb.get("R")), float),
                            np.asarray(obb["extent"], float))
    else:
        lo, hi = np.asarray(aabb["min"], float), np.asarray(aabb["max"], float)
        box = OrientedBox3D((lo + hi) / 2.0, np.eye(3), hi - lo)
    if box.center.shape != (3,) or box.rotation.shape != (3, 3) or box.extent.shape != (3,):
        raise ValueError("the box has the wrong shape")
    corners = box.corners()
    bounds = (np.asarray([aabb["min"], aabb["max"]], float) if aabb
              else np.stack([corners.min(0), corners.max(0)]))
    class_id = int(r.get("class_id", r.get("semantic", 0)) or 0)
    return InstanceRecord(
        id=int(r["id"]), class_id=class_id, class_name=str(r.get("class_name") or f"class_{class_id}"),
        count=int(r.get("count", 0)), centroid=np.asarray(r.get("centroid", box.center), float), aabb=bounds,
        obb=box, mean_confidence=float(r.get("mean_confidence", float("nan"))),
    )
