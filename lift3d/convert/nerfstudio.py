"""nerfstudio and instant-ngp ``transforms.json`` files into a scene folder.

Both tools write one JSON object with shared camera keys at the top level, per-frame overrides, and a
``frames`` list of ``{"file_path", "transform_matrix", ...}``. What this reader relies on (read in
nerfstudio's ``nerfstudio_dataparser.py``, ``cameras.py``, ``camera_utils.py``, ``process_data/colmap_utils.py``
and instant-ngp's ``src/nerf_loader.cu``, ``include/neural-graphics-primitives/nerf_loader.h``,
``scripts/colmap2nerf.py``, ``docs/nerf_dataset_tips.md``):

* ``transform_matrix`` is camera-to-world in **OpenGL** axes (x right, y up, looking down -z) in both.
  instant-ngp applies its own ``scale`` (default 0.33) and ``offset`` (default 0.5) when it loads the file,
  and nerfstudio re-centres and re-scales at load; neither is in the file, so the file's world is kept.
* Pixel centres are at +0.5 in both (nerfstudio's ``pixel_offset = 0.5``; instant-ngp's normalised ``cx / w``),
  as in lift3d: ``cx``, ``cy`` are used unchanged (default ``w / 2``, ``h / 2``).
* Focal lengths: ``fl_x``/``fl_y`` (both tools), or instant-ngp's ``camera_angle_x``/``camera_angle_y``
  (radians) and ``x_fov``/``y_fov`` (degrees), ``f = 0.5 size / tan(angle / 2)``. One axis alone serves both.
* Distortion: nerfstudio applies ``k1 k2 k3 k4 p1 p2`` to every perspective camera (``1 + k1 r² + k2 r⁴ +
  k3 r⁶ + k4 r⁸`` and OpenCV's tangential terms), whatever ``camera_model`` (absent: perspective) says,
  and the fisheye polynomial in θ for ``OPENCV_FISHEYE``; instant-ngp switches to OpenCV's fisheye model
  with ``is_fisheye``. ``k4`` of a perspective camera (an r⁸ term OpenCV's model lacks) and ``p1 p2`` of a
  fisheye camera stop the conversion rather than being dropped.
* nerfstudio's multi-camera files carry ``camera_model`` and the intrinsics per frame; ``distortion_params``
  is its unnamed ``[k1, k2, k3, k4, p1, p2]`` (it wins over named coefficients). A key given both at the top
  level and in a frame: the frame's value is used, as instant-ngp and lift3d's scene reader do (nerfstudio
  ignores the frames' values of a key the top level has).
* nerfstudio's ``applied_transform`` (3x4; ``ns-process-data`` writes the rotation it gave COLMAP's world)
  and ``applied_scale`` say how the original world was moved into the file's:
  ``x_file = applied_scale (R x_original + t)``.
* Depth: nerfstudio's ``depth_file_path`` (z-depth, uint16 in ``depth_unit_scale_factor`` units, which is a
  training option, 1 mm by default, not in the file); instant-ngp's ``depth_path``, read only when the file
  gives ``integer_depth_scale`` (world units per integer step; z-depth).
* Masks: nerfstudio's ``mask_path`` (non-zero = train on the pixel); instant-ngp's
  ``dynamic_mask_<stem>.png`` beside an image (non-zero = leave the pixel out).
* instant-ngp's ``aabb_scale``: it models space out to ``aabb_scale`` times its unit cube, the cube being
  ``[0, 1]³`` after its ``scale``/``offset`` (or ``aabb``) mapping; 1 becomes a bounded ``scene_box``, more
  is left to training (see :func:`scene_box_from_aabb_scale`).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, Callable

import numpy as np

from lift3d.convert import FrameInput, WriteOptions, every_nth, note, split_every, write_scene
from lift3d.convert.predictions import PredictionFolder
from lift3d.convert.scannet import natural_key
from lift3d.data.cameras import opengl_to_opencv
from lift3d.data.images import read_rgb
from lift3d.data.scene import Category, Scene, frame_pose
from lift3d.errors import InputError
from lift3d.utils.files import read_json

#: Extensions tried, in this order, for a ``file_path`` without one (NeRF-synthetic writes ``./train/r_0``),
#: as instant-ngp does; only formats OpenCV reads.
IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp")

#: ``camera_model`` values nerfstudio reads as a perspective camera (distortion from the coefficients).
PERSPECTIVE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
#: ... and as OpenCV's fisheye model.
FISHEYE_MODELS = ("OPENCV_FISHEYE",)

#: nerfstudio's ``distortion_params`` order.
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")

# instant-ngp's defaults for mapping the file's world into its unit cube (NERF_SCALE and the offset).
_NGP_SCALE = 0.33
_NGP_OFFSET = (0.5, 0.5, 0.5)

# Keys that change what the original tool trains on and that lift3d does not follow, with the reason.
_IGNORED = {
    "n_frames": "instant-ngp would train on the first {value} frames only; every frame with an image is converted",
    "sharpness_discard_threshold": "instant-ngp would drop frames blurrier than their neighbours; none are dropped",
    "fisheye_crop_radius": "lift3d trains on every pixel of the image; give the frames a mask_path to leave the "
                           "border of a fisheye image out",
}


def find_transforms(src: str | Path) -> Path:
    """The ``transforms.json`` of ``SRC``: the file itself (any name ending in ``.json``) or the one in the
    folder.

    Raises
    ------
    InputError
        When there is no such file; a folder holding only ``transforms_<split>.json`` (NeRF-synthetic) is told
        to name one of them.
    """
    src = Path(src)
    if src.is_file():
        return src
    if not src.is_dir():
        raise InputError(src, "not found")
    path = src / "transforms.json"
    if not path.is_file():
        others = sorted(p.name for p in src.glob("transforms*.json"))
        hint = f" (pass one of {', '.join(others)} as SRC)" if others else ""
        raise InputError(path, f"file not found{hint}")
    return path


def _get(meta: dict, frame: dict, key: str, default: Any = None) -> Any:
    """A camera key of ``frame``, else of the top level (both tools let a frame override the shared value)."""
    return frame[key] if key in frame else meta.get(key, default)


def _number(value: Any, where: Path, field_name: str) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise InputError(where, f"{field_name}: not a number ({value!r})") from None
    if not math.isfinite(out):
        raise InputError(where, f"{field_name}: not finite")
    return out


def _field(meta: dict, frame: dict, key: str, k: int) -> str:
    """The name of ``key`` where :func:`_get` found it, for error messages."""
    return f"frames[{k}].{key}" if key in frame else key


def focal_lengths(meta: dict, frame: dict, size: tuple[int, int], where: Path, k: int) -> tuple[float, float]:
    """``(fx, fy)`` in pixels of frame ``k`` whose intrinsics refer to an image of ``size = (w, h)``.

    Per axis, the frame's own key wins over the top level's, and among the keys instant-ngp's order: ``x_fov``
    (degrees), ``fl_x``, ``camera_angle_x`` (radians). An axis without any takes the other's focal length.

    Examples
    --------
    >>> fx, fy = focal_lengths({"camera_angle_x": 2 * math.atan(0.5)}, {}, (800, 600), Path("t.json"), 0)
    >>> round(fx, 9), round(fy, 9)
    (800.0, 800.0)
    """
    def axis(name: str, extent: int) -> float | None:
        for source in (frame, meta):
            prefix = f"frames[{k}]." if source is frame else ""
            if f"{name}_fov" in source:
                angle = math.radians(_number(source[f"{name}_fov"], where, f"{prefix}{name}_fov"))
            elif f"fl_{name}" in source:
                return _number(source[f"fl_{name}"], where, f"{prefix}fl_{name}")
            elif f"camera_angle_{name}" in source:
                angle = _number(source[f"camera_angle_{name}"], where, f"{prefix}camera_angle_{name}")
            else:
                continue
            if not 0 < angle < math.pi:
                raise InputError(where, f"{prefix}{name}: field of view must lie in (0, 180) degrees")
            return 0.5 * extent / math.tan(0.5 * angle)
        return None

    fx, fy = axis("x", size[0]), axis("y", size[1])
    if fx is None and fy is None:
        raise InputError(where, f"fl_x: missing for frames[{k}] (give fl_x/fl_y or camera_angle_x at top level "
                                "or per frame)")
    fx = fy if fx is None else fx
    fy = fx if fy is None else fy
    if fx <= 0 or fy <= 0:
        raise InputError(where, f"fl_x/fl_y: focal lengths of frames[{k}] must be positive (got {fx}, {fy})")
    return fx, fy


def intrinsics_size(meta: dict, frame: dict, where: Path, k: int) -> tuple[int, int] | None:
    """``(w, h)`` the file gives frame ``k``'s intrinsics for, or None when it gives none (NeRF-synthetic)."""
    if _get(meta, frame, "w") is None or _get(meta, frame, "h") is None:
        return None
    w = _number(_get(meta, frame, "w"), where, _field(meta, frame, "w", k))
    h = _number(_get(meta, frame, "h"), where, _field(meta, frame, "h", k))
    if w < 1 or h < 1 or w != int(w) or h != int(h):
        raise InputError(where, f"{_field(meta, frame, 'w', k)}/h: image size must be positive integers "
                                f"(got {w} x {h})")
    return int(w), int(h)


def frame_intrinsics(meta: dict, frame: dict, size: tuple[int, int], where: Path,
                     k: int) -> tuple[float, float, float, float]:
    """``(fx, fy, cx, cy)`` of frame ``k`` for an image of ``size = (w, h)``; ``cx, cy`` default to the
    image centre and are used unchanged (both tools put pixel centres at +0.5, as lift3d does).

    Examples
    --------
    >>> frame_intrinsics({"fl_x": 50.0, "cy": 20.5}, {"cx": 31.0}, (64, 48), Path("t.json"), 0)
    (50.0, 50.0, 31.0, 20.5)
    """
    fx, fy = focal_lengths(meta, frame, size, where, k)
    cx = _number(_get(meta, frame, "cx", size[0] / 2), where, _field(meta, frame, "cx", k))
    cy = _number(_get(meta, frame, "cy", size[1] / 2), where, _field(meta, frame, "cy", k))
    if not (0 <= cx <= size[0] and 0 <= cy <= size[1]):
        raise InputError(where, f"cx/cy: principal point ({cx}, {cy}) of frames[{k}] lies outside the "
                                f"{size[0]}x{size[1]} image")
    return fx, fy, cx, cy


def camera_of(meta: dict, frame: dict, where: Path, k: int) -> tuple[str, dict[str, float]]:
    """Frame ``k``'s camera kind and the distortion lift3d writes for it.

    Returns
    -------
    kind : str
        ``OPENCV`` (perspective, with or without distortion) or ``OPENCV_FISHEYE``.
    distortion : dict
        ``k1 k2 p1 p2 k3`` (perspective) or ``k1 k2 k3 k4`` (fisheye); empty when every coefficient is 0.

    Raises
    ------
    InputError
        For a camera model lift3d cannot represent, or a non-zero coefficient it would have to drop.
    """
    model = _get(meta, frame, "camera_model")
    fisheye_flag = bool(_get(meta, frame, "is_fisheye", False))
    if model is not None:
        model = str(model)
        if model not in PERSPECTIVE_MODELS + FISHEYE_MODELS:
            raise InputError(where, f"{_field(meta, frame, 'camera_model', k)}: {model!r} is not supported (lift3d "
                                    f"reads {', '.join(PERSPECTIVE_MODELS + FISHEYE_MODELS)})")
        if fisheye_flag and model not in FISHEYE_MODELS:
            raise InputError(where, f"{_field(meta, frame, 'is_fisheye', k)}: true, but camera_model is {model}")
    fisheye = model in FISHEYE_MODELS or (model is None and fisheye_flag)

    coeffs = dict.fromkeys(DISTORTION_KEYS, 0.0)
    where_from = {}
    unnamed = _get(meta, frame, "distortion_params")
    if unnamed is not None:
        name = _field(meta, frame, "distortion_params", k)
        if not isinstance(unnamed, list) or len(unnamed) != len(DISTORTION_KEYS):
            raise InputError(where, f"{name}: expected [k1, k2, k3, k4, p1, p2] (FISHEYE624's 12 values are not "
                                    "supported)")
        for j, key in enumerate(DISTORTION_KEYS):
            coeffs[key], where_from[key] = _number(unnamed[j], where, f"{name}[{j}]"), f"{name}[{j}]"
    else:
        for key in DISTORTION_KEYS:
            if key in frame or key in meta:
                coeffs[key] = _number(_get(meta, frame, key), where, _field(meta, frame, key, k))
                where_from[key] = _field(meta, frame, key, k)
    unusable = ("p1", "p2") if fisheye else ("k4",)
    for key in unusable:
        if coeffs[key] != 0.0:
            kind = "a fisheye camera" if fisheye else "a perspective camera (an r^8 radial term)"
            raise InputError(where, f"{where_from[key]}: {coeffs[key]} is non-zero; lift3d cannot represent {key} "
                                    f"of {kind}: undistort the images first")
    names = ("k1", "k2", "k3", "k4") if fisheye else ("k1", "k2", "p1", "p2", "k3")
    distortion = {key: coeffs[key] for key in names} if any(coeffs[key] for key in names) else {}
    return ("OPENCV_FISHEYE" if fisheye else "OPENCV"), distortion


def resolve_image(root: Path, file_path: str) -> Path | None:
    """The image a ``file_path`` names (relative to the JSON's folder; Windows separators allowed; a path
    without extension tries :data:`IMAGE_EXTS`), or None when it does not exist."""
    rel = file_path.replace("\\", "/")
    path = Path(rel) if Path(rel).is_absolute() else root / rel
    if path.is_file():
        return path
    if path.suffix.lower() not in IMAGE_EXTS:
        for ext in IMAGE_EXTS:
            candidate = path.with_name(path.name + ext)
            if candidate.is_file():
                return candidate
    return None


def _split_key(file_path: str) -> str:
    """A ``file_path`` as split lists name it: posix separators, no leading ``./``."""
    rel = file_path.replace("\\", "/")
    while rel.startswith("./"):
        rel = rel[2:]
    return rel


def file_splits(meta: dict, listed: dict[str, str], converted: list[str], where: Path) -> dict[str, list[str]] | None:
    """nerfstudio's ``train_filenames`` / ``val_filenames`` / ``test_filenames`` as frame names, or None.

    Entries are matched to the frames' ``file_path`` (``listed``: split key → frame name, every frame of the
    file), else by file stem; entries of frames that were not ``converted`` (no image) are dropped. A file
    that lists ``test`` but no ``train`` trains on every other frame.

    Examples
    --------
    >>> listed = {"images/a.png": "a", "images/b.png": "b", "images/c.png": "c"}
    >>> file_splits({"test_filenames": ["./images/b.png"]}, listed, ["a", "b", "c"], Path("t.json"))
    {'test': ['b'], 'train': ['a', 'c']}
    """
    if not any(f"{s}_filenames" in meta for s in ("train", "val", "test")):
        return None
    by_stem = {Path(key).stem: name for key, name in listed.items()}
    converted_set = set(converted)
    out: dict[str, list[str]] = {}
    for split in ("train", "val", "test"):
        entries = meta.get(f"{split}_filenames")
        if entries is None:
            continue
        if not isinstance(entries, list):
            raise InputError(where, f"{split}_filenames: must be a list of file paths")
        names = []
        for entry in entries:
            key = _split_key(str(entry))
            name = listed.get(key) or by_stem.get(Path(key).stem)
            if name is None:
                raise InputError(where, f"{split}_filenames: {entry!r} is not one of the frames")
            if name in converted_set:
                names.append(name)
        out[split] = names
    if "train" not in out:
        held_out = set(out.get("test", []))
        out["train"] = [n for n in converted if n not in held_out] or list(converted)
    return out


def _unit_cube(meta: dict, where: Path) -> np.ndarray:
    """instant-ngp's unit cube ``[0, 1]³`` in the file's world coordinates, ``[2, 3]`` (min, max).

    instant-ngp maps a file position ``p`` to ``scale * p + offset`` (then only permutes the axes), with
    ``scale``/``offset`` from the file or 0.33/0.5; an ``aabb`` key instead fits that box's longest side to the
    cube, centred at 0.5.
    """
    scale = _number(meta.get("scale", _NGP_SCALE), where, "scale")
    offset = meta.get("offset", list(_NGP_OFFSET))
    offset = [offset] * 3 if not isinstance(offset, list) else offset
    if len(offset) != 3:
        raise InputError(where, "offset: must be a number or [x, y, z]")
    offset = np.array([_number(v, where, "offset") for v in offset])
    if "aabb" in meta:
        try:
            aabb = np.asarray(meta["aabb"], np.float64).reshape(2, 3)
        except (TypeError, ValueError):
            raise InputError(where, "aabb: must be [[min x, y, z], [max x, y, z]]") from None
        scale = 1.0 / max(float(np.abs(aabb[1] - aabb[0]).max()), 1e-6)
        offset = 0.5 - aabb.mean(0) * scale
    if not scale > 0:
        raise InputError(where, f"scale: must be positive (got {scale})")
    return np.stack([(0.0 - offset) / scale, (1.0 - offset) / scale])


def scene_box_from_aabb_scale(meta: dict, where: Path) -> tuple[str, np.ndarray] | None:
    """The ``scene_box`` instant-ngp's ``aabb_scale`` stands for, or None.

    instant-ngp models its unit cube (:func:`_unit_cube`) enlarged ``aabb_scale`` times about its centre; its
    documentation: 1 when the scene fits in the cube, larger "for natural scenes where there is a
    background". Only 1 says where the scene is: a ``bounded`` box, the cube itself (training warns when the
    content reaches past it). A larger value says only that something lies beyond the cube (``colmap2nerf``
    writes 32 by default, whatever the scene): no box, lift3d sizes the space from the content.

    Examples
    --------
    >>> kind, box = scene_box_from_aabb_scale({"aabb_scale": 1}, Path("t.json"))
    >>> kind, np.round(box, 3).tolist()
    ('bounded', [[-1.515, -1.515, -1.515], [1.515, 1.515, 1.515]])
    >>> scene_box_from_aabb_scale({"aabb_scale": 32}, Path("t.json")) is None
    True
    """
    if "aabb_scale" not in meta:
        return None
    aabb_scale = _number(meta["aabb_scale"], where, "aabb_scale")
    if aabb_scale < 1:
        raise InputError(where, f"aabb_scale: must be >= 1 (got {aabb_scale:g})")
    return ("bounded", _unit_cube(meta, where)) if aabb_scale == 1 else None


def _applied(meta: dict, where: Path) -> dict:
    """nerfstudio's ``applied_transform`` / ``applied_scale``, checked, to keep in ``converted_from``."""
    out: dict[str, Any] = {}
    if "applied_transform" in meta:
        try:
            m = np.asarray(meta["applied_transform"], np.float64)
        except (TypeError, ValueError):
            m = np.zeros(0)
        if m.shape not in ((3, 4), (4, 4)) or not np.all(np.isfinite(m)):
            raise InputError(where, "applied_transform: must be a 3x4 matrix of numbers")
        out["applied_transform"] = m[:3].tolist()
    if "applied_scale" in meta:
        out["applied_scale"] = _number(meta["applied_scale"], where, "applied_scale")
    return out


def convert(
    src: str | Path,
    out: str | Path,
    *,
    predictions: str | Path,
    categories: list[Category] | None = None,
    things: list[int] | None = None,
    test_every: int = 8,
    use_depth: bool = True,
    options: WriteOptions | None = None,
) -> Scene:
    """Convert a nerfstudio or instant-ngp ``transforms.json`` plus 2D panoptic predictions into a scene folder.

    Parameters
    ----------
    src : str or Path
        The ``transforms.json`` (any ``*.json`` of that format) or the folder holding ``transforms.json``.
    out : str or Path
        Output scene folder.
    predictions : str or Path
        2D panoptic predictions, matched to the images by file stem (:mod:`lift3d.convert.predictions`).
    categories, things
        As for :func:`lift3d.convert.colmap.convert`.
    test_every : int
        Every N-th frame (natural order of ``file_path``) is a test frame, unless the file has split lists;
        0 keeps all for training.
    use_depth : bool
        Include the frames' depth maps (``depth_file_path``, or ``depth_path`` with ``integer_depth_scale``).
    options : WriteOptions, optional
        Output options; ``depth_scale`` applies to ``depth_file_path`` maps.

    Returns
    -------
    Scene
        The written scene, loaded back.

    Examples
    --------
    >>> from lift3d.convert import nerfstudio                                          # doctest: +SKIP
    >>> scene = nerfstudio.convert("data/fox", "scenes/fox", predictions="data/fox/m2f")  # doctest: +SKIP
    >>> scene.cameras.camera_model                                                     # doctest: +SKIP
    'OPENCV'
    """
    opts = options or WriteOptions()
    tpath = find_transforms(src)
    root = tpath.parent
    meta = read_json(tpath)
    if not isinstance(meta, dict):
        raise InputError(tpath, "must hold a JSON object")
    raw = meta.get("frames")
    if not isinstance(raw, list) or not raw:
        raise InputError(tpath, "frames: missing or empty")
    preds = PredictionFolder(predictions, categories, things)

    # Frames in instant-ngp's order (natural sort of file_path); those whose image is absent are skipped.
    listed, present = {}, []
    for k, frame in enumerate(raw):
        if not isinstance(frame, dict) or not isinstance(frame.get("file_path"), str) or not frame["file_path"]:
            raise InputError(tpath, f"frames[{k}].file_path: missing (every frame needs its image's path)")
        listed[_split_key(frame["file_path"])] = Path(_split_key(frame["file_path"])).stem
        image = resolve_image(root, frame["file_path"])
        if image is not None:
            present.append((k, frame, image))
    if not present:
        raise InputError(tpath, f"none of the {len(raw)} frames listed has its image (the first names "
                                f"{root / _split_key(raw[0]['file_path'])})")
    if len(present) < len(raw):
        note(f"{len(raw) - len(present)} of {len(raw)} frames listed in {tpath.name} have no image: skipped")
    present.sort(key=lambda item: natural_key(_split_key(item[1]["file_path"])))
    present = every_nth(present, opts.frame_step)
    for key, template in _IGNORED.items():
        if key in meta:
            note(f"{key} ignored: {template.format(value=meta[key])}")

    # instant-ngp reads depth_path only with integer_depth_scale, its unit (world units per integer step);
    # the scene keeps that unit, so the integers pass unchanged. depth_file_path maps are in --depth-scale.
    depth_keys = ["depth_file_path"] + (["depth_path"] if "integer_depth_scale" in meta else [])
    if use_depth and "integer_depth_scale" not in meta and any("depth_path" in fr for _, fr, _ in present):
        note("depth_path ignored: instant-ngp reads it only with integer_depth_scale, which this file does not give")
    # Intrinsics that need the image size (fields of view, default principal point) use the file's w and h,
    # else the first image's; write_scene scales them to every image of the same aspect ratio.
    first_size: tuple[int, int] | None = None
    kinds, depth_used, frames = set(), set(), []
    for k, frame, image in present:
        size = intrinsics_size(meta, frame, tpath, k)
        if size is None:
            if first_size is None:
                first_size = read_rgb(image).shape[1::-1]
            size = first_size
        intrinsics = frame_intrinsics(meta, frame, size, tpath, k)
        kind, distortion = camera_of(meta, frame, tpath, k)
        kinds.add(kind)

        depth_path = None
        depth_key = next((key for key in depth_keys if key in frame), None) if use_depth else None
        if depth_key is not None:
            depth_path = _existing(root, frame[depth_key], tpath, f"frames[{k}].{depth_key}")
            if depth_path.suffix.lower() == ".npy":
                raise InputError(depth_path, "a .npy depth map's unit is ambiguous (nerfstudio scales it by its "
                                             "depth_unit_scale_factor, lift3d reads .npy as world units): save it "
                                             "as a uint16 PNG or pass --no-depth")
            depth_used.add(depth_key)
        # nerfstudio's mask_path marks the pixels to train on; instant-ngp's dynamic masks those to leave out.
        mask_path, marks_valid = image.parent / f"dynamic_mask_{image.stem}.png", False
        if "mask_path" in frame:
            mask_path, marks_valid = _existing(root, frame["mask_path"], tpath, f"frames[{k}].mask_path"), True
        frames.append(FrameInput(
            name=image.stem, image_path=image, c2w_opencv=opengl_to_opencv(frame_pose(frame, tpath, k)),
            pose_source=tpath, intrinsics=intrinsics, intrinsics_size=size, labels=_labels_of(preds, image.stem),
            distortion=distortion, depth_path=depth_path, mask_path=mask_path if mask_path.is_file() else None,
            mask_marks_valid=marks_valid,
        ))
    if len(kinds) > 1:
        raise InputError(tpath, "fisheye and perspective cameras are mixed; lift3d needs one camera model per scene")
    if len(depth_used) > 1:
        raise InputError(tpath, "frames mix depth_file_path (unit: --depth-scale) and depth_path (unit: "
                                "integer_depth_scale); give one kind")
    if depth_used == {"depth_path"}:
        scale = _number(meta["integer_depth_scale"], tpath, "integer_depth_scale")
        if not scale > 0:
            raise InputError(tpath, f"integer_depth_scale: must be positive (got {scale})")
        opts = dataclasses.replace(opts, depth_scale=scale)
    camera_model = "OPENCV_FISHEYE" if kinds == {"OPENCV_FISHEYE"} else (
        "OPENCV" if any(fr.distortion for fr in frames) else "PINHOLE")

    stems = [fr.name for fr in frames]
    preds.check(stems)
    cats = preds.resolve_categories(stems, progress=opts.progress)
    splits = file_splits(meta, listed, stems, tpath) or split_every(stems, test_every)
    box = scene_box_from_aabb_scale(meta, tpath)
    if box is not None:
        corners = " .. ".join("[" + ", ".join(f"{v:.3g}" for v in corner) + "]" for corner in box[1])
        note(f"aabb_scale 1: instant-ngp models its unit cube only, so the scene is bounded: scene_box {corners}")
    elif "aabb_scale" in meta:
        note(f"aabb_scale {meta['aabb_scale']}: instant-ngp models space beyond its unit cube; no scene_box is "
             "written, training sizes the space from the content (depth maps or triangulated points)")
    extra = {"source": "nerfstudio", "file": str(tpath), **_applied(meta, tpath)}
    return write_scene(out, frames, cats, camera_model=camera_model, splits=splits, scene_box=box, options=opts,
                       extra_meta={"converted_from": extra})


def _existing(root: Path, rel: Any, where: Path, field_name: str) -> Path:
    if not isinstance(rel, str) or not rel:
        raise InputError(where, f"{field_name}: must be a non-empty path string")
    rel = rel.replace("\\", "/")
    path = Path(rel) if Path(rel).is_absolute() else root / rel
    if not path.is_file():
        raise InputError(path, f"file not found (from {field_name} in {where.name})")
    return path


def _labels_of(preds: PredictionFolder, stem: str) -> Callable:
    return lambda: preds.labels(stem)
