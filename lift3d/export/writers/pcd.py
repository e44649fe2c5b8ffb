"""``pcd``: PCL's PCD v0.7 (``points.pcd``), ``DATA binary`` (default) or ``ascii``.

Fields ``x y z`` (F4), ``rgba`` (U4: ``255 << 24 | r << 16 | g << 8 | b``, the field ``pcl::PointXYZRGBL``
registers), ``label`` (U4, the semantic category id, as ``pcl::PointXYZRGBL``), ``instance`` (U4) and
``confidence`` (F4). PCL unpacks a colour field named ``rgb`` only when it is typed ``F``; an ``rgb`` typed
``U`` makes ``pcl_pcd2ply`` write swapped colours and shifted fields without a warning, so the colour is
``rgba`` with an opaque alpha (``loadPCDFile`` into ``PointXYZRGBL`` then reads alpha 255, not 0).
``pcl_pcd2ply``, ``pcl::io::loadPCDFile`` and Open3D's tensor reader (``o3d.t.io.read_point_cloud``:
``positions``, ``colors`` uint8, and ``label``, ``instance``, ``confidence`` as ``[N, 1]`` tensors) all read
the same values back; :func:`read_pcd` reads ``rgb`` (F or U) and ``rgba`` colours.

Examples
--------
>>> import numpy as np, tempfile, os
>>> d = tempfile.mkdtemp()
>>> xyz = np.zeros((2, 3), np.float32); rgb = np.array([[255, 0, 0], [0, 0, 255]], np.uint8)
>>> write_pcd(os.path.join(d, "p.pcd"), xyz, rgb=rgb, semantic=np.array([3, 4]), instance=np.array([1, 0]))
>>> p = read_pcd(os.path.join(d, "p.pcd"))
>>> p["label"].tolist(), p["rgb"].tolist(), hex(int(p["rgba"][0]))
([3, 4], [[255, 0, 0], [0, 0, 255]], '0xffff0000')
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from lift3d.errors import InputError
from lift3d.export.writers import ExportContext, ExportWriter, register
from lift3d.utils.atomic import write_bytes_atomic

#: PCD fields written by :func:`write_pcd`: name → (numpy dtype, PCD TYPE).
PCD_FIELDS = {
    "x": ("<f4", "F"), "y": ("<f4", "F"), "z": ("<f4", "F"),
    "rgba": ("<u4", "U"), "label": ("<u4", "U"), "instance": ("<u4", "U"), "confidence": ("<f4", "F"),
}
_PCD_TYPES = {("F", 4): "<f4", ("F", 8): "<f8", ("U", 1): "u1", ("U", 2): "<u2", ("U", 4): "<u4", ("U", 8): "<u8",
              ("I", 1): "i1", ("I", 2): "<i2", ("I", 4): "<i4", ("I", 8): "<i8"}



@register
class PcdWriter(ExportWriter):
    name = "pcd"
    help = "points.pcd: PCL fields x y z, rgba, label (= semantic), instance, confidence (--pcd-ascii)"
    files = ("points.pcd",)

    def write(self, ctx: ExportContext) -> list[str]:
        if ctx.points is None:
            return []
        p = ctx.points
        write_pcd(ctx.out / "points.pcd", p.xyz, rgb=p.rgb, semantic=p.semantic, instance=p.instance,
                  confidence=p.confidence, binary=not ctx.options.pcd_ascii)
        return ["points.pcd"]


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
        columns["rgba"] = np.uint32(255 << 24) | (c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]
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
        One ``[N]`` array per field, plus ``xyz`` ``[N, 3]`` float32 and, with an ``rgb`` or ``rgba`` field,
        ``rgb`` ``[N, 3]`` uint8.
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
    colour = "rgba" if "rgba" in names else "rgb" if "rgb" in names else None
    if colour is not None and table.dtype[colour].itemsize == 4:
        # The packed bytes, whatever the declared type (PCL writes rgb as F4 holding the same bits).
        packed = np.ascontiguousarray(table[colour]).view(np.uint32)
        out["rgb"] = np.stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255], -1).astype(np.uint8)
    return out


