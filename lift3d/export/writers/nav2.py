"""``nav2``: a 2D occupancy map for Nav2's ``map_server`` (``map.pgm`` + ``map.yaml``) and one PNG layer
per class (``map_layers/<id>_<name>.png``).

The map lies in the plane across the scene's up axis (``--up``; map x/y are world axes, see
:func:`lift3d.export.ground.map_frame`), in cells of side ``--map-resolution``. Each cell is

* **occupied** (pixel 0) when an exported point of a non-floor class lies in it with its height above the
  floor level in ``--height-band LOW HIGH`` (default 0.1 to 1.8 world units: low enough for a step or a
  toy, high enough to pass under a ceiling lamp; the floor level is the median height of the floor points);
* else **free** (254) when a point of a floor-like class (``--floor-classes``; by default names with
  ``floor``, ``rug``, ``road``, ``sidewalk``, ``grass``, ``ground``... in them) lies in it;
* else **unknown** (205).

``map.yaml`` has ``mode: trinary``, ``negate: 0``, ``occupied_thresh: 0.65`` and ``free_thresh: 0.1``.
Nav2 reads a pixel ``v`` as the occupancy probability ``p = (255 - v) / 255``: occupied 0 → 1.0 (> 0.65,
occupied), free 254 → 0.004 (< 0.1, free), unknown 205 → 0.196, which is neither, so unknown. (With the
common ``free_thresh: 0.196`` or ``0.25`` unknown cells would load as free.) The image's first row is the
map's largest y; ``origin`` is the pose of the lower-left cell's corner ``[x, y, 0]``.

The class layers have the same size and origin: 255 where the cell holds points of that class at any
height, else 0.
"""

from __future__ import annotations

import re

import numpy as np

from lift3d.errors import InputError
from lift3d.export.ground import floor_class_ids, map_frame
from lift3d.export.writers import ExportContext, ExportWriter, register
from lift3d.utils.atomic import write_bytes_atomic, write_text_atomic

OCCUPIED, FREE, UNKNOWN = 0, 254, 205
OCCUPIED_THRESH, FREE_THRESH = 0.65, 0.1
#: Default obstacle height band above the floor, in world units.
HEIGHT_BAND = (0.1, 1.8)
#: Largest map side in cells (a 20000² uint8 image is 400 MB).
MAX_CELLS = 20000


@register
class Nav2Writer(ExportWriter):
    name = "nav2"
    help = "map.pgm + map.yaml (Nav2 map_server, trinary) + map_layers/<id>_<class>.png per class"
    files = ("map.pgm", "map.yaml", "map_layers/")

    def write(self, ctx: ExportContext) -> list[str]:
        import cv2

        cloud = ctx.cloud
        floors = floor_class_ids(ctx.classes, ctx.options.floor_classes)
        band = ctx.options.height_band or tuple(b * ctx.world_length for b in HEIGHT_BAND)
        grid = occupancy_grid(cloud.xyz, cloud.semantic, ctx.up, ctx.resolution, floors, band)
        written = []
        write_bytes_atomic(ctx.out / "map.pgm", _encode(cv2, ".pgm", grid["image"]))
        write_text_atomic(ctx.out / "map.yaml", map_yaml("map.pgm", ctx.resolution, grid["origin"],
                                                        ctx.options.frame_id, grid["rotation"]))
        written += ["map.pgm", "map.yaml"]
        for c in ctx.classes:
            layer = grid["layers"].get(int(c["id"]))
            if layer is None:
                continue
            name = f"{int(c['id'])}_{re.sub(r'[^A-Za-z0-9_.-]+', '-', c['name'])}.png"
            write_bytes_atomic(ctx.out / "map_layers" / name, _encode(cv2, ".png", layer))
            written.append(f"map_layers/{name}")
        names = {int(c["id"]): c["name"] for c in ctx.classes}
        ctx.notes["nav2"] = {"resolution": ctx.resolution, "size": list(grid["image"].shape[::-1]),
                             "floor_classes": [names.get(i, str(i)) for i in floors],
                             "floor_level": grid["floor_level"], "height_band": list(band),
                             "cells": grid["counts"]}
        return written


def occupancy_grid(xyz: np.ndarray, semantic: np.ndarray, up: np.ndarray, res: float, floor_ids,
                   band: tuple[float, float]) -> dict:
    """The trinary map image and per-class layers (rules in the module docstring).

    Returns
    -------
    dict
        ``image`` ``[H, W]`` uint8 (row 0 = largest y), ``origin`` ``[x, y]`` of the lower-left corner,
        ``rotation`` (map ← output frame), ``layers`` {class id: ``[H, W]`` uint8}, ``floor_level`` and
        ``counts`` of occupied / free / unknown cells.

    Examples
    --------
    >>> xyz = np.array([[0.05, 0.05, 0.0], [0.15, 0.05, 0.0], [0.15, 0.05, 0.5], [0.25, 0.05, 3.0]])
    >>> g = occupancy_grid(xyz, np.array([1, 1, 2, 2]), np.array([0, 0, 1.0]), 0.1, [1], (0.1, 1.8))
    >>> g["image"].tolist(), g["origin"]
    ([[254, 0, 205]], [0.0, 0.0])
    """
    low, high = (float(b) for b in band)
    if not high > low:
        raise InputError("--height-band", f"needs LOW < HIGH, got {low:g} {high:g}")
    rot = map_frame(up)
    local = np.asarray(xyz, np.float64) @ rot.T
    semantic = np.asarray(semantic)
    is_floor = np.isin(semantic, list(floor_ids))
    floor_level = float(np.median(local[is_floor, 2])) if is_floor.any() else \
        float(local[:, 2].min()) if len(local) else 0.0
    if len(local) == 0:
        lo = np.zeros(2)
        ij = np.zeros((0, 2), np.int64)
        w = h = 1
    else:
        lo = np.floor(local[:, :2].min(0) / res) * res
        ij = np.floor((local[:, :2] - lo) / res).astype(np.int64)
        w, h = (int(v) + 1 for v in ij.max(0))
    if max(w, h) > MAX_CELLS:
        raise InputError("--map-resolution", f"{res:g} makes a {w}x{h}-cell map (at most {MAX_CELLS} a side)")
    height = local[:, 2] - floor_level
    obstacle = ~is_floor & (height >= low) & (height <= high)
    grid = np.full((h, w), UNKNOWN, np.uint8)
    rows = h - 1 - ij[:, 1]  # image row 0 is the top: the largest y
    grid[rows[is_floor], ij[is_floor, 0]] = FREE
    grid[rows[obstacle], ij[obstacle, 0]] = OCCUPIED
    layers = {}
    for cid in np.unique(semantic):
        layer = np.zeros((h, w), np.uint8)
        m = semantic == cid
        layer[rows[m], ij[m, 0]] = 255
        layers[int(cid)] = layer
    counts = {"occupied": int((grid == OCCUPIED).sum()), "free": int((grid == FREE).sum()),
              "unknown": int((grid == UNKNOWN).sum())}
    return {"image": grid, "origin": [float(lo[0]), float(lo[1])], "rotation": rot, "layers": layers,
            "floor_level": floor_level, "counts": counts}


def map_yaml(image: str, res: float, origin, frame_id: str, rotation: np.ndarray) -> str:
    """``map.yaml`` for Nav2's map_server (trinary, thresholds in the module docstring)."""
    rows = "; ".join(" ".join(f"{v:g}" for v in r) for r in np.asarray(rotation))
    return (f"# lift3d export: Nav2 occupancy map in frame '{frame_id}'.\n"
            f"# map xyz = R @ export xyz with R = [{rows}] (up axis -> map z).\n"
            f"# Nav2 reads p = (255 - v) / 255: occupied 0 -> 1.0, free 254 -> 0.004, unknown 205 -> 0.196.\n"
            f"image: {image}\n"
            f"mode: trinary\n"
            f"resolution: {res:.9g}\n"
            f"origin: [{origin[0]:.9g}, {origin[1]:.9g}, 0.0]\n"
            f"negate: 0\n"
            f"occupied_thresh: {OCCUPIED_THRESH}\n"
            f"free_thresh: {FREE_THRESH}\n")


def _encode(cv2, ext: str, image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(ext, image)
    if not ok:
        raise RuntimeError(f"OpenCV could not encode {ext}")
    return buf.tobytes()
