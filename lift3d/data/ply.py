"""Labelled PLY files (points and meshes) through ``plyfile``.

Open3D drops custom vertex attributes of meshes on write, and its legacy point-cloud writer knows only
xyz/rgb/normals, so lift3d writes its labelled geometry itself: float32 ``x y z``, uchar ``red green blue``,
int32 ``semantic`` and ``instance``, float32 ``confidence`` (docs/export.md), binary little-endian.
These files open in Open3D's tensor API (``o3d.t.io.read_point_cloud`` keeps the int32 attributes as
``[N, 1]`` tensors named ``semantic``/``instance``/``confidence``, beside ``positions``/``colors``/``normals``),
plyfile, PyVista and CloudCompare. PyVista (VTK's PLY reader) keeps only geometry, faces and colours
(``RGB``) and drops the label properties: read them with :func:`read_labelled_ply` and attach them.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyElement

from lift3d.errors import InputError
from lift3d.utils.atomic import write_bytes_atomic

#: The CloudCompare flavour's renames: CloudCompare (2.11+) keeps a PLY vertex property as a scalar field only
#: when its name starts with ``scalar_`` (and saves scalar fields back under such names).
CLOUDCOMPARE_NAMES = {"semantic": "scalar_semantic", "instance": "scalar_instance",
                      "confidence": "scalar_confidence"}

# Vertex property name → numpy dtype, in the order they are written.
VERTEX_FIELDS = {
    "x": "f4", "y": "f4", "z": "f4",
    "nx": "f4", "ny": "f4", "nz": "f4",
    "red": "u1", "green": "u1", "blue": "u1",
    "semantic": "i4", "instance": "i4", "confidence": "f4",
    "field_semantic": "i4", "field_instance": "i4",
}


def write_labelled_ply(
    path: str | Path,
    xyz: np.ndarray,
    *,
    rgb: np.ndarray | None = None,
    normals: np.ndarray | None = None,
    semantic: np.ndarray | None = None,
    instance: np.ndarray | None = None,
    confidence: np.ndarray | None = None,
    faces: np.ndarray | None = None,
    comments: list[str] | None = None,
    names: dict[str, str] | None = None,
    field_semantic: np.ndarray | None = None,
    field_instance: np.ndarray | None = None,
) -> None:
    """Write a (labelled) point cloud or triangle mesh as binary PLY, atomically.

    Parameters
    ----------
    path : str or Path
        Output ``.ply`` file.
    xyz : np.ndarray
        ``[N, 3]`` vertex positions (stored as float32).
    rgb : np.ndarray, optional
        ``[N, 3]`` uint8 colours (floats in [0, 1] are converted).
    normals : np.ndarray, optional
        ``[N, 3]`` normals.
    semantic, instance : np.ndarray, optional
        ``[N]`` integer class and instance ids (stored as int32).
    confidence : np.ndarray, optional
        ``[N]`` float confidence in [0, 1].
    faces : np.ndarray, optional
        ``[M, 3]`` triangle vertex indices; written as ``vertex_indices`` lists (a mesh).
    comments : list of str, optional
        Header comments (e.g. the lift3d version and frame).
    names : dict, optional
        Property renames, e.g. :data:`CLOUDCOMPARE_NAMES` (``semantic`` → ``scalar_semantic``: CloudCompare
        loads only vertex properties named ``scalar_*`` as scalar fields).
    field_semantic, field_instance : np.ndarray, optional
        ``[N]`` the field's own class and instance channel at each point (what ``lift3d.load_run(...)
        .query_points`` gives there), beside the export's final ``semantic`` / ``instance`` (stored as int32).

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> p = os.path.join(tempfile.mkdtemp(), "pts.ply")
    >>> write_labelled_ply(p, np.zeros((2, 3)), semantic=np.array([1, 2]), instance=np.array([0, 7]))
    >>> read_labelled_ply(p)["instance"].tolist()
    [0, 7]
    """
    xyz = np.asarray(xyz)
    n = len(xyz)
    cols: dict[str, np.ndarray] = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}
    if normals is not None:
        normals = np.asarray(normals)
        cols.update(nx=normals[:, 0], ny=normals[:, 1], nz=normals[:, 2])
    if rgb is not None:
        rgb = np.asarray(rgb)
        if rgb.dtype != np.uint8:
            rgb = np.clip(np.round(rgb * 255.0), 0, 255).astype(np.uint8)
        cols.update(red=rgb[:, 0], green=rgb[:, 1], blue=rgb[:, 2])
    for name, arr in (("semantic", semantic), ("instance", instance), ("confidence", confidence),
                      ("field_semantic", field_semantic), ("field_instance", field_instance)):
        if arr is not None:
            cols[name] = np.asarray(arr).reshape(n)
    names = names or {}
    vertex = np.empty(n, dtype=[(names.get(k, k), VERTEX_FIELDS[k]) for k in VERTEX_FIELDS if k in cols])
    for k, v in cols.items():
        vertex[names.get(k, k)] = v
    elements = [PlyElement.describe(vertex, "vertex")]
    if faces is not None:
        faces = np.asarray(faces, dtype=np.int32)
        face = np.empty(len(faces), dtype=[("vertex_indices", "i4", (3,))])
        face["vertex_indices"] = faces
        elements.append(PlyElement.describe(face, "face"))
    buf = io.BytesIO()
    PlyData(elements, text=False, byte_order="<", comments=comments or []).write(buf)
    write_bytes_atomic(path, buf.getvalue())


def read_labelled_ply(path: str | Path) -> dict[str, np.ndarray]:
    """Read a PLY written by :func:`write_labelled_ply` (or any PLY with x, y, z).

    The labels are also found under their CloudCompare names (``scalar_semantic`` ...), so a file of the
    ``ply-cloudcompare`` flavour, or one CloudCompare saved, reads the same.

    Returns
    -------
    dict
        ``xyz`` ``[N, 3]`` float32 and, when present, ``rgb`` ``[N, 3]`` uint8, ``normals``,
        ``semantic``/``instance`` ``[N]`` int32, ``confidence`` ``[N]`` float32, ``field_semantic`` /
        ``field_instance`` ``[N]`` int32 (the field's own labels, in lift3d's exports), ``faces`` ``[M, 3]`` int32,
        and ``comments`` (list of header comments).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file not found")
    try:
        try:  # fast path for triangle meshes: fixed-length face lists
            ply = PlyData.read(str(path), known_list_len={"face": {"vertex_indices": 3}})
        except Exception:
            ply = PlyData.read(str(path))
        v = ply["vertex"].data
    except Exception as exc:  # plyfile raises several types for corrupt files
        raise InputError(path, f"not a readable PLY file ({exc})") from exc
    names = v.dtype.names or ()
    if not {"x", "y", "z"} <= set(names):
        raise InputError(path, "PLY vertices have no x, y, z")
    out: dict = {"xyz": np.stack([v["x"], v["y"], v["z"]], -1).astype(np.float32)}
    if {"red", "green", "blue"} <= set(names):
        out["rgb"] = np.stack([v["red"], v["green"], v["blue"]], -1).astype(np.uint8)
    if {"nx", "ny", "nz"} <= set(names):
        out["normals"] = np.stack([v["nx"], v["ny"], v["nz"]], -1).astype(np.float32)
    for name, dt in (("semantic", np.int32), ("instance", np.int32), ("confidence", np.float32),
                     ("field_semantic", np.int32), ("field_instance", np.int32)):
        for key in (name, CLOUDCOMPARE_NAMES.get(name, name)):
            if key in names:
                values = np.asarray(v[key])
                # CloudCompare saves scalar fields as float32: ids round to their integer value.
                out[name] = (np.rint(values) if dt == np.int32 and values.dtype.kind == "f" else values).astype(dt)
                break
    if "face" in ply:
        f = ply["face"].data
        key = "vertex_indices" if "vertex_indices" in f.dtype.names else f.dtype.names[0]
        faces = f[key]
        if faces.dtype == object:
            # Variable-length lists (the fast path failed): only triangles are supported; a quad mesh from
            # another tool must fail as bad input, not as a numpy reshape error.
            if any(len(x) != 3 for x in faces):
                raise InputError(path, f"face.{key}: only triangle meshes are supported (found polygons with "
                                       f"{sorted({len(x) for x in faces} - {3})} vertices)")
            faces = np.stack([np.asarray(x, np.int32) for x in faces]) if len(f) else np.zeros((0, 3))
        out["faces"] = np.asarray(faces, np.int32).reshape(-1, 3)
    out["comments"] = list(ply.comments)
    return out
