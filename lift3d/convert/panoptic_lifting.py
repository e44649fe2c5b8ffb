"""Panoptic Lifting scene folders (Siddiqui et al., CVPR 2023, ``data/<dataset>/<scene>/``) into a scene
folder.

The layout, as Panoptic Lifting's data loader and preprocessing scripts read and write it::

    SRC/
      color/<n>.jpg                    colour frames
      pose/<n>.txt                     4x4 camera-to-world, OpenCV axes (its in-the-wild preprocessing
                                       turns instant-ngp/OpenGL poses into these by flipping y and z)
      intrinsic/intrinsic_color.txt    4x4 K of the colour images
      m2f_semantics/<n>.png            Mask2Former class ids (0 = void), the 2D pseudo-labels
      m2f_instance/<n>.png             Mask2Former instance ids (0 on stuff; unique across frames)
      m2f_probabilities/<n>.npz        optional: ``confidence`` (and ``confidence_notta``) per pixel
      m2f_notta_semantics|instance/    the same without test-time augmentation (--labels-prefix m2f_notta)
      rs_semantics/<n>.png             optional ground truth, class ids
      rs_instance/<n>.png              optional ground truth, scene-consistent instance ids (0 on stuff)
      splits.json                      {"train": [stems], "test": [stems]} (and sometimes "val")
      segmentation_data.pkl            "fg_classes" (thing class ids), "num_semantic_classes"
      invalid/<n>.jpg                  optional: non-zero = pixel outside the undistorted image
      depth/<n>.png                    optional uint16 depth in millimetres

Rays in Panoptic Lifting are ``((i - cx) / fx, (j - cy) / fy, 1)`` rotated by the pose, for pixel column
``i`` and row ``j``: OpenCV camera axes and pixel centres on integer coordinates. lift3d puts pixel centres at
+0.5, so 0.5 is added to ``cx, cy`` (see :func:`lift3d.convert.scannet.half_pixel`).

Thing classes come from ``--things``, else from ``segmentation_data.pkl``'s ``fg_classes``. That pickle is
read with an unpickler that only builds plain containers and numpy arrays, so a foreign pickle cannot run
code. In Panoptic Lifting's own in-the-wild scenes ``rs_*`` are copies of the Mask2Former labels, not
annotations; pass ``--no-gt`` for those.
"""

from __future__ import annotations

import io
import pickle
from pathlib import Path
from typing import Any, Callable

import numpy as np

from lift3d.convert import (
    FrameInput,
    PanopticFrame,
    WriteOptions,
    every_nth,
    generic_categories,
    note,
    split_every,
    write_scene,
)
from lift3d.convert.predictions import (
    gt_from_semantic_instance,
    gt_thing_offset,
    panoptic_from_semantic_instance,
)
from lift3d.convert.scannet import half_pixel, intrinsics_file, list_frames, posed_frames, read_intrinsics
from lift3d.data.images import read_label_map
from lift3d.data.scene import Category, Scene
from lift3d.errors import InputError
from lift3d.utils.files import read_json
from lift3d.utils.progress import progress_bar

# What segmentation_data.pkl may contain: builtin containers/scalars and numpy arrays (the GT boxes).
_SAFE_GLOBALS = {
    ("builtins", n) for n in ("dict", "list", "tuple", "set", "frozenset", "int", "float", "bool", "str",
                              "bytes", "bytearray", "complex", "slice")
} | {
    ("collections", "OrderedDict"), ("collections", "defaultdict"), ("collections", "Counter"),
    ("_codecs", "encode"), ("numpy", "ndarray"), ("numpy", "dtype"),
    ("numpy.core.multiarray", "_reconstruct"), ("numpy.core.multiarray", "scalar"),
    ("numpy._core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "scalar"),
    ("numpy.core.numeric", "_frombuffer"), ("numpy._core.numeric", "_frombuffer"),
}


class _DataOnlyUnpickler(pickle.Unpickler):
    """Unpickles data, refuses anything that would import other code (e.g. a torch tensor or a class)."""

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) in _SAFE_GLOBALS:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"refusing to load {module}.{name}")


def read_segmentation_data(path: Path) -> dict:
    """``segmentation_data.pkl`` as a dict, without executing code from it.

    Raises
    ------
    InputError
        When the file is unreadable, not a dict, or holds anything but plain data.
    """
    try:
        data = _DataOnlyUnpickler(io.BytesIO(path.read_bytes())).load()
    except OSError as exc:
        raise InputError(path, f"cannot be read ({exc})") from exc
    except Exception as exc:  # noqa: BLE001 - any unpickling failure means the same thing to the user
        raise InputError(path, f"not a plain-data pickle ({exc}); pass --things IDS instead") from exc
    if not isinstance(data, dict):
        raise InputError(path, "expected a dict with 'fg_classes'")
    return data


def read_splits(path: Path, stems: list[str]) -> dict[str, list[str]]:
    """``splits.json`` lists of frame stems (Panoptic Lifting writes them as strings or numbers)."""
    raw = read_json(path)
    if not isinstance(raw, dict) or not isinstance(raw.get("train"), list):
        raise InputError(path, "expected {\"train\": [...], \"test\": [...]}")
    known = set(stems)
    out: dict[str, list[str]] = {}
    for split in ("train", "val", "test"):
        if split not in raw:
            continue
        if not isinstance(raw[split], list):
            raise InputError(path, f"{split}: must be a list of frame names")
        names = [str(x) for x in raw[split]]
        unknown = [n for n in names if n not in known]
        if unknown:
            raise InputError(path, f"{split}: frames {unknown[:3]} have no image in color/")
        out[split] = names
    return out


def _things_and_ids(root: Path, categories: list[Category] | None, things: list[int] | None
                    ) -> tuple[list[int] | None, list[int] | None]:
    """Thing ids and (when known without reading pixels) the category ids, from flags or the pickle."""
    pkl = root / "segmentation_data.pkl"
    data = read_segmentation_data(pkl) if pkl.is_file() and (categories is None) else None
    if categories is not None:
        return [c.id for c in categories if c.isthing], [c.id for c in categories]
    ids = None
    if data is not None and "num_semantic_classes" in data:
        ids = list(range(1, int(data["num_semantic_classes"])))
    if things is not None:
        return things, ids
    if data is not None and "fg_classes" in data:
        return sorted(int(i) for i in data["fg_classes"] if int(i) > 0), ids
    raise InputError(pkl, "file not found or without 'fg_classes': pass --things IDS (thing class ids) or "
                          "--categories FILE")


def _confidence(root: Path, prefix: str, stem: str) -> np.ndarray | None:
    """Panoptic Lifting's per-pixel segmenter confidence (TTA agreement) for a frame, when present."""
    # Its loader reads "<first word of the prefix>_probabilities", i.e. m2f_probabilities for m2f_notta too.
    path = root / f"{prefix.split('_')[0]}_probabilities" / f"{stem}.npz"
    if not path.is_file():
        return None
    try:
        with np.load(path) as npz:
            key = "confidence_notta" if "notta" in prefix and "confidence_notta" in npz.files else "confidence"
            if key not in npz.files:
                raise InputError(path, "no 'confidence' array")
            conf = np.asarray(npz[key], np.float32)
    except (OSError, ValueError) as exc:
        raise InputError(path, f"not a readable .npz ({exc})") from exc
    if conf.ndim != 2:
        raise InputError(path, f"{key}: expected an [H, W] map (got shape {conf.shape})")
    # Interpolated probabilities may overshoot [0, 1] slightly; clip rather than reject.
    return np.clip(np.nan_to_num(conf, nan=0.0), 0.0, 1.0)


def convert(
    src: str | Path,
    out: str | Path,
    *,
    categories: list[Category] | None = None,
    things: list[int] | None = None,
    labels_prefix: str = "m2f",
    use_confidence: bool = True,
    use_gt: bool = True,
    use_depth: bool = True,
    test_every: int = 8,
    intrinsics_size: tuple[int, int] | None = None,
    options: WriteOptions | None = None,
) -> Scene:
    """Convert a Panoptic Lifting scene folder into a scene folder.

    Parameters
    ----------
    src : str or Path
        The Panoptic Lifting scene (module docstring).
    out : str or Path
        Output scene folder.
    categories : list of Category, optional
        Label vocabulary; default: generic ``class_<id>`` names.
    things : list of int, optional
        Thing class ids (default: ``fg_classes`` of ``segmentation_data.pkl``).
    labels_prefix : str
        Pseudo-labels from ``<prefix>_semantics`` and ``<prefix>_instance``.
    use_confidence, use_gt, use_depth : bool
        Include per-pixel confidence, ``rs_*`` ground truth and depth when present.
    test_every : int
        Held-out rule when there is no ``splits.json``.
    intrinsics_size : (int, int), optional
        Size the intrinsics refer to (default: the colour images' own size).
    options : WriteOptions, optional
        Output options.
    """
    root = Path(src)
    if not root.is_dir():
        raise InputError(root, "folder not found")
    sem_dir, inst_dir = root / f"{labels_prefix}_semantics", root / f"{labels_prefix}_instance"
    for d in (sem_dir, inst_dir):
        if not d.is_dir():
            raise InputError(d, "folder not found (Panoptic Lifting pseudo-labels; see --labels-prefix)")
    intr = half_pixel(read_intrinsics(intrinsics_file(root)))
    all_frames = list_frames(root)
    frames_raw, skipped = posed_frames(root, all_frames)
    if skipped:
        note(f"{skipped} frames have an invalid (-inf) pose and are left out")
    if not frames_raw:
        raise InputError(root / "pose", "no frame has a valid pose")
    frames_raw = every_nth(frames_raw, (options or WriteOptions()).frame_step)
    stems = [s for s, _, _ in frames_raw]
    for stem in stems:
        for d in (sem_dir, inst_dir):
            if not (d / f"{stem}.png").is_file():
                raise InputError(d / f"{stem}.png", f"file not found (pseudo-labels of frame {stem!r})")

    gt_on = use_gt and (root / "rs_semantics").is_dir() and (root / "rs_instance").is_dir()
    thing_ids, cat_ids = _things_and_ids(root, categories, things)
    if categories is None:
        if cat_ids is None:
            cat_ids = sorted(_ids_present(root, stems, [sem_dir] + ([root / "rs_semantics"] if gt_on else []),
                                          options.progress if options else True))
        categories = generic_categories(cat_ids, thing_ids)
    offset = gt_thing_offset(categories)

    frames = []
    no_gt = 0
    for stem, img, c2w in frames_raw:
        gt_loader = None
        if gt_on and all((root / d / f"{stem}.png").is_file() for d in ("rs_semantics", "rs_instance")):
            gt_loader = _gt_loader(root, stem, thing_ids, offset)
        elif gt_on:
            no_gt += 1
        depth = root / "depth" / f"{stem}.png"
        mask = next((p for p in (root / "invalid" / f"{stem}.jpg", root / "invalid" / f"{stem}.png")
                     if p.is_file()), None)
        frames.append(FrameInput(
            name=stem, image_path=img, c2w_opencv=c2w, pose_source=root / "pose" / f"{stem}.txt",
            intrinsics=intr, intrinsics_size=intrinsics_size,
            labels=_labels_loader(root, labels_prefix, stem, thing_ids, use_confidence), gt=gt_loader,
            depth_path=depth if use_depth and depth.is_file() else None, mask_path=mask,
        ))
    if no_gt:
        note(f"{no_gt} frames have no rs_semantics/rs_instance ground truth")

    split_path = root / "splits.json"
    if split_path.is_file():
        splits = read_splits(split_path, [s for s, _ in all_frames])
        lost = sum(1 for v in splits.values() for n in v if n not in set(stems))
        if lost:
            note(f"{lost} split entries name frames without a valid pose; they are left out")
    else:
        splits = split_every(stems, test_every)
    return write_scene(out, frames, categories, camera_model="PINHOLE", splits=splits, options=options,
                       extra_meta={"converted_from": {"source": "panoptic-lifting", "path": str(root),
                                                      "labels": labels_prefix}})


def _ids_present(root: Path, stems: list[str], dirs: list[Path], progress: bool) -> set[int]:
    """Every class id used in the given label folders (generic categories need the full list up front)."""
    ids: set[int] = set()
    for stem in progress_bar(stems, desc="scan class ids", unit="frame", disable=not progress):
        for d in dirs:
            p = d / f"{stem}.png"
            if p.is_file():
                ids.update(np.unique(read_label_map(p)).tolist())
    ids.discard(0)
    if not ids:
        raise InputError(dirs[0], "the labels mark no pixel with a class (all 0 = void)")
    return ids


def _labels_loader(root: Path, prefix: str, stem: str, thing_ids: list[int], use_confidence: bool
                   ) -> Callable[[], PanopticFrame]:
    def load() -> PanopticFrame:
        sem_path = root / f"{prefix}_semantics" / f"{stem}.png"
        sem = read_label_map(sem_path)
        inst = read_label_map(root / f"{prefix}_instance" / f"{stem}.png")
        conf = _confidence(root, prefix, stem) if use_confidence else None
        return panoptic_from_semantic_instance(sem, inst, thing_ids, sem_path, conf)

    return load


def _gt_loader(root: Path, stem: str, thing_ids: list[int], offset: int) -> Callable[[], PanopticFrame]:
    def load() -> PanopticFrame:
        sem_path = root / "rs_semantics" / f"{stem}.png"
        return gt_from_semantic_instance(read_label_map(sem_path), read_label_map(root / "rs_instance" / f"{stem}.png"),
                                         thing_ids, offset, sem_path)

    return load
