"""3D metrics: a labelled predicted point cloud against labelled GT points (docs/metrics.md).

Labels are transferred from the prediction to the GT points by nearest
neighbour (``scipy.spatial.cKDTree``) within ``tau``; the point labels are then
scored with the same :func:`~lift3d.eval.metrics.miou` and
:func:`~lift3d.eval.metrics.pq_scene` as images (points play the part of the
pixels of one frame).  Geometry is scored with accuracy / completeness /
Chamfer distance and precision / recall / F-score at ``tau``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from lift3d.eval.metrics import miou as _miou
from lift3d.eval.metrics import pq_scene as _pq_scene

__all__ = ["points3d", "nearest_distances"]

_CHUNK = 1 << 20  # query points per cKDTree call


def _xyz(a, name: str) -> np.ndarray:
    x = np.asarray(a, dtype=np.float64)
    if x.size == 0:
        return x.reshape(0, 3)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"{name}: expected an N×3 array of points, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name}: contains non-finite coordinates")
    return x


def _labels(a, n: int, name: str) -> np.ndarray:
    x = np.asarray(a)
    if x.size == 0 and n == 0:
        return np.zeros(0, np.int64)
    x = x.ravel()
    if x.shape[0] != n:
        raise ValueError(f"{name}: expected {n} labels (one per point), got {x.shape[0]}")
    if not np.issubdtype(x.dtype, np.integer):
        raise TypeError(f"{name}: expected integer labels, got dtype {x.dtype}")
    return x


def nearest_distances(query: np.ndarray, tree: cKDTree | None, chunk: int = _CHUNK):
    """Distance to, and index of, the nearest tree point for every query point.

    Queries run in chunks of ``chunk`` points on all cores.  With no tree (an
    empty reference cloud) distances are ``inf`` and indices ``-1``.

    Examples
    --------
    >>> d, i = nearest_distances(np.array([[0.0, 0, 0], [3, 0, 0]]), cKDTree([[1.0, 0, 0]]))
    >>> d.tolist(), i.tolist()
    ([1.0, 2.0], [0, 0])
    """
    n = len(query)
    dist = np.full(n, np.inf)
    idx = np.full(n, -1, dtype=np.int64)
    if tree is None or n == 0:
        return dist, idx
    for s in range(0, n, chunk):
        d, i = tree.query(query[s : s + chunk], k=1, workers=-1)
        dist[s : s + chunk] = d
        idx[s : s + chunk] = i
    return dist, idx


def points3d(
    pred_xyz,
    pred_sem,
    pred_inst,
    gt_xyz,
    gt_sem,
    gt_inst,
    tau: float | None = None,
    things=None,
    stuff=None,
    min_area: float = 0.005,
    min_instance_points: int = 500,
) -> dict:
    """Label and geometry metrics of a predicted labelled point cloud against GT points.

    Every GT point takes the semantic and instance label of the nearest
    predicted point if that point is within ``tau`` (distance ``<= tau``);
    otherwise it gets a void prediction (semantic 0, instance 0).  GT points
    with semantic 0 are GT-void and are not scored by ``miou`` / ``pq``.

    Parameters
    ----------
    pred_xyz : array_like, (P, 3)
        Predicted points (may be empty).
    pred_sem, pred_inst : array_like of int, (P,)
        Their semantic (0 = void) and instance ids.
    gt_xyz : array_like, (M, 3)
        GT points (at least one).
    gt_sem, gt_inst : array_like of int, (M,)
        GT semantic (0 = void) and scene-consistent instance ids.
    tau : float, optional
        Distance threshold; default 1 % of the diagonal of the GT bounding box.
    things, stuff : iterable of int, optional
        Class sets for PQ.  By default every non-void class present in GT or
        prediction; a class is a thing when any of its GT points has a nonzero
        instance id (for classes absent from the GT: any of its predicted
        points).  When only one set is given, the other is the remaining
        present classes.
    min_area : float
        Class-area filter of ``miou`` and ``pq``: a class under this fraction of the scored GT points in the
        prediction and in the GT (mIoU) or in either (PQ) is not scored, as in the 2D metrics (docs/metrics.md
        section 4; default 0.005). The ``*_strict`` keys are the same metrics at 0.
    min_instance_points : int
        GT thing instances with at least this many GT points count for ``instance_recall``.

    Returns
    -------
    dict
        ``miou``, ``pq``, ``sq``, ``rq`` (point labels at ``min_area``; NaN if no class to score) and
        ``miou_strict``, ``pq_strict``, ``sq_strict``, ``rq_strict`` (at ``min_area`` 0),
        ``accuracy`` (mean distance from each predicted point to its nearest GT
        point), ``completeness`` (mean distance from each GT point to its
        nearest predicted point), ``chamfer`` (mean of the two), ``precision``
        (fraction of predicted points within ``tau`` of the GT), ``recall``
        (fraction of GT points within ``tau`` of the prediction), ``fscore``
        (harmonic mean, 0 when both are 0), ``tau``, ``n_pred``, ``n_gt``,
        ``things``, ``stuff``, ``instance_recall`` (fraction of GT thing
        instances with at least ``min_instance_points`` points that one
        predicted instance covers with point IoU > 0.5, class-agnostic; NaN
        when there is none) with ``n_instances`` (how many were scored), and
        the full ``pq_detail`` / ``miou_detail`` dicts, ``objects`` (:func:`object_recovery`: per GT object its
        size and best point IoU).  With an empty prediction: accuracy, completeness and chamfer
        are ``inf``; precision, recall, F-score, mIoU, PQ, SQ, RQ are 0 as
        long as the GT has a non-void class.

    Examples
    --------
    >>> gt = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    >>> sem = np.array([1, 1, 2, 2]); inst = np.array([5, 5, 0, 0])
    >>> r = points3d(gt + [0.001, 0, 0], sem, inst, gt, sem, inst, tau=0.01)
    >>> r["miou"], r["pq"], r["fscore"], round(r["chamfer"], 6)
    (1.0, 1.0, 1.0, 0.001)
    """
    gx = _xyz(gt_xyz, "gt_xyz")
    px = _xyz(pred_xyz, "pred_xyz")
    m, n = len(gx), len(px)
    if m == 0:
        raise ValueError("points3d: the GT point cloud is empty")
    gs = _labels(gt_sem, m, "gt_sem")
    gi = _labels(gt_inst, m, "gt_inst")
    ps = _labels(pred_sem, n, "pred_sem")
    pi = _labels(pred_inst, n, "pred_inst")

    if tau is None:
        tau = 0.01 * float(np.linalg.norm(gx.max(axis=0) - gx.min(axis=0)))
    tau = float(tau)
    if not (tau >= 0 and np.isfinite(tau)):
        raise ValueError(f"points3d: tau must be a finite non-negative distance, got {tau}")

    geo = geometry3d(px, gx, tau)
    d_gt, nn = geo.pop("_gt_to_pred")
    geo.pop("_pred_to_gt")
    # label transfer: nearest prediction within tau, else void.
    reach = d_gt <= tau
    t_sem = np.zeros(m, dtype=np.int64)
    t_inst = np.zeros(m, dtype=np.int64)
    t_sem[reach] = ps[nn[reach]]
    t_inst[reach] = pi[nn[reach]]
    accuracy, completeness, chamfer = geo["accuracy"], geo["completeness"], geo["chamfer"]
    precision, recall, fscore = geo["precision"], geo["recall"], geo["fscore"]

    # classes for PQ.
    things_s, stuff_s = _default_classes(ps, pi, gs, gi, things, stuff)

    mi = _miou(t_sem, gs, min_area=min_area, void=0)
    pq = _pq_scene(t_sem, t_inst, gs, gi, things_s, stuff_s, min_area=min_area, void=0)
    mi_strict = _miou(t_sem, gs, min_area=0.0, void=0)
    pq_strict = _pq_scene(t_sem, t_inst, gs, gi, things_s, stuff_s, min_area=0.0, void=0)
    found, scored = instance_recall(t_inst, gs, gi, things_s, min_points=min_instance_points)
    objects = object_recovery(gx, t_inst, gs, gi, things_s)
    return {
        "miou": mi["miou"],
        "pq": pq["pq"],
        "sq": pq["sq"],
        "rq": pq["rq"],
        "miou_strict": mi_strict["miou"],
        "pq_strict": pq_strict["pq"],
        "sq_strict": pq_strict["sq"],
        "rq_strict": pq_strict["rq"],
        "min_area": float(min_area),
        "accuracy": accuracy,
        "completeness": completeness,
        "chamfer": chamfer,
        "precision": precision,
        "recall": recall,
        "fscore": float(fscore),
        "tau": tau,
        "n_pred": int(n),
        "n_gt": int(m),
        "things": sorted(things_s),
        "stuff": sorted(stuff_s),
        "instance_recall": found / scored if scored else float("nan"),
        "n_instances": scored,
        "pq_detail": pq,
        "miou_detail": mi,
        "objects": objects,
    }


def geometry3d(pred_xyz, gt_xyz, tau: float) -> dict:
    """Geometry of a predicted point cloud against GT points: ``accuracy`` (mean distance from each predicted
    point to the GT), ``completeness`` (from each GT point to the prediction), ``chamfer`` (their mean),
    ``precision`` / ``recall`` (shares within ``tau``), ``fscore``, ``tau``, ``n_pred``, ``n_gt``; under
    ``_gt_to_pred``, each GT point's distance to and index of its nearest predicted point (for label transfer), and
    under ``_pred_to_gt`` each predicted point's distance to the GT (callers pop both).

    Examples
    --------
    >>> gt = np.array([[0.0, 0, 0], [1, 0, 0]])
    >>> g = geometry3d(np.array([[0.0, 0, 0.005], [5, 5, 5]]), gt, tau=0.01)
    >>> g["precision"], g["recall"], round(g["fscore"], 3)
    (0.5, 0.5, 0.5)
    """
    gx, px = _xyz(gt_xyz, "gt_xyz"), _xyz(pred_xyz, "pred_xyz")
    n = len(px)
    d_gt, nn = nearest_distances(gx, cKDTree(px) if n else None)  # GT -> prediction
    d_pred = np.zeros(0)
    if n:
        d_pred, _ = nearest_distances(px, cKDTree(gx))  # prediction -> GT
        accuracy, completeness, precision = float(d_pred.mean()), float(d_gt.mean()), float(np.mean(d_pred <= tau))
    else:
        accuracy = completeness = float("inf")
        precision = 0.0
    recall = float(np.mean(d_gt <= tau))
    fscore = 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)
    return {"accuracy": accuracy, "completeness": completeness, "chamfer": 0.5 * (accuracy + completeness),
            "precision": precision, "recall": recall, "fscore": float(fscore), "tau": float(tau), "n_pred": int(n),
            "n_gt": int(len(gx)), "_gt_to_pred": (d_gt, nn), "_pred_to_gt": d_pred}


def instance_recall(pred_inst, gt_sem, gt_inst, things, min_points: int = 500) -> tuple[int, int]:
    """How many GT thing instances one predicted instance recovers (point IoU > 0.5), of how many scored.

    Every array is per GT point: ``pred_inst`` is the instance id transferred from the prediction (0 =
    none). A GT instance is a (class, id) pair of a thing class with at least ``min_points`` points; it is
    found when some predicted id ``p`` ≠ 0 has ``|G ∩ P| / |G ∪ P| > 0.5`` over the GT points, where ``P``
    is the set of GT points labelled ``p``. IoU > 0.5 makes the match unique, so no assignment is needed.

    Examples
    --------
    >>> gs = np.array([3, 3, 3, 3, 4, 4]); gi = np.array([1, 1, 1, 1, 2, 2])
    >>> instance_recall(np.array([7, 7, 7, 0, 9, 8]), gs, gi, things={3, 4}, min_points=2)
    (1, 2)
    """
    pred_inst = np.asarray(pred_inst, dtype=np.int64)
    gt_sem = np.asarray(gt_sem, dtype=np.int64)
    gt_inst = np.asarray(gt_inst, dtype=np.int64)
    on_thing = np.isin(gt_sem, list(things)) & (gt_inst != 0)
    if not on_thing.any():
        return 0, 0
    keys, gt_id, gt_size = np.unique(np.stack([gt_sem[on_thing], gt_inst[on_thing]], 1), axis=0,
                                     return_inverse=True, return_counts=True)
    gt_id = gt_id.reshape(-1)
    pred_ids, pred_of_point, pred_size = np.unique(pred_inst, return_inverse=True, return_counts=True)
    pred_of_point = pred_of_point.reshape(-1)[on_thing]
    # Intersections: how many points of each GT instance carry each predicted id.
    pairs, inter = np.unique(np.stack([gt_id, pred_of_point], 1), axis=0, return_counts=True)
    union = gt_size[pairs[:, 0]] + pred_size[pairs[:, 1]] - inter
    hit = (inter / union > 0.5) & (pred_ids[pairs[:, 1]] != 0)
    big = gt_size >= min_points
    found = np.zeros(len(keys), dtype=bool)
    found[pairs[hit, 0]] = True
    return int((found & big).sum()), int(big.sum())


def object_recovery(gt_xyz, pred_inst, gt_sem, gt_inst, things) -> list[dict]:
    """Per GT thing instance: its class, GT point count, size (the largest side of its points' axis-aligned
    box, world units) and the best point IoU any one predicted instance reaches on it (as
    :func:`instance_recall` measures it; 0 when none overlaps). Sorted by size, smallest first.

    Examples
    --------
    >>> xyz = np.array([[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [5, 5, 5], [5, 5.4, 5.0]])
    >>> gs = np.array([3, 3, 3, 4, 4]); gi = np.array([1, 1, 1, 2, 2])
    >>> [(r["class_id"], r["size"], round(r["iou"], 2)) for r in object_recovery(xyz, [7, 7, 0, 9, 9], gs, gi, {3, 4})]
    [(3, 0.2, 0.67), (4, 0.4, 1.0)]
    """
    gt_xyz = np.asarray(gt_xyz, np.float64)
    pred_inst = np.asarray(pred_inst, np.int64)
    gt_sem, gt_inst = np.asarray(gt_sem, np.int64), np.asarray(gt_inst, np.int64)
    on_thing = np.isin(gt_sem, list(things)) & (gt_inst != 0)
    out = []
    if not on_thing.any():
        return out
    pred_ids, pred_size = np.unique(pred_inst, return_counts=True)
    size_of = dict(zip(pred_ids.tolist(), pred_size.tolist()))
    keys = np.unique(np.stack([gt_sem[on_thing], gt_inst[on_thing]], 1), axis=0)
    for c, g in keys:
        mine = (gt_sem == c) & (gt_inst == g)
        ids, inter = np.unique(pred_inst[mine], return_counts=True)
        n = int(mine.sum())
        ious = [k / (n + size_of[int(p)] - k) for p, k in zip(ids, inter) if p != 0]
        extent = np.ptp(gt_xyz[mine], axis=0) if n > 1 else np.zeros(3)
        out.append({"class_id": int(c), "instance": int(g), "points": n, "size": round(float(extent.max()), 4),
                    "iou": float(max(ious)) if ious else 0.0})
    return sorted(out, key=lambda r: (r["size"], r["class_id"], r["instance"]))


def _default_classes(ps, pi, gs, gi, things, stuff):
    """things / stuff sets: as given, else derived from the classes present."""
    gcls = np.unique(gs)
    pcls = np.unique(ps)
    present = (set(gcls.tolist()) | set(pcls.tolist())) - {0}
    gt_thing = set(np.unique(gs[gi != 0]).tolist())
    pred_thing = set(np.unique(ps[pi != 0]).tolist())
    auto_things = {c for c in present if c in gt_thing or (c not in set(gcls.tolist()) and c in pred_thing)}
    if things is None and stuff is None:
        return auto_things, present - auto_things
    if things is None:
        stuff_s = {int(c) for c in stuff}
        return present - stuff_s - {0}, stuff_s
    things_s = {int(c) for c in things}
    if stuff is None:
        return things_s, present - things_s - {0}
    return things_s, {int(c) for c in stuff}
