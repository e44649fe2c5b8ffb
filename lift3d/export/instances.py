"""From the field's label heads to stable instance ids and per-instance records.

Three steps turn points into what a robot map consumes:

1. :meth:`lift3d.model.panoptic.PanopticModel.query_labels` runs the field once per point (in chunks):
   density, colour, semantic and instance probabilities → category id (argmax, void excluded), raw instance
   *channel* (argmax over the instance channels, only on thing classes), and the probability of the chosen
   class.
2. :func:`assign_instances` turns raw channels into exported instances. A thing instance is a spatially
   connected set of points with the same (class, channel): a channel the field shares between two
   separated objects of one class becomes two instances. Components smaller than ``min_points`` are
   *relabelled* to the majority label of their surrounding points (KD-tree neighbours outside the small
   components) and *dropped* only when no such point lies within ``4 × link_radius``. Ids are contiguous
   ``1..K``, ordered by size (largest first), ties by centroid ``x, y, z``; 0 is stuff.
3. :func:`instance_records` summarises every instance: class, count, centroid, axis-aligned and oriented
   bounding box (Open3D), mean confidence.

:func:`nearest_instance_ids` carries the exported ids back to anything else in 3D, e.g. the surface points
of rendered pixels, so that renders and the exported map name each object alike.

Examples
--------
>>> import numpy as np
>>> xyz = np.array([[0, 0, 0], [0.1, 0, 0], [5, 0, 0], [5.1, 0, 0], [5.2, 0, 0]], float)
>>> sem = np.array([7, 7, 7, 7, 7]); chan = np.array([3, 3, 3, 3, 3])
>>> result = assign_instances(xyz, sem, chan, link_radius=0.5)
>>> result.instance.tolist()  # one channel, two separated objects → two instances, the larger first
[2, 2, 1, 1, 1]
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from lift3d.errors import InputError

#: Neighbour offsets that, with their negatives, make the 26-neighbourhood of a voxel (each edge once).
_HALF_NEIGHBOURHOOD = np.array(
    [(di, dj, dk) for di in (-1, 0, 1) for dj in (-1, 0, 1) for dk in (-1, 0, 1) if (di, dj, dk) > (0, 0, 0)],
    dtype=np.int64,
)

#: Neighbours consulted when a small fragment is relabelled to its surroundings.
FRAGMENT_NEIGHBOURS = 8


# ------------------------------------------------------------------------------------------ components
def voxel_components(xyz: np.ndarray, cell: float) -> np.ndarray:
    """Connected components of points under voxel 26-connectivity.

    Points are binned into cubes of side ``cell``; occupied cubes that touch (faces, edges or corners) are
    connected. Points closer than ``cell`` are always connected; points up to ``2·√3·cell`` apart may be.
    Sparse (sorted voxel keys + ``searchsorted``), so memory grows with the points, not the extent.

    Parameters
    ----------
    xyz : np.ndarray
        ``[N, 3]`` points.
    cell : float
        Voxel side (> 0).

    Returns
    -------
    np.ndarray
        ``[N]`` int64 component label per point, ``0..C-1``.

    Examples
    --------
    >>> voxel_components(np.array([[0, 0, 0], [0.9, 0, 0], [3, 0, 0]], float), 1.0).tolist()
    [0, 0, 1]
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(xyz)
    if n == 0:
        return np.zeros(0, np.int64)
    ijk = np.floor(np.asarray(xyz, np.float64) / cell).astype(np.int64)
    # One voxel of padding on each side keeps every neighbour key inside the box (no wrap-around).
    ijk -= ijk.min(0) - 1
    dims = ijk.max(0) + 2
    keys = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    voxels, point_voxel = np.unique(keys, return_inverse=True)
    m = len(voxels)
    rows, cols = [np.arange(m)], [np.arange(m)]
    for di, dj, dk in _HALF_NEIGHBOURHOOD:
        neighbour = voxels + (di * dims[1] + dj) * dims[2] + dk
        pos = np.searchsorted(voxels, neighbour)
        pos[pos == m] = 0
        hit = voxels[pos] == neighbour
        rows.append(np.flatnonzero(hit))
        cols.append(pos[hit])
    r, c = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(m, m))
    _, voxel_label = connected_components(graph, directed=False)
    return voxel_label[point_voxel.ravel()].astype(np.int64)


@dataclass
class InstanceAssignment:
    """Result of :func:`assign_instances`."""

    semantic: np.ndarray  # [N] int32 (fragments may have taken their surroundings' class)
    instance: np.ndarray  # [N] int32 contiguous 1..K on things, 0 on stuff
    keep: np.ndarray  # [N] bool, False for dropped isolated fragments
    stats: dict[str, Any]


def assign_instances(xyz: np.ndarray, semantic: np.ndarray, channel: np.ndarray, *, link_radius: float,
                     min_points: int = 0) -> InstanceAssignment:
    """Stable, contiguous instance ids from raw instance channels.

    Parameters
    ----------
    xyz : np.ndarray
        ``[N, 3]`` point positions.
    semantic : np.ndarray
        ``[N]`` category ids.
    channel : np.ndarray
        ``[N]`` raw instance channel (> 0 on thing points, 0 on stuff).
    link_radius : float
        Points of one (class, channel) closer than this belong to one instance (see
        :func:`voxel_components`); same units as ``xyz``.
    min_points : int
        Components with fewer points are fragments: each takes the majority (class, instance) of the
        :data:`FRAGMENT_NEIGHBOURS` nearest points of every one of its points among the points outside
        fragments, within ``4 × link_radius``; a fragment with no such neighbour is dropped (``keep`` False).
        0 keeps every component as an instance.

    Returns
    -------
    InstanceAssignment
        ``instance`` ids are ``1..K`` ordered by point count (descending), ties by centroid ``x, y, z``.

    Examples
    --------
    >>> xyz = np.array([[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [0.3, 0, 0], [0.45, 0, 0]], float)
    >>> sem = np.array([2, 2, 2, 2, 2]); chan = np.array([1, 1, 1, 1, 4])  # a one-point fragment (channel 4)
    >>> assign_instances(xyz, sem, chan, link_radius=0.12).instance.tolist()
    [1, 1, 1, 1, 2]
    >>> assign_instances(xyz, sem, chan, link_radius=0.12, min_points=2).instance.tolist()
    [1, 1, 1, 1, 1]
    """
    xyz = np.asarray(xyz, np.float64)
    semantic = np.asarray(semantic, np.int32).copy()
    channel = np.asarray(channel, np.int64)
    n = len(xyz)
    keep = np.ones(n, bool)
    component = np.full(n, -1, np.int64)  # global component id of thing points, -1 on stuff
    thing = np.flatnonzero(channel > 0)
    if len(thing):
        # (class, channel) groups; components inside each group.
        group_key = semantic[thing].astype(np.int64) * (int(channel.max()) + 1) + channel[thing]
        order = np.argsort(group_key, kind="stable")
        bounds = np.flatnonzero(np.diff(group_key[order])) + 1
        next_id = 0
        for members in np.split(thing[order], bounds):
            labels = voxel_components(xyz[members], link_radius)
            component[members] = labels + next_id
            next_id += int(labels.max()) + 1
    counts = np.bincount(component[component >= 0]) if len(thing) else np.zeros(0, np.int64)
    stats: dict[str, Any] = {"components": int(len(counts)), "link_radius": float(link_radius),
                             "min_points": int(min_points), "fragments_relabelled": 0, "fragment_points_relabelled": 0,
                             "fragments_dropped": 0, "fragment_points_dropped": 0}
    if min_points > 0 and len(counts):
        small = counts < min_points
        in_fragment = np.zeros(n, bool)
        in_fragment[component >= 0] = small[component[component >= 0]]
        if in_fragment.any():
            _relabel_fragments(xyz, semantic, component, in_fragment, keep, 4.0 * link_radius, stats)
    instance = _contiguous_ids(xyz, component, keep)
    instance[component < 0] = 0
    stats["instances"] = int(instance.max()) if n else 0
    return InstanceAssignment(semantic=semantic, instance=instance.astype(np.int32), keep=keep, stats=stats)


def _relabel_fragments(xyz, semantic, component, in_fragment, keep, max_distance, stats,
                       stay_when_isolated=()) -> None:
    """Give every fragment the majority (class, component) of its surroundings, in place; drop isolated
    fragments, except those in ``stay_when_isolated`` (component ids), which then stay as they are. Majority
    over all neighbour votes of the fragment's points, so a fragment stays one piece."""
    anchors = np.flatnonzero(~in_fragment)
    frag_points = np.flatnonzero(in_fragment)
    # Only anchors near a fragment can vote: keep those in the 27 cells (of side max_distance) around the
    # fragments' cells, so the KD-tree holds the neighbourhood of a few crumbs, not a million points.
    cell = np.floor(xyz / max_distance).astype(np.int64)
    lo = cell.min(0) - 1
    dims = cell.max(0) - lo + 2
    key = ((cell[:, 0] - lo[0]) * dims[1] + (cell[:, 1] - lo[1])) * dims[2] + (cell[:, 2] - lo[2])
    near = np.unique(key[frag_points])
    near = np.unique((near[:, None] + ((np.arange(-1, 2)[:, None, None] * dims[1] + np.arange(-1, 2)[None, :, None])
                                       * dims[2] + np.arange(-1, 2)[None, None, :]).reshape(1, -1)).ravel())
    anchors = anchors[np.isin(key[anchors], near)]
    if len(anchors) == 0:
        drop = frag_points[~np.isin(component[frag_points], np.asarray(list(stay_when_isolated), np.int64))]
        keep[drop] = False
        stats["fragments_dropped"] += int(len(np.unique(component[drop])))
        stats["fragment_points_dropped"] += int(len(drop))
        return
    k = min(FRAGMENT_NEIGHBOURS, len(anchors))
    dist, idx = cKDTree(xyz[anchors]).query(xyz[frag_points], k=k, distance_upper_bound=max_distance, workers=-1)
    dist, idx = dist.reshape(len(frag_points), k), idx.reshape(len(frag_points), k)
    frag_of_point = component[frag_points]
    for frag in np.unique(frag_of_point):
        rows = frag_of_point == frag
        valid = np.isfinite(dist[rows])
        members = frag_points[rows]
        if not valid.any():
            if frag in stay_when_isolated:
                continue
            keep[members] = False
            stats["fragments_dropped"] += 1
            stats["fragment_points_dropped"] += int(len(members))
            continue
        voters = anchors[idx[rows][valid]]
        # Vote on the (class, component) pair; ties go to the smallest pair (deterministic).
        pairs = np.stack([semantic[voters].astype(np.int64), component[voters]], 1)
        uniq, votes = np.unique(pairs, axis=0, return_counts=True)
        winner = uniq[int(np.argmax(votes))]
        semantic[members] = winner[0]
        component[members] = winner[1]
        stats["fragments_relabelled"] += 1
        stats["fragment_points_relabelled"] += int(len(members))


def _contiguous_ids(xyz: np.ndarray, component: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Map component ids (≥ 0) of kept points to 1..K by size (desc), then centroid x, y, z; others 0."""
    out = np.zeros(len(component), np.int64)
    sel = np.flatnonzero((component >= 0) & keep)
    if len(sel) == 0:
        return out
    comps, inverse, counts = np.unique(component[sel], return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    centroid = np.stack([np.bincount(inverse, weights=xyz[sel, a]) for a in range(3)], 1) / counts[:, None]
    # np.lexsort sorts by the last key first: count (descending), then x, y, z.
    order = np.lexsort((centroid[:, 2], centroid[:, 1], centroid[:, 0], -counts))
    new_id = np.empty(len(comps), np.int64)
    new_id[order] = np.arange(1, len(comps) + 1)
    out[sel] = new_id[inverse]
    return out


def nearest_instance_ids(query_xyz: np.ndarray, query_semantic: np.ndarray, xyz: np.ndarray,
                         semantic: np.ndarray, instance: np.ndarray) -> np.ndarray:
    """The id of the nearest exported thing point of the same class, for each query point.

    Parameters
    ----------
    query_xyz : np.ndarray
        ``[Q, 3]`` points, in the frame of ``xyz``.
    query_semantic : np.ndarray
        ``[Q]`` their category ids.
    xyz, semantic, instance : np.ndarray
        An exported labelled cloud: ``[N, 3]`` points, ``[N]`` category and instance ids (0 = stuff).

    Returns
    -------
    np.ndarray
        ``[Q]`` int64 instance ids; 0 where the cloud has no instance of the query's class.

    Examples
    --------
    >>> xyz = np.array([[0.0, 0, 0], [1, 0, 0], [5, 0, 0]]); sem = np.array([7, 7, 8]); inst = np.array([1, 2, 3])
    >>> nearest_instance_ids(np.array([[0.2, 0, 0], [0.9, 0, 0], [0.3, 0, 0], [9, 9, 9]]), np.array([7, 7, 8, 9]),
    ...                      xyz, sem, inst).tolist()
    [1, 2, 3, 0]
    """
    query_xyz = np.asarray(query_xyz, np.float64).reshape(-1, 3)
    query_semantic = np.asarray(query_semantic).ravel()
    semantic, instance = np.asarray(semantic).ravel(), np.asarray(instance).ravel()
    out = np.zeros(len(query_xyz), np.int64)
    for c in np.unique(query_semantic):
        source = (semantic == c) & (instance > 0)
        if not source.any():
            continue
        ask = query_semantic == c
        _, nearest = cKDTree(np.asarray(xyz, np.float64)[source]).query(query_xyz[ask])
        out[ask] = instance[source][nearest]
    return out


def join_filled_instances(xyz: np.ndarray, semantic: np.ndarray, instance: np.ndarray, filled: np.ndarray,
                          radius: float, channel: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Instances made mostly of filled points (``filled``) join the nearest other instance of their class, when
    within ``radius``; ids are then made contiguous again (by size, then centroid).

    Points that fill a hole of an object's isosurface lie more than the instance link radius from it (they fill
    only where the isosurface has nothing), so alone they would make instances of their own, or lift a crumb of
    the isosurface above the size at which it folds into its neighbour: on an images-only tuning room, an extra
    table of 82 points on the table's top. A mostly-filled instance joins the nearest instance that is not mostly
    filled, else the nearest that is (an object with no isosurface at all is filled in pieces that join each
    other). Each joins one other, so two instances that are not mostly filled never join through them. And each
    joins one at least its own size: a filled patch is smaller than the object it belongs to, while a whole
    object can be mostly filled too (images only: a table with 53 % filled points, 2 116 of them, joined the
    table beside it, 1 781 points and 0.8 m away, through a few stray points of fog between them).

    With ``channel`` (each point's instance channel in the field), an instance joins only one of its own channel.
    Instances are connected components of one (class, channel), so a patch of an object the field knows as one
    carries that object's channel, while a whole object the isosurface barely reaches (images only) has a channel
    of its own, and joining it to the nearest instance of its class would merge two objects: on five images-only
    cluttered tuning rooms, boxes 0.03-0.3 m apart and chairs 0.4 m apart did so (objects found 39 → 44 of 51).

    Parameters
    ----------
    xyz : np.ndarray
        ``[N, 3]`` points.
    semantic, instance : np.ndarray
        ``[N]`` category and instance ids (0 = stuff).
    filled : np.ndarray
        ``[N] bool``: the point fills a hole.
    radius : float
        Farthest an instance of filled points may be from the instance it joins (units of ``xyz``).
    channel : np.ndarray, optional
        ``[N]`` instance channel of each point: an instance joins only one of the channel most of its points carry.

    Returns
    -------
    (np.ndarray, int)
        The instance ids, and how many fewer instances there are.

    Examples
    --------
    A table (instance 1) and filled patches of table: one 0.15 from it joins it, and of two 2 away one joins the
    other.

    >>> xyz = np.array([[0.0, 0, 0], [0.05, 0, 0], [0.2, 0, 0], [2.1, 0, 0], [2.2, 0, 0]])
    >>> ids, joined = join_filled_instances(xyz, np.array([5, 5, 5, 5, 5]), np.array([1, 1, 2, 3, 4]),
    ...                                     np.array([False, False, True, True, True]), radius=0.2)
    >>> ids.tolist(), joined
    ([1, 1, 1, 2, 2], 2)

    The field gives the patch 0.15 away a channel of its own (another object): it stays apart.

    >>> ids, joined = join_filled_instances(xyz, np.array([5, 5, 5, 5, 5]), np.array([1, 1, 2, 3, 4]),
    ...                                     np.array([False, False, True, True, True]), radius=0.2,
    ...                                     channel=np.array([1, 1, 2, 3, 3]))
    >>> ids.tolist(), joined
    ([1, 1, 3, 2, 2], 1)
    """
    xyz = np.asarray(xyz, np.float64)
    instance = np.asarray(instance, np.int64).copy()
    filled = np.asarray(filled, bool)
    ids, counts = np.unique(instance[instance > 0], return_counts=True)
    if not len(ids) or not filled.any():
        return instance, 0
    filled_counts = np.bincount(instance[filled & (instance > 0)], minlength=int(ids.max()) + 1)[ids]
    mostly_filled = ids[filled_counts > 0.5 * counts]
    size = np.zeros(int(ids.max()) + 1, np.int64)
    size[ids] = counts
    point_size = size[instance]  # each point's instance's size (0 on stuff)
    joins = {}  # each mostly-filled instance -> the nearest other of its class within the radius, solid ones first
    for i in mostly_filled:
        own = instance == i
        c = semantic[own][0]
        other = (semantic == c) & (instance > 0) & ~own & (point_size >= size[i])
        if channel is not None:
            other &= channel == np.bincount(channel[own]).argmax()
        for candidates in (other & ~np.isin(instance, mostly_filled), other):
            if not candidates.any():
                continue
            dist, nearest = cKDTree(xyz[candidates]).query(xyz[own], distance_upper_bound=radius)
            if np.isfinite(dist).any():
                joins[int(i)] = int(instance[candidates][nearest[np.argmin(dist)]])
                break

    group = {int(i): int(i) for i in ids}  # union-find over the joins

    def find(i: int) -> int:
        while group[i] != i:
            group[i] = group[group[i]]
            i = group[i]
        return i

    for i, j in joins.items():
        group[find(i)] = find(j)
    joined = len(ids) - len({find(int(i)) for i in ids})
    if joined:
        lookup = np.zeros(int(ids.max()) + 1, np.int64)
        lookup[ids] = [find(int(i)) for i in ids]
        instance = _contiguous_ids(xyz, np.where(instance > 0, lookup[instance], 0) - 1, np.ones(len(instance), bool))
    return instance, int(joined)


#: Where the instance ids of rendered thing pixels come from (``lift3d eval --instances``, ``lift3d render
#: --instances``): ``export``, the exported cloud's objects (what instances.json lists; the default), or
#: ``field``, the argmax of the instance head. Export by default: on eight tuning rooms its PQ^scene was 0.033
#: higher on average (docs/notes/2026-11-29-benchmark-history.md, "Instance ids from the export in 2D").
INSTANCE_SOURCES = ("export", "field")


def check_instance_source(value: str) -> str:
    """``value`` if it is one of :data:`INSTANCE_SOURCES`, else a one-line :class:`InputError`."""
    if value not in INSTANCE_SOURCES:
        raise InputError("--instances", f"unknown instance source {value!r} ({', '.join(INSTANCE_SOURCES)})")
    return value


def frame_instance_ids(cameras, frame: int, semantic: np.ndarray, depth: np.ndarray, xyz: np.ndarray,
                       cloud_semantic: np.ndarray, cloud_instance: np.ndarray, things, downscale: int = 1) -> np.ndarray:
    """Exported instance ids for the thing pixels of one rendered frame.

    Each pixel of a thing class is lifted to the world along its ray by its rendered z-depth and takes the id
    of the nearest exported point of its class (:func:`nearest_instance_ids`), so that one object has one id
    in every view, the id of its record in ``instances.json``.

    Parameters
    ----------
    cameras : lift3d.data.cameras.Cameras
        The cameras that rendered the frame, in the frame of ``xyz``.
    frame : int
        Index of the camera in ``cameras``.
    semantic, depth : np.ndarray
        ``[H', W']`` rendered category ids and z-depth (0 = nothing hit).
    xyz, cloud_semantic, cloud_instance : np.ndarray
        The exported cloud: ``[N, 3]`` points, ``[N]`` category and instance ids (0 = stuff).
    things : iterable of int
        Thing category ids.
    downscale : int
        The frame was rendered at every ``downscale``-th pixel block (its pixels are the blocks' centres).

    Returns
    -------
    np.ndarray
        ``[H', W']`` int64 ids; 0 on stuff, void, pixels with no depth and classes the cloud has no object of.

    Examples
    --------
    >>> from lift3d.data.cameras import Cameras
    >>> cams = Cameras(c2w=np.eye(4)[None], fx=2.0, fy=2.0, cx=1.0, cy=1.0, width=2, height=2)
    >>> sem, z = np.array([[7, 7], [1, 7]]), np.array([[3.0, 3.0], [3.0, 0.0]])
    >>> cloud = np.array([[-0.75, 0.75, -3.0], [0.75, 0.75, -3.0]])  # what the two top pixels see
    >>> frame_instance_ids(cams, 0, sem, z, cloud, np.array([7, 7]), np.array([4, 9]), things=[7]).tolist()
    [[4, 9], [0, 0]]
    """
    semantic, depth = np.asarray(semantic), np.asarray(depth)
    out = np.zeros(semantic.shape, np.int64)
    lift = np.isin(semantic, list(things)) & (depth > 0)
    if lift.any():
        rows, cols = np.nonzero(lift)
        off = (downscale - 1) / 2.0  # the centre of a downscale x downscale block, as a pixel index
        world = cameras.unproject(frame, cols * downscale + off, rows * downscale + off, depth[lift])
        out[lift] = nearest_instance_ids(world, semantic[lift], xyz, cloud_semantic, cloud_instance)
    return out


# ------------------------------------------------------------------------------------------ down-sampling
def voxel_downsample_majority(xyz: np.ndarray, rgb: np.ndarray, semantic: np.ndarray, channel: np.ndarray,
                              confidence: np.ndarray, voxel_size: float) -> tuple[np.ndarray, ...]:
    """Voxel down-sampling that keeps labels exact: one point per occupied voxel.

    Position and colour are the voxel means; the (semantic, channel) pair is the majority of the voxel's
    points (ties → the smallest pair); confidence is the mean confidence of the points carrying the winning
    pair. Open3D's ``voxel_down_sample`` would *average* integer labels (class 3 and 5 → 4), so it is not
    used for labels.

    Returns
    -------
    tuple
        ``xyz, rgb, semantic, channel, confidence`` of the voxels, ordered by voxel key.

    Examples
    --------
    >>> xyz = np.array([[0.1, 0, 0], [0.2, 0, 0], [0.3, 0, 0], [1.5, 0, 0]])
    >>> rgb = np.zeros((4, 3), np.uint8); conf = np.array([0.5, 0.9, 0.7, 1.0], np.float32)
    >>> out = voxel_downsample_majority(xyz, rgb, np.array([3, 5, 5, 3]), np.array([0, 1, 1, 0]), conf, 1.0)
    >>> out[2].tolist(), out[3].tolist(), [round(float(c), 3) for c in out[4]]
    ([5, 3], [1, 0], [0.8, 1.0])
    """
    xyz = np.asarray(xyz, np.float64)
    ijk = np.floor(xyz / voxel_size).astype(np.int64)
    _, voxel = np.unique(ijk, axis=0, return_inverse=True)
    voxel = voxel.ravel()
    m = int(voxel.max()) + 1 if len(voxel) else 0
    counts = np.bincount(voxel, minlength=m).astype(np.float64)
    mean_xyz = np.stack([np.bincount(voxel, weights=xyz[:, a], minlength=m) for a in range(3)], 1) / counts[:, None]
    rgb = np.asarray(rgb, np.float64)
    mean_rgb = np.stack([np.bincount(voxel, weights=rgb[:, a], minlength=m) for a in range(3)], 1) / counts[:, None]
    # Majority of (semantic, channel) per voxel: count each (voxel, semantic, channel) triple, keep the first
    # triple of every voxel after sorting by (voxel, -votes, semantic, channel).
    triples, triple_of_point, votes = np.unique(
        np.stack([voxel, np.asarray(semantic, np.int64), np.asarray(channel, np.int64)], 1),
        axis=0, return_inverse=True, return_counts=True)
    triple_of_point = triple_of_point.ravel()
    conf_sum = np.bincount(triple_of_point, weights=np.asarray(confidence, np.float64), minlength=len(triples))
    order = np.lexsort((triples[:, 2], triples[:, 1], -votes, triples[:, 0]))
    first = order[np.r_[True, np.diff(triples[order, 0]) != 0]]
    winner_voxel = triples[first, 0]
    sem_out = np.empty(m, np.int32)
    chan_out = np.empty(m, np.int32)
    conf_out = np.empty(m, np.float32)
    sem_out[winner_voxel] = triples[first, 1]
    chan_out[winner_voxel] = triples[first, 2]
    conf_out[winner_voxel] = conf_sum[first] / votes[first]
    return (mean_xyz.astype(np.float32), np.clip(np.round(mean_rgb), 0, 255).astype(np.uint8), sem_out, chan_out,
            conf_out)


# ------------------------------------------------------------------------------------------ records
def oriented_box(points: np.ndarray) -> dict[str, Any]:
    """Open3D's oriented bounding box (PCA of the convex hull) as ``{center, rotation, extent}``.

    Degenerate sets (fewer than 4 points, or all on a plane or line) fall back to Open3D's robust mode and
    then to the axis-aligned box with an identity rotation.

    Examples
    --------
    >>> corners = np.array([[x, y, z] for x in (0, 2) for y in (0, 1) for z in (0, 1)], float)
    >>> sorted(round(e, 6) for e in oriented_box(corners)["extent"])
    [1.0, 1.0, 2.0]
    """
    import open3d as o3d

    pts = np.asarray(points, np.float64)
    box = None
    if len(pts) >= 4:
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        for robust in (False, True):
            try:
                box = cloud.get_oriented_bounding_box(robust=robust)
                break
            except RuntimeError:  # Qhull: flat or collinear input
                continue
    if box is None:
        lo, hi = pts.min(0), pts.max(0)
        return {"center": ((lo + hi) / 2).tolist(), "rotation": np.eye(3).tolist(), "extent": (hi - lo).tolist()}
    return {"center": np.asarray(box.center).tolist(), "rotation": np.asarray(box.R).tolist(),
            "extent": np.asarray(box.extent).tolist()}


def instance_records(xyz: np.ndarray, semantic: np.ndarray, instance: np.ndarray, confidence: np.ndarray,
                     class_names: dict[int, str] | None = None) -> list[dict[str, Any]]:
    """One JSON-ready record per instance id > 0, in id order.

    Each record: ``id``, ``class_id`` (majority class of its points), ``class_name``, ``count``,
    ``centroid``, ``aabb`` (``{"min", "max"}``), ``obb`` (``{"center", "rotation", "extent"}``: the box is
    ``center + rotation @ (extent/2 · [±1, ±1, ±1])``), ``mean_confidence``.

    Examples
    --------
    >>> xyz = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [5, 5, 5]], float)
    >>> recs = instance_records(xyz, np.array([7, 7, 7, 7, 1]), np.array([1, 1, 1, 1, 0]),
    ...                         np.full(5, 0.5), {7: "chair"})
    >>> recs[0]["class_name"], recs[0]["count"], recs[0]["aabb"]["max"]
    ('chair', 4, [1.0, 1.0, 1.0])
    """
    class_names = class_names or {}
    xyz = np.asarray(xyz, np.float64)
    instance = np.asarray(instance)
    records = []
    ids = np.unique(instance[instance > 0])
    order = np.argsort(instance, kind="stable")
    starts = np.searchsorted(instance[order], ids)
    ends = np.searchsorted(instance[order], ids, side="right")
    for inst_id, s, e in zip(ids, starts, ends):
        members = order[s:e]
        pts = xyz[members]
        classes, votes = np.unique(np.asarray(semantic)[members], return_counts=True)
        class_id = int(classes[int(np.argmax(votes))])
        records.append({
            "id": int(inst_id),
            "class_id": class_id,
            "class_name": class_names.get(class_id, f"class_{class_id}"),
            "count": int(len(members)),
            "centroid": pts.mean(0).tolist(),
            "aabb": {"min": pts.min(0).tolist(), "max": pts.max(0).tolist()},
            "obb": oriented_box(pts),
            "mean_confidence": float(np.mean(np.asarray(confidence)[members])),
        })
    return records
