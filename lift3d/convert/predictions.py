"""A folder of per-image 2D panoptic predictions, turned into what :class:`SceneWriter` takes.

Two layouts are accepted, matched to images by **file stem** (``IMG_0042.jpg`` ↔ ``IMG_0042.png``)::

    (a) COCO panoptic                       (b) two PNGs per image
    PRED/                                   PRED/
      panoptic.json                           semantic/<stem>.png    category id per pixel, 0 = void
      <stem>.png  (or panoptic/<stem>.png,    instance/<stem>.png    instance id per pixel, 0 = none
                   or <json stem>/<stem>.png) confidence/<stem>.png  optional, 8/16-bit scaled to [0, 1]
                                                                     (or .npy float in [0, 1])

(a) is what COCO panoptic segmenters write (Mask2Former, ``panopticapi``): segment ids ``R + 256 G + 256² B``
and a JSON whose ``annotations[].segments_info[]`` give each segment's ``category_id`` and optionally its
``score``. Its ``categories`` list is used unless ``--categories`` overrides it.

(b) is what semantic + instance segmenters write. Each distinct (class, instance) pair of a frame becomes a
segment; on stuff classes the instance id is ignored (one segment per stuff class and frame). The folder
names ``semantics/`` and ``instances/`` are accepted too.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Iterable, Sequence

import cv2
import numpy as np

from lift3d.convert import PanopticFrame, distinct_color, generic_categories
from lift3d.data.categories import Category
from lift3d.data.categories import parse_categories as parse_scene_categories
from lift3d.data.images import read_label_map, read_panoptic_png
from lift3d.data.scene import Segment
from lift3d.errors import InputError
from lift3d.utils.files import read_json
from lift3d.utils.progress import progress_bar

# Thing instance ids (scene-consistent GT) are offset past every category id so they never collide with
# the stuff segments, whose id is their category id; a multiple of 1000 keeps them readable.
_GT_THING_OFFSET_STEP = 1000


def load_categories(path: str | Path) -> list[Category]:
    """Read COCO panoptic categories: a JSON list ``[{"id", "name", "isthing", "color"}]`` or any JSON
    object with such a ``categories`` list (a COCO panoptic annotation file).

    Raises
    ------
    InputError
        Missing file, bad JSON, or a category without an integer ``id`` ≥ 1 (ids must be unique).
    """
    path = Path(path)
    raw = read_json(path)
    if isinstance(raw, dict):
        raw = raw.get("categories")
    return parse_categories(raw, path)


def parse_categories(raw: Any, where: Path) -> list[Category]:
    """Categories from already-parsed JSON (see :func:`load_categories`); colours by list position."""
    return parse_scene_categories(raw, where, default_color=lambda k, cid: distinct_color(k))


def panoptic_from_semantic_instance(semantic: np.ndarray, instance: np.ndarray, thing_ids: Iterable[int],
                                    source: Path, confidence: np.ndarray | None = None) -> PanopticFrame:
    """Per-frame panoptic segments from a semantic map and an instance map.

    Parameters
    ----------
    semantic, instance : np.ndarray
        ``[H, W]`` category ids (0 = void) and instance ids (0 = none).
    thing_ids : iterable of int
        Categories whose instance ids separate objects; on all others the instance id is ignored.
    source : Path
        The semantic map's path (for errors).
    confidence : np.ndarray, optional
        Per-pixel confidence carried along unchanged.

    Returns
    -------
    PanopticFrame
        Segment ids ``1..N`` (one per distinct (class, instance) pair, in increasing order), score 1.

    Examples
    --------
    >>> import numpy as np
    >>> sem = np.array([[1, 1, 2, 2]]); inst = np.array([[7, 8, 3, 4]])
    >>> fr = panoptic_from_semantic_instance(sem, inst, thing_ids=[2], source=Path("x.png"))
    >>> fr.panoptic.tolist(), [(s.id, s.category_id) for s in fr.segments]
    ([[1, 1, 2, 3]], [(1, 1), (2, 2), (3, 2)])
    """
    thing_list = [int(t) for t in thing_ids]
    sem = np.asarray(semantic, np.int64)
    inst = np.asarray(instance, np.int64)
    if sem.shape != inst.shape:
        raise InputError(source, f"semantic map is {sem.shape[1]}x{sem.shape[0]} but its instance map is "
                                 f"{inst.shape[1]}x{inst.shape[0]}")
    things = np.isin(sem, np.asarray(thing_list, np.int64))
    key = sem * (1 << 32) + np.where(things, inst, 0)
    valid = sem > 0
    keys, inverse = np.unique(key[valid], return_inverse=True)
    panoptic = np.zeros(sem.shape, np.int64)
    panoptic[valid] = inverse.reshape(-1) + 1
    segments = []
    for k, key_value in enumerate(keys.tolist()):
        cat, ins = divmod(int(key_value), 1 << 32)
        # A thing pixel without an instance id is a region of several objects: COCO calls that a crowd.
        is_crowd = int(ins == 0 and cat in thing_list)
        segments.append(Segment(k + 1, cat, 1.0, is_crowd))
    return PanopticFrame(panoptic, segments, confidence, source)


def gt_thing_offset(categories: Sequence[Category]) -> int:
    """Offset added to GT instance ids so that thing segment ids never equal a category id."""
    top = max((c.id for c in categories), default=0)
    return (top // _GT_THING_OFFSET_STEP + 1) * _GT_THING_OFFSET_STEP


def gt_from_semantic_instance(semantic: np.ndarray, instance: np.ndarray, thing_ids: Iterable[int],
                              offset: int, source: Path) -> PanopticFrame:
    """Ground-truth panoptic segments whose ids are the **same in every frame**.

    A stuff pixel gets its category id as segment id (one segment per stuff class for the whole scene); a
    thing pixel with instance ``i > 0`` gets ``offset + i``, so one object keeps one id across frames as
    long as the source's instance ids do (Panoptic Lifting's ``rs_instance`` ones do).

    Examples
    --------
    >>> import numpy as np
    >>> fr = gt_from_semantic_instance(np.array([[1, 2, 2]]), np.array([[0, 5, 6]]), [2], 1000, Path("g.png"))
    >>> fr.panoptic.tolist(), sorted((s.id, s.category_id) for s in fr.segments)
    ([[1, 1005, 1006]], [(1, 1), (1005, 2), (1006, 2)])
    """
    sem = np.asarray(semantic, np.int64)
    inst = np.asarray(instance, np.int64)
    if sem.shape != inst.shape:
        raise InputError(source, f"GT semantic map is {sem.shape[1]}x{sem.shape[0]} but its instance map is "
                                 f"{inst.shape[1]}x{inst.shape[0]}")
    thing_list = list(thing_ids)
    things = np.isin(sem, np.asarray(thing_list, np.int64)) & (inst > 0)
    if sem.max(initial=0) >= offset:
        raise InputError(source, f"category id {int(sem.max())} is not in the categories")
    panoptic = np.where(things, offset + inst, sem)
    panoptic[sem <= 0] = 0
    if panoptic.max(initial=0) >= 256**3:
        raise InputError(source, "instance ids too large for a COCO panoptic PNG")
    ids, first = np.unique(panoptic.reshape(-1), return_index=True)
    sem_flat = sem.reshape(-1)
    segments = []
    for sid, pos in zip(ids.tolist(), first.tolist()):
        if sid == 0:
            continue
        cat = int(sem_flat[pos])
        crowd = int(sid < offset and cat in thing_list)
        segments.append(Segment(int(sid), cat, 1.0, crowd))
    return PanopticFrame(panoptic, segments, None, source)


class PredictionFolder:
    """2D panoptic predictions for a set of images, found by image file stem.

    Parameters
    ----------
    root : str or Path
        The predictions folder (layout (a) or (b) of the module docstring).
    categories : list of Category, optional
        Overrides the categories the predictions carry (``--categories``).
    things : list of int, optional
        Thing class ids for generic categories (``--things``) when the predictions carry none.

    Raises
    ------
    InputError
        When the folder matches neither layout.
    """

    def __init__(self, root: str | Path, categories: list[Category] | None = None,
                 things: list[int] | None = None):
        self.root = Path(root)
        if not self.root.is_dir():
            raise InputError(self.root, "predictions folder not found")
        self._things_arg = things
        self._coco: dict[str, tuple[Path, list[Segment]]] = {}
        self.json_path: Path | None = None
        self.categories: list[Category] | None = categories
        json_path = self._find_coco_json()
        if json_path is not None:
            self.layout = "coco"
            self._load_coco(json_path, categories is None)
        else:
            sem_dir = _first_dir(self.root, ("semantic", "semantics"))
            inst_dir = _first_dir(self.root, ("instance", "instances"))
            if sem_dir is None or inst_dir is None:
                raise InputError(self.root, "not a predictions folder: expected panoptic.json + PNGs (COCO "
                                            "panoptic) or semantic/ + instance/ PNG folders")
            self.layout = "two-png"
            self.semantic_dir, self.instance_dir = sem_dir, inst_dir
            self.confidence_dir = _first_dir(self.root, ("confidence",))

    # ------------------------------------------------------------------ discovery
    def _find_coco_json(self) -> Path | None:
        p = self.root / "panoptic.json"
        if p.is_file():
            return p
        # panopticapi names the JSON after the split (panoptic_val2017.json) with a folder of the same stem.
        for cand in sorted(self.root.glob("*.json")):
            raw = read_json(cand)
            if isinstance(raw, dict) and isinstance(raw.get("annotations"), list):
                return cand
        return None

    def _load_coco(self, path: Path, use_categories: bool) -> None:
        self.json_path = path
        raw = read_json(path)
        if not isinstance(raw, dict) or not isinstance(raw.get("annotations"), list):
            raise InputError(path, "annotations: missing (expected COCO panoptic JSON)")
        if use_categories and raw.get("categories"):
            self.categories = parse_categories(raw["categories"], path)
        folders = [self.root, self.root / "panoptic", self.root / path.stem]
        for a, ann in enumerate(raw["annotations"]):
            if not isinstance(ann, dict) or not isinstance(ann.get("file_name"), str):
                raise InputError(path, f"annotations[{a}].file_name: missing")
            name = os.path.basename(ann["file_name"])
            png = next((d / name for d in folders if (d / name).is_file()), folders[0] / name)
            segs = []
            infos = ann.get("segments_info", [])
            if not isinstance(infos, list):
                raise InputError(path, f"annotations[{a}].segments_info: must be a list")
            for s, info in enumerate(infos):
                where = f"annotations[{a}].segments_info[{s}]"
                try:
                    sid, cid = int(info["id"]), int(info["category_id"])
                    score = float(info.get("score", 1.0))
                except (KeyError, TypeError, ValueError):
                    raise InputError(path, f"{where}: needs integer id and category_id") from None
                if sid <= 0:
                    raise InputError(path, f"{where}.id: must be > 0 (0 is void)")
                if not 0.0 <= score <= 1.0:
                    raise InputError(path, f"{where}.score: {score} is not in [0, 1]")
                segs.append(Segment(sid, cid, score, int(info.get("iscrowd", 0))))
            self._coco[Path(name).stem] = (png, segs)

    # ------------------------------------------------------------------ categories
    def resolve_categories(self, stems: Sequence[str], progress: bool = True) -> list[Category]:
        """The label vocabulary: ``--categories``, else the COCO JSON's, else generic ``class_<id>``
        names for the ids the predictions use (needs ``--things``)."""
        if self.categories is not None:
            return self.categories
        if self._things_arg is None:
            raise InputError(self.json_path or self.root,
                             "the predictions carry no categories: pass --categories FILE (COCO panoptic "
                             "categories JSON) or --things IDS to use generic class names")
        ids: set[int] = set()
        if self.layout == "coco":
            for stem in stems:
                ids.update(s.category_id for s in self._entry(stem)[1])
        else:
            for stem in progress_bar(stems, desc="scan class ids", unit="frame", disable=not progress):
                ids.update(np.unique(read_label_map(self._two_png_paths(stem)[0])).tolist())
        ids.discard(0)
        if not ids:
            raise InputError(self.root, "the predictions label no pixel (every semantic id is 0 = void)")
        self.categories = generic_categories(ids, self._things_arg)
        return self.categories

    # ------------------------------------------------------------------ per frame
    def _entry(self, stem: str) -> tuple[Path, list[Segment]]:
        if stem not in self._coco:
            raise InputError(self.json_path, f"no annotation for image {stem!r} (prediction missing; "
                                             f"annotations are matched to images by file stem)")
        return self._coco[stem]

    def _two_png_paths(self, stem: str) -> tuple[Path, Path]:
        sem, inst = self.semantic_dir / f"{stem}.png", self.instance_dir / f"{stem}.png"
        for p in (sem, inst):
            if not p.is_file():
                raise InputError(p, f"file not found (prediction missing for image {stem!r})")
        return sem, inst

    def check(self, stems: Iterable[str]) -> None:
        """Raise on the first image without predictions (before anything is written)."""
        for stem in stems:
            if self.layout == "coco":
                png = self._entry(stem)[0]
                if not png.is_file():
                    raise InputError(png, f"file not found (panoptic PNG of image {stem!r})")
            else:
                self._two_png_paths(stem)

    def labels(self, stem: str) -> PanopticFrame:
        """The predictions of the image with file stem ``stem``."""
        if self.categories is None:
            raise RuntimeError("call resolve_categories() first")
        if self.layout == "coco":
            png, segments = self._entry(stem)
            seg_map = read_panoptic_png(png)
            listed = {s.id for s in segments}
            missing = [int(i) for i in np.unique(seg_map) if i != 0 and int(i) not in listed]
            if missing:
                raise InputError(png, f"segment ids {missing[:5]} are in the PNG but not in its segments_info "
                                      f"({self.json_path.name})")
            # Segments listed but absent from the PNG (fully occluded, cropped) are harmless; keep them out
            # of the scene so areas and counts describe what is really there.
            present = set(np.unique(seg_map).tolist())
            return PanopticFrame(seg_map, [s for s in segments if s.id in present], None, png)
        sem_path, inst_path = self._two_png_paths(stem)
        sem = read_label_map(sem_path)
        inst = read_label_map(inst_path)
        confidence = self._confidence(stem)
        things = [c.id for c in self.categories if c.isthing]
        return panoptic_from_semantic_instance(sem, inst, things, sem_path, confidence)

    def _confidence(self, stem: str) -> np.ndarray | None:
        if self.confidence_dir is None:
            return None
        for ext in (".png", ".npy"):
            p = self.confidence_dir / f"{stem}{ext}"
            if p.is_file():
                return read_unit_image(p)
        return None


def read_unit_image(path: Path) -> np.ndarray:
    """A confidence map in [0, 1]: 8/16-bit PNG scaled by its bit depth, or a float ``.npy``."""
    if path.suffix == ".npy":
        try:
            c = np.load(path).astype(np.float32)
        except (OSError, ValueError) as exc:
            raise InputError(path, f"not a readable .npy array ({exc})") from exc
    else:
        data = np.fromfile(str(path), dtype=np.uint8)
        img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
        if img is None or img.ndim != 2 or img.dtype not in (np.uint8, np.uint16):
            raise InputError(path, "confidence must be a single-channel 8- or 16-bit PNG")
        c = img.astype(np.float32) / (255.0 if img.dtype == np.uint8 else 65535.0)
    if c.ndim != 2 or not np.all(np.isfinite(c)) or c.min(initial=0) < 0 or c.max(initial=0) > 1:
        raise InputError(path, "confidence must be a 2D map of values in [0, 1]")
    return c


def _first_dir(root: Path, names: Sequence[str]) -> Path | None:
    return next((root / n for n in names if (root / n).is_dir()), None)
