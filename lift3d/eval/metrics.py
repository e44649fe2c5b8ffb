"""2D evaluation metrics on plain numpy arrays: PQ^scene, mIoU, PSNR, depth errors.

Every function here takes numpy arrays (anything ``np.asarray`` accepts) and
returns plain Python numbers / dicts, so the results can go straight into
``metrics.json``.  The exact definitions are those of docs/metrics.md; they
reproduce Panoptic Lifting's evaluator (``util/panoptic_quality.py`` and
``util/metrics.py``) bit for bit where it matters:

* the ``min_area`` class filter of :func:`pq_scene` compares the class-area
  fraction in float32, and so does every per-segment IoU and "more than half
  void" test, as the reference (torch integer division) does;
* the ``min_area`` class filter of :func:`miou` compares in float64 (the
  reference keeps its confusion matrix in float64).

Everything is vectorised: pixels are turned into small dense integer ids
(``np.bincount`` + lookup tables, ``np.unique`` only when ids are too sparse),
segment areas and intersections come from one ``np.bincount`` of integer pair
keys, and Python loops only ever run over segments or classes.
"""

from __future__ import annotations

import math
import time
from typing import Iterable

import numpy as np

__all__ = [
    "pq_scene",
    "miou",
    "confusion_matrix",
    "psnr",
    "psnr_per_image",
    "depth_error",
    "benchmark_pq_scene",
]

# Largest value span turned into a dense id through a bincount lookup table
# (8M entries: 64 MB of int64 counts).  Sparser ids fall back to np.unique.
_LUT_LIMIT = 1 << 23


# --------------------------------------------------------------------------- helpers


def _small_uint(n: int) -> np.dtype:
    """Smallest unsigned dtype that holds the values ``0 .. n``."""
    for dt in (np.uint8, np.uint16, np.uint32):
        if n <= np.iinfo(dt).max:
            return np.dtype(dt)
    return np.dtype(np.uint64)


def _as_int_array(x, name: str) -> np.ndarray:
    a = np.asarray(x)
    if a.dtype == bool:
        a = a.astype(np.uint8)
    if not np.issubdtype(a.dtype, np.integer):
        if a.size and np.issubdtype(a.dtype, np.floating) and np.all(np.mod(a, 1) == 0):
            a = a.astype(np.int64)
        else:
            raise TypeError(f"{name}: expected an integer label array, got dtype {a.dtype}")
    return a


def _shifted_intp(x: np.ndarray, lo: int) -> np.ndarray:
    """``x - lo`` as a non-negative intp array (what np.bincount needs)."""
    if lo == 0:
        return x.astype(np.intp, copy=False)
    return np.subtract(x, lo, dtype=np.intp)


def _dense_ids(x: np.ndarray):
    """Dense ids of an integer array.

    Returns ``(values, ids, counts)``: the sorted distinct values, ``ids`` (same
    shape as ``x``, smallest unsigned dtype) with ``values[ids] == x``, and how
    often each value occurs.
    """
    x = np.asarray(x).ravel()
    if x.size == 0:
        return x[:0].astype(np.int64), np.zeros(0, np.uint8), np.zeros(0, np.int64)
    lo, hi = int(x.min()), int(x.max())
    if lo >= 0 and hi < _LUT_LIMIT:
        lo = 0  # small non-negative ids: index directly, no shifted copy
    span = hi - lo + 1
    if span <= _LUT_LIMIT:
        sx = _shifted_intp(x, lo)
        counts = np.bincount(sx, minlength=span)
        present = np.flatnonzero(counts)
        dt = _small_uint(max(len(present) - 1, 0))
        lut = np.zeros(span, dtype=dt)
        lut[present] = np.arange(len(present), dtype=dt)
        ids = lut[sx]
        return present.astype(np.int64) + lo, ids, counts[present].astype(np.int64)
    values, ids, counts = np.unique(x, return_inverse=True, return_counts=True)
    ids = ids.ravel().astype(_small_uint(max(len(values) - 1, 0)))
    return values.astype(np.int64), ids, counts.astype(np.int64)


def _value_counts(x: np.ndarray):
    """Sorted distinct values of an integer array and their counts."""
    x = np.asarray(x).ravel()
    if x.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    lo, hi = int(x.min()), int(x.max())
    if lo >= 0 and hi < _LUT_LIMIT:
        lo = 0
    if hi - lo + 1 <= _LUT_LIMIT:
        counts = np.bincount(_shifted_intp(x, lo), minlength=hi - lo + 1)
        present = np.flatnonzero(counts)
        return present.astype(np.int64) + lo, counts[present].astype(np.int64)
    values, counts = np.unique(x, return_counts=True)
    return values.astype(np.int64), counts.astype(np.int64)


def _map_to_index(x: np.ndarray, keys: np.ndarray, default: int) -> np.ndarray:
    """Index of each element of ``x`` in the sorted array ``keys``; ``default`` if absent."""
    x = np.asarray(x).ravel()
    dt = _small_uint(max(default, len(keys)))
    if x.size == 0:
        return np.zeros(0, dt)
    lo, hi = int(x.min()), int(x.max())
    if lo >= 0 and hi < _LUT_LIMIT:
        lo = 0
    if hi - lo + 1 <= _LUT_LIMIT:
        lut = np.full(hi - lo + 1, default, dtype=dt)
        inside = (keys >= lo) & (keys <= hi)
        lut[keys[inside] - lo] = np.flatnonzero(inside).astype(dt)
        return lut[_shifted_intp(x, lo)]
    if len(keys) == 0:
        return np.full(x.shape, default, dtype=dt)
    pos = np.searchsorted(keys, x)
    pos_c = np.minimum(pos, len(keys) - 1)
    hit = keys[pos_c] == x
    return np.where(hit, pos_c, default).astype(dt)


def _frames(a: np.ndarray, name: str) -> np.ndarray:
    if a.ndim == 2:
        return a[None]
    if a.ndim != 3 and a.ndim != 1:
        raise ValueError(f"{name}: expected F×H×W frames or one H×W frame, got shape {a.shape}")
    return a


def _class_set(c, name: str) -> set[int]:
    if c is None:
        return set()
    if isinstance(c, (int, np.integer)):
        return {int(c)}
    return {int(v) for v in np.asarray(list(c), dtype=np.int64).ravel()}


def _mean_or_nan(v: np.ndarray) -> float:
    return float(np.mean(v)) if len(v) else float("nan")


# --------------------------------------------------------------------------- PQ^scene


def pq_scene(
    pred_sem,
    pred_inst,
    gt_sem,
    gt_inst,
    things: Iterable[int],
    stuff: Iterable[int],
    min_area: float = 0.005,
    void: int = 0,
) -> dict:
    """Scene-level panoptic quality (PQ^scene of Panoptic Lifting).

    All frames are evaluated together: a thing segment is every pixel, across
    all frames, with the same (class, instance id), so instance ids must be
    consistent across frames to score well.  The rules (docs/metrics.md):

    1. pixels whose GT semantic is ``void`` are dropped, in prediction and GT;
    2. the remaining pixels of all frames form one list;
    3. classes of ``things`` ∪ ``stuff`` present in neither list are dropped, and
       so is a class covering less than ``min_area`` of the pixels in the
       prediction OR in the GT (fraction computed in float32).  Pixels of
       dropped classes, and predicted pixels of classes outside things ∪ stuff
       (including predicted ``void``), become void in their own list;
    4. stuff pixels get instance 0 (one segment per stuff class);
    5. a predicted and a GT segment of the same class match when
       IoU > 0.5 with union = |P| − |P ∩ GT-void| + |G| − |G ∩ pred-void| − |P ∩ G|
       (IoU computed in float32, as the reference);
    6. an unmatched GT segment is a FN unless more than half of it is predicted
       void; an unmatched predicted segment is a FP unless more than half of it
       lies on GT void (void here includes the dropped classes);
    7. per class PQ = ΣIoU / (TP + FP/2 + FN/2), SQ = ΣIoU / TP, RQ = TP / (TP + FP/2 + FN/2),
       each 0 when its denominator is 0 (such a kept class still counts in the mean).

    Parameters
    ----------
    pred_sem, pred_inst, gt_sem, gt_inst : array_like of int
        F×H×W stacks of frames (or one H×W frame, or a flat list of pixels),
        any integer dtype, all of the same shape.  ``gt_inst`` must be
        scene-consistent; instance ids of stuff pixels are ignored.
    things, stuff : iterable of int
        Disjoint class-id sets.  ``void`` must be in neither.
    min_area : float
        Minimum class-area fraction (0.005 = published numbers, 0 = strict).
    void : int
        Semantic id of void.

    Returns
    -------
    dict
        ``pq``, ``sq``, ``rq``: plain means over the kept classes (things and stuff
        together); ``n_classes``: number of kept classes; ``per_class``:
        ``{class_id: {iou_sum, tp, fp, fn, pq, sq, rq, isthing}}`` for the kept
        classes; ``things`` and ``stuff``: ``{pq, sq, rq, n}`` over that subset;
        ``dropped_classes``: classes of things ∪ stuff removed by the area
        filter; ``min_area``.  Any mean over an empty set of classes (no kept
        class at all, or no kept thing / stuff class) is ``float('nan')``,
        never ``None``, with ``n`` (or ``n_classes``) 0.

    Examples
    --------
    >>> import numpy as np
    >>> gt_sem = np.array([[1, 1, 2, 2]]); gt_inst = np.array([[7, 7, 0, 0]])
    >>> pred_sem = np.array([[1, 1, 2, 1]]); pred_inst = np.array([[3, 3, 0, 3]])
    >>> r = pq_scene(pred_sem, pred_inst, gt_sem, gt_inst, things={1}, stuff={2}, min_area=0)
    >>> round(r["pq"], 4), round(r["per_class"][1]["sq"], 4), r["per_class"][2]["tp"]
    (0.3333, 0.6667, 0)

    (class 2 has IoU exactly 0.5, which is not a match: one FP and one FN.)
    """
    ps = _as_int_array(pred_sem, "pred_sem")
    pi = _as_int_array(pred_inst, "pred_inst")
    gs = _as_int_array(gt_sem, "gt_sem")
    gi = _as_int_array(gt_inst, "gt_inst")
    shapes = {a.shape for a in (ps, pi, gs, gi)}
    if len(shapes) != 1:
        raise ValueError(
            "pq_scene: pred_sem, pred_inst, gt_sem, gt_inst must have the same shape, got "
            f"{ps.shape}, {pi.shape}, {gs.shape}, {gi.shape}"
        )
    _frames(ps, "pred_sem")
    things_s, stuff_s = _class_set(things, "things"), _class_set(stuff, "stuff")
    if things_s & stuff_s:
        raise ValueError(f"pq_scene: classes {sorted(things_s & stuff_s)} are in both things and stuff")
    if void in things_s or void in stuff_s:
        raise ValueError(f"pq_scene: the void id {void} cannot be a thing or stuff class")
    if not 0.0 <= min_area < 1.0:
        raise ValueError(f"pq_scene: min_area must be in [0, 1), got {min_area}")

    # 1.-2. drop GT void, concatenate the frames.
    valid = gs != void
    if valid.all():
        ps, pi, gs, gi = ps.ravel(), pi.ravel(), gs.ravel(), gi.ravel()
    else:
        ps, pi, gs, gi = ps[valid], pi[valid], gs[valid], gi[valid]
    del valid
    n_pix = ps.size

    # 3. class filter.
    pv, pc = _value_counts(ps)
    gv, gc = _value_counts(gs)
    candidates = np.array(sorted(things_s | stuff_s), dtype=np.int64)
    present = np.isin(candidates, pv) | np.isin(candidates, gv)
    candidates = candidates[present]
    dropped: list[int] = []
    if min_area > 0 and n_pix > 0:
        thr = np.float32(min_area)
        tot = np.float32(n_pix)
        small = set(pv[(pc.astype(np.float32) / tot) < thr].tolist())
        small |= set(gv[(gc.astype(np.float32) / tot) < thr].tolist())
        keep = np.array([c not in small for c in candidates.tolist()], dtype=bool)
        dropped = candidates[~keep].tolist()
        candidates = candidates[keep]
    kept = candidates  # sorted class ids
    nk = len(kept)
    is_thing = np.zeros(nk + 1, dtype=bool)  # index nk is void
    is_thing[:nk] = np.isin(kept, np.array(sorted(things_s), dtype=np.int64))

    # class index per pixel: 0..nk-1 kept, nk void.
    pk = _map_to_index(ps, kept, nk)
    gk = _map_to_index(gs, kept, nk)
    del ps, gs

    # 4. segments.
    p_seg, p_cls, p_area = _segments(pk, pi, is_thing)
    g_seg, g_cls, g_area = _segments(gk, gi, is_thing)
    del pk, gk, pi, gi
    n_p, n_g = len(p_cls), len(g_cls)

    # intersections of every (pred segment, GT segment) pair that overlaps.
    if n_p * n_g <= _LUT_LIMIT:
        key = p_seg.astype(np.intp) * n_g + g_seg
        inter_full = np.bincount(key, minlength=n_p * n_g)
        del key
        pair = np.flatnonzero(inter_full)
        inter = inter_full[pair].astype(np.int64)
        del inter_full
    else:
        key = p_seg.astype(np.int64) * n_g + g_seg
        pair, inter = np.unique(key, return_counts=True)
        del key
    del p_seg, g_seg
    ip = (pair // n_g).astype(np.int64)
    ig = (pair % n_g).astype(np.int64)

    p_void = np.flatnonzero(p_cls == nk)  # at most one void segment per side
    g_void = np.flatnonzero(g_cls == nk)
    pred_on_gvoid = np.zeros(n_p, np.int64)  # |P ∩ GT-void|
    gt_on_pvoid = np.zeros(n_g, np.int64)  # |G ∩ pred-void|
    if len(g_void):
        m = ig == g_void[0]
        pred_on_gvoid[ip[m]] = inter[m]
    if len(p_void):
        m = ip == p_void[0]
        gt_on_pvoid[ig[m]] = inter[m]

    # 5. matching.
    cand = (p_cls[ip] == g_cls[ig]) & (g_cls[ig] != nk)
    cp, cg, ci = ip[cand], ig[cand], inter[cand]
    union = p_area[cp] - pred_on_gvoid[cp] + g_area[cg] - gt_on_pvoid[cg] - ci
    iou = ci.astype(np.float32) / union.astype(np.float32)
    match = iou > 0.5
    mp, mg, miou_ = cp[match], cg[match], iou[match].astype(np.float64)
    m_cls = g_cls[mg]
    iou_sum = np.bincount(m_cls, weights=miou_, minlength=nk)[:nk] if nk else np.zeros(0)
    tp = np.bincount(m_cls, minlength=nk)[:nk]

    # 6. unmatched segments.
    g_unmatched = np.ones(n_g, bool)
    g_unmatched[mg] = False
    g_unmatched &= g_cls != nk
    g_mostly_void = (gt_on_pvoid.astype(np.float32) / g_area.astype(np.float32)) > 0.5
    fn = np.bincount(g_cls[g_unmatched & ~g_mostly_void], minlength=nk)[:nk]
    p_unmatched = np.ones(n_p, bool)
    p_unmatched[mp] = False
    p_unmatched &= p_cls != nk
    p_mostly_void = (pred_on_gvoid.astype(np.float32) / p_area.astype(np.float32)) > 0.5
    fp = np.bincount(p_cls[p_unmatched & ~p_mostly_void], minlength=nk)[:nk]

    # 7. per class and means.
    den = tp + 0.5 * fp + 0.5 * fn
    with np.errstate(divide="ignore", invalid="ignore"):
        pq_c = np.where(den > 0, iou_sum / np.where(den > 0, den, 1), 0.0)
        sq_c = np.where(tp > 0, iou_sum / np.maximum(tp, 1), 0.0)
        rq_c = np.where(den > 0, tp / np.where(den > 0, den, 1), 0.0)

    per_class = {}
    for k, c in enumerate(kept.tolist()):
        per_class[int(c)] = {
            "iou_sum": float(iou_sum[k]),
            "tp": int(tp[k]),
            "fp": int(fp[k]),
            "fn": int(fn[k]),
            "pq": float(pq_c[k]),
            "sq": float(sq_c[k]),
            "rq": float(rq_c[k]),
            "isthing": bool(is_thing[k]),
        }
    th = is_thing[:nk]

    def block(sel):
        return {
            "pq": _mean_or_nan(pq_c[sel]),
            "sq": _mean_or_nan(sq_c[sel]),
            "rq": _mean_or_nan(rq_c[sel]),
            "n": int(np.count_nonzero(sel)),
        }

    return {
        "pq": _mean_or_nan(pq_c),
        "sq": _mean_or_nan(sq_c),
        "rq": _mean_or_nan(rq_c),
        "n_classes": int(nk),
        "per_class": per_class,
        "things": block(th),
        "stuff": block(~th),
        "dropped_classes": [int(c) for c in dropped],
        "min_area": float(min_area),
    }


def _segments(cls_k: np.ndarray, inst: np.ndarray, is_thing: np.ndarray):
    """Segment id per pixel from class indices (``nk`` = void) and instance ids.

    Stuff and void pixels get instance 0.  Returns ``(seg_ids, seg_class, seg_area)``.
    """
    thing_pix = is_thing[cls_k]
    inst_full = np.zeros(cls_k.shape, dtype=np.uint8)
    n_inst = 1
    if thing_pix.any():
        _, tid, _ = _dense_ids(inst[thing_pix])
        n_inst = int(tid.max()) + 2
        inst_full = inst_full.astype(_small_uint(n_inst))
        inst_full[thing_pix] = tid + 1  # 0 stays "no instance" (stuff / void)
    del thing_pix
    if n_inst == 1:
        key = cls_k
    else:
        key = cls_k.astype(np.int64) * n_inst + inst_full
    del inst_full
    vals, seg, area = _dense_ids(key)
    return seg, (vals // n_inst).astype(np.int64), area


# --------------------------------------------------------------------------- mIoU


def confusion_matrix(pred, gt, num_classes: int) -> np.ndarray:
    """Confusion matrix of two label arrays.

    Parameters
    ----------
    pred, gt : array_like of int
        Labels of the same shape, each in ``[0, num_classes)``.
    num_classes : int
        Size of the matrix.

    Returns
    -------
    numpy.ndarray
        int64 ``[num_classes, num_classes]``; entry ``[g, p]`` counts the pixels
        with GT label ``g`` and predicted label ``p`` (rows GT, columns prediction).

    Examples
    --------
    >>> confusion_matrix([0, 1, 1, 2], [0, 1, 2, 2], 3)
    array([[1, 0, 0],
           [0, 1, 0],
           [0, 1, 1]])
    """
    p = _as_int_array(pred, "pred").ravel()
    g = _as_int_array(gt, "gt").ravel()
    if p.shape != g.shape:
        raise ValueError(f"confusion_matrix: pred has {p.size} labels, gt has {g.size}")
    n = int(num_classes)
    if n <= 0:
        raise ValueError(f"confusion_matrix: num_classes must be positive, got {num_classes}")
    for a, name in ((p, "pred"), (g, "gt")):
        if a.size and (int(a.min()) < 0 or int(a.max()) >= n):
            raise ValueError(
                f"confusion_matrix: {name} labels must lie in [0, {n}), got [{int(a.min())}, {int(a.max())}]"
            )
    key = g.astype(np.intp) * n
    key += p
    return np.bincount(key, minlength=n * n).reshape(n, n).astype(np.int64)


def miou(pred_sem, gt_sem, min_area: float = 0.005, void: int = 0, num_classes: int | None = None) -> dict:
    """Mean IoU over the GT-valid pixels of all frames (Panoptic Lifting's ConfusionMatrix).

    The confusion matrix covers every label id ``0 .. num_classes-1`` of the
    pixels whose GT is not ``void``.  Note that the predicted ``void`` label is
    an ordinary class here (as in the reference): predicting void on valid
    pixels gives the void class IoU 0, which counts in the mean unless it is
    filtered by ``min_area``.  A class is ignored when it covers less than
    ``min_area`` of the valid pixels in the prediction AND in the GT (float64
    fractions); classes absent from both (IoU 0/0 = NaN) are ignored too.

    Parameters
    ----------
    pred_sem, gt_sem : array_like of int
        Semantic labels, same shape (F×H×W, H×W, or flat), non-negative.
    min_area : float
        Area fraction under which a class absent-enough from both is ignored.
    void : int
        GT label of pixels that are not evaluated.
    num_classes : int, optional
        Size of the confusion matrix; default ``1 + max label`` over both
        (after removing GT-void pixels).  Labels must lie in ``[0, num_classes)``.

    Returns
    -------
    dict
        ``miou`` (float, NaN when no class is left), ``per_class_iou`` (float
        array of length ``num_classes``, NaN where the union is empty),
        ``classes`` (ids averaged), ``ignored`` (ids removed by ``min_area``),
        ``confusion`` (int64 matrix, rows GT, columns prediction),
        ``num_classes``, ``n_pixels``.

    Examples
    --------
    >>> r = miou([1, 1, 2, 2, 0], [1, 1, 2, 1, 0], min_area=0)
    >>> round(r["miou"], 4), r["classes"]
    (0.5833, [1, 2])
    """
    p = _as_int_array(pred_sem, "pred_sem")
    g = _as_int_array(gt_sem, "gt_sem")
    if p.shape != g.shape:
        raise ValueError(f"miou: pred_sem shape {p.shape} differs from gt_sem shape {g.shape}")
    valid = g != void
    if valid.all():
        p, g = p.ravel(), g.ravel()
    else:
        p, g = p[valid], g[valid]
    del valid
    if num_classes is None:
        num_classes = 1 + max(int(p.max()) if p.size else 0, int(g.max()) if g.size else 0)
    cm = confusion_matrix(p, g, num_classes)
    cmf = cm.astype(np.float64)
    inter = np.diag(cmf)
    gt_area = cmf.sum(axis=1)
    pred_area = cmf.sum(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        iou = inter / (gt_area + pred_area - inter)
    total = cmf.sum()
    ignored: list[int] = []
    if min_area > 0 and total > 0:
        small = (pred_area / total < min_area) & (gt_area / total < min_area)
        ignored = [int(c) for c in np.flatnonzero(small & ~np.isnan(iou))]
    else:
        small = np.zeros(num_classes, bool)
    use = ~np.isnan(iou) & ~small
    value = float(np.mean(iou[use])) if use.any() else float("nan")
    return {
        "miou": value,
        "per_class_iou": iou,
        "classes": [int(c) for c in np.flatnonzero(use)],
        "ignored": ignored,
        "confusion": cm,
        "num_classes": int(num_classes),
        "n_pixels": int(total),
    }


# --------------------------------------------------------------------------- images


def psnr(pred, gt, max_val: float = 1.0) -> float:
    """Peak signal-to-noise ratio over all elements: ``10 log10(max_val² / MSE)``.

    Parameters
    ----------
    pred, gt : array_like of float
        Images with values in ``[0, max_val]``, same shape (any shape).
    max_val : float
        Peak value (1.0 for images in [0, 1]).

    Returns
    -------
    float
        PSNR in dB; ``inf`` for identical inputs.

    Examples
    --------
    >>> round(psnr([0.0, 0.5], [0.1, 0.5]), 3)
    23.01
    """
    p = np.asarray(pred, dtype=np.float64)
    g = np.asarray(gt, dtype=np.float64)
    if p.shape != g.shape:
        raise ValueError(f"psnr: pred shape {p.shape} differs from gt shape {g.shape}")
    if p.size == 0:
        raise ValueError("psnr: empty images")
    mse = float(np.mean((p - g) ** 2))
    if mse == 0.0:
        return float("inf")
    return float(10.0 * math.log10(max_val**2 / mse))


def psnr_per_image(pred, gt, max_val: float = 1.0) -> np.ndarray:
    """PSNR of every image of a stack (first axis = image), as a float64 array.

    The usual scene PSNR is the mean of these per-image values.

    Examples
    --------
    >>> a = np.zeros((2, 4, 4, 3)); b = a.copy(); b[1] += 0.1
    >>> np.round(psnr_per_image(b, a), 3)
    array([inf, 20.])
    """
    p = np.asarray(pred, dtype=np.float64)
    g = np.asarray(gt, dtype=np.float64)
    if p.shape != g.shape:
        raise ValueError(f"psnr_per_image: pred shape {p.shape} differs from gt shape {g.shape}")
    if p.ndim < 1 or p.shape[0] == 0:
        raise ValueError("psnr_per_image: expected a non-empty stack of images")
    mse = ((p - g) ** 2).reshape(p.shape[0], -1).mean(axis=1)
    with np.errstate(divide="ignore"):
        return 10.0 * np.log10(max_val**2 / mse)


def depth_error(pred_depth, gt_depth, valid=None) -> dict:
    """Depth errors over the valid pixels (GT > 0 and finite, and ``valid`` if given).

    Parameters
    ----------
    pred_depth, gt_depth : array_like of float
        Depths of the same shape, same units.
    valid : array_like of bool, optional
        Extra mask of pixels to evaluate.

    Returns
    -------
    dict
        ``abs_rel`` = mean(|p − g| / g), ``rmse`` = sqrt(mean((p − g)²)),
        ``mae`` = mean(|p − g|), ``share_over_0.1`` = share of pixels off by more than 0.1 (10 cm in a metric
        scene), ``n_valid``.  With no valid pixel the errors are NaN.  A non-finite prediction on a valid
        pixel propagates.

    Examples
    --------
    >>> r = depth_error([1.0, 2.5, 7.0], [1.0, 2.0, 0.0])
    >>> r["abs_rel"], r["mae"], r["share_over_0.1"], r["n_valid"]
    (0.125, 0.25, 0.5, 2)
    """
    p = np.asarray(pred_depth, dtype=np.float64)
    g = np.asarray(gt_depth, dtype=np.float64)
    if p.shape != g.shape:
        raise ValueError(f"depth_error: pred shape {p.shape} differs from gt shape {g.shape}")
    m = np.isfinite(g) & (g > 0)
    if valid is not None:
        v = np.asarray(valid, dtype=bool)
        if v.shape != g.shape:
            raise ValueError(f"depth_error: valid shape {v.shape} differs from depth shape {g.shape}")
        m &= v
    n = int(np.count_nonzero(m))
    if n == 0:
        nan = float("nan")
        return {"abs_rel": nan, "rmse": nan, "mae": nan, "share_over_0.1": nan, "n_valid": 0}
    d = p[m] - g[m]
    return {
        "abs_rel": float(np.mean(np.abs(d) / g[m])),
        "rmse": float(np.sqrt(np.mean(d * d))),
        "mae": float(np.mean(np.abs(d))),
        "share_over_0.1": float(np.mean(np.abs(d) > 0.1)),
        "n_valid": n,
    }


# --------------------------------------------------------------------------- benchmark


def _synthetic_panoptic(n_frames: int, size: int, seed: int):
    """Synthetic scene-consistent GT and a noisy prediction (uint16 labels)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:size, 0:size]
    block = max(size // 8, 1)
    gt_sem = np.empty((n_frames, size, size), np.uint16)
    gt_inst = np.empty((n_frames, size, size), np.uint16)
    for f in range(n_frames):
        by = (yy + 7 * f) // block
        bx = (xx + 11 * f) // block
        cell = by * 64 + bx  # scene-consistent object id
        gt_sem[f] = (cell % 12) + 1
        gt_inst[f] = np.where(gt_sem[f] <= 6, cell + 1, 0)
    gt_sem[:, : size // 16] = 0  # a void band
    pred_sem = gt_sem.copy()
    pred_inst = gt_inst.copy()
    noise = rng.random(gt_sem.shape) < 0.05
    pred_sem[noise] = rng.integers(0, 14, size=int(noise.sum()), dtype=np.uint16)
    pred_inst[noise] = rng.integers(0, 2000, size=int(noise.sum()), dtype=np.uint16)
    # a third of the frames carry per-frame (inconsistent) instance ids
    for f in range(0, n_frames, 3):
        pred_inst[f] = (pred_inst[f].astype(np.uint32) * 7 + f) % 60000
    return pred_sem, pred_inst, gt_sem, gt_inst


def benchmark_pq_scene(n_frames: int = 100, size: int = 512, seed: int = 0) -> dict:
    """Time :func:`pq_scene` and :func:`miou` on a synthetic F×size×size scene.

    Returns
    -------
    dict
        ``seconds`` (wall time of one ``pq_scene`` call), ``miou_seconds``,
        ``n_pixels``, ``pq``, ``n_frames``, ``size``.

    Examples
    --------
    >>> r = benchmark_pq_scene(n_frames=2, size=64)
    >>> r["n_pixels"], r["seconds"] >= 0
    (8192, True)
    """
    ps, pi, gs, gi = _synthetic_panoptic(n_frames, size, seed)
    things, stuff = set(range(1, 7)), set(range(7, 13))
    t0 = time.perf_counter()
    r = pq_scene(ps, pi, gs, gi, things, stuff, min_area=0.005)
    t1 = time.perf_counter()
    miou(ps, gs)
    t2 = time.perf_counter()
    return {
        "seconds": t1 - t0,
        "miou_seconds": t2 - t1,
        "n_pixels": int(gs.size),
        "pq": r["pq"],
        "n_frames": int(n_frames),
        "size": int(size),
    }
