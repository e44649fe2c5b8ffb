"""Depth targets from the images themselves, for training frames without a depth map (docs/sfm.md).

With the poses known, triangulated points say where some surfaces are: a ray through the pixel where a
training frame sees a point should end at the point's depth, give or take its standard deviation. That is
what a depth-supervised NeRF (DS-NeRF, Deng et al., CVPR 2022) trains with. Where the targets come from:

* the scene's own sparse points (``sparse_points`` in ``transforms.json``: ``lift3d triangulate``'s, or
  COLMAP's ``points3D`` kept by ``lift3d convert``), or points the caller triangulated already;
* otherwise points triangulated here at the start of training (:func:`lift3d.sfm.triangulate_scene` on the
  training frames), cached in the run folder so that a resumed run does not redo them;
* with ``image_depth.source dense``, also plane-sweep depth maps (the scene's ``mvs_depth_file_path``, or
  :func:`lift3d.sfm.plane_sweep_scene` here, cached likewise);
* with ``image_depth.source planes``, also the planes of the stuff classes fitted to those points
  (:mod:`lift3d.sfm.planes`): at every ``plane_stride``-th pixel the 2D labels give a stuff class, where the
  ray first meets a plane of that class.

The targets are made by an ordered list of named steps (:mod:`lift3d.train.target_steps`), each with its
settings, the scene premises it needs (:mod:`lift3d.model.profiles`) and the counts it records; ``config.yml``
lists them (``scene.image_depth.steps``). Too few points (too little texture, overlap or baseline) is a warning
recorded there and in the training summary; training then goes on with what there is, RGB only when there is
nothing.
"""

from __future__ import annotations

import dataclasses
import io
import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from lift3d.data.scene import Scene
from lift3d.data.stereo import DenseDepth, SparsePoints, read_sparse_points, write_sparse_points_files
from lift3d.errors import InputError
from lift3d.model.config import ImageDepthConfig
from lift3d.model.profiles import PROFILES
from lift3d.train.profile import premises_from_planes
from lift3d.utils.atomic import write_bytes_atomic
from lift3d.utils.steps import run_steps

#: Fewer usable observations than this per training frame (median) is reported as a warning.
MIN_OBSERVATIONS_PER_FRAME = 10
#: The cache of a run folder: triangulated points and plane-sweep maps computed at training start.
CACHE_DIR = "image_depth"
SOURCES = ("auto", "sparse", "dense", "planes", "none")
#: The steps that are sources of their own (their counts were top-level entries of ``scene.image_depth``);
#: every other step belongs to the stuff planes (its counts were under ``planes``).
SOURCE_STEPS = ("sparse-points", "plane-sweep", "plane-sweep-on-things")


@dataclass
class DepthTargets:
    """Per-pixel depth targets of the training frames (one row per target).

    Attributes
    ----------
    frame : np.ndarray
        ``int64 [T]`` scene frame index.
    u, v : np.ndarray
        ``float32 [T]`` pixel coordinates in :class:`~lift3d.render.rays.RayGenerator`'s convention (the
        centre of pixel column ``c`` is ``u = c``); a sparse point's ray goes exactly through its keypoint.
    z, sigma : np.ndarray
        ``float32 [T]`` z-depth (along the optical axis) and its standard deviation, world units.
    dense : np.ndarray
        ``bool [T]`` the target comes from a plane-sweep depth map or a stuff plane (else from a sparse point).
    info : dict
        What config.yml and the summary record: ``source``, ``requested``, ``premises``, ``points_from``,
        ``points``, ``median_error_px``, ``dense_from``, ``targets``, ``frames_with_targets``,
        ``frames_without_depth``, ``seconds``, ``warnings``, and ``steps``: each step's
        :meth:`~lift3d.utils.steps.StepRecord.to_json` (what it counted: ``observations``,
        ``dense_coverage``, the planes' counts...; :func:`flat_info` puts them where they were before the
        steps).
    """

    frame: np.ndarray
    u: np.ndarray
    v: np.ndarray
    z: np.ndarray
    sigma: np.ndarray
    dense: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.frame)

    @classmethod
    def empty(cls, info: dict[str, Any] | None = None) -> "DepthTargets":
        f = np.zeros(0, np.float32)
        return cls(np.zeros(0, np.int64), f, f, f, f, np.zeros(0, bool), dict(info or {}))


def frames_without_depth(scene: Scene, frames: np.ndarray) -> np.ndarray:
    """The frames of ``frames`` that have no depth map of their own (``depth_file_path``)."""
    return np.asarray([int(i) for i in frames if scene.frames[int(i)].depth_path is None], np.int64)


def is_bounded(scene: Scene | None) -> bool:
    """Whether ``scene`` has a bounded scene box."""
    return scene is not None and scene.scene_box is not None and scene.scene_box.type == "bounded"


def default_premises(scene: Scene | None) -> frozenset[str]:
    """The premises the depth targets assumed before scenes had profiles, so that leaving them out changes
    nothing: a scene with a bounded box is a room with square walls that fills its box (``manhattan-room``);
    elsewhere the planes (which only an explicit ``source planes`` fits there) still assumed a room with square
    walls, but not the box."""
    return PROFILES["manhattan-room"] if is_bounded(scene) else frozenset({"room", "manhattan"})


def shown_premises(scene: Scene | None, premises: Iterable[str] | None = None) -> frozenset[str]:
    """``premises`` (default: :func:`default_premises`), without ``box`` where the scene has no bounded box to be
    the room."""
    shown = default_premises(scene) if premises is None else frozenset(premises)
    return shown if is_bounded(scene) else shown - {"box"}


def auto_source(scene: Scene | None, premises: Iterable[str] | None = None, profile: str | None = None) -> str:
    """What ``image_depth.source auto`` is. With the scene's profile (:mod:`lift3d.train.profile`): ``planes``
    where the room premise holds (the stuff planes and the room rules: measured on rooms), ``sparse`` outdoors
    (the plane sweep is not measured there), ``dense`` elsewhere (plane-sweep stereo assumes nothing of the
    scene). Without one (callers from before profiles): ``planes`` in a bounded scene box, ``sparse`` otherwise."""
    if profile is None:
        return "planes" if is_bounded(scene) else "sparse"
    if "room" in set(premises or ()):
        return "planes"
    return "sparse" if profile == "outdoor" else "dense"


def resolve_source(source: str, scene: Scene | None = None, premises: Iterable[str] | None = None,
                   profile: str | None = None) -> str:
    """``source``, with ``auto`` resolved by :func:`auto_source`; an unknown source is an :class:`InputError`."""
    if source not in SOURCES:
        raise InputError("--image_depth.source", f"unknown source {source!r} ({', '.join(SOURCES)})")
    return auto_source(scene, premises, profile) if source == "auto" else source


def image_depth_targets(scene: Scene, frames: np.ndarray, cfg: ImageDepthConfig, cache: Path | None = None,
                        progress: bool = False, premises: Iterable[str] | None = None,
                        sparse: SparsePoints | None = None, profile: str | None = None,
                        dense: DenseDepth | None = None, refine_room: bool = False) -> DepthTargets:
    """Depth targets for the frames of ``frames`` that have no depth map.

    Parameters
    ----------
    scene : Scene
    frames : np.ndarray
        The training frames (held-out views never contribute: triangulation uses these frames only).
    cfg : ImageDepthConfig
    cache : Path, optional
        Folder (the run's ``image_depth/``) where points and maps computed here are kept and read back.
    progress : bool
    premises : iterable of str, optional
        The premises the scene shows (its profile's, :mod:`lift3d.model.profiles`): a step that needs one it
        does not show is skipped, and recorded so. Default: :func:`default_premises` (as before profiles).
    sparse : SparsePoints, optional
        Points the caller has already (:func:`scene_sparse_points`: the scene space is sized from them before
        training), observations indexing the scene's frames by name: used instead of the scene's, the cached or
        newly triangulated ones, and written to ``cache``.
    profile : str, optional
        The scene's profile, for what ``auto`` means (:func:`auto_source`).
    dense : DenseDepth, optional
        Plane-sweep maps of ``frames`` the caller computed already (:func:`scene_dense_maps`), used instead of
        the scene's, the cached or newly computed ones, and written to ``cache``.
    refine_room : bool
        In a room (``premises`` hold ``room``), decide ``manhattan`` and ``box`` again from the stuff planes once
        they are fitted with the labels' wall feet (:func:`lift3d.train.profile.premises_from_planes`); the
        result is in ``info["premises"]`` and ``info["room_evidence"]``.

    Returns
    -------
    DepthTargets
        Possibly empty (source ``none``, every frame has a depth map, nothing could be triangulated).
    """
    shown = shown_premises(scene, premises)
    source = resolve_source(cfg.source, scene, shown, profile)
    targets_for = frames_without_depth(scene, frames)
    info: dict[str, Any] = {"source": source, "requested": cfg.source, "premises": sorted(shown), "warnings": []}
    if source == "none" or len(targets_for) == 0:
        if source != "none":
            info["source"] = "none (every training frame has a depth map)"
        return DepthTargets.empty(info)
    t0 = time.perf_counter()
    points, origin = scene_sparse_points(scene, frames, cache, progress, sparse)
    info["points_from"] = origin
    info["points"] = int(len(points))
    info["median_error_px"] = round(points.median_error, 3) if len(points) else None
    if origin == "triangulated" or sparse is not None:  # the triangulation's own warnings
        info["warnings"] += list(points.info.get("warnings", []))
    given_dense, dense, labels = dense, None, None
    if source in ("dense", "planes"):
        dense, info["dense_from"] = scene_dense_maps(scene, frames, points, cache, progress, given_dense)
    if source == "planes":
        labels = {int(i): scene.pseudo_labels(int(i)).semantic for i in frames}  # read once for every step
    # here, not at module level: keeps `import lift3d.train` cheap (the steps use lift3d.sfm, which loads OpenCV)
    from lift3d.train.target_steps import PlaneSettings, TargetContext, TargetState, target_steps

    context = TargetContext(scene, np.asarray(frames), targets_for, points, dense, labels, shown,
                            PlaneSettings.from_config(cfg))
    state = TargetState()
    steps = target_steps(source, cfg)
    # A room's square walls and whether its box is the room: the content before training may not show them
    # (plain walls give stereo next to nothing); the stuff planes fitted with the labels' wall feet do.
    split = next((k + 1 for k, step in enumerate(steps) if step.name == "floor-boundary"), len(steps))
    records = run_steps(steps[:split], state, context, shown)
    if refine_room and "room" in shown and state.has_planes():
        shown, info["room_evidence"] = _room_premises(scene, state)
        context = dataclasses.replace(context, premises=shown)
        info["premises"] = sorted(shown)
    records += run_steps(steps[split:], state, context, shown)
    info["steps"] = [r.to_json() for r in records]
    empty = DepthTargets.empty()
    rows = state.rows or [(empty.frame, empty.u, empty.v, empty.z, empty.sigma, empty.dense)]
    frame, u, v, z, sigma, dense_flag = (np.concatenate(a) for a in zip(*rows))
    finite = np.isfinite(z) & np.isfinite(sigma) & (z > 0) & (sigma > 0)
    targets = DepthTargets(frame[finite], u[finite], v[finite], z[finite], sigma[finite], dense_flag[finite], info)
    counts = np.bincount(np.searchsorted(targets_for, targets.frame), minlength=len(targets_for))
    info["targets"] = int(len(targets))
    info["frames_with_targets"] = int((counts > 0).sum())
    info["frames_without_depth"] = int(len(targets_for))
    info["seconds"] = round(time.perf_counter() - t0, 2)
    if np.median(counts) < MIN_OBSERVATIONS_PER_FRAME:
        info["warnings"].append(
            f"only {int(np.median(counts))} depth targets per training frame (median): too little texture, overlap "
            "or baseline for depth from the images; training relies on the colours" +
            (" alone" if len(targets) == 0 else " mostly"))
    return targets


def _room_premises(scene: Scene, state) -> tuple[frozenset[str], dict[str, Any]]:
    """The room's premises from the stuff planes fitted so far (:func:`lift3d.train.profile.premises_from_planes`)."""
    up = state.floor[1] if state.floor is not None else state.level_to
    box = np.asarray(scene.scene_box.aabb, float) if is_bounded(scene) else None
    premises, evidence = premises_from_planes(state.planes, np.asarray(up, float), box)
    return premises, evidence


def flat_info(info: dict[str, Any] | None) -> dict[str, Any] | None:
    """``scene.image_depth`` in the layout it had before the steps: each source step's counts at the top, the
    plane steps' under ``planes`` (what the training summary reads). A record of that layout is returned as it
    is.

    Examples
    --------
    >>> flat_info({"source": "planes", "targets": 9, "steps": [
    ...     {"name": "sparse-points", "ran": True, "why": "on", "seconds": 0.0, "counts": {"observations": 4}},
    ...     {"name": "square-walls", "ran": True, "why": "on", "seconds": 0.1, "counts": {"walls_squared": 2}},
    ...     {"name": "wall-reach", "ran": False, "why": "premise not shown: box"}]})
    {'source': 'planes', 'targets': 9, 'observations': 4, 'planes': {'walls_squared': 2}}
    """
    if not info or "steps" not in info:
        return info
    out = {k: v for k, v in info.items() if k not in ("steps", "premises")}
    planes: dict[str, Any] = {}
    for record in info["steps"]:
        (out if record["name"] in SOURCE_STEPS else planes).update(record.get("counts", {}))
    if any(record["name"] not in SOURCE_STEPS for record in info["steps"]):
        out["planes"] = planes
    return out


# ------------------------------------------------------------------------------------------ sparse points
def scene_sparse_points(scene: Scene, frames: np.ndarray, cache: Path | None, progress: bool,
                        given: SparsePoints | None = None) -> tuple[SparsePoints, str]:
    """``given`` (written to the cache), else the scene's sparse points, else the cached ones, else triangulated
    now from the images of ``frames`` (and cached); observations indexed by scene frame. Returns them and where
    they came from (also kept in their ``info["origin"]``, so points handed on say where they were made)."""
    if given is not None:
        if cache is not None:
            write_sparse_points_files(cache, given)
        origin = given.info.get("origin") or f"given ({given.info.get('source', 'by the caller')})"
        return _by_scene_frame(scene, given), str(origin)
    own = scene.sparse_points()
    if own is not None:
        return _with_origin(own, f"scene ({_scene_points_source(scene)})")
    names = [f.name for f in scene.frames]
    if cache is not None and (cache / "sparse" / "points3D.ply").is_file():
        return _with_origin(read_sparse_points(cache / "sparse" / "points3D.ply", cache / "sparse" / "observations.npz",
                                               frame_names=names), "triangulated (cached)")
    # here, not at module level: keeps `import lift3d.train` cheap (OpenCV's feature code loads only when a
    # run triangulates)
    from lift3d.sfm import triangulate_scene

    sparse = triangulate_scene(scene, frames, progress=progress)
    if cache is not None:
        write_sparse_points_files(cache, sparse)
    sparse.info["origin"] = "triangulated"
    return _by_scene_frame(scene, sparse), "triangulated"


def _with_origin(sparse: SparsePoints, origin: str) -> tuple[SparsePoints, str]:
    sparse.info["origin"] = origin
    return sparse, origin


def _by_scene_frame(scene: Scene, sparse: SparsePoints) -> SparsePoints:
    """``sparse`` with its observations indexing the scene's frames (its ``frame_names`` are the scene's)."""
    index = {f.name: k for k, f in enumerate(scene.frames)}
    missing = sorted(set(sparse.frame_names) - set(index))
    if missing:
        raise InputError("sparse points", f"observations of frames the scene does not have ({', '.join(missing[:3])})")
    lut = np.asarray([index[n] for n in sparse.frame_names], np.int64)
    return replace(sparse, obs_frame=lut[sparse.obs_frame].astype(np.int32), frame_names=[f.name for f in scene.frames])


def _scene_points_source(scene: Scene) -> str:
    try:
        meta = json.loads((scene.root / "transforms.json").read_text(encoding="utf-8"))
        return str(meta.get("sparse_points", {}).get("source", "sparse_points"))
    except (OSError, ValueError):
        return "sparse_points"


# ------------------------------------------------------------------------------------------ dense maps
def scene_dense_maps(scene: Scene, frames: np.ndarray, sparse: SparsePoints, cache: Path | None, progress: bool,
                     given: DenseDepth | None = None) -> tuple[DenseDepth, str]:
    """Plane-sweep depth maps of ``frames``: ``given`` (written to the cache), else the scene's
    (``mvs_depth_file_path``), else the cached ones, else computed now from the images (and cached); and where they
    came from."""
    names = [scene.frames[int(i)].name for i in frames]
    path = None if cache is None else cache / "mvs.npz"
    if given is not None:
        if list(given.frame_names) != names:
            raise InputError("plane-sweep maps", "given for other frames than the training frames")
        if path is not None and given.support is not None:
            _write_dense_cache(path, names, given)
        return given, str(given.info.get("origin", "given by the caller"))
    if all(scene.frames[int(i)].mvs_depth_path is not None for i in frames):
        maps = [scene.mvs_depth(int(i)) for i in frames]
        supports = [scene.mvs_support(int(i)) for i in frames]
        return DenseDepth(names, [m[0] for m in maps], [m[1] for m in maps],
                          support=supports if all(n is not None for n in supports) else None), \
            "scene (mvs_depth_file_path)"
    if path is not None and path.is_file():
        with np.load(path, allow_pickle=False) as z:
            if [str(n) for n in z["names"]] == names:
                support = list(z["support"]) if "support" in z.files else None
                return DenseDepth(names, list(z["depth"]), list(z["sigma"]), support=support), \
                    "plane sweep (cached)"
    # here, not at module level: keeps `import lift3d.train` cheap (the plane sweep's OpenCV code loads only
    # when a run uses it)
    from lift3d.sfm import plane_sweep_scene

    dense = plane_sweep_scene(scene, frames, sparse=sparse, progress=progress)
    dense.info["origin"] = "plane sweep"
    if path is not None:
        _write_dense_cache(path, names, dense)
    return dense, "plane sweep"


def _write_dense_cache(path: Path, names: list[str], dense: DenseDepth) -> None:
    buf = io.BytesIO()
    np.savez_compressed(buf, names=np.asarray(names, dtype=str), depth=np.stack(dense.depth),
                        sigma=np.stack(dense.sigma), support=np.stack(dense.support))
    write_bytes_atomic(path, buf.getvalue())
