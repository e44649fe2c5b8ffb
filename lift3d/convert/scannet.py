"""ScanNet-style folders (the layout ScanNet's ``SensReader`` exports) into a scene folder::

    SRC/
      color/<n>.jpg                      colour frames (numeric stems sort numerically)
      pose/<n>.txt                       4x4 camera-to-world, OpenCV axes (x right, y down, z forward)
      intrinsic/intrinsic_color.txt      4x4 (or 3x3) K of the colour camera
      depth/<n>.png                      optional uint16 depth, millimetres (--depth-scale)

with 2D panoptic predictions from ``--predictions`` (see :mod:`lift3d.convert.predictions`), or without any,
for ``lift3d label`` to add afterwards.

Conventions checked against Panoptic Lifting's loader, which reads this same layout: poses are used as
camera-to-world with rays ``((i - cx) / fx, (j - cy) / fy, 1)`` for pixel column ``i`` and row ``j`` — OpenCV
axes, and pixel centres on **integer** coordinates. lift3d puts pixel centres at +0.5, so 0.5 is added to
``cx`` and ``cy`` here. Frames whose pose is ``-inf`` (ScanNet's mark for lost tracking) are skipped.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Callable

import numpy as np

from lift3d.convert import (FrameInput, WriteOptions, every_nth, note, read_matrix_txt, read_pose_txt, split_every,
                            write_scene)
from lift3d.convert.predictions import PredictionFolder
from lift3d.data.scene import Category, Scene
from lift3d.errors import InputError

IMAGE_EXTS = (".jpg", ".jpeg", ".png")


def natural_key(stem: str) -> tuple:
    """Sort ``2`` before ``10`` (ScanNet stems are unpadded frame numbers).

    Examples
    --------
    >>> sorted(["10", "2", "a1"], key=natural_key)
    ['2', '10', 'a1']
    """
    return tuple((0, int(t), "") if t.isdigit() else (1, 0, t) for t in re.split(r"(\d+)", stem) if t)


def list_frames(root: Path, folder: str = "color") -> list[tuple[str, Path]]:
    """``(stem, path)`` of every image in ``root/folder``, in natural order."""
    d = root / folder
    if not d.is_dir():
        raise InputError(d, "folder not found")
    found = [p for p in d.iterdir() if p.suffix.lower() in IMAGE_EXTS and p.is_file()]
    if not found:
        raise InputError(d, "no .jpg/.png images")
    return [(p.stem, p) for p in sorted(found, key=lambda p: natural_key(p.stem))]


def intrinsics_file(root: Path) -> Path:
    """``intrinsic/intrinsic_color.txt``, else the only ``intrinsic/*.txt`` that is not about depth or
    extrinsics."""
    d = root / "intrinsic"
    preferred = d / "intrinsic_color.txt"
    if preferred.is_file():
        return preferred
    others = [p for p in sorted(d.glob("*.txt")) if "depth" not in p.name and "extrinsic" not in p.name]
    if len(others) == 1:
        return others[0]
    raise InputError(preferred, "file not found (the colour camera's intrinsics)")


def read_intrinsics(path: Path) -> tuple[float, float, float, float]:
    """``(fx, fy, cx, cy)`` of a 3x3 or 4x4 K text file, unchanged (integer pixel-centre convention)."""
    k = read_matrix_txt(path, "intrinsics")
    if k.shape not in ((3, 3), (4, 4), (3, 4)):
        raise InputError(path, f"intrinsics must be a 3x3 or 4x4 matrix (got {k.shape[0]}x{k.shape[1]})")
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    if not (fx > 0 and fy > 0 and np.isfinite([fx, fy, cx, cy]).all()):
        raise InputError(path, f"focal lengths must be positive and finite (got fx={fx}, fy={fy})")
    return float(fx), float(fy), float(cx), float(cy)


def half_pixel(intrinsics: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """Integer-centred intrinsics (OpenCV calibration, ScanNet) in lift3d's +0.5 pixel-centre convention."""
    fx, fy, cx, cy = intrinsics
    return fx, fy, cx + 0.5, cy + 0.5


def parse_size(text: str | None, where: str = "--intrinsics-size") -> tuple[int, int] | None:
    """``"1296x968"`` → ``(1296, 968)``."""
    if text is None:
        return None
    m = re.fullmatch(r"\s*(\d+)\s*[xX,]\s*(\d+)\s*", text)
    if not m or int(m.group(1)) < 1 or int(m.group(2)) < 1:
        raise InputError(where, f"expected WIDTHxHEIGHT, e.g. 1296x968 (got {text!r})")
    return int(m.group(1)), int(m.group(2))


def posed_frames(root: Path, stems_paths: list[tuple[str, Path]]) -> tuple[list[tuple[str, Path, np.ndarray]], int]:
    """Attach ``pose/<stem>.txt`` to every colour frame; returns the posed frames and how many were
    skipped for an invalid (``-inf``) pose."""
    out, skipped = [], 0
    for stem, img in stems_paths:
        c2w = read_pose_txt(root / "pose" / f"{stem}.txt")
        if c2w is None:
            skipped += 1
            continue
        out.append((stem, img, c2w))
    return out, skipped


def convert(
    src: str | Path,
    out: str | Path,
    *,
    predictions: str | Path | None,
    categories: list[Category] | None = None,
    things: list[int] | None = None,
    test_every: int = 8,
    use_depth: bool = True,
    intrinsics_size: tuple[int, int] | None = None,
    options: WriteOptions | None = None,
) -> Scene:
    """Convert a ScanNet-style folder plus 2D panoptic predictions into a scene folder.

    Parameters
    ----------
    src : str or Path
        The ScanNet-style folder (module docstring).
    out : str or Path
        Output scene folder.
    predictions : str or Path or None
        2D panoptic predictions, matched to ``color/`` images by stem; None writes a scene without
        pseudo-labels (``lift3d label`` adds them).
    categories, things
        As for :func:`lift3d.convert.colmap.convert`.
    test_every : int
        Every N-th posed frame (natural order) is a test frame; 0 keeps all for training.
    use_depth : bool
        Include ``depth/<n>.png`` when present.
    intrinsics_size : (int, int), optional
        Image size ``intrinsic_color.txt`` refers to, when the colour images were resized since
        (default: the images' own size).
    options : WriteOptions, optional
        Output options.
    """
    root = Path(src)
    if not root.is_dir():
        raise InputError(root, "folder not found")
    intr = half_pixel(read_intrinsics(intrinsics_file(root)))
    frames_raw, skipped = posed_frames(root, list_frames(root))
    if skipped:
        note(f"{skipped} frames have an invalid (-inf) pose and are left out")
    if not frames_raw:
        raise InputError(root / "pose", "no frame has a valid pose")
    frames_raw = every_nth(frames_raw, (options or WriteOptions()).frame_step)
    stems = [s for s, _, _ in frames_raw]
    preds, cats = prediction_folder(predictions, categories, things, stems, options)
    frames = []
    for stem, img, c2w in frames_raw:
        depth = root / "depth" / f"{stem}.png"
        frames.append(FrameInput(
            name=stem, image_path=img, c2w_opencv=c2w, pose_source=root / "pose" / f"{stem}.txt",
            intrinsics=intr, intrinsics_size=intrinsics_size, labels=_labels_of(preds, stem) if preds else None,
            depth_path=depth if use_depth and depth.is_file() else None,
        ))
    return write_scene(out, frames, cats, camera_model="PINHOLE", splits=split_every(stems, test_every),
                       options=options, extra_meta={"converted_from": {"source": "scannet", "path": str(root)}})


def prediction_folder(predictions: str | Path | None, categories: list[Category] | None, things: list[int] | None,
                      stems: list[str], options: WriteOptions | None) -> tuple[PredictionFolder | None, list[Category]]:
    """The checked predictions folder and its categories; ``(None, [])`` without predictions (then the
    categories are for ``lift3d label`` to choose, and giving some is a mistake worth saying)."""
    if predictions is None:
        if categories is not None or things is not None:
            raise InputError("--categories" if categories is not None else "--things",
                             "only used with --predictions (lift3d label sets the categories of a scene without "
                             "pseudo-labels)")
        return None, []
    preds = PredictionFolder(predictions, categories, things)
    preds.check(stems)
    return preds, preds.resolve_categories(stems, progress=options.progress if options else True)


def _labels_of(preds: PredictionFolder, stem: str) -> Callable:
    return lambda: preds.labels(stem)
