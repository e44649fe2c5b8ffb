"""``make_scene``: build a synthetic scene, place cameras, ray cast every view, simulate the 2D segmenter and
the sensors, and write the scene folder (docs/scene-format.md).

Random streams are separate and seeded from ``seed`` alone, so a scene is reproducible byte for byte and each
option changes only what it is about (a ``moderate`` and a ``view-correlated`` scene of one seed differ only in
their pseudo-labels; ``--depth`` changes only the depth maps; ``--pose-noise`` only the written poses):

* layout (room or street, objects, textures, lighting) ``SeedSequence([seed, 0, kind])``,
* cameras (path choice under ``auto``, field of view, the path) ``SeedSequence([seed, 1, kind])``,
* the segmenter of frame ``i`` ``SeedSequence([seed, 2, kind, i])`` — one stream per frame, which is what
  makes the independent errors independent across views,
* the view-correlated confusers ``SeedSequence([seed, 3, kind])`` and their per-frame draws
  ``SeedSequence([seed, 4, kind, i])``,
* the depth sensor of frame ``i`` ``SeedSequence([seed, 5, kind, i])``,
* the pose noise ``SeedSequence([seed, 6, kind])``,
* the clutter (``--clutter``: whether ``auto`` makes a dense room, and what the dense room adds)
  ``SeedSequence([seed, 7, kind])``.
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from lift3d.data.cameras import Cameras
from lift3d.data.scene import FrameGroundTruth, FramePseudoLabels, Segment, SceneWriter
from lift3d.errors import InputError
from lift3d.synth.cameras import MIN_CLEARANCE, PATHS, PATHS_OF_KIND
from lift3d.synth.cameras import camera_path as plan_camera_path
from lift3d.synth.geometry import RayCaster, SceneContent
from lift3d.synth.indoor import CLUTTER_LEVELS, ROOM_SHAPES, build_indoor
from lift3d.synth.polygons import upright_box, yawed_box
from lift3d.synth.noise import PRESETS, NoiseConfig, NoiseStats, ViewConfusers, noise_config, simulate_segmenter
from lift3d.synth.outdoor import build_outdoor
from lift3d.synth.sensors import DEPTH_MODES, DepthSensor, perturb_poses, pose_error
from lift3d.utils.atomic import write_json_atomic
from lift3d.utils.progress import progress_bar

KINDS = ("indoor", "outdoor")
#: ``--camera-path`` choices.
CAMERA_PATHS = ("auto",) + PATHS
#: Marker in transforms.json: a folder holding it may be overwritten by a new ``lift3d synth`` run.
SYNTH_META_KEY = "lift3d_synth"
#: Version of what ``lift3d synth`` writes (2: scene variety, camera paths, sensor depth, pose noise,
#: view-correlated noise, disjoint val/test splits).
SYNTH_VERSION = 2
#: What ``make_scene`` writes, and so what it may remove when it overwrites an earlier synthetic scene.
_OWNED = ("images", "panoptic", "gt", "depth", "transforms.json", "panoptic.json", "synth_noise.json")
#: Rotated-grid supersampling offsets (pixels from the centre): anti-aliased colour with 4 rays per pixel.
_SUBPIXEL = np.array([[-0.125, -0.375], [0.375, -0.125], [0.125, 0.375], [-0.375, 0.125]])
#: Share of seeds whose room ``--clutter auto`` makes dense.
AUTO_DENSE_SHARE = 1 / 3
#: A thing is *thin* when its thinnest part (legs, poles, wings) is below this (metres), *flat* when its
#: upright box is at most :data:`FLAT_HEIGHT` high and at most :data:`FLAT_RATIO` of its length (``gt/objects.json``).
THIN_PART = 0.05
FLAT_HEIGHT = 0.1
FLAT_RATIO = 0.3
#: Options that override a ``--noise`` preset's field, and their flags (named in errors).
NOISE_FLAGS = {"view_confusion": "--view-confusion", "score_informativeness": "--score-informativeness"}


@dataclass(frozen=True)
class SynthOptions:
    """What :func:`make_scene` builds: the options of ``lift3d synth`` (``docs/synth.md``). The same options give
    the same files byte for byte; all of them are recorded in ``transforms.json`` under ``lift3d_synth``.

    Attributes
    ----------
    kind : {"indoor", "outdoor"}
        A furnished room (bounded) or a long street with sky (unbounded).
    seed : int
        Seed of everything random (the room, its objects, textures, lighting, cameras and every noise).
    noise : {"clean", "moderate", "hard", "view-correlated"} or NoiseConfig
        The simulated segmenter's errors (``docs/synth.md``).
    n_views : int
        Number of frames.
    width, height : int
        Image size in pixels.
    camera_path : {"auto", "orbit", "walk", "handheld"}
        How the camera moves; ``auto`` picks one from the seed (``orbit`` is indoor only).
    depth : {"sensor", "exact", "none"}
        The depth maps of ``depth_file_path``: a structured-light sensor's (noise, holes, quantisation), the
        exact ones, or none (images only). The exact depth is always written as ground truth
        (``gt_depth_file_path``).
    pose_noise : (float, float)
        RMS rotation (degrees) and translation (centimetres) noise of the written poses; rendering uses the
        true ones (``gt_transform_matrix``).
    view_confusion : float, optional
        Share of things and stuff patches with an active view-correlated confuser (default: the preset's).
    score_informativeness : float, optional
        How much segment scores say about correctness, 0-1 (default: the preset's).
    room_shape : str
        Indoor: the room's shape, one of ``auto`` (the seed's rectangle or L), ``box``, ``l``, ``polygon``,
        ``hexagon``, ``sloped``, ``vaulted``, ``round``, ``open`` (``docs/synth.md``).
    clutter : {"none", "auto", "dense"}
        Indoor: ``dense`` fills the room with 30-40 things (rows of one class, thin and flat things, things on
        tables); ``auto`` lets the seed choose (dense in one room of three).
    """

    kind: str = "indoor"
    seed: int = 0
    noise: str | NoiseConfig = "moderate"
    n_views: int = 60
    width: int = 128
    height: int = 128
    camera_path: str = "auto"
    depth: str = "sensor"
    pose_noise: tuple[float, float] = (0.0, 0.0)
    view_confusion: float | None = None
    score_informativeness: float | None = None
    room_shape: str = "auto"
    clutter: str = "none"


def _check_args(out, options: SynthOptions) -> NoiseConfig:
    """The segmenter noise ``options`` ask for; :class:`InputError` naming the flag of the first bad option, or
    ``out`` when it is a folder ``make_scene`` may not write to."""
    o = options
    overrides = {"view_confusion": o.view_confusion, "score_informativeness": o.score_informativeness}
    if not isinstance(o.seed, (int, np.integer)) or not 0 <= o.seed < 2**63:
        raise InputError("--seed", f"must be a non-negative integer, got {o.seed!r}")
    if o.kind not in KINDS:
        raise InputError("--kind", f"{o.kind!r} is not one of {', '.join(KINDS)}")
    try:
        cfg = noise_config(o.noise)
    except KeyError:
        raise InputError("--noise", f"{o.noise!r} is not one of {', '.join(PRESETS)}") from None
    for name, value in overrides.items():
        if value is not None:
            if not isinstance(value, (int, float, np.floating)) or not 0.0 <= float(value) <= 1.0:
                raise InputError(NOISE_FLAGS[name], f"must be a number in [0, 1], got {value!r}")
    cfg = replace(cfg, **{k: float(v) for k, v in overrides.items() if v is not None})
    for field_name, problem in cfg.problems():
        raise InputError(NOISE_FLAGS.get(field_name, f"--noise ({field_name})"), problem)
    if o.camera_path not in CAMERA_PATHS:
        raise InputError("--camera-path", f"{o.camera_path!r} is not one of {', '.join(CAMERA_PATHS)}")
    if o.camera_path != "auto" and o.camera_path not in PATHS_OF_KIND[o.kind]:
        raise InputError("--camera-path", f"{o.camera_path!r} needs a room; {o.kind} scenes take "
                                          f"{', '.join(('auto',) + PATHS_OF_KIND[o.kind])}")
    if o.depth not in DEPTH_MODES:
        raise InputError("--depth", f"{o.depth!r} is not one of {', '.join(DEPTH_MODES)}")
    if o.room_shape not in ROOM_SHAPES:
        raise InputError("--room-shape", f"{o.room_shape!r} is not one of {', '.join(ROOM_SHAPES)}")
    if o.room_shape != "auto" and o.kind != "indoor":
        raise InputError("--room-shape", f"{o.room_shape!r} needs a room; {o.kind} scenes take auto")
    if o.clutter not in CLUTTER_LEVELS:
        raise InputError("--clutter", f"{o.clutter!r} is not one of {', '.join(CLUTTER_LEVELS)}")
    if o.clutter == "dense" and o.kind != "indoor":
        raise InputError("--clutter", f"dense needs a room; {o.kind} scenes take none or auto")
    try:
        deg, cm = (float(x) for x in o.pose_noise)
    except (TypeError, ValueError):
        raise InputError("--pose-noise", f"needs two numbers DEG CM, got {o.pose_noise!r}") from None
    if not (0.0 <= deg <= 90.0 and 0.0 <= cm <= 200.0):
        raise InputError("--pose-noise", f"DEG must be in [0, 90] and CM in [0, 200], got {deg:g} {cm:g}")
    if not isinstance(o.n_views, (int, np.integer)) or o.n_views < 2:
        raise InputError("--views", f"need at least 2 views (one to train on, one to test), got {o.n_views}")
    if o.n_views > 10000:
        raise InputError("--views", f"{o.n_views} views is more than the 10000 supported")
    for flag, size in (("--width", o.width), ("--height", o.height)):
        if not isinstance(size, (int, np.integer)) or not 16 <= size <= 4096:
            raise InputError(flag, f"image size must be an integer in [16, 4096], got {size}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(out, "exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):
        marker = out / "transforms.json"
        owned = False
        if marker.is_file():
            try:
                owned = SYNTH_META_KEY in json.loads(marker.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                owned = False
        if not owned:
            raise InputError(out, "folder is not empty and is not an earlier `lift3d synth` scene; "
                                  "choose a new --out")
    return cfg


# --------------------------------------------------------------------------------------------- content
def build_content(kind: str, seed: int, room_shape: str = "auto", clutter: str = "none") -> tuple[SceneContent, str]:
    """The scene content ``make_scene`` builds for these arguments, and the clutter level it has (``auto``
    resolved: ``none`` or ``dense``) — for pictures and tests that need the geometry without the files."""
    kind_code = KINDS.index(kind)

    def stream(*keys: int) -> np.random.Generator:
        return np.random.default_rng(np.random.SeedSequence([seed, keys[0], kind_code, *keys[1:]]))

    if kind != "indoor":
        return build_outdoor(stream(0)), "none"
    clutter_rng = stream(7)
    # Drawn whatever the option, so `auto` on a seed it makes dense is that same room.
    auto_dense = bool(clutter_rng.random() < AUTO_DENSE_SHARE)
    level = {"none": "none", "dense": "dense", "auto": "dense" if auto_dense else "none"}[clutter]
    return build_indoor(stream(0), room_shape=room_shape, clutter=level, clutter_rng=clutter_rng), level


def objects_table(content: SceneContent, pixels: dict[int, list[int]], gt_instance: np.ndarray) -> list[dict]:
    """``gt/objects.json``: every GT thing's id (its instance id in ``gt/points.ply`` and the GT panoptic
    maps), class, oriented box (upright, turned as the thing was turned when placed; the smallest upright box
    when that is not known), largest dimension, thinnest part, whether it is thin or flat, what it stands on,
    and how much the cameras see of it (views with a pixel of it, its pixels, its GT points)."""
    cats = {c.id: c.name for c in content.categories}
    n_points = dict(zip(*np.unique(gt_instance[gt_instance > 0], return_counts=True)))
    rows = []
    for o in content.things:
        box = upright_box(o.mesh.vertices) if o.yaw is None else yawed_box(o.mesh.vertices, o.yaw)
        ext = box["extent"]
        seen = pixels.get(o.segment_id, [])
        rows.append({
            "id": o.segment_id, "class": cats[o.category_id], "name": o.name,
            "on": "floor" if o.rests_on == 0 else o.rests_on,
            "centre_m": np.round(box["centre"], 4).tolist(), "yaw_deg": round(float(np.degrees(box["yaw"])), 2),
            "extent_m": np.round(ext, 4).tolist(), "max_dim_m": round(float(ext.max()), 4),
            "thinnest_part_m": None if o.thin is None else round(float(o.thin), 4),
            "thin": o.thin is not None and o.thin < THIN_PART,
            "flat": bool(ext[2] <= FLAT_HEIGHT and ext[2] <= FLAT_RATIO * ext[0]),
            "views": len(seen), "pixels": int(sum(seen)), "gt_points": int(n_points.get(o.segment_id, 0)),
        })
    return rows


# --------------------------------------------------------------------------------------------- cameras
def _intrinsics(width: int, height: int, hfov_deg: float) -> tuple[float, float, float, float]:
    fx = 0.5 * width / np.tan(np.radians(hfov_deg) / 2)
    return fx, fx, width / 2.0, height / 2.0


def split_names(names: list[str]) -> dict[str, list[str]]:
    """The synthetic scenes' splits: ``test`` and ``val`` are disjoint from each other and from ``train``.

    * **test**: ``round(n / 5)`` views (12 of 60), evenly spread along the path — view ``floor((k + 0.5) n /
      n_test)`` for ``k = 0 … n_test − 1`` (views 2, 7, 12, …, 57 of 60), never two neighbours;
    * **val**: ``n // 12`` views (5 of 60) half-way between two test views (views 5, 15, 30, 45, 55 of 60), so
      neither a test view nor its neighbour;
    * **train**: the rest (43 of 60).

    Below 12 views there is no view to spare: ``val`` is then one training view (the middle one), still
    never a test view.

    Examples
    --------
    >>> s = split_names([f"f{i}" for i in range(60)])
    >>> len(s["train"]), len(s["val"]), len(s["test"]), s["test"][:3], s["val"]
    (43, 5, 12, ['f2', 'f7', 'f12'], ['f5', 'f15', 'f30', 'f45', 'f55'])
    """
    n = len(names)
    n_test = max(1, round(n / 5))
    test = sorted({int((k + 0.5) * n / n_test) for k in range(n_test)})
    gaps = [int((k + 1) * n / n_test) for k in range(n_test - 1)]
    gaps = [g for g in gaps if g not in test]
    n_val = n // 12
    if n_val and gaps:
        val = sorted({gaps[int(round(x))] for x in np.linspace(0, len(gaps) - 1, min(n_val, len(gaps)))})
        train = [i for i in range(n) if i not in set(test) | set(val)]
    else:
        train = [i for i in range(n) if i not in set(test)]
        val = [train[len(train) // 2]]
    return {"train": [names[i] for i in train], "val": [names[i] for i in val], "test": [names[i] for i in test]}


# --------------------------------------------------------------------------------------------- rendering
def render_view(caster: RayCaster, cameras: Cameras, i: int, supersample: bool = True,
                edge_threshold: float = 0.05) -> dict[str, np.ndarray]:
    """Ray cast frame ``i``.

    Labels, depth and surface points come from the ray through each pixel centre (the ray ``Cameras.rays``
    gives, so they agree with ``Cameras.project``). Colour is anti-aliased where it matters: pixels whose
    centre colour differs from a 4-neighbour's by more than ``edge_threshold`` (or whose segment or material
    differs) average 4 rotated-grid sub-pixel rays, as a sensor integrates over the pixel; elsewhere the
    band-limited textures are smooth at pixel scale and the centre ray suffices.

    Returns
    -------
    dict
        ``rgb`` ``uint8 [H, W, 3]``, ``segment`` ``int64 [H, W]`` GT panoptic ids, ``category`` ``int64
        [H, W]``, ``depth`` ``float64 [H, W]`` z-depth (0 where nothing is hit), and for the pixels whose centre
        ray hit a surface: ``hit`` ``bool [H, W]``, ``points`` ``[P, 3]`` and ``point_rgb`` ``[P, 3]`` in
        [0, 1] (``P`` = hits, row-major pixel order).
    """
    h, w = int(cameras.height[i]), int(cameras.width[i])
    v, u = np.mgrid[0:h, 0:w]
    u, v = u.ravel().astype(np.float64), v.ravel().astype(np.float64)
    pixel_angle = 1.0 / float(cameras.fx[i])
    origins, dirs = cameras.rays(i, u, v)
    centre = caster.cast(origins, dirs)
    rgb = caster.shade(centre, dirs, pixel_angle)
    if supersample:
        img = rgb.reshape(h, w, 3)
        seg = centre.segment.reshape(h, w)
        mat = np.full(h * w, -1, np.int64)
        mat[centre.index] = centre.material
        mat = mat.reshape(h, w)
        edge = np.zeros((h, w), bool)
        for a, b in (((slice(None), slice(1, None)), (slice(None), slice(None, -1))),
                     ((slice(1, None), slice(None)), (slice(None, -1), slice(None)))):
            differs = (np.abs(img[a] - img[b]).max(axis=-1) > edge_threshold) | (seg[a] != seg[b]) | (mat[a] != mat[b])
            edge[a] |= differs
            edge[b] |= differs
        sel = np.flatnonzero(edge.ravel())
        if len(sel):
            k = len(_SUBPIXEL)
            us = (u[sel][None, :] + _SUBPIXEL[:, 0:1]).ravel()
            vs = (v[sel][None, :] + _SUBPIXEL[:, 1:2]).ravel()
            o, d = cameras.rays(i, us, vs)
            sub = caster.shade(caster.cast(o, d), d, pixel_angle)
            rgb = rgb.copy()
            rgb[sel] = sub.reshape(k, len(sel), 3).mean(axis=0)
    forward = cameras.forward[i]
    depth = np.zeros(h * w)
    depth[centre.index] = centre.t[centre.index] * (dirs[centre.index] @ forward)
    return {
        "rgb": np.round(rgb.reshape(h, w, 3) * 255.0).astype(np.uint8),
        "segment": centre.segment.reshape(h, w),
        "category": centre.category.reshape(h, w),
        "depth": depth.reshape(h, w),
        "hit": centre.hit.reshape(h, w),
        "points": centre.points,
        "point_rgb": rgb[centre.index],
    }


def voxel_dedup(points: np.ndarray, voxel: float) -> np.ndarray:
    """Sorted indices of the first point in every occupied voxel of size ``voxel`` (deterministic)."""
    cells = np.floor(points / voxel).astype(np.int64)
    cells -= cells.min(axis=0)
    dims = cells.max(axis=0) + 1
    key = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]  # one int64 per voxel: 1-D unique
    _, first = np.unique(key, return_index=True)
    return np.sort(first)


def surface_samples(caster: RayCaster, cameras: Cameras, grid: int = 16) -> dict[int, np.ndarray]:
    """What the cameras see, sparsely: GT segment id → ``[P, 3]`` surface points hit by a ``grid`` × ``grid``
    of pixel rays in every view."""
    out: dict[int, list] = {}
    for i in range(len(cameras)):
        w, h = float(cameras.width[i]), float(cameras.height[i])
        u, v = np.meshgrid((np.arange(grid) + 0.5) * w / grid, (np.arange(grid) + 0.5) * h / grid)
        o, d = cameras.rays(i, u.ravel(), v.ravel())
        hits = caster.cast(o, d)
        seg = hits.segment[hits.index]
        for s in np.unique(seg):
            out.setdefault(int(s), []).append(hits.points[seg == s])
    return {s: np.concatenate(v) for s, v in out.items()}


def in_view(cameras: Cameras, points: np.ndarray) -> np.ndarray:
    """``[M, N]`` bool: which of the ``N`` cameras have each of ``points`` ``[M, 3]`` in their image (in front
    of the camera and inside the frame; occlusion is not checked)."""
    out = np.zeros((len(points), len(cameras)), bool)
    for i in range(len(cameras)):
        uv, z = cameras.project(i, points)
        out[:, i] = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cameras.width[i]) & (uv[:, 1] >= 0) & \
            (uv[:, 1] < cameras.height[i])
    return out


def _check_pose_noise(true_c2w: np.ndarray, noisy_c2w: np.ndarray, caster: RayCaster, names: list[str],
                      deg: float, cm: float) -> None:
    """A written camera must stay in free space: the segment from its true to its noisy centre crosses no
    surface and ends at least 2 cm in front of one."""
    offset = noisy_c2w[:, :3, 3] - true_c2w[:, :3, 3]
    dist = np.linalg.norm(offset, axis=1)
    moved = np.flatnonzero(dist > 1e-9)
    if not len(moved):
        return
    hits = caster.cast(true_c2w[moved, :3, 3], offset[moved] / dist[moved, None])
    bad = np.flatnonzero(hits.t < dist[moved] + 0.02)
    if len(bad):
        k = int(moved[bad[0]])
        raise InputError("--pose-noise", f"{deg:g} deg {cm:g} cm puts the written camera of {names[k]} inside or "
                                         f"behind geometry ({len(bad)} of {len(dist)} cameras): use less "
                                         "translation noise")


# --------------------------------------------------------------------------------------------- main
def make_scene(out: str | Path, options: SynthOptions | None = None, *, progress: bool = True) -> dict:
    """Write a synthetic labelled scene folder with simulated 2D segmenter noise and sensor models.

    Every option is recorded in ``transforms.json`` under ``lift3d_synth`` (with what the seed chose: room or
    street, textures, lighting, objects), so a scene says how it was made.

    Parameters
    ----------
    out : str or Path
        Output folder (created; an earlier synthetic scene there is replaced, any other non-empty folder
        is refused).
    options : SynthOptions, optional
        What to build: kind, seed, segmenter noise, views and their size, camera path, depth, pose noise, room
        shape and clutter (default: :class:`SynthOptions`'s, a moderate-noise room of 60 views of 128 × 128).
    progress : bool
        Show a progress bar.

    Returns
    -------
    dict
        A report: options, content, noise statistics (also written to ``<out>/synth_noise.json``), the
        pseudo-labels' metrics on the test views, depth and pose statistics, paths, and wall time in seconds.

    Examples
    --------
    >>> import tempfile
    >>> rep = make_scene(tempfile.mkdtemp() + "/s", SynthOptions(n_views=4, width=32, height=32), progress=False)
    >>> rep["n_views"], rep["noise"]["name"], rep["depth"]["mode"]
    (4, 'moderate', 'sensor')
    """
    started = time.perf_counter()
    options = SynthOptions() if options is None else options
    cfg = _check_args(out, options)
    kind, camera_path, depth, pose_noise = options.kind, options.camera_path, options.depth, options.pose_noise
    room_shape, clutter = options.room_shape, options.clutter
    n_views, width, height, seed = int(options.n_views), int(options.width), int(options.height), int(options.seed)
    deg, cm = (float(x) for x in pose_noise)
    out = Path(out)
    kind_code = KINDS.index(kind)

    def stream(*keys: int) -> np.random.Generator:
        return np.random.default_rng(np.random.SeedSequence([seed, keys[0], kind_code, *keys[1:]]))

    content, clutter_level = build_content(kind, seed, room_shape, clutter)
    caster = RayCaster(content)
    camera_rng = stream(1)
    paths = PATHS_OF_KIND[kind]
    chosen = paths[int(camera_rng.integers(len(paths)))]  # drawn always, so `auto` and explicit agree
    path_name = chosen if camera_path == "auto" else camera_path
    hfov = float(camera_rng.uniform(60.0, 80.0) if kind == "indoor" else camera_rng.uniform(65.0, 85.0))
    c2w = plan_camera_path(content, caster, path_name, n_views, camera_rng, fov=(hfov, width / height))
    fx, fy, cx, cy = _intrinsics(width, height, hfov)
    cameras = Cameras(c2w=c2w, fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height)
    names = [f"frame_{i:04d}" for i in range(n_views)]

    written_c2w = c2w
    if deg > 0 or cm > 0:
        written_c2w = perturb_poses(c2w, deg, cm, stream(6))
        _check_pose_noise(c2w, written_c2w, caster, names, deg, cm)
    rot_err, trans_err = pose_error(c2w, written_c2w)

    gt_category = {o.segment_id: o.category_id for o in content.objects}
    if content.sky_category is not None:
        gt_category[content.sky_category] = content.sky_category
    stuff_ids = {c.id for c in content.categories if not c.isthing}
    seen = surface_samples(caster, cameras)
    confusers = ViewConfusers.build(
        [(o.segment_id, o.category_id, o.mesh.bounds.mean(axis=0)) for o in content.things],
        {s: p for s, p in seen.items() if s in stuff_ids}, lambda pts: in_view(cameras, pts), cameras.centers,
        content.confusable, cfg, stream(3), patch_radius=(0.3, 0.8) if kind == "indoor" else (2.0, 5.0))
    sensor = DepthSensor()

    if out.is_dir():  # an earlier synthetic scene (checked above): remove only what make_scene writes
        for name in _OWNED:
            p = out / name
            if p.is_dir():
                shutil.rmtree(p)
            elif p.exists():
                p.unlink()

    splits = split_names(names)
    test_names = set(splits["test"])
    options = {
        "version": SYNTH_VERSION, "kind": kind, "seed": seed, "n_views": n_views, "width": width, "height": height,
        "noise": cfg.name, "noise_config": cfg.to_json(),
        "view_confusion": cfg.view_confusion, "score_informativeness": cfg.score_informativeness,
        "camera_path": path_name, "camera_path_option": camera_path, "hfov_deg": round(hfov, 3),
        "min_camera_clearance_m": MIN_CLEARANCE,
        "depth": depth, "depth_sensor": sensor.to_json() if depth == "sensor" else None,
        "pose_noise": {"deg": deg, "cm": cm, "rms_deg": round(float(np.sqrt(np.mean(rot_err**2))), 4),
                       "rms_cm": round(float(100 * np.sqrt(np.mean(trans_err**2))), 4)},
        "splits": "test: every 5th view spread along the path; val: n // 12 views between test views, disjoint "
                  "from train and test (below 12 views one train view); train: the rest",
    }
    # Recorded when not the defaults, so the scenes of the defaults keep their bytes (absent: auto, none).
    if room_shape != "auto":
        options["room_shape"] = room_shape
    if clutter != "none":
        options["clutter"] = clutter
        options["clutter_level"] = clutter_level
    options["scene"] = content.description
    stats = NoiseStats(content.categories)
    pts, pt_sem, pt_inst, pt_rgb = [], [], [], []
    seen_segments: set[int] = set()
    thing_ids = {c.id for c in content.categories if c.isthing}
    test_arrays: list[tuple[np.ndarray, ...]] = []
    depth_stats: list[dict] = []
    thing_pixels: dict[int, list[int]] = {}
    with SceneWriter(out, content.categories, depth_unit_scale_factor=content.depth_unit_scale_factor,
                     extra_meta={SYNTH_META_KEY: options}) as writer:
        for i in progress_bar(range(n_views), desc=f"synth {kind}", disable=not progress, unit="view"):
            view = render_view(caster, cameras, i)
            seg = view["segment"]
            xyz = np.full((height * width, 3), np.nan)
            xyz[view["hit"].ravel()] = view["points"]
            view_errors = confusers.for_view(seg, view["category"], xyz.reshape(height, width, 3),
                                             cameras.centers[i], stream(4, i))
            pseudo = simulate_segmenter(seg, gt_category, content.categories, content.confusable, cfg, stream(2, i),
                                        view_errors=view_errors)
            ids, n_px = np.unique(seg, return_counts=True)
            present = [int(s) for s in ids if s != 0]
            seen_segments.update(present)
            for seg_id, count in zip(ids.tolist(), n_px.tolist()):
                if seg_id and gt_category[seg_id] in thing_ids:
                    thing_pixels.setdefault(seg_id, []).append(count)
            gt_segments = [Segment(s, gt_category[s], 1.0) for s in present]
            pseudo_sem = np.zeros(seg.shape, np.int64)
            pseudo_thing = np.zeros(seg.shape, bool)
            for s in pseudo.segments:
                on = pseudo.panoptic == s.id
                pseudo_sem[on] = s.category_id
                pseudo_thing[on] = s.category_id in thing_ids
            stats.add(pseudo.counts, view["category"], pseudo_sem)
            if depth == "sensor":
                depth_in, info = sensor.apply(view["depth"], stream(5, i))
                depth_stats.append(info)
            else:
                depth_in = view["depth"] if depth == "exact" else None
            name = names[i]
            writer.add_frame(
                name, view["rgb"], written_c2w[i], (fx, fy, cx, cy),
                labels=FramePseudoLabels(pseudo.panoptic, pseudo.segments), depth=depth_in,
                gt=FrameGroundTruth(seg, gt_segments, depth=view["depth"], c2w=c2w[i]),
            )
            hit = view["hit"]
            gt_inst = np.where(np.isin(view["category"], list(thing_ids)), seg, 0)
            if name in test_names:
                test_arrays.append((pseudo_sem, np.where(pseudo_thing, pseudo.panoptic, 0), view["category"], gt_inst))
            pts.append(view["points"])
            pt_sem.append(view["category"][hit])
            pt_inst.append(gt_inst[hit])
            pt_rgb.append(view["point_rgb"])

        file_paths = {n: f"images/{n}.png" for n in names}
        writer.set_splits(*([file_paths[n] for n in splits[s]] for s in ("train", "val", "test")))
        centres = np.concatenate([cameras.centers, written_c2w[:, :3, 3]])
        if content.scene_box_type == "bounded":
            scene_box = content.aabb + np.array([[-0.01] * 3, [0.01] * 3])
        else:
            # Foreground box: the near street around the camera path; everything beyond is contracted.
            lo, hi = centres.min(0), centres.max(0)
            half = content.description["street"]["grass_end_m"] + 3.0
            scene_box = np.array([[-half, lo[1] - 4.0, -0.5], [half, hi[1] + 16.0, 8.0]])
        writer.set_scene_box(content.scene_box_type, scene_box)

        xyz = np.concatenate(pts)
        # Deduplicate the back-projected centre-ray hits on a voxel grid; grow the voxel until at most 200k
        # points remain (the GT is for 3D metrics, where a few centimetres of spacing is plenty).
        voxel = 0.02 if kind == "indoor" else 0.05
        keep = voxel_dedup(xyz, voxel)
        while len(keep) > 200_000:
            voxel *= 1.5
            keep = voxel_dedup(xyz, voxel)
        writer.write_gt_points(xyz[keep], np.concatenate(pt_sem)[keep], np.concatenate(pt_inst)[keep],
                               rgb=np.concatenate(pt_rgb)[keep])

    summary = stats.summary()
    test_metrics = _pseudo_label_metrics(test_arrays, content)
    baseline = float(np.max(np.linalg.norm(cameras.centers[:, None] - cameras.centers[None], axis=-1)))
    gt_xyz = xyz[keep]
    extent = float(np.linalg.norm(gt_xyz.max(0) - gt_xyz.min(0))) if len(gt_xyz) else 0.0
    cats = {c.id: c for c in content.categories}
    things = content.things
    clearance = caster.distance(cameras.centers)
    depth_report = {"mode": depth}
    if depth_stats:
        depth_report.update({k: round(float(np.mean([d[k] for d in depth_stats])), 4) for k in depth_stats[0]})
    noise_json = {
        "kind": kind, "seed": seed, "n_views": n_views, "width": width, "height": height,
        "config": cfg.to_json(), **summary, "test_views": test_metrics,
        "view_confusers": confusers.to_json(),
    }
    write_json_atomic(out / "synth_noise.json", noise_json)
    objects = objects_table(content, thing_pixels, np.concatenate(pt_inst)[keep])
    write_json_atomic(out / "gt" / "objects.json", {
        "thin_part_m": THIN_PART, "flat": {"height_m": FLAT_HEIGHT, "of_length": FLAT_RATIO},
        "objects": objects})
    return {
        "out": str(out), "kind": kind, "seed": seed, "n_views": n_views, "width": width, "height": height,
        "options": {**{k: options[k] for k in ("camera_path", "camera_path_option", "hfov_deg", "depth",
                                               "view_confusion", "score_informativeness")},
                    "room_shape": room_shape, "clutter": clutter, "clutter_level": clutter_level},
        "noise": {"name": cfg.name, **summary, "test_views": test_metrics},
        "depth": depth_report,
        "pose_noise": options["pose_noise"],
        "content": {
            "scene": content.description,
            "n_things": len(things),
            "thing_classes": sorted({cats[o.category_id].name for o in things}),
            "n_thing_classes": len({o.category_id for o in things}),
            "segments_seen": len(seen_segments),
            "extent_m": round(extent, 3),
            "camera_baseline_m": round(baseline, 3),
            "camera_clearance_m": [round(float(clearance.min()), 3), round(float(np.median(clearance)), 3)],
            "extent_over_baseline": round(extent / baseline, 2) if baseline > 0 else None,
            "scene_box": {"type": content.scene_box_type, "aabb": np.round(scene_box, 4).tolist()},
            "gt_points": int(len(keep)),
            "gt_points_voxel_m": round(voxel, 4),
            "thin_things": sum(o["thin"] for o in objects), "flat_things": sum(o["flat"] for o in objects),
            "things_seen_in_3_views": sum(o["views"] >= 3 for o in objects),
        },
        "splits": {k: len(v) for k, v in splits.items()},
        "paths": {
            "scene": str(out), "transforms": str(out / "transforms.json"), "pseudo_labels": str(out / "panoptic.json"),
            "gt_points": str(out / "gt" / "points.ply"), "gt_objects": str(out / "gt" / "objects.json"),
            "noise_stats": str(out / "synth_noise.json"),
        },
        "seconds": round(time.perf_counter() - started, 3),
    }


def _pseudo_label_metrics(arrays: list[tuple[np.ndarray, ...]], content: SceneContent) -> dict:
    """mIoU and PQ^scene of the pseudo-labels on the test views, as ``lift3d eval`` scores its baseline."""
    # here, not at module level: lift3d.eval loads torch; keeps `import lift3d.synth` cheap
    from lift3d.eval import compute_2d_metrics

    if not arrays:
        return {}
    ps, pi, gs, gi = (np.concatenate([a[k].ravel() for a in arrays]) for k in range(4))
    things = [c.id for c in content.categories if c.isthing]
    stuff = [c.id for c in content.categories if not c.isthing]
    m = compute_2d_metrics((ps, pi), (gs, gi), things, stuff)
    return {k: (None if m[k] is None or not np.isfinite(m[k]) else round(float(m[k]), 4))
            for k in ("miou", "pq_scene", "sq_scene", "rq_scene", "miou_strict", "pq_scene_strict")}
