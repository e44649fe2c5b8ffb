"""Export file formats besides PLY (which :mod:`lift3d.data.ply` writes): PCL's PCD, SemanticKITTI labels,
and the JSON side files ``classes.json``, ``instances.json`` and ``metadata.json``. Every writer is atomic
(:mod:`lift3d.utils.atomic`): a failure never leaves a partial file behind.

PCD (``points.pcd``)
    PCL's v0.7 format, ``DATA binary`` (default) or ``ascii``, fields ``x y z`` (F4), ``rgb`` (PCL's packed
    colour: ``r << 16 | g << 8 | b`` in a 4-byte field, declared U4), ``label`` (U4, the semantic category
    id, as ``pcl::PointXYZRGBL``), ``instance`` (U4) and ``confidence`` (F4). Open3D's tensor reader
    (``o3d.t.io.read_point_cloud``) returns ``positions``, ``colors`` (uint8) and the ``label``, ``instance``
    and ``confidence`` attributes as ``[N, 1]`` tensors.
SemanticKITTI (``points.label`` + ``points.bin``)
    ``.label``: one little-endian uint32 per point, ``instance << 16 | semantic`` (both must fit 16 bits).
    SemanticKITTI tools read labels beside a ``.bin`` scan of float32 ``x y z remission`` rows; lift3d
    writes that too, with the confidence as remission. Points are in the same order as ``points.ply``.

Examples
--------
>>> import numpy as np, tempfile, os
>>> d = tempfile.mkdtemp()
>>> xyz = np.zeros((2, 3), np.float32); rgb = np.array([[255, 0, 0], [0, 0, 255]], np.uint8)
>>> write_pcd(os.path.join(d, "p.pcd"), xyz, rgb=rgb, semantic=np.array([3, 4]), instance=np.array([1, 0]))
>>> read_pcd(os.path.join(d, "p.pcd"))["label"].tolist()
[3, 4]
>>> write_semantickitti_label(os.path.join(d, "p.label"), np.array([3, 4]), np.array([1, 0]))
>>> read_semantickitti_label(os.path.join(d, "p.label"))
(array([3, 4], dtype=int32), array([1, 0], dtype=int32))
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np

from lift3d.errors import InputError
from lift3d.utils.atomic import write_bytes_atomic, write_json_atomic

#: PCD fields written by :func:`write_pcd`: name → (numpy dtype, PCD TYPE).
PCD_FIELDS = {
    "x": ("<f4", "F"), "y": ("<f4", "F"), "z": ("<f4", "F"),
    "rgb": ("<u4", "U"), "label": ("<u4", "U"), "instance": ("<u4", "U"), "confidence": ("<f4", "F"),
}
_PCD_TYPES = {("F", 4): "<f4", ("F", 8): "<f8", ("U", 1): "u1", ("U", 2): "<u2", ("U", 4): "<u4", ("U", 8): "<u8",
              ("I", 1): "i1", ("I", 2): "<i2", ("I", 4): "<i4", ("I", 8): "<i8"}


# ------------------------------------------------------------------------------------------ PCD
def write_pcd(path: str | Path, xyz: np.ndarray, *, rgb: np.ndarray | None = None, semantic: np.ndarray | None = None,
              instance: np.ndarray | None = None, confidence: np.ndarray | None = None, binary: bool = True) -> None:
    """Write a labelled point cloud as PCL PCD v0.7 (atomically).

    Parameters
    ----------
    path : str or Path
    xyz : np.ndarray
        ``[N, 3]`` positions (stored as float32).
    rgb : np.ndarray, optional
        ``[N, 3]`` uint8 colours.
    semantic, instance : np.ndarray, optional
        ``[N]`` non-negative ids, stored as ``label`` and ``instance`` (uint32).
    confidence : np.ndarray, optional
        ``[N]`` float.
    binary : bool
        ``DATA binary`` (default) or ``DATA ascii``.
    """
    xyz = np.asarray(xyz)
    n = len(xyz)
    columns: dict[str, np.ndarray] = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}
    if rgb is not None:
        c = np.asarray(rgb, np.uint32)
        columns["rgb"] = (c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]
    for name, arr in (("label", semantic), ("instance", instance)):
        if arr is not None:
            arr = np.asarray(arr).reshape(n)
            if n and arr.min() < 0:
                raise InputError(path, f"PCD field {name!r} is unsigned; got negative ids")
            columns[name] = arr
    if confidence is not None:
        columns["confidence"] = np.asarray(confidence).reshape(n)
    names = [k for k in PCD_FIELDS if k in columns]
    table = np.empty(n, dtype=[(k, PCD_FIELDS[k][0]) for k in names])
    for k in names:
        table[k] = columns[k]
    header = "\n".join([
        "# .PCD v0.7 - Point Cloud Data file format (lift3d export)",
        "VERSION 0.7",
        "FIELDS " + " ".join(names),
        "SIZE " + " ".join("4" for _ in names),
        "TYPE " + " ".join(PCD_FIELDS[k][1] for k in names),
        "COUNT " + " ".join("1" for _ in names),
        f"WIDTH {n}",
        "HEIGHT 1",
        "VIEWPOINT 0 0 0 1 0 0 0",
        f"POINTS {n}",
        f"DATA {'binary' if binary else 'ascii'}",
    ]) + "\n"
    if binary:
        body = table.tobytes()
    else:
        buf = io.StringIO()
        fmts = ["%.9g" if PCD_FIELDS[k][1] == "F" else "%d" for k in names]
        # float64 holds every uint32 id exactly; 9 significant digits round-trip a float32.
        np.savetxt(buf, np.stack([table[k].astype(np.float64) for k in names], 1), fmt=fmts, delimiter=" ")
        body = buf.getvalue().encode("ascii")
    write_bytes_atomic(path, header.encode("ascii") + body)


def read_pcd(path: str | Path) -> dict[str, np.ndarray]:
    """Read an uncompressed (``binary`` or ``ascii``) PCD file with one value per field.

    Returns
    -------
    dict
        One ``[N]`` array per field, plus ``xyz`` ``[N, 3]`` float32 and, with an ``rgb`` field, ``rgb``
        ``[N, 3]`` uint8.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(path, f"cannot read ({exc.strerror or exc})") from exc
    header: dict[str, list[str]] = {}
    offset = 0
    while True:
        end = data.find(b"\n", offset)
        if end < 0:
            raise InputError(path, "PCD header has no DATA line")
        line = data[offset:end].decode("ascii", "replace").strip()
        offset = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        header[key.upper()] = values
        if key.upper() == "DATA":
            break
    try:
        names = header["FIELDS"]
        sizes = [int(s) for s in header["SIZE"]]
        types = header["TYPE"]
        counts = [int(c) for c in header.get("COUNT", ["1"] * len(names))]
        n = int(header["POINTS"][0])
        mode = header["DATA"][0]
        dtype = np.dtype([(nm, _PCD_TYPES[(t, s)]) for nm, t, s in zip(names, types, sizes)])
    except (KeyError, ValueError, IndexError) as exc:
        raise InputError(path, f"malformed PCD header ({exc})") from exc
    if any(c != 1 for c in counts):
        raise InputError(path, "PCD fields with COUNT > 1 are not supported")
    if mode == "binary":
        table = np.frombuffer(data, dtype=dtype, count=n, offset=offset)
    elif mode == "ascii":
        rows = np.loadtxt(io.StringIO(data[offset:].decode("ascii")), ndmin=2) if n else np.zeros((0, len(names)))
        table = np.empty(n, dtype)
        for i, nm in enumerate(names):
            table[nm] = rows[:, i]
    else:
        raise InputError(path, f"PCD DATA {mode!r} is not supported (binary or ascii)")
    out: dict[str, np.ndarray] = {nm: np.array(table[nm]) for nm in names}
    if {"x", "y", "z"} <= set(names):
        out["xyz"] = np.stack([table["x"], table["y"], table["z"]], -1).astype(np.float32)
    if "rgb" in names:
        packed = np.ascontiguousarray(table["rgb"]).view(np.uint32)
        out["rgb"] = np.stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255], -1).astype(np.uint8)
    return out


# ------------------------------------------------------------------------------------------ SemanticKITTI
def semantickitti_encode(semantic: np.ndarray, instance: np.ndarray, where: str | Path = "points.label") -> np.ndarray:
    """``instance << 16 | semantic`` as uint32; both ids must be in ``[0, 65535]``.

    Examples
    --------
    >>> semantickitti_encode(np.array([7]), np.array([2])).tolist()
    [131079]
    """
    semantic = np.asarray(semantic, np.int64)
    instance = np.asarray(instance, np.int64)
    for name, arr in (("semantic", semantic), ("instance", instance)):
        if arr.size and (arr.min() < 0 or arr.max() > 0xFFFF):
            raise InputError(where, f"SemanticKITTI labels hold 16-bit {name} ids; got "
                                    f"{int(arr.min())}..{int(arr.max())}")
    return ((instance << 16) | semantic).astype("<u4")


def write_semantickitti_label(path: str | Path, semantic: np.ndarray, instance: np.ndarray) -> None:
    """Write a SemanticKITTI ``.label`` file (atomically)."""
    write_bytes_atomic(path, semantickitti_encode(semantic, instance, path).tobytes())


def write_semantickitti_scan(path: str | Path, xyz: np.ndarray, remission: np.ndarray | None = None) -> None:
    """Write a SemanticKITTI/KITTI ``.bin`` scan: float32 ``x y z remission`` rows (atomically)."""
    xyz = np.asarray(xyz, np.float32)
    scan = np.zeros((len(xyz), 4), "<f4")
    scan[:, :3] = xyz
    if remission is not None:
        scan[:, 3] = remission
    write_bytes_atomic(path, scan.tobytes())


def read_semantickitti_label(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """``(semantic, instance)`` int32 arrays from a ``.label`` file."""
    raw = np.fromfile(path, dtype="<u4")
    return (raw & 0xFFFF).astype(np.int32), (raw >> 16).astype(np.int32)


# ------------------------------------------------------------------------------------------ JSON side files
def class_table(categories, semantic_ids=None) -> list[dict[str, Any]]:
    """``classes.json`` rows ``{id, name, isthing, color}`` for the scene's categories.

    Parameters
    ----------
    categories : iterable of lift3d.data.scene.Category or dict
    semantic_ids : iterable of int, optional
        The categories the field predicts; others are listed with ``"predicted": false``.

    Examples
    --------
    >>> class_table([{"id": 2, "name": "chair", "isthing": 1, "color": [1, 2, 3]}])
    [{'id': 2, 'name': 'chair', 'isthing': True, 'color': [1, 2, 3], 'predicted': True}]
    """
    predicted = None if semantic_ids is None else {int(i) for i in semantic_ids}
    rows = []
    for c in categories:
        d = c if isinstance(c, dict) else c.to_json()
        cid = int(d["id"])
        rows.append({"id": cid, "name": str(d["name"]), "isthing": bool(d["isthing"]),
                     "color": [int(v) for v in d.get("color", (128, 128, 128))],
                     "predicted": predicted is None or cid in predicted})
    return sorted(rows, key=lambda r: r["id"])


def write_classes_json(path: str | Path, classes: list[dict[str, Any]]) -> None:
    """``classes.json``: ``{"void": 0, "classes": [...]}`` (atomically)."""
    write_json_atomic(path, {"void": 0, "note": "semantic id 0 is void (never exported); instance 0 is stuff",
                             "classes": classes})


def write_instances_json(path: str | Path, records: list[dict[str, Any]], *, frame: str, units: str,
                         source: str) -> None:
    """``instances.json``: ``{"frame", "units", "source", "instances": [...]}`` (atomically)."""
    write_json_atomic(path, {"frame": frame, "units": units, "source": source,
                             "obb_convention": "corners = center + rotation @ (extent / 2 * [±1, ±1, ±1])",
                             "instances": records})


def write_metadata_json(path: str | Path, metadata: dict[str, Any]) -> None:
    """``metadata.json`` (atomically)."""
    write_json_atomic(path, metadata)
