"""Panoptic predictions made elsewhere in detectron2's ``(panoptic_seg, segments_info)`` form.

A detectron2 (or Mask2Former repository) predictor returns ``predictions["panoptic_seg"]``: a segment-id
map (0 = void) and a list of dicts with ``id``, ``category_id``, ``isthing`` and ``score``. Save one file
per image, named by the image's **file stem**, in a folder::

    PRED/<stem>.pt    torch.save(predictions["panoptic_seg"], path)             # the (map, list) tuple
                      or torch.save({"panoptic_seg": map, "segments_info": infos[, "confidence": c]}, path)
    PRED/<stem>.npz   np.savez(path, panoptic_seg=map.cpu().numpy(),
                               segments_info=json.dumps(infos)[, confidence=c])

``category_id`` is detectron2's contiguous class index (0..132 for COCO panoptic) unless the categories
the files use are given (``--prediction-categories FILE``: a COCO categories JSON whose ``id`` values are
the files' ``category_id``). An optional ``confidence`` array (``[H, W]`` in [0, 1]) becomes the frame's
per-pixel confidence map. ``isthing`` is not needed: thing or stuff is the target category's.

Files are read without unpickling arbitrary objects (``torch.load(weights_only=True)``,
``np.load(allow_pickle=False)``): a prediction file cannot run code.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from lift3d.data.scene import Segment
from lift3d.errors import InputError
from lift3d.label.classes import ClassMapping

#: File suffixes looked for, in this order, for each frame stem.
SUFFIXES = (".pt", ".pth", ".npz")


class Detectron2Prediction:
    """One frame's prediction as read from disk.

    Attributes
    ----------
    panoptic_seg : np.ndarray
        ``int64 [H, W]`` segment ids, 0 (or negative) = void.
    segments_info : list of dict
        ``{"id", "category_id", "score"}`` per segment (validated).
    confidence : np.ndarray or None
        Optional ``float32 [H, W]`` per-pixel confidence in [0, 1].
    path : Path
    """

    def __init__(self, panoptic_seg: np.ndarray, segments_info: list[dict], confidence: np.ndarray | None,
                 path: Path):
        self.panoptic_seg = panoptic_seg
        self.segments_info = segments_info
        self.confidence = confidence
        self.path = path


def find_prediction(folder: Path, stem: str) -> Path | None:
    """The prediction file of image ``stem`` in ``folder``, or None."""
    for suffix in SUFFIXES:
        p = folder / f"{stem}{suffix}"
        if p.is_file():
            return p
    return None


def _to_numpy(x: Any, path: Path, what: str) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    try:
        return np.asarray(x)
    except (TypeError, ValueError):
        raise InputError(path, f"{what}: not an array") from None


def _load_pt(path: Path) -> tuple[Any, Any, Any]:
    import torch

    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # unpickling errors come in many types; all mean "not a file we can read"
        raise InputError(path, f"not a readable torch file of tensors and lists ({' '.join(str(exc).split())[:120]})") \
            from exc
    if isinstance(obj, dict) and "panoptic_seg" in obj and isinstance(obj["panoptic_seg"], (tuple, list)):
        obj = obj["panoptic_seg"]  # the whole detectron2 predictions dict (with only picklable-safe parts)
    if isinstance(obj, (tuple, list)) and len(obj) == 2:
        return obj[0], obj[1], None
    if isinstance(obj, dict) and "panoptic_seg" in obj and "segments_info" in obj:
        return obj["panoptic_seg"], obj["segments_info"], obj.get("confidence")
    raise InputError(path, "expected a (panoptic_seg, segments_info) pair or a dict with those keys")


def _load_npz(path: Path) -> tuple[Any, Any, Any]:
    try:
        with np.load(path, allow_pickle=False) as data:
            if "panoptic_seg" not in data or "segments_info" not in data:
                raise InputError(path, "needs arrays 'panoptic_seg' and 'segments_info' (a JSON string)")
            seg = data["panoptic_seg"]
            info = data["segments_info"]
            conf = data["confidence"] if "confidence" in data else None
    except InputError:
        raise
    except ValueError as exc:
        if "allow_pickle" in str(exc):
            raise InputError(path, "segments_info is a pickled object array: save it as a JSON string "
                                   "(np.savez(..., segments_info=json.dumps(segments_info)))") from exc
        raise InputError(path, f"not a readable .npz ({exc})") from exc
    except (OSError, EOFError) as exc:
        raise InputError(path, f"not a readable .npz ({exc})") from exc
    if info.dtype.kind not in "US" or info.ndim != 0:
        raise InputError(path, "segments_info must be a JSON string (np.savez(..., segments_info=json.dumps(...)))")
    try:
        infos = json.loads(str(info.item() if info.dtype.kind == "U" else info.item().decode("utf-8")))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(path, f"segments_info is not valid JSON ({exc})") from exc
    return seg, infos, conf


def read_prediction(path: str | Path) -> Detectron2Prediction:
    """Read and check one ``.pt``/``.pth``/``.npz`` prediction file (module docstring)."""
    path = Path(path)
    seg_raw, infos_raw, conf_raw = _load_npz(path) if path.suffix == ".npz" else _load_pt(path)
    seg = _to_numpy(seg_raw, path, "panoptic_seg")
    if seg.ndim == 3 and seg.shape[0] == 1:
        seg = seg[0]
    if seg.ndim != 2 or seg.dtype.kind not in "iuf":
        raise InputError(path, f"panoptic_seg must be an [H, W] integer map (got shape {seg.shape}, {seg.dtype})")
    if seg.dtype.kind == "f":
        if not np.all(np.isfinite(seg)) or not np.array_equal(seg, np.round(seg)):
            raise InputError(path, "panoptic_seg holds non-integer values")
    seg = np.where(seg > 0, seg, 0).astype(np.int64)
    if not isinstance(infos_raw, (list, tuple)):
        raise InputError(path, "segments_info must be a list of {id, category_id, score}")
    infos: list[dict] = []
    seen: set[int] = set()
    for k, info in enumerate(infos_raw):
        try:
            sid, cid = int(info["id"]), int(info["category_id"])
            score = float(info.get("score", 1.0))
        except (KeyError, TypeError, ValueError, AttributeError):
            raise InputError(path, f"segments_info[{k}]: needs integer 'id' and 'category_id'") from None
        if sid <= 0:
            raise InputError(path, f"segments_info[{k}].id: must be > 0 (0 is void)")
        if sid in seen:
            raise InputError(path, f"segments_info[{k}].id: duplicate segment id {sid}")
        if not np.isfinite(score) or not 0.0 <= score <= 1.0:
            raise InputError(path, f"segments_info[{k}].score: {score} is not in [0, 1]")
        seen.add(sid)
        infos.append({"id": sid, "category_id": cid, "score": score})
    missing = sorted(set(np.unique(seg).tolist()) - seen - {0})
    if missing:
        raise InputError(path, f"segment ids {missing[:5]} are in panoptic_seg but not in segments_info")
    conf = None
    if conf_raw is not None:
        conf = _to_numpy(conf_raw, path, "confidence").astype(np.float32)
        if conf.shape != seg.shape:
            raise InputError(path, f"confidence is {conf.shape} but panoptic_seg is {seg.shape}")
        if not np.all(np.isfinite(conf)) or conf.min(initial=0) < 0 or conf.max(initial=0) > 1:
            raise InputError(path, "confidence must lie in [0, 1]")
    return Detectron2Prediction(seg, infos, conf, path)


def _resize_to(pred: Detectron2Prediction, size: tuple[int, int]) -> Detectron2Prediction:
    """Nearest-neighbour resize to the image size when only the resolution differs (same aspect ratio)."""
    h, w = size
    ph, pw = pred.panoptic_seg.shape
    if (ph, pw) == (h, w):
        return pred
    if abs(pw / ph - w / h) > 0.01 * (w / h):
        raise InputError(pred.path, f"prediction is {pw}x{ph} but the image is {w}x{h} (another aspect ratio)")
    if pred.panoptic_seg.max(initial=0) >= 2**31:
        raise InputError(pred.path, "segment ids too large")
    seg = cv2.resize(pred.panoptic_seg.astype(np.int32), (w, h), interpolation=cv2.INTER_NEAREST).astype(np.int64)
    conf = None
    if pred.confidence is not None:
        conf = np.clip(cv2.resize(pred.confidence, (w, h), interpolation=cv2.INTER_LINEAR), 0.0, 1.0)
    return Detectron2Prediction(seg, pred.segments_info, conf, pred.path)


def convert_prediction(pred: Detectron2Prediction, mapping: ClassMapping, size: tuple[int, int],
                       file_ids: dict[int, int]) -> tuple[np.ndarray, list[Segment], np.ndarray | None]:
    """A detectron2-style prediction in the scene's vocabulary.

    Parameters
    ----------
    pred : Detectron2Prediction
    mapping : ClassMapping
        Source classes (what ``category_id`` means) → target categories.
    size : (int, int)
        ``(H, W)`` of the image; a prediction at another resolution with the same aspect ratio is resized.
    file_ids : dict
        The files' ``category_id`` → source class index.

    Returns
    -------
    (panoptic, segments, confidence)
        Segment ids (0 = void; classes that map to void are void), segments with target category ids
        (stuff segments of one category fused into the lowest id, score = area-weighted mean), and the
        optional per-pixel confidence.
    """
    pred = _resize_to(pred, size)
    seg = pred.panoptic_seg
    ids, counts = np.unique(seg, return_counts=True)
    area = dict(zip(ids.tolist(), counts.tolist()))
    out = seg.copy()
    cats = mapping.categories
    kept: dict[int, list] = {}  # kept segment id -> [category index, score × area, area]
    stuff_owner: dict[int, int] = {}  # stuff category index -> segment id that keeps it
    for info in sorted(pred.segments_info, key=lambda d: d["id"]):
        sid, cid = info["id"], info["category_id"]
        if cid not in file_ids:
            raise InputError(pred.path, f"category_id {cid} of segment {sid} is not one of the prediction classes "
                                        f"(ids {min(file_ids)}..{max(file_ids)}; see --prediction-categories)")
        a = area.get(sid, 0)
        if a == 0:
            continue  # listed but not in the map (occluded by later segments): nothing to write
        target = int(mapping.target_of[file_ids[cid]])
        if target < 0:
            out[seg == sid] = 0
            continue
        if not cats[target].isthing and target in stuff_owner:
            owner = stuff_owner[target]
            out[seg == sid] = owner
            kept[owner][1] += info["score"] * a
            kept[owner][2] += a
            continue
        if not cats[target].isthing:
            stuff_owner[target] = sid
        kept[sid] = [target, info["score"] * a, a]
    segments = [Segment(sid, cats[t].id, min(1.0, max(0.0, s / a))) for sid, (t, s, a) in sorted(kept.items())]
    return out, segments, pred.confidence
