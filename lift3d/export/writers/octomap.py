"""``octomap``: ``map.bt`` (occupancy ``OcTree``) and ``map.ot`` (``ColorOcTree`` in class colours).

Every voxel of side ``--map-resolution`` (default: ``--voxel-size`` when given, else the export's instance
link radius, about two field grid cells; the value is in ``metadata.json``) that holds an exported point
is marked occupied once (OctoMap's hit probability 0.7, above its 0.5 threshold). Voxels are OctoMap's own:
voxel ``k`` along an axis spans ``[k·res, (k+1)·res)``, so its centre is ``(k + 0.5)·res``. There are no
sensor rays in an export, so free space is left unknown. In ``map.ot`` each occupied voxel has the colour
(``classes.json``) of the majority class of its points. ``map.bt`` is OctoMap's compact binary
(maximum-likelihood, pruned); ``map.ot`` is its full format, which keeps the colours.

``octovis map.ot`` shows the coloured map; ROS's ``octomap_server`` loads either file
(``ros2 run octomap_server octomap_server_node --ros-args -p octomap_path:=map.bt``). Written with
``pyoctomap`` (OctoMap 1.10 bundled; ``pip install 'lift3d[octomap]'``).
"""

from __future__ import annotations

import numpy as np

from lift3d.errors import InputError
from lift3d.export.writers import ExportContext, ExportWriter, register
from lift3d.utils.atomic import write_bytes_atomic

#: OctoMap keys are 16 bit: coordinates must lie within ±32768 voxels of the origin.
_KEY_HALF_RANGE = 32768


@register
class OctomapWriter(ExportWriter):
    name = "octomap"
    help = "map.bt (occupancy) + map.ot (ColorOcTree in class colours)"
    files = ("map.bt", "map.ot")
    extra = "octomap"
    modules = ("pyoctomap",)

    def write(self, ctx: ExportContext) -> list[str]:
        import pyoctomap

        res = ctx.resolution
        cloud = ctx.cloud
        colors = {int(c["id"]): c["color"] for c in ctx.classes}
        centers, classes = occupied_voxels(cloud.xyz, cloud.semantic, res)
        if len(centers) and np.abs(centers).max() / res >= _KEY_HALF_RANGE - 1:
            raise InputError("--map-resolution", f"{res:g} is too fine for OctoMap's 16-bit keys over a scene "
                                                 f"reaching {np.abs(centers).max():.4g} from the origin")
        tree = pyoctomap.OcTree(res)
        color_tree = pyoctomap.ColorOcTree(res)
        tree.updateNodes(centers, True)
        palette = np.array([colors.get(int(c), (128, 128, 128)) for c in classes], np.int64).reshape(-1, 3)
        for center, (r, g, b) in zip(centers, palette):
            color_tree.updateNode(center, True)
            color_tree.setNodeColor(center, int(r), int(g), int(b))
        tree.updateInnerOccupancy()
        color_tree.updateInnerOccupancy()
        write_bytes_atomic(ctx.out / "map.bt", tree.writeBinary())
        write_bytes_atomic(ctx.out / "map.ot", color_tree.write())
        ctx.notes["octomap"] = {"resolution": res, "occupied_voxels": int(len(centers))}
        return ["map.bt", "map.ot"]


def occupied_voxels(xyz: np.ndarray, semantic: np.ndarray, res: float) -> tuple[np.ndarray, np.ndarray]:
    """Centres ``[V, 3]`` (float64) of OctoMap voxels of side ``res`` holding points, and the majority class
    ``[V]`` of their points (ties: the smaller id).

    Examples
    --------
    >>> c, k = occupied_voxels(np.array([[0.01, 0.01, 0.01], [0.02, 0, 0], [0.03, 0, 0], [-0.05, 0, 0]]),
    ...                        np.array([2, 5, 5, 7]), 0.1)
    >>> c.tolist(), k.tolist()
    ([[-0.05, 0.05, 0.05], [0.05, 0.05, 0.05]], [7, 5])
    """
    idx = np.floor(np.asarray(xyz, np.float64) / res).astype(np.int64)
    semantic = np.asarray(semantic, np.int64)
    if len(idx) == 0:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    # Count (voxel, class) pairs, then keep the most frequent class per voxel.
    pairs, counts = np.unique(np.column_stack([idx, semantic]), axis=0, return_counts=True)
    order = np.lexsort((pairs[:, 3], -counts, pairs[:, 2], pairs[:, 1], pairs[:, 0]))
    pairs = pairs[order]
    first = np.ones(len(pairs), bool)
    first[1:] = np.any(pairs[1:, :3] != pairs[:-1, :3], axis=1)
    best = pairs[first]
    return (best[:, :3] + 0.5) * res, best[:, 3]
