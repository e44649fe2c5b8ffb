"""3D instance clean-up of an exported point cloud: one instance per object, no crumbs.

:func:`lift3d.export.instances.assign_instances` makes one instance per spatially connected (class, instance
channel) group. A trained field often splits one object over two channels (or a channel over two pieces),
and leaves specks of a channel inside another object; a robot map wants one record per object. Two steps
fix that, using the views the field was trained from:

1. **Fragments merge.** In every training view (up to ``max_views``, evenly spread) the thing points are
   projected with a z-buffer of all exported points (a point is visible when it is not behind the nearest
   point within one pixel by more than ``depth_tolerance``), and each instance's visible points vote for
   the 2D pseudo-label segment they land on. Two instances of the same class are fragments of one object
   when, in the views that see both (at least ``min_views``), the same 2D segment holds the majority of each
   one's points on 2D thing segments in at least ``min_share`` of those views (points on stuff pixels do not
   count: a fragment whose label spilled onto the floor around it still belongs to its object). A 2D
   segmenter that merges two touching objects does so in some frames, not in most, so neighbours of one
   class stay apart; and it splits one object into two segments more rarely still, so the default share,
   :data:`MERGE_MIN_SHARE` = 2/3, lets a view that shows the two apart outweigh two views that show them
   together. Groups are joined transitively.
2. **Unconfirmed instances fold.** An object the 2D segmenter never confirms is not an object: an instance
   (after merging) must have the majority of its visible points on one 2D thing segment in at least
   ``min_support_views`` of the voting views. Specks of fog in front of a wall and slivers beside an object
   land on stuff, or show too few points to vote, in every view; a real small thing seen by a single view
   is confirmed there. One with nothing around it stays as it is.
3. **Crumbs fold.** An instance with fewer than ``min_points`` points (or an unconfirmed or unsure one) takes
   the majority (class, instance) of the points around it (within ``4 × link_radius``, outside crumbs) and
   disappears into it; with no such point a crumb is dropped.

A thing the training views agree on keeps its class: an instance to fold whose class the 2D pseudo-labels
confirm in at least ``keep_confirmed_views`` of the voting views (most of its visible points on one 2D segment
of its own class) folds only into an instance of that class; where its surroundings are of another class (a
figurine on a table, a toy plane on the floor) it stays an instance of its own. Segment ids carry their class
for this (:func:`class_segments`).

Counts before and after each step go to the export's ``metadata.json`` (the ``instance-cleanup`` step's record).

Examples
--------
Two fragments (instances 1 and 2) that one 2D segment covers in both views merge; instance 3 keeps its id:

>>> votes = np.array([[0, 1, 7, 10, 10], [0, 2, 7, 8, 9], [0, 3, 5, 6, 6],
...                   [1, 1, 4, 9, 9], [1, 2, 4, 7, 7], [1, 3, 2, 5, 5]])
>>> merged, n = merge_fragments(np.array([1, 2, 3, 2]), np.array([0, 9, 9, 9]), votes, min_views=2)
>>> merged.tolist(), n
([1, 1, 3, 1], 1)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from lift3d.export.instances import _contiguous_ids, _relabel_fragments


#: Points of the vote cloud (a random subset of the export when it is larger). 128 × 128 views see a few points
#: per pixel at this size, so larger exports only repeat the same votes (projecting 1M points into 24 views was
#: most of the clean-up's time).
VOTE_POINTS = 200_000
#: Share of the views that see two same-class instances in which one 2D segment must hold both for them to
#: merge. Two thirds, not half: segmenters merge touching objects of one class (two cabinets side by side)
#: more often than they split one object in two, so a view that separates them says more than one that joins
#: them. On tuning room 5 two cabinets shared a segment in 3 of the 5 views that saw both and merged at one
#: half; at two thirds no other tuning room (6-10, sensor depth; 5-6, images only) changed its objects found.
MERGE_MIN_SHARE = 2.0 / 3.0


def segment_votes(xyz_world: np.ndarray, instance: np.ndarray, cameras, frames: np.ndarray,
                  segments_of: Callable[[int], np.ndarray], *, max_views: int = 24, min_points: int = 5,
                  depth_tolerance: float = 0.03, max_points: int = VOTE_POINTS, seed: int = 0) -> np.ndarray:
    """What 2D segment each instance's visible points land on, view by view.

    Parameters
    ----------
    xyz_world : np.ndarray
        ``[N, 3]`` every exported point (stuff too: it occludes), in the cameras' world frame.
    instance : np.ndarray
        ``[N]`` instance id (0 = stuff).
    cameras : lift3d.data.cameras.Cameras
        World-frame cameras (``project``).
    frames : np.ndarray
        Frames to use (training frames); at most ``max_views`` of them, evenly spread, are used.
    segments_of : callable
        ``frame -> [H, W]`` int 2D thing-segment ids of that frame's pseudo-labels (0 = none).
    min_points : int
        An instance needs this many visible points in a view to vote there.
    depth_tolerance : float
        Relative depth margin of the visibility test.
    max_points : int
        Vote with a random subset of this many points (fixed ``seed``) when there are more; 0 = all.

    Returns
    -------
    np.ndarray
        ``[K, 5]`` int64 rows ``(frame, instance, segment, points in segment, visible points of the instance)``.
    """
    from scipy.ndimage import minimum_filter

    frames = np.asarray(frames, np.int64)
    if len(frames) > max_views:
        frames = frames[np.linspace(0, len(frames) - 1, max_views).round().astype(np.int64)]
    xyz_world = np.asarray(xyz_world, np.float64)
    instance = np.asarray(instance, np.int64)
    n_inst = int(instance.max(initial=0)) + 1
    if 0 < max_points < len(xyz_world):
        pick = np.sort(np.random.default_rng(seed).choice(len(xyz_world), max_points, replace=False))
        xyz_world, instance = xyz_world[pick], instance[pick]
    rows = []
    for f in frames:
        f = int(f)
        uv, z = cameras.project(f, xyz_world)
        w, h = int(cameras.width[f]), int(cameras.height[f])
        with np.errstate(invalid="ignore"):
            ok = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        idx = np.flatnonzero(ok)
        if len(idx) == 0:
            continue
        pix = uv[idx, 1].astype(np.int64) * w + uv[idx, 0].astype(np.int64)
        zbuf = np.full(w * h, np.inf)
        np.minimum.at(zbuf, pix, z[idx])
        # The nearest point within one pixel: points are sparser than pixels in places, and a hole in the
        # z-buffer would let the surface behind show through.
        zbuf = minimum_filter(zbuf.reshape(h, w), size=3).reshape(-1)
        visible = z[idx] <= zbuf[pix] * (1.0 + depth_tolerance)
        thing = instance[idx] > 0
        idx, pix = idx[visible & thing], pix[visible & thing]
        if len(idx) == 0:
            continue
        inst = instance[idx]
        total = np.bincount(inst, minlength=n_inst)
        seg = np.asarray(segments_of(f)).reshape(-1)[pix].astype(np.int64)
        pairs, counts = np.unique(np.stack([inst, seg], 1), axis=0, return_counts=True)
        use = (pairs[:, 1] > 0) & (total[pairs[:, 0]] >= min_points)
        for (a, s), c in zip(pairs[use], counts[use]):
            rows.append((f, a, s, c, total[a]))
    return np.asarray(rows, np.int64).reshape(-1, 5)


def merge_fragments(instance: np.ndarray, instance_class: np.ndarray, votes: np.ndarray, *,
                    min_share: float = MERGE_MIN_SHARE, min_views: int = 2) -> tuple[np.ndarray, int]:
    """Join instances of one class that one 2D segment covers in the views that see both.

    Parameters
    ----------
    instance : np.ndarray
        ``[N]`` instance ids (0 = stuff).
    instance_class : np.ndarray
        ``[max id + 1]`` class of each instance id.
    votes : np.ndarray
        :func:`segment_votes` rows.
    min_share, min_views : float, int
        See the module docstring.

    Returns
    -------
    merged : np.ndarray
        ``[N]`` ids: every joined group takes its smallest id.
    merges : int
        How many instances disappeared into another.
    """
    instance = np.asarray(instance, np.int64)
    n_inst = int(instance.max(initial=0)) + 1
    parent = np.arange(n_inst)

    def root(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    # The segment holding the majority of an instance's visible points on thing segments in a view (if one
    # does); points on stuff or void pixels abstain (a fragment's label may spill onto the floor around it).
    if len(votes):
        key = votes[:, 0] * (int(votes[:, 1].max()) + 1) + votes[:, 1]
        _, inv = np.unique(key, return_inverse=True)
        on_things = np.bincount(inv.ravel(), weights=votes[:, 3])[inv.ravel()]
        major = votes[2 * votes[:, 3] > on_things]
    else:
        major = votes
    co: dict[tuple[int, int], int] = {}
    same: dict[tuple[int, int], int] = {}
    for f in np.unique(major[:, 0]) if len(major) else []:
        rows = major[major[:, 0] == f]
        for x in range(len(rows)):
            for y in range(x + 1, len(rows)):
                a, b = int(rows[x, 1]), int(rows[y, 1])
                if instance_class[a] != instance_class[b]:
                    continue
                key = (min(a, b), max(a, b))
                co[key] = co.get(key, 0) + 1
                same[key] = same.get(key, 0) + int(rows[x, 2] == rows[y, 2])
    merges = 0
    for (a, b), n in sorted(co.items()):
        if n >= min_views and same[(a, b)] >= min_share * n - 1e-9:  # (2/3 of 3 views is 2, not 2.0000001)
            ra, rb = root(a), root(b)
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
                merges += 1
    roots = np.array([root(a) for a in range(n_inst)], np.int64)
    return roots[instance], merges


def supporting_views(votes: np.ndarray, old_instance: np.ndarray, new_instance: np.ndarray,
                     min_share: float = 0.5) -> np.ndarray:
    """``[max new id + 1]`` views in which most of an instance's visible points land on one 2D thing segment.

    Parameters
    ----------
    votes : np.ndarray
        :func:`segment_votes` rows ``(frame, instance, segment, points in segment, visible points)`` for the
        ids of ``old_instance``.
    old_instance, new_instance : np.ndarray
        ``[N]`` ids before and after :func:`merge_fragments` (the votes are counted for the merged groups).
    min_share : float
        Share of the visible points one segment must hold in a view.

    Examples
    --------
    Instance 1 is confirmed in views 0 and 1, instance 2 (merged into 1) adds nothing, instance 3 only in view 1:

    >>> votes = np.array([[0, 1, 7, 9, 10], [1, 1, 4, 8, 10], [1, 3, 5, 3, 4], [0, 3, 5, 1, 4]])
    >>> supporting_views(votes, np.array([1, 2, 3]), np.array([1, 1, 3])).tolist()
    [0, 2, 0, 1]
    """
    old_instance, new_instance = np.asarray(old_instance, np.int64), np.asarray(new_instance, np.int64)
    n_new = int(new_instance.max(initial=0)) + 1
    out = np.zeros(n_new, np.int64)
    if len(votes) == 0:
        return out
    to_new = np.zeros(max(int(old_instance.max(initial=0)), int(votes[:, 1].max())) + 1, np.int64)
    to_new[old_instance] = new_instance
    frame, inst, seg, count, total = (votes[:, k] for k in range(5))
    new = to_new[inst]
    # Visible points of a merged group in a view: the sum over its pieces (each piece's total once).
    piece = np.unique(np.stack([frame, inst], 1), axis=0, return_index=True)[1]
    view_key = frame * n_new + new
    totals = np.bincount(view_key[piece], weights=total[piece], minlength=int(view_key.max()) + 1)
    seg_key, seg_inv = np.unique(np.stack([view_key, seg], 1), axis=0, return_inverse=True)
    seg_count = np.bincount(seg_inv.ravel(), weights=count)
    confirmed = seg_count >= min_share * totals[seg_key[:, 0]]
    views = np.unique(seg_key[confirmed, 0])
    np.add.at(out, views % n_new, 1)
    return out


#: A :func:`class_segments` id is ``class << SEGMENT_CLASS_SHIFT | segment``.
SEGMENT_CLASS_SHIFT = 32


def class_segments(semantic: np.ndarray, instance: np.ndarray) -> np.ndarray:
    """2D thing-segment ids that carry their class: ``class << SEGMENT_CLASS_SHIFT | segment`` on thing pixels
    (``instance`` > 0), 0 elsewhere. Two pixels share an id exactly when they share a segment, so merging by
    these ids is merging by segments.

    Examples
    --------
    >>> class_segments(np.array([[7, 2]]), np.array([[3, 0]])).tolist() == [[7 << SEGMENT_CLASS_SHIFT | 3, 0]]
    True
    """
    semantic, instance = np.asarray(semantic, np.int64), np.asarray(instance, np.int64)
    return np.where(instance > 0, (semantic << SEGMENT_CLASS_SHIFT) | instance, 0)


def confirming_views(votes: np.ndarray, old_instance: np.ndarray, new_instance: np.ndarray,
                     old_class: np.ndarray) -> np.ndarray:
    """``[max new id + 1]`` views in which most of an instance's visible points land on one 2D segment of the
    instance's own class (:func:`supporting_views` over the votes on :func:`class_segments` ids of that class).

    Examples
    --------
    Instance 1 (class 7) lands on a class-7 segment in view 0 and on a class-5 one in view 1:

    >>> seg7, seg5 = 7 << SEGMENT_CLASS_SHIFT | 4, 5 << SEGMENT_CLASS_SHIFT | 4
    >>> votes = np.array([[0, 1, seg7, 9, 10], [1, 1, seg5, 8, 10]])
    >>> confirming_views(votes, np.array([1]), np.array([1]), np.array([0, 7])).tolist()
    [0, 1]
    """
    if len(votes):
        votes = votes[(votes[:, 2] >> SEGMENT_CLASS_SHIFT) == np.asarray(old_class)[votes[:, 1]]]
    return supporting_views(votes, old_instance, new_instance)


def instance_classes(semantic: np.ndarray, instance: np.ndarray) -> np.ndarray:
    """``[max id + 1]`` majority class of every instance id (0 for ids without points)."""
    instance = np.asarray(instance, np.int64)
    out = np.zeros(int(instance.max(initial=0)) + 1, np.int64)
    sel = instance > 0
    if sel.any():
        pairs, counts = np.unique(np.stack([instance[sel], np.asarray(semantic, np.int64)[sel]], 1), axis=0,
                                  return_counts=True)
        order = np.lexsort((-counts, pairs[:, 0]))
        first = order[np.r_[True, np.diff(pairs[order, 0]) != 0]]
        out[pairs[first, 0]] = pairs[first, 1]
    return out


def count_instances(instance: np.ndarray) -> int:
    """Number of distinct instances (ids > 0)."""
    instance = np.asarray(instance)
    return int(len(np.unique(instance[instance > 0])))


@dataclass(frozen=True)
class CleanupRules:
    """What :func:`clean_instances` merges and folds (module docstring)."""

    merge: bool = True
    """Merge fragments (step 1); off, no instances merge."""
    max_views: int = 24
    """Voting views, evenly spread over the training views."""
    min_share: float = MERGE_MIN_SHARE
    """Share of the views seeing two same-class instances in which one 2D segment must hold both to merge them."""
    min_views: int = 2
    """Fewest views that must see both for them to merge."""
    min_support_views: int = 0
    """Instances confirmed by the 2D thing segments in fewer of the voting views fold like crumbs (step 2; 0 = off)."""
    min_confidence: float = 0.0
    """Instances (after merging) whose points' mean class probability is below this fold like crumbs (0 = off)."""
    keep_confirmed_views: int = 0
    """An instance to fold that the 2D segments confirm as its own class in at least this many voting views does
    not change class: it folds only into its own class, else stays (0 = off; needs :func:`class_segments` ids)."""


def clean_instances(xyz: np.ndarray, xyz_world: np.ndarray, semantic: np.ndarray, instance: np.ndarray, *,
                    cameras, frames: np.ndarray, segments_of: Callable[[int], np.ndarray], link_radius: float,
                    crumb_points: int, rules: CleanupRules = CleanupRules(), confidence: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """Merge fragments, then fold crumbs and unsure instances (see the module docstring).

    Parameters
    ----------
    xyz : np.ndarray
        ``[N, 3]`` points in the export frame (``link_radius`` is in its units).
    xyz_world : np.ndarray
        The same points in the cameras' world frame.
    semantic, instance : np.ndarray
        ``[N]`` class and instance ids (:func:`lift3d.export.instances.assign_instances`).
    cameras, frames, segments_of
        Views and their 2D thing segments (:func:`segment_votes`).
    link_radius : float
        The instance link radius; crumbs look for their neighbour within 4 × this.
    crumb_points : int
        Instances with fewer points are crumbs (0 = keep every instance).
    rules : CleanupRules
        What merges and what else folds like crumbs.
    confidence : np.ndarray, optional
        ``[N]`` probability of each point's class; needed when ``rules.min_confidence`` > 0.

    Returns
    -------
    semantic, instance, keep, stats
        Instance ids contiguous ``1..K`` by size as :func:`~lift3d.export.instances.assign_instances` gives
        them; ``keep`` False for dropped crumbs; ``stats`` the counts for ``metadata.json``.
    """
    merge, max_views, min_share, min_views = rules.merge, rules.max_views, rules.min_share, rules.min_views
    min_support_views, min_confidence = rules.min_support_views, rules.min_confidence
    semantic = np.asarray(semantic, np.int32).copy()
    instance = np.asarray(instance, np.int64)
    stats: dict[str, Any] = {"instances_before": count_instances(instance), "fragments_merged": 0,
                             "merge": {"views": int(min(max_views, len(frames))), "min_share": float(min_share),
                                       "min_views": int(min_views)} if merge else "off",
                             "crumb_points": int(crumb_points)}
    keep_views = int(rules.keep_confirmed_views)
    votes = None
    if (merge and stats["instances_before"] > 1) or ((min_support_views > 0 or keep_views > 0)
                                                      and stats["instances_before"]):
        votes = segment_votes(xyz_world, instance, cameras, frames, segments_of, max_views=max_views)
    before = instance
    if merge and stats["instances_before"] > 1:
        instance, stats["fragments_merged"] = merge_fragments(instance, instance_classes(semantic, instance), votes,
                                                              min_share=min_share, min_views=min_views)
    stats["after_merge"] = count_instances(instance)
    support = None
    stats["min_support_views"] = 0
    stats["unsupported"] = 0
    if votes is not None and min_support_views > 0:
        stats["min_support_views"] = need = int(min_support_views)
        support = supporting_views(votes, before, instance)
    keep = np.ones(len(instance), bool)
    # Components in the sense of _relabel_fragments: instance id - 1 on things, -1 on stuff.
    component = np.where(instance > 0, instance - 1, -1)
    crumb_stats = {"fragments_relabelled": 0, "fragment_points_relabelled": 0, "fragments_dropped": 0,
                   "fragment_points_dropped": 0}
    thing = component >= 0
    in_crumb = np.zeros(len(component), bool)
    if crumb_points > 0 and thing.any():
        sizes = np.bincount(component[thing])
        in_crumb[thing] = sizes[component[thing]] < crumb_points
    stats["min_confidence"] = float(min_confidence)
    stats["unsure"] = 0
    if support is not None and thing.any():
        unsupported = (instance > 0) & (support[instance] < need)
        # Counted among the instances that are not crumbs already (those fold anyway).
        stats["unsupported"] = count_instances(instance[unsupported & ~in_crumb])
        # One with nothing around it to fold into keeps its points (and its id): the geometry is not in doubt.
        stay = set(np.unique(component[unsupported & ~in_crumb]).tolist())
        in_crumb |= unsupported
    else:
        stay = set()
    if min_confidence > 0 and thing.any():
        if confidence is None:
            raise ValueError("clean_instances: min_confidence > 0 needs the points' confidence")
        sizes = np.bincount(component[thing])
        mean_conf = np.bincount(component[thing], weights=np.asarray(confidence, np.float64)[thing]) / \
            np.maximum(sizes, 1)
        unsure = (mean_conf < min_confidence) & (sizes >= max(crumb_points, 1))
        stats["unsure"] = int(unsure.sum())
        in_crumb[thing] |= unsure[component[thing]]
        # An unsure instance with nothing sure around it (a field that is unsure everywhere) stays.
        stay |= set(np.flatnonzero(unsure).tolist())
    stats["keep_confirmed_views"] = keep_views
    stats["confirmed_kept"] = 0
    if in_crumb.any():
        guard = votes is not None and keep_views > 0
        if guard:
            before_class, before_component = semantic.copy(), component.copy()
        _relabel_fragments(np.asarray(xyz, np.float64), semantic, component, in_crumb, keep, 4.0 * link_radius,
                           crumb_stats, stay_when_isolated=stay)
        if guard:
            # Confirmed things that folded into another class go back to what they were.
            confirmed = confirming_views(votes, before, instance, instance_classes(before_class, before))
            back = in_crumb & (instance > 0) & (confirmed[np.maximum(instance, 0)] >= keep_views) \
                & (semantic != before_class)
            semantic[back], component[back], keep[back] = before_class[back], before_component[back], True
            stats["confirmed_kept"] = count_instances(instance[back])
    stats.update(crumbs_folded=crumb_stats["fragments_relabelled"], crumbs_dropped=crumb_stats["fragments_dropped"],
                 crumb_points_moved=crumb_stats["fragment_points_relabelled"],
                 crumb_points_dropped=crumb_stats["fragment_points_dropped"])
    new = _contiguous_ids(np.asarray(xyz, np.float64), component, keep)
    new[component < 0] = 0
    stats["instances_after"] = count_instances(new[keep])
    return semantic, new.astype(np.int32), keep, stats
