"""Open3D's RGB-D dataset layout (its reconstruction system, its RGB-D recorders, Redwood data) into a scene
folder::

    DIR/
      image/<n>.jpg|png          colour frames (or color/, rgb/: the first that exists, as Open3D looks)
      depth/<n>.png              uint16 depth, millimetres by default (--depth-scale)
      scene/trajectory.log       camera poses, as Open3D's reconstruction system writes them (or --poses)
      intrinsic.json             PinholeCameraIntrinsic (Open3D's recorders write it; or --intrinsic)

with optional 2D panoptic predictions from ``--predictions`` (:mod:`lift3d.convert.predictions`).

Conventions, as Open3D's source code has them (``cpp/open3d/io/file_format/FileLOG.cpp``,
``cpp/open3d/utility/IJsonConvertible.cpp``, ``cpp/open3d/pipelines/registration/PoseGraph.cpp``,
``cpp/open3d/geometry/PointCloudFactory.cpp``, ``examples/python/reconstruction_system``):

* **trajectory.log** (Redwood's "log" format): per frame a line of three integers (metadata; Open3D writes
  ``i i i+1`` and its reader ignores them), then the 4×4 **camera-to-world** matrix row by row. Open3D's
  reader sets the camera's extrinsic (world-to-camera) to the inverse of that matrix. Poses pair with the
  colour frames in order.
* **PoseGraph JSON** (``class_name: PoseGraph``): ``nodes[k].pose`` is **camera-to-world** (the reconstruction
  system makes node ``k`` the inverse of the accumulated odometry and integrates frame ``k`` with extrinsic
  ``inv(pose)``); Open3D stores 4×4 matrices as 16 numbers in **column-major** order (Eigen's).
* **PinholeCameraTrajectory JSON**: ``parameters[k].extrinsic`` is world-to-camera (column-major); it is
  inverted here.
* **PinholeCameraIntrinsic JSON**: ``width``, ``height`` and ``intrinsic_matrix``, the 3×3 K as 9 numbers in
  column-major order: ``[fx, 0, 0, 0, fy, 0, cx, cy, 1]``. Recorders add ``depth_scale``, depth units per
  metre (1000 = millimetres): the inverse of lift3d's ``--depth-scale``.
* **Camera axes** are OpenCV's (x right, y down, looking down +z): Open3D back-projects pixel column ``u``,
  row ``v`` at depth ``z`` to ``((u − cx) z / fx, (v − cy) z / fy, z)``.
* **Pixel centres**: in that formula ``u, v`` are the integer pixel indices, so Open3D puts pixel centres on
  integer coordinates (its PrimeSense default ``cx = 319.5`` is the middle of a 640-pixel row). lift3d puts
  them at +0.5, so 0.5 is added to ``cx`` and ``cy``.

The poses' world frame is kept (no recentring).

Open3D's own readers (``open3d.io.read_pinhole_camera_trajectory`` …) are not used: on a malformed file they
log a warning and return an empty or partly filled object, where a conversion must stop with the file and
line at fault.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lift3d.convert import FrameInput, WriteOptions, every_nth, note, split_every, write_scene
from lift3d.convert.scannet import half_pixel, list_frames, prediction_folder
from lift3d.data.cameras import is_rigid
from lift3d.data.scene import Category, Scene
from lift3d.errors import InputError
from lift3d.utils.files import read_json

#: Colour folders, in the order Open3D's reconstruction system looks for them.
COLOUR_FOLDERS = ("image", "rgb", "color")
#: Where the poses are looked for without ``--poses`` (relative to DIR); then ``*/trajectory.log``.
POSE_FILES = ("trajectory.log", "scene/trajectory.log")
#: ``--intrinsic primesense``: Open3D's ``PinholeCameraIntrinsicParameters.PrimeSenseDefault``
#: ``(width, height, fx, fy, cx, cy)``, integer pixel centres.
PRIMESENSE = (640, 480, 525.0, 525.0, 319.5, 239.5)


def colour_frames(root: Path) -> list[tuple[str, Path]]:
    """``(stem, path)`` of the colour frames in the first of ``image/``, ``rgb/``, ``color/``, natural order.

    Raises
    ------
    InputError
        No colour folder, no images, or ``.jpg`` and ``.png`` frames mixed (Open3D would list all ``.jpg``
        frames before all ``.png`` ones, so the order the poses refer to would be unclear).
    """
    folder = next((f for f in COLOUR_FOLDERS if (root / f).is_dir()), None)
    if folder is None:
        raise InputError(root / COLOUR_FOLDERS[0], "folder not found (colour frames: image/, rgb/ or color/)")
    frames = list_frames(root, folder)
    kinds = {p.suffix.lower().replace(".jpeg", ".jpg") for _, p in frames}
    if len(kinds) > 1:
        raise InputError(root / folder, "holds both .jpg and .png frames; keep one format so the frame order "
                                        "is the one the poses were made in")
    return frames


def depth_frames(root: Path, colour: list[tuple[str, Path]]) -> list[Path] | None:
    """The ``depth/*.png`` frame of every colour frame, paired by sorted (natural) order as Open3D pairs
    them; None when there is no ``depth/`` folder.

    Raises
    ------
    InputError
        When the counts differ, or when some file names match but not at the same place in the order
        (a frame missing on one side, which pairing by order would hide).
    """
    d = root / "depth"
    if not d.is_dir():
        return None
    depth = list_frames(root, "depth")
    if len(depth) != len(colour):
        raise InputError(d, f"has {len(depth)} depth frames but {colour[0][1].parent.name}/ has {len(colour)} "
                            "colour frames (they pair in sorted order)")
    colour_stems = [s for s, _ in colour]
    depth_stems = [s for s, _ in depth]
    if set(colour_stems) & set(depth_stems):
        for (cs, _), (ds, _) in zip(colour, depth):
            if cs != ds:
                raise InputError(d, f"colour frame {cs!r} pairs with depth frame {ds!r} in sorted order, but "
                                    "other file names match: is a frame missing on one side?")
    not_png = [p.name for _, p in depth if p.suffix.lower() != ".png"]
    if not_png:
        raise InputError(d / not_png[0], "depth frames must be 16-bit PNGs")
    return [p for _, p in depth]


def find_pose_file(root: Path, poses: str | Path | None) -> Path:
    """``--poses``, else the first of ``DIR/trajectory.log``, ``DIR/scene/trajectory.log``, else the only
    ``DIR/*/trajectory.log``.

    Raises
    ------
    InputError
        ``--poses`` missing on disk, no pose file found, or several ``*/trajectory.log`` to choose from.
    """
    if poses is not None:
        p = Path(poses)
        if not p.is_file():
            raise InputError(p, "file not found (--poses)")
        return p
    for rel in POSE_FILES:
        if (root / rel).is_file():
            return root / rel
    found = sorted(p for p in root.glob("*/trajectory.log") if p.is_file())
    if len(found) == 1:
        note(f"poses from {found[0]}")
        return found[0]
    if found:
        listed = ", ".join(str(p.relative_to(root)) for p in found)
        raise InputError(root, f"several trajectory.log files ({listed}); choose one with --poses FILE")
    raise InputError(root, "no poses: found none of trajectory.log, scene/trajectory.log, */trajectory.log; pass "
                           "--poses FILE (a trajectory .log, or an Open3D pose graph or camera trajectory .json)")


def read_trajectory_log(path: Path) -> list[np.ndarray]:
    """Camera-to-world matrices (OpenCV axes) of a trajectory ``.log``, in file order.

    Examples
    --------
    >>> import tempfile, os
    >>> p = Path(tempfile.mkdtemp()) / "trajectory.log"
    >>> _ = p.write_text("0 0 1\\n1 0 0 0.5\\n0 1 0 0\\n0 0 1 2\\n0 0 0 1\\n")
    >>> read_trajectory_log(p)[0][:3, 3].tolist()
    [0.5, 0.0, 2.0]

    Raises
    ------
    InputError
        Naming the line: a metadata line that is not three integers, a matrix row that is not four numbers,
        a file that ends inside a block, a matrix that is not a rigid transform.
    """
    if not path.is_file():
        raise InputError(path, "file not found")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot be read ({exc})") from exc
    lines = [(n, line.split()) for n, line in enumerate(text.splitlines(), 1)
             if line.strip() and not line.lstrip().startswith("#")]
    poses = []
    for start in range(0, len(lines), 5):
        block = lines[start:start + 5]
        n, meta = block[0]
        if len(meta) != 3 or not all(t.lstrip("+-").isdigit() for t in meta):
            raise InputError(path, f"line {n}: expected three integers (the frame's metadata line) before each "
                                   f"4x4 matrix (got {' '.join(meta)!r})")
        if len(block) < 5:
            raise InputError(path, f"line {n}: the file ends before this frame's 4x4 matrix is complete")
        rows = []
        for n_row, tokens in block[1:]:
            try:
                row = [float(t) for t in tokens]
            except ValueError:
                row = []
            if len(row) != 4:
                raise InputError(path, f"line {n_row}: expected a row of four numbers of a 4x4 camera-to-world "
                                       f"matrix (got {' '.join(tokens)!r})")
            rows.append(row)
        poses.append(_checked_pose(np.array(rows), path, f"line {n}: the pose of frame {len(poses)}"))
    if not poses:
        raise InputError(path, "no poses in the file")
    return poses


def read_pose_json(path: Path) -> list[np.ndarray]:
    """Camera-to-world matrices (OpenCV axes) of an Open3D ``PoseGraph`` (node poses) or
    ``PinholeCameraTrajectory`` (inverted extrinsics) JSON, in file order.

    Raises
    ------
    InputError
        Naming the file and the entry: another kind of JSON, a matrix that is not 16 finite numbers, a pose
        that is not a rigid transform.
    """
    doc = read_json(path)
    kind = doc.get("class_name") if isinstance(doc, dict) else None
    if kind == "PoseGraph" or (isinstance(doc, dict) and "nodes" in doc and kind is None):
        entries, key, field, inverse = doc.get("nodes"), "nodes", "pose", False
    elif kind == "PinholeCameraTrajectory":
        entries, key, field, inverse = doc.get("parameters"), "parameters", "extrinsic", True
    else:
        raise InputError(path, "expected an Open3D PoseGraph (nodes[].pose) or PinholeCameraTrajectory "
                               f"(parameters[].extrinsic) JSON (class_name is {kind!r})")
    if not isinstance(entries, list) or not entries:
        raise InputError(path, f"{key}: missing or empty")
    poses = []
    for k, entry in enumerate(entries):
        where = f"{key}[{k}].{field}"
        values = entry.get(field) if isinstance(entry, dict) else None
        try:
            m = np.asarray(values, dtype=np.float64)
        except (TypeError, ValueError):
            m = np.zeros(0)
        if m.shape != (16,):
            raise InputError(path, f"{where}: expected 16 numbers (a 4x4 matrix, column-major)")
        m = m.reshape(4, 4, order="F")  # Open3D writes Eigen's storage order: column by column
        m = _checked_pose(m, path, where)
        poses.append(np.linalg.inv(m) if inverse else m)
    return poses


def _checked_pose(m: np.ndarray, path: Path, where: str) -> np.ndarray:
    if not np.all(np.isfinite(m)):
        raise InputError(path, f"{where} is not finite")
    if not is_rigid(m, atol=1e-3):
        raise InputError(path, f"{where} is not a rigid transform (rotation must be orthonormal with det +1, "
                               "last row 0 0 0 1)")
    return m


def read_poses(path: Path) -> list[np.ndarray]:
    """The camera-to-world matrices of a pose file: ``.log`` (or ``.txt``) trajectory, or ``.json``."""
    suffix = path.suffix.lower()
    if suffix in (".log", ".txt"):
        return read_trajectory_log(path)
    if suffix == ".json":
        return read_pose_json(path)
    raise InputError(path, "poses must be a trajectory .log or an Open3D pose graph / camera trajectory .json")


def read_intrinsic(spec: str | Path | None, root: Path,
                   depth_scale: float) -> tuple[tuple[float, float, float, float], tuple[int, int], str]:
    """Intrinsics from ``--intrinsic``: an Open3D PinholeCameraIntrinsic JSON, or ``primesense``.

    Parameters
    ----------
    spec : str, Path or None
        The flag's value; None looks for ``DIR/intrinsic.json`` (what Open3D's recorders write).
    root : Path
        The dataset folder.
    depth_scale : float
        ``--depth-scale`` (metres per unit), checked against the JSON's ``depth_scale`` when it has one.

    Returns
    -------
    intrinsics : tuple
        ``(fx, fy, cx, cy)`` in Open3D's convention (integer pixel centres).
    size : tuple
        ``(width, height)`` they refer to.
    source : str
        The file, or ``primesense``.

    Raises
    ------
    InputError
        Naming the file (or ``--intrinsic``): missing, not JSON, missing or malformed fields, a matrix in row
        order, skew, a ``depth_scale`` that contradicts ``--depth-scale``.
    """
    if spec is not None and str(spec).lower() == "primesense":
        w, h, fx, fy, cx, cy = PRIMESENSE
        return (fx, fy, cx, cy), (w, h), "primesense"
    if spec is None:
        path = root / "intrinsic.json"
        if not path.is_file():
            raise InputError("--intrinsic", f"required: an Open3D PinholeCameraIntrinsic JSON ({path} not "
                                            "found), or 'primesense' for Open3D's PrimeSense default (640x480, "
                                            "f = 525)")
        note(f"intrinsics from {path}")
    else:
        path = Path(spec)
    doc = read_json(path)
    if isinstance(doc, dict) and "intrinsic_matrix" not in doc and isinstance(doc.get("intrinsic"), dict):
        doc = doc["intrinsic"]  # a PinholeCameraParameters JSON holds one
    if not isinstance(doc, dict) or "intrinsic_matrix" not in doc:
        raise InputError(path, "expected an Open3D PinholeCameraIntrinsic JSON with width, height and "
                               "intrinsic_matrix")
    w, h = doc.get("width"), doc.get("height")
    if not (isinstance(w, int) and isinstance(h, int) and w > 0 and h > 0):
        raise InputError(path, f"width/height: must be positive integers, the image size (got {w!r}, {h!r})")
    try:
        values = np.asarray(doc["intrinsic_matrix"], dtype=np.float64)
    except (TypeError, ValueError):
        values = np.zeros(0)
    if values.shape != (9,) or not np.all(np.isfinite(values)):
        raise InputError(path, "intrinsic_matrix: expected 9 finite numbers (3x3 K, column-major)")
    k = values.reshape(3, 3, order="F")  # Open3D writes Eigen's storage order: column by column
    if k[1, 0] != 0 or k[2, 0] != 0 or k[2, 1] != 0 or k[2, 2] != 1:
        hint = " (it looks written row by row)" if values[2] != 0 and values[6] == values[7] == 0 else ""
        raise InputError(path, "intrinsic_matrix: expected Open3D's column-major [fx, 0, 0, 0, fy, 0, cx, cy, "
                               f"1] (got {values.tolist()}){hint}")
    if k[0, 1] != 0:
        raise InputError(path, f"intrinsic_matrix: skew {k[0, 1]} is not supported (lift3d cameras have none)")
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    if not (fx > 0 and fy > 0):
        raise InputError(path, f"intrinsic_matrix: focal lengths must be positive (got fx={fx}, fy={fy})")
    if "depth_scale" in doc:
        units = doc["depth_scale"]
        if not isinstance(units, (int, float)) or not units > 0:
            raise InputError(path, f"depth_scale: must be a positive number of depth units per metre (got "
                                   f"{units!r})")
        if abs(1.0 / units - depth_scale) > 1e-6 * depth_scale:
            raise InputError(path, f"depth_scale {units:g} (depth units per metre) does not match --depth-scale "
                                   f"{depth_scale:g} (metres per unit): pass --depth-scale {1.0 / units:g}")
    return (float(fx), float(fy), float(cx), float(cy)), (w, h), str(path)


def convert(
    src: str | Path,
    out: str | Path,
    *,
    intrinsic: str | Path | None,
    poses: str | Path | None = None,
    predictions: str | Path | None = None,
    categories: list[Category] | None = None,
    things: list[int] | None = None,
    test_every: int = 8,
    use_depth: bool = True,
    options: WriteOptions | None = None,
) -> Scene:
    """Convert an Open3D RGB-D dataset folder (module docstring) into a scene folder.

    Parameters
    ----------
    src : str or Path
        The dataset folder ``DIR``.
    out : str or Path
        Output scene folder.
    intrinsic : str, Path or None
        An Open3D PinholeCameraIntrinsic JSON, ``"primesense"``, or None for ``DIR/intrinsic.json``.
    poses : str or Path, optional
        Pose file (``.log`` or ``.json``); default: :func:`find_pose_file`.
    predictions : str or Path, optional
        2D panoptic predictions matched to the colour frames by stem; None writes a scene without
        pseudo-labels (``lift3d label`` adds them).
    categories, things
        As for :func:`lift3d.convert.colmap.convert` (only with ``predictions``).
    test_every : int
        Every N-th frame (in order) is a test frame; 0 keeps all for training.
    use_depth : bool
        Include ``depth/*.png``.
    options : WriteOptions, optional
        Output options (``depth_scale`` also reads the input depth; ``depth_as_gt``).

    Examples
    --------
    >>> convert("livingroom1", "scenes/livingroom1", intrinsic="primesense",  # doctest: +SKIP
    ...         options=WriteOptions(depth_as_gt=True))
    """
    opts = options or WriteOptions()
    root = Path(src)
    if not root.is_dir():
        raise InputError(root, "folder not found")
    colour = colour_frames(root)
    depth = depth_frames(root, colour) if use_depth else None
    if use_depth and depth is None:
        note(f"{root / 'depth'} not found: converting colour frames and poses only")
    intr, size, intr_source = read_intrinsic(intrinsic, root, opts.depth_scale)
    pose_file = find_pose_file(root, poses)
    c2w = read_poses(pose_file)
    if len(c2w) != len(colour):
        hint = (" (a reconstruction system's scene pose graph has one node per fragment, not per frame: use "
                "scene/trajectory.log)" if pose_file.suffix.lower() == ".json" and len(c2w) < len(colour) else "")
        raise InputError(pose_file, f"has {len(c2w)} poses but {colour[0][1].parent} has {len(colour)} colour "
                                    f"frames (poses pair with frames in sorted order){hint}")
    kept = every_nth(range(len(colour)), opts.frame_step)
    colour, c2w = [colour[k] for k in kept], [c2w[k] for k in kept]
    depth = [depth[k] for k in kept] if depth is not None else None
    stems = [s for s, _ in colour]
    preds, cats = prediction_folder(predictions, categories, things, stems, opts)
    frames = [FrameInput(
        name=stem, image_path=img, c2w_opencv=pose, pose_source=pose_file, intrinsics=half_pixel(intr),
        intrinsics_size=size, labels=(lambda stem=stem: preds.labels(stem)) if preds else None,
        depth_path=depth[k] if depth is not None else None,
    ) for k, ((stem, img), pose) in enumerate(zip(colour, c2w))]
    meta = {"converted_from": {"source": "open3d", "path": str(root), "poses": str(pose_file),
                               "intrinsic": intr_source}}
    return write_scene(out, frames, cats, camera_model="PINHOLE", splits=split_every(stems, test_every),
                       options=opts, extra_meta=meta)
