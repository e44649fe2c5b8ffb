"""``label``: SemanticKITTI ``points.label`` + ``points.bin``.

``.label``: one little-endian uint32 per point, ``instance << 16 | semantic`` (both must fit 16 bits).
SemanticKITTI tools read labels beside a ``.bin`` scan of float32 ``x y z remission`` rows; lift3d writes
that too, with the confidence as remission. Points are in the same order as ``points.ply``.

Examples
--------
>>> import numpy as np, tempfile, os
>>> d = tempfile.mkdtemp()
>>> write_semantickitti_label(os.path.join(d, "p.label"), np.array([3, 4]), np.array([1, 0]))
>>> read_semantickitti_label(os.path.join(d, "p.label"))
(array([3, 4], dtype=int32), array([1, 0], dtype=int32))
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lift3d.errors import InputError
from lift3d.export.writers import ExportContext, ExportWriter, register
from lift3d.utils.atomic import write_bytes_atomic


@register
class SemanticKittiWriter(ExportWriter):
    name = "label"
    help = "points.label (SemanticKITTI uint32 instance << 16 | semantic) + points.bin scan"
    files = ("points.label", "points.bin")

    def write(self, ctx: ExportContext) -> list[str]:
        if ctx.points is None:
            return []
        p = ctx.points
        write_semantickitti_label(ctx.out / "points.label", p.semantic, p.instance)
        write_semantickitti_scan(ctx.out / "points.bin", p.xyz, p.confidence)
        return ["points.label", "points.bin"]


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


