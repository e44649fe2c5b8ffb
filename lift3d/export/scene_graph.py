"""``scene_graph.json``: objects, the stuff they stand on, and geometric relations (a 3D scene graph).

Task planners consume scenes as graphs of objects with classes, boxes and relations (as Hydra and
ConceptGraphs build them). lift3d derives one from the labelled points of the export, with these rules
(``h`` = height along the scene's up axis, "horizontal" = the two other axes, ``t`` = the contact tolerance,
the export's map resolution):

* **nodes** — ``room`` (the axis-aligned box of all stuff points, or of all points when there is no stuff),
  ``stuff:<class id>`` per stuff class present, ``object:<id>`` per instance of ``instances.json``.
* **stands on** — object A's bottom is the 2nd percentile of ``h`` over its points. Its *support
  candidates* are the other points within ``2t`` horizontally of one of A's points. A candidate group (one
  object, or one stuff class) supports A when at least :data:`MIN_SUPPORT` of its candidate points lie within
  ``t`` of A's bottom height and its candidate points do not rise above it (95th percentile of their ``h``
  at most bottom + ``t``; a wall beside A rises, the floor around A's feet does not). Of several, the one
  with most points in that band wins. The object's ``stands_on`` names it; the relation is ``on``.
* **next_to** — two objects, neither on the other, whose closest points are at most ``NEXT_TO_GAP`` world
  units (0.3, metres for synthetic scenes) apart and whose height ranges overlap.
* **inside** — an object whose centroid lies in the ``room`` box grown by ``t``.

Examples
--------
A box standing on a floor, a cup on the box, a second box beside the first:

>>> import numpy as np
>>> g = np.stack(np.meshgrid(np.arange(0, 3, 0.05), np.arange(0, 3, 0.05), [0.0]), -1).reshape(-1, 3)
>>> def cube(lo, hi):
...     p = np.random.default_rng(0).uniform(lo, hi, (400, 3)); return p
>>> parts = [g, cube([1, 1, 0], [1.5, 1.5, 0.5]), cube([1.2, 1.2, 0.5], [1.3, 1.3, 0.6]),
...          cube([1.6, 1, 0], [2, 1.5, 0.4])]
>>> xyz = np.concatenate(parts)
>>> sem = np.repeat([1, 2, 3, 2], [len(p) for p in parts]); inst = np.repeat([0, 1, 2, 3], [len(p) for p in parts])
>>> from lift3d.export.instances import instance_records
>>> names = {1: "floor", 2: "box", 3: "cup"}
>>> recs = instance_records(xyz, sem, inst, np.ones(len(xyz)), names)
>>> classes = [{"id": 1, "name": "floor", "isthing": False}, {"id": 2, "name": "box", "isthing": True},
...            {"id": 3, "name": "cup", "isthing": True}]
>>> graph = build_scene_graph(xyz, sem, inst, np.ones(len(xyz)), recs, classes, up=np.array([0, 0, 1.0]),
...                           contact=0.05)
>>> sorted((r["subject"], r["relation"], r["object"]) for r in graph["relations"] if r["relation"] != "inside")
[('object:1', 'next_to', 'object:3'), ('object:1', 'on', 'stuff:1'), ('object:2', 'on', 'object:1'), ('object:3', 'on', 'stuff:1')]
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from lift3d.export.ground import floor_class_ids, map_frame
from lift3d.utils.atomic import write_json_atomic

#: Points of a group that must touch an object's bottom for the group to support it.
MIN_SUPPORT = 3
#: Largest gap between two objects that are ``next_to`` each other, in world units.
NEXT_TO_GAP = 0.3
#: Percentiles for an object's bottom and a support's top (robust to a few stray points).
BOTTOM_PERCENTILE, TOP_PERCENTILE = 2.0, 95.0


def build_scene_graph(xyz: np.ndarray, semantic: np.ndarray, instance: np.ndarray, confidence: np.ndarray,
                      records: list[dict[str, Any]], classes: list[dict[str, Any]], *, up: np.ndarray,
                      contact: float, floor_classes=(), world_length: float = 1.0) -> dict[str, Any]:
    """The scene graph of labelled points (rules in the module docstring).

    Parameters
    ----------
    xyz : np.ndarray
        ``[N, 3]`` positions; ``semantic``, ``instance``, ``confidence`` ``[N]``.
    records : list of dict
        ``instances.json`` records of these points.
    classes : list of dict
        ``classes.json`` rows.
    up : np.ndarray
        ``[3]`` up axis (a signed unit axis).
    contact : float
        The contact tolerance ``t`` (output units).
    floor_classes : sequence of str
        Walkable classes (names or ids); default from the class names.
    world_length : float
        Output units per world unit (scales :data:`NEXT_TO_GAP`).

    Returns
    -------
    dict
        ``nodes`` (room, stuff, objects), ``relations`` (``{subject, relation, object}``) and ``rules``.
    """
    xyz = np.asarray(xyz, np.float64)
    semantic = np.asarray(semantic)
    instance = np.asarray(instance)
    confidence = np.asarray(confidence, np.float64)
    up = np.asarray(up, np.float64)
    t = float(contact)
    gap = NEXT_TO_GAP * world_length
    local = xyz @ map_frame(up).T  # horizontal = local[:, :2], height = local[:, 2]
    h, horiz = local[:, 2], local[:, :2]
    names = {int(c["id"]): str(c["name"]) for c in classes}
    floors = set(floor_class_ids(classes, floor_classes))
    # Group of each point: the object id (> 0), or minus the stuff class id.
    group = np.where(instance > 0, instance, -semantic.astype(np.int64))

    stuff_mask = instance == 0
    room_pts = xyz[stuff_mask] if stuff_mask.any() else xyz
    room_box = (room_pts.min(0), room_pts.max(0)) if len(room_pts) else (np.zeros(3), np.zeros(3))
    nodes: list[dict[str, Any]] = [{"node": "room", "kind": "room",
                                    "aabb": {"min": room_box[0].tolist(), "max": room_box[1].tolist()}}]
    for cid in np.unique(semantic[stuff_mask]):
        m = stuff_mask & (semantic == cid)
        nodes.append({"node": f"stuff:{int(cid)}", "kind": "stuff", "class_id": int(cid),
                      "class_name": names.get(int(cid), f"class_{int(cid)}"), "count": int(m.sum()),
                      "floor_like": int(cid) in floors,
                      "aabb": {"min": xyz[m].min(0).tolist(), "max": xyz[m].max(0).tolist()}})

    relations: list[dict[str, str]] = []
    order = np.argsort(instance, kind="stable")
    bounds = np.searchsorted(instance[order], [(int(r["id"]), int(r["id"]) + 1) for r in records]).reshape(-1, 2)
    members = {int(r["id"]): order[a:b] for r, (a, b) in zip(records, bounds)}
    by_x = np.argsort(horiz[:, 0], kind="stable")  # candidate search: a slice of points sorted by x
    sorted_x = horiz[by_x, 0]
    support: dict[int, str | None] = {}
    for r in records:
        support[int(r["id"])] = _support(int(r["id"]), members[int(r["id"])], h, horiz, group, t, by_x, sorted_x)
    for r in records:
        oid = int(r["id"])
        idx = members[oid]
        sup = support[oid]
        if sup is not None:
            relations.append({"subject": f"object:{oid}", "relation": "on", "object": sup})
        centroid = np.asarray(r["centroid"], float)
        inside = bool(np.all(centroid >= room_box[0] - t) and np.all(centroid <= room_box[1] + t))
        if inside:
            relations.append({"subject": f"object:{oid}", "relation": "inside", "object": "room"})
        nodes.append({
            "node": f"object:{oid}", "kind": "object", "id": oid, "class_id": int(r["class_id"]),
            "class_name": r["class_name"], "centroid": r["centroid"], "obb": r["obb"], "aabb": r["aabb"],
            "count": int(r["count"]), "confidence": float(np.mean(confidence[idx])) if len(idx) else 0.0,
            "bottom": float(np.percentile(h[idx], BOTTOM_PERCENTILE)) if len(idx) else 0.0,
            "stands_on": None if sup is None else {"node": sup, "class_name": _node_class(sup, records, names)},
        })
    ids = sorted(i for i in members if len(members[i]))
    box = {i: (xyz[members[i]].min(0), xyz[members[i]].max(0), h[members[i]].min(), h[members[i]].max())
           for i in ids}
    trees: dict[int, Any] = {}
    for i, a in enumerate(ids):
        for b in ids[i + 1:]:
            if support[a] == f"object:{b}" or support[b] == f"object:{a}":
                continue
            if _next_to(members[a], members[b], xyz, box[a], box[b], gap, trees, key=b):
                relations.append({"subject": f"object:{a}", "relation": "next_to", "object": f"object:{b}"})
    return {
        "up": up.tolist(),
        "nodes": nodes,
        "relations": relations,
        "rules": {"contact_tolerance": t, "footprint_margin": 2 * t, "min_support_points": MIN_SUPPORT,
                  "next_to_gap": gap, "bottom_percentile": BOTTOM_PERCENTILE, "top_percentile": TOP_PERCENTILE,
                  "floor_classes": sorted(floors)},
    }


def _support(oid: int, idx: np.ndarray, h: np.ndarray, horiz: np.ndarray, group: np.ndarray, t: float,
             by_x: np.ndarray, sorted_x: np.ndarray) -> str | None:
    """The node an object stands on, or None (rule in the module docstring). ``by_x`` orders all points by
    horizontal x (``sorted_x`` those values), so candidates are found in a slice instead of all points."""
    from scipy.spatial import cKDTree

    if len(idx) == 0:
        return None
    bottom = np.percentile(h[idx], BOTTOM_PERCENTILE)
    lo, hi = horiz[idx].min(0) - 2 * t, horiz[idx].max(0) + 2 * t
    near = by_x[np.searchsorted(sorted_x, lo[0]):np.searchsorted(sorted_x, hi[0], side="right")]
    near = np.sort(near[(horiz[near, 1] >= lo[1]) & (horiz[near, 1] <= hi[1]) & (group[near] != oid)])
    if len(near) == 0:
        return None
    dist, _ = cKDTree(horiz[idx]).query(horiz[near], distance_upper_bound=2 * t)
    near = near[np.isfinite(dist)]
    best, best_count = None, 0
    for g in np.unique(group[near]):
        pts = near[group[near] == g]
        touching = int((np.abs(h[pts] - bottom) <= t).sum())
        if touching < MIN_SUPPORT or np.percentile(h[pts], TOP_PERCENTILE) > bottom + t:
            continue
        if touching > best_count:
            best, best_count = int(g), touching
    if best is None:
        return None
    return f"object:{best}" if best > 0 else f"stuff:{-best}"


def _next_to(a: np.ndarray, b: np.ndarray, xyz: np.ndarray, box_a, box_b, gap: float, trees: dict,
             key: int) -> bool:
    """Closest points at most ``gap`` apart and overlapping height ranges (``box_*``: xyz min, max and the
    height range of each object)."""
    from scipy.spatial import cKDTree

    if box_a[3] < box_b[2] or box_b[3] < box_a[2]:
        return False
    # Box distance first: most pairs are far apart.
    box_gap = np.maximum(0, np.maximum(box_a[0] - box_b[1], box_b[0] - box_a[1]))
    if np.linalg.norm(box_gap) > gap:
        return False
    if key not in trees:
        trees[key] = cKDTree(xyz[b])
    dist, _ = trees[key].query(xyz[a], distance_upper_bound=gap)
    return bool(np.isfinite(dist).any())


def _node_class(node: str, records, names) -> str:
    kind, _, num = node.partition(":")
    if kind == "stuff":
        return names.get(int(num), f"class_{num}")
    return next((r["class_name"] for r in records if int(r["id"]) == int(num)), "")


def write_scene_graph_json(path: str | Path, graph: dict[str, Any], *, frame: str, units: str) -> None:
    """``scene_graph.json``: ``{"frame", "units", "up", "nodes", "relations", "rules"}`` (atomically)."""
    write_json_atomic(path, {"frame": frame, "units": units, **graph})
