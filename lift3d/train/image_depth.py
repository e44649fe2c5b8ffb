"""Depth targets from the images themselves, for training frames without a depth map (docs/sfm.md).

With the poses known, triangulated points say where some surfaces are: a ray through the pixel where a
training frame sees a point should end at the point's depth, give or take its standard deviation. That is
what a depth-supervised NeRF (DS-NeRF, Deng et al., CVPR 2022) trains with. Where the targets come from:

* the scene's own sparse points (``sparse_points`` in ``transforms.json``: ``lift3d triangulate``'s, or
  COLMAP's ``points3D`` kept by ``lift3d convert``);
* otherwise points triangulated here at the start of training (:func:`lift3d.sfm.triangulate_scene` on the
  training frames), cached in the run folder so that a resumed run does not redo them;
* with ``image_depth.source dense``, also plane-sweep depth maps (the scene's ``mvs_depth_file_path``, or
  :func:`lift3d.sfm.plane_sweep_scene` here, cached likewise);
* with ``image_depth.source planes``, also the planes of the stuff classes fitted to those points
  (:mod:`lift3d.sfm.planes`): at every ``plane_stride``-th pixel the 2D labels give a stuff class, where the
  ray first meets a plane of that class.

Too few points (too little texture, overlap or baseline) is a warning recorded in ``config.yml`` and the
training summary; training then goes on with what there is, RGB only when there is nothing.
"""

from __future__ import annotations

import io
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lift3d.data.scene import Scene
from lift3d.data.stereo import DenseDepth, SparsePoints, read_sparse_points, write_sparse_points_files
from lift3d.errors import InputError
from lift3d.model.config import ImageDepthConfig
from lift3d.utils.atomic import write_bytes_atomic

#: Fewer usable observations than this per training frame (median) is reported as a warning.
MIN_OBSERVATIONS_PER_FRAME = 10
#: The cache of a run folder: triangulated points and plane-sweep maps computed at training start.
CACHE_DIR = "image_depth"
#: Fewest other views whose labels must look at a plane target before they can refute it.
MIN_LABEL_VOTES = 2
#: Share of the stereo depths a face of a standing thing meets that must agree with it
#: (lift3d.sfm.standing.stereo_agreement): on six images-only tuning rooms, faces whose targets were mostly
#: within 1 % of the diagonal agreed with 58-100 % of them, plants, shelves and chairs with 0-53 %.
STANDING_AGREEMENT = 0.65
#: Disagreeing stereo depths a face may always have (a few edge depths of a plain box are off).
MIN_REFUTING_DEPTHS = 5
SOURCES = ("auto", "sparse", "dense", "planes", "none")


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
        What config.yml and the summary record: ``source``, ``points``, ``observations``,
        ``median_error_px``, ``dense_coverage``, ``targets``, ``frames_with_targets``, ``seconds``,
        ``warnings``.
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


def resolve_source(source: str, scene: Scene | None = None) -> str:
    """``auto`` → the source measured best by default (docs/sfm.md, "Training with it"): ``planes`` for a
    bounded scene (rooms: measured there), ``sparse`` otherwise (the planes are not measured outdoors yet)."""
    if source not in SOURCES:
        raise InputError("--image_depth.source", f"unknown source {source!r} ({', '.join(SOURCES)})")
    if source != "auto":
        return source
    bounded = scene is not None and scene.scene_box is not None and scene.scene_box.type == "bounded"
    return "planes" if bounded else "sparse"


def image_depth_targets(scene: Scene, frames: np.ndarray, cfg: ImageDepthConfig, cache: Path | None = None,
                        progress: bool = False) -> DepthTargets:
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

    Returns
    -------
    DepthTargets
        Possibly empty (source ``none``, every frame has a depth map, nothing could be triangulated).
    """
    source = resolve_source(cfg.source, scene)
    targets_for = frames_without_depth(scene, frames)
    info: dict[str, Any] = {"source": source, "requested": cfg.source, "warnings": []}
    if source == "none" or len(targets_for) == 0:
        if source != "none":
            info["source"] = "none (every training frame has a depth map)"
        return DepthTargets.empty(info)
    t0 = time.perf_counter()
    sparse, origin = _sparse_points(scene, frames, cache, progress)
    info["points_from"] = origin
    info["points"] = int(len(sparse))
    info["median_error_px"] = round(sparse.median_error, 3) if len(sparse) else None
    info["warnings"] += list(sparse.info.get("warnings", [])) if origin == "triangulated" else []
    parts = [_sparse_rows(scene, sparse, targets_for)]
    info["observations"] = int(len(parts[0][0]))
    if source == "dense":
        dense, dense_origin = _dense_maps(scene, frames, sparse, cache, progress)
        info["dense_from"] = dense_origin
        rows = _dense_rows(scene, dense, targets_for)
        info["dense_coverage"] = round(float(len(rows[0])) / max(1, _pixels(scene, targets_for)), 4)
        parts.append(rows)
    if source == "planes":
        dense, info["dense_from"] = _dense_maps(scene, frames, sparse, cache, progress)
        labels = {int(i): scene.pseudo_labels(int(i)).semantic for i in frames}  # read once for both steps
        rows, info["planes"] = _plane_rows(scene, sparse, dense, frames, targets_for, labels, cfg)
        parts.append(rows)
        if cfg.plane_dense_things and scene.thing_ids:
            # the planes hold stuff only: objects get the plane sweep's depths where the labels see one
            rows = _dense_rows(scene, dense, targets_for)
            on_thing = np.zeros(len(rows[0]), bool)
            one_source = np.zeros(len(rows[0]), bool)
            support = dict(zip(dense.frame_names, dense.support)) if dense.support is not None else {}
            for i in np.unique(rows[0]):
                k = np.flatnonzero(rows[0] == i)
                sem = labels[int(i)]  # targets_for is a subset of the training frames
                r, c = rows[2][k].astype(np.int64), rows[1][k].astype(np.int64)
                on_thing[k] = np.isin(sem[r, c], scene.thing_ids)
                if scene.frames[int(i)].name in support:
                    one_source[k] = np.asarray(support[scene.frames[int(i)].name])[r, c] == 1
            parts.append(tuple(a[on_thing] for a in rows))
            info["dense_on_things"] = int(on_thing.sum())
            info["dense_on_things_one_source"] = int((on_thing & one_source).sum())
    frame, u, v, z, sigma, dense_flag = (np.concatenate(a) for a in zip(*parts))
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


# ------------------------------------------------------------------------------------------ sparse points
def _sparse_points(scene: Scene, frames: np.ndarray, cache: Path | None, progress: bool) -> tuple[SparsePoints, str]:
    """The scene's sparse points, else the cached ones, else triangulated now (and cached)."""
    own = scene.sparse_points()
    if own is not None:
        return own, f"scene ({_scene_points_source(scene)})"
    names = [f.name for f in scene.frames]
    if cache is not None and (cache / "sparse" / "points3D.ply").is_file():
        return read_sparse_points(cache / "sparse" / "points3D.ply", cache / "sparse" / "observations.npz",
                                  frame_names=names), "triangulated (cached)"
    # here, not at module level: keeps `import lift3d.train` cheap (OpenCV's feature code loads only when a
    # run triangulates)
    from lift3d.sfm import triangulate_scene

    sparse = triangulate_scene(scene, frames, progress=progress)
    if cache is not None:
        write_sparse_points_files(cache, sparse)
    # Observations index the triangulated frames; re-index them by scene frame.
    sparse.obs_frame = np.asarray(frames, np.int64)[sparse.obs_frame].astype(np.int32)
    sparse.frame_names = names
    return sparse, "triangulated"


def _scene_points_source(scene: Scene) -> str:
    try:
        meta = json.loads((scene.root / "transforms.json").read_text(encoding="utf-8"))
        return str(meta.get("sparse_points", {}).get("source", "sparse_points"))
    except (OSError, ValueError):
        return "sparse_points"


def _sparse_rows(scene: Scene, sparse: SparsePoints, targets_for: np.ndarray):
    """Observations in the frames of ``targets_for``, inside their image."""
    keep = np.isin(sparse.obs_frame, targets_for)
    f = sparse.obs_frame[keep].astype(np.int64)
    uv = sparse.obs_uv[keep].astype(np.float32)
    w, h = scene.cameras.width[f], scene.cameras.height[f]
    inside = (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] < w) & (uv[:, 1] < h)
    f, uv = f[inside], uv[inside]
    z, s = sparse.obs_depth[keep][inside], sparse.obs_sigma[keep][inside]
    # observations.npz puts pixel (c, r)'s centre at (c + .5, r + .5); rays put it at (c, r).
    return f, uv[:, 0] - 0.5, uv[:, 1] - 0.5, z.astype(np.float32), s.astype(np.float32), np.zeros(len(f), bool)


# ------------------------------------------------------------------------------------------ stuff planes
def scene_diagonal(scene: Scene, sparse: SparsePoints | None = None) -> float:
    """Length of the scene box's diagonal, else of the box around the cameras and the middle 90 % of the
    sparse points (world units)."""
    if scene.scene_box is not None:
        box = np.asarray(scene.scene_box.aabb, np.float64)
        return float(np.linalg.norm(box[1] - box[0]))
    pts = scene.cameras.centers
    if sparse is not None and len(sparse):
        lo, hi = np.percentile(sparse.xyz, [5, 95], axis=0)
        pts = np.r_[pts, lo[None], hi[None]]
    return float(np.linalg.norm(pts.max(0) - pts.min(0)))


def _dense_points(scene: Scene, dense: DenseDepth, labels: dict[int, np.ndarray], min_support: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The plane sweep's depths as world points ``[N, 3]``, their pixels' classes ``[N]`` and their cameras'
    centres ``[N, 3]``, leaving out depths fewer than ``min_support`` source views confirmed (when recorded)."""
    index = {f.name: k for k, f in enumerate(scene.frames)}
    supports = dense.support if dense.support is not None else [None] * len(dense)
    xyz, cls, cams = [np.zeros((0, 3))], [np.zeros(0, np.int64)], [np.zeros((0, 3))]
    for name, depth, support in zip(dense.frame_names, dense.depth, supports):
        i = index[name]
        depth = np.asarray(depth)
        use = depth > 0
        if support is not None:
            use &= np.asarray(support) >= min_support
        r, c = np.nonzero(use)
        if not len(r):
            continue
        o, d = scene.cameras.rays(i, c, r)
        xyz.append(o + d * (depth[r, c] / (d @ scene.cameras.c2w_opencv[i][:3, 2]))[:, None])
        cls.append(labels[i][r, c].astype(np.int64)), cams.append(o)
    return np.concatenate(xyz), np.concatenate(cls), np.concatenate(cams)


def _plane_rows(scene: Scene, sparse: SparsePoints, dense: DenseDepth, frames: np.ndarray, targets_for: np.ndarray,
                labels: dict[int, np.ndarray], cfg: ImageDepthConfig):
    """Targets where the rays of stuff-labelled pixels first meet a plane holding their class.

    The planes are fitted to the sparse points (each with its observations' majority class) and the
    plane-sweep depths (each with its pixel's class): walls get 1–2 sparse points per 1000 pixels but a few
    percent dense coverage (docs/sfm.md). Points are thinned to one per ``plane_voxel`` cell and class, so a
    textured corner that the plane sweep covers densely does not outvote a wall; every observation is a
    sight line for :func:`lift3d.sfm.planes.fit_planes`' free-space test. With ``plane_floor_boundary``, the
    planes are fitted once more with the wall points the labels' wall-on-floor boundaries give. With
    ``plane_standing``, the pixels of things get the depth of the upright faces rising from where the labels put
    them on the floor plane (:mod:`lift3d.sfm.standing`), unless the plane sweep's depths on them disagree.
    With ``plane_wall_reach`` (bounded scenes), stuff pixels that met no plane of their class get a wall's plane
    past its margin where it still reaches (:func:`lift3d.sfm.planes.wall_reach`); with ``plane_enclosed``,
    segments a plane surrounds get its depth (:func:`lift3d.sfm.planes.enclosed_segments`).
    ``labels``: frame → semantic pseudo-labels of every frame of ``frames``."""
    # here, not at module level: keeps `import lift3d.train` cheap (lift3d.sfm loads OpenCV)
    from lift3d.sfm.mvs import scene_up
    from lift3d.sfm.planes import enclosed_segments, fit_planes, floor_boundary_points, label_support
    from lift3d.sfm.planes import ceiling_points, corner_cutters, point_classes, square_walls, wall_directions
    from lift3d.sfm.planes import floor_plane, height_above, wall_reach
    from lift3d.sfm.standing import standing_faces, stereo_agreement

    empty = (np.zeros(0, np.int64),) + (np.zeros(0, np.float32),) * 4 + (np.zeros(0, bool),)
    stuff = scene.stuff_ids
    info: dict[str, Any] = {"planes": 0}
    if not stuff:
        return empty, info
    diag = scene_diagonal(scene, sparse)
    obs_class = np.zeros(len(sparse.obs_frame), np.int64)
    for i, sem in labels.items():
        k = np.flatnonzero(sparse.obs_frame == i)
        h, w = sem.shape
        col = np.clip(np.floor(sparse.obs_uv[k, 0]).astype(np.int64), 0, w - 1)
        row = np.clip(np.floor(sparse.obs_uv[k, 1]).astype(np.int64), 0, h - 1)
        obs_class[k] = sem[row, col]
    xyz, cls = [sparse.xyz], [point_classes(sparse.obs_point, obs_class, len(sparse))]
    cams, seen_xyz = [scene.cameras.centers[sparse.obs_frame]], [sparse.xyz[sparse.obs_point]]
    index = {f.name: k for k, f in enumerate(scene.frames)}
    p, c, o = _dense_points(scene, dense, labels, cfg.plane_min_support)
    xyz.append(p), cls.append(c), cams.append(o), seen_xyz.append(p)
    xyz, cls = np.concatenate(xyz), np.concatenate(cls).astype(np.int64)
    cams, seen_xyz = np.concatenate(cams), np.concatenate(seen_xyz)

    def thin(xyz, cls):
        if cfg.plane_voxel > 0 and len(xyz):
            key = np.c_[np.floor(xyz / (cfg.plane_voxel * diag)).astype(np.int64), cls]
            first = np.unique(key, axis=0, return_index=True)[1]
            xyz, cls = xyz[first], cls[first]
        return xyz, cls

    up = scene_up(scene.cameras)

    def fit(xyz, cls, cams, seen_xyz):  # points already thinned
        return fit_planes(xyz, cls, stuff, threshold=cfg.plane_threshold * diag, min_points=min_points,
                          margin=cfg.plane_margin * diag, up=up, sightlines=(cams, seen_xyz))

    thinned, thinned_cls = thin(xyz, cls)
    n_stuff = int(np.isin(thinned_cls, stuff).sum())
    # from the stereo points alone: the boundary points below would raise it and lose the walls few views see
    min_points = max(cfg.plane_min_points, int(cfg.plane_min_share * n_stuff))
    planes = fit(thinned, thinned_cls, cams, seen_xyz)
    if cfg.plane_floor_boundary and len(planes):
        # The floor fixes where the labels' wall-on-floor boundaries are in 3D: wall points without texture
        # (lift3d.sfm.planes.floor_boundary_points). Fitted again with them.
        floor = floor_plane(planes, up)
        if floor is not None:
            f, n, d = floor
            walls = [c for c in stuff if c not in planes.classes[f]]
            height = height_above(thinned, n, d)
            foot, foot_cls, foot_cam = floor_boundary_points(
                scene.cameras, frames, labels, n, d, planes.classes[f], walls, step=2 * cfg.plane_threshold * diag,
                max_height=height, tolerance=cfg.plane_threshold * diag)
            info["floor_boundary_points"] = int(len(foot))
            if len(foot):
                # thinning the thinned points again keeps them (one per cell and class already, first in order)
                thinned, thinned_cls = thin(np.r_[thinned, foot], np.r_[thinned_cls, foot_cls])
                cams, seen_xyz = np.r_[cams, foot_cam], np.r_[seen_xyz, foot]
                planes = fit(thinned, thinned_cls, cams, seen_xyz)
    if cfg.plane_corner_cutters and len(planes):
        # a plane across a corner, through the ends of its two walls, hides the corner and stops their reach
        floor = floor_plane(planes, up)
        cut = corner_cutters(planes, thinned, thinned_cls, cfg.plane_threshold * diag,
                             floor[1] if floor is not None else up, scene.cameras.centers[frames].mean(0))
        info["corner_cutters_dropped"] = int(cut.sum())
        planes = planes.subset(~cut)
    if cfg.plane_floor_line_walls and len(planes):
        # far plain walls: their near feet were too few, but many views' boundaries agree in pixels
        floor = floor_plane(planes, up)
        if floor is not None:
            height = height_above(thinned, floor[1], floor[2])
            planes, found = _floor_line_walls(scene, frames, labels, planes, floor, stuff, cfg, diag, height,
                                              (cams, seen_xyz))
            info.update(found)
    if cfg.plane_square_walls and len(planes):
        # a plain wall's few stereo points turn its plane by a degree or more: rooms are mostly square
        floor = floor_plane(planes, up)
        directions = wall_directions(planes, floor[1] if floor is not None else up)
        if directions is not None:
            planes, info["walls_squared"] = square_walls(planes, directions, thinned, cfg.plane_threshold * diag)
    if cfg.plane_ceiling_boundary and len(planes):
        # walls from stereo alone are enough to place a ceiling: this does not need the floor line
        planes, found = _ceiling_plane(scene, frames, labels, planes, up, stuff, cfg, diag, min_points,
                                       (cams, seen_xyz))
        info.update(found)
    reach = None
    bounded = scene.scene_box is not None and scene.scene_box.type == "bounded"
    if cfg.plane_wall_reach and len(planes) and bounded:
        # a long wall few views see end-on has points on part of its length only (docs/sfm.md)
        ground = floor_plane(planes, up)
        if ground is not None:
            f, fn, fd = ground
            floor_xyz, _, floor_cams = ceiling_points(scene.cameras, frames, labels, fn, fd, planes.classes[f],
                                                      stride=max(1, int(cfg.plane_stride)))
            threshold = cfg.plane_threshold * diag
            reach = wall_reach(planes, (cams, seen_xyz), (floor_cams, floor_xyz), fn, threshold,
                               np.asarray(scene.scene_box.aabb, np.float64) + [[-threshold] * 3, [threshold] * 3])
    if cfg.plane_margin_seen_through and len(planes):
        planes = planes.with_seen_through(cams, seen_xyz, cfg.plane_threshold * diag)
    info.update(planes=len(planes), classes=[sorted(c) for c in planes.classes], stuff_points=n_stuff,
                points_on_planes=int(planes.inliers.sum()),
                median_rms=round(float(np.median(planes.rms)), 4) if len(planes) else None)
    if not len(planes):
        return empty, info
    stride = max(1, int(cfg.plane_stride))
    floor_sigma = 0.5 * cfg.plane_threshold * diag
    out = []
    dropped = enclosed = 0
    held = set().union(*planes.classes)
    # a window in a second wall: the plane holding the window class is the first wall's
    enclosable = sorted(set(stuff) if cfg.plane_enclosed_held else set(stuff) - held) if cfg.plane_enclosed else []
    faces = None
    floor = floor_plane(planes, up) if cfg.plane_standing and scene.thing_ids else None
    if floor is not None:
        # a plain cabinet: upright faces rising from where the labels put things on the floor
        f, fn, fd = floor
        faces = standing_faces(scene.cameras, frames, labels, fn, fd, planes.classes[f], scene.thing_ids, stuff,
                               threshold=cfg.plane_threshold * diag, step=0.5 * cfg.plane_threshold * diag,
                               max_height=height_above(thinned, fn, fd),
                               tolerance=2 * cfg.plane_threshold * diag)
        # a plant's leaves spread wider than its pot: where stereo matched a thing, its depths refute a face
        met, agreeing = stereo_agreement(faces, scene.cameras, [index[n] for n in dense.frame_names], labels,
                                         dense.depth, tolerance=cfg.plane_threshold * diag)
        refuted = met - agreeing > np.maximum(MIN_REFUTING_DEPTHS, (1 - STANDING_AGREEMENT) * met)
        info["standing_faces"] = int(len(faces) - refuted.sum())
        info["standing_faces_refuted"] = int(refuted.sum())
        faces = faces.subset(~refuted)
    standing = reached = 0
    for i in targets_for:
        i = int(i)
        sem = labels[i]  # targets_for is a subset of the training frames
        h, w = sem.shape
        r, c = np.mgrid[stride // 2:h:stride, stride // 2:w:stride]
        r, c = r.ravel(), c.ravel()
        cls = sem[r, c]
        keep = np.isin(cls, sorted(held))
        r, c, cls = r[keep], c[keep], cls[keep]
        if not len(r):
            continue
        o, d = scene.cameras.rays(i, c, r)
        t, k = planes.first_hit(o, d, classes=cls)
        ok = k >= 0
        ok &= planes.holds(k, cls)
        if reach is not None and not ok.all():
            # pixels of a wall past its points and margin, where the wall still reaches
            idx = np.flatnonzero(~ok)
            rt, rk = reach.first_hit(o[idx], d[idx])
            on = (rt < t[idx]) & planes.holds(rk, cls[idx])
            t[idx[on]], k[idx[on]], ok[idx[on]] = rt[on], rk[on], True
            reached += int(on.sum())
        if cfg.plane_label_support > 0 and ok.any():
            # a wardrobe one view labels wall would get the wall's depth: the views that see that spot of the
            # wall label what stands in front of it
            idx = np.flatnonzero(ok)
            support, votes = label_support(scene.cameras, frames, labels, planes, o[idx] + t[idx, None] * d[idx],
                                           k[idx], i, tolerance=2 * cfg.plane_threshold * diag)
            refuted = (votes >= MIN_LABEL_VOTES) & (support < cfg.plane_label_support * votes)
            ok[idx[refuted]] = False
            dropped += int(refuted.sum())
        axis = scene.cameras.c2w_opencv[i][:3, 2]
        r, c, k, t, d = r[ok], c[ok], k[ok], t[ok], d[ok]
        if enclosable:
            # a window inside a wall whose plane does not hold it: the wall's depth
            # (lift3d.sfm.planes.enclosed_segments); pixels that met a plane holding their class keep that depth
            targeted = np.zeros(sem.shape, bool)
            targeted[r, c] = True
            er, ec, et, ek = enclosed_segments(scene.cameras, i, sem, enclosable, planes, stride, targeted=targeted,
                                               margin=bounded and cfg.plane_enclosed_margin)
            if len(er):
                r, c, t, k = np.r_[r, er], np.r_[c, ec], np.r_[t, et], np.r_[k, ek]
                d = np.r_[d, scene.cameras.rays(i, ec, er)[1]]
                enclosed += len(er)
        z = t * (d @ axis)
        sigma = np.maximum(planes.rms[k], floor_sigma)
        if faces is not None and len(faces):
            sr, sc = np.mgrid[stride // 2:h:stride, stride // 2:w:stride]
            sr, sc = sr.ravel(), sc.ravel()
            on = np.isin(sem[sr, sc], faces.classes)
            sr, sc = sr[on], sc[on]
            so, sd = scene.cameras.rays(i, sc, sr)
            st, sk = faces.first_hit(so, sd, sem[sr, sc])
            hit = sk >= 0
            r, c = np.r_[r, sr[hit]], np.r_[c, sc[hit]]
            z = np.r_[z, st[hit] * (sd[hit] @ axis)]
            sigma = np.r_[sigma, np.maximum(faces.rms[sk[hit]], floor_sigma)]
            standing += int(hit.sum())
        n = len(r)
        out.append((np.full(n, i, np.int64), c.astype(np.float32), r.astype(np.float32),
                    z.astype(np.float32), sigma.astype(np.float32), np.ones(n, bool)))
    if not out:
        return empty, info
    rows = tuple(np.concatenate(a) for a in zip(*out))
    info["targets"] = int(len(rows[0]))
    if cfg.plane_label_support > 0:
        info["refuted_by_other_views"] = dropped
    if cfg.plane_enclosed:
        info["enclosed"] = enclosed
    if floor is not None:
        info["standing"] = standing
    if reach is not None:
        info["wall_reach"] = reached
    return rows, info


def _floor_line_walls(scene: Scene, frames, labels, planes, floor, stuff, cfg: ImageDepthConfig, diag: float,
                      max_height: float, sightlines: tuple[np.ndarray, np.ndarray]):
    """The planes and the walls that the views' wall-on-floor boundaries agree on in pixels and no plane has yet
    (:func:`lift3d.sfm.planes.floor_line_walls`), in the walls' directions (the mean of the vertical planes'
    normals modulo a right angle, weighted by their points) and at right angles to them, of the classes
    :func:`lift3d.sfm.planes.wall_classes` allows, added by :func:`lift3d.sfm.planes.add_walls`."""
    # here, not at module level: keeps `import lift3d.train` cheap (lift3d.sfm loads OpenCV)
    from lift3d.sfm.planes import add_walls, correct_walls, floor_line, floor_line_walls, wall_classes, wall_directions

    f, n, d = floor
    directions = wall_directions(planes, n)
    if directions is None:
        return planes, {"floor_line_walls": 0, "floor_line_moved": 0, "floor_line_observations": 0}
    upright = wall_classes(planes, f, n, stuff)
    line = floor_line(scene.cameras, frames, labels, n, d, sorted(set(planes.classes[f]) - set(upright)), upright)
    threshold = cfg.plane_threshold * diag
    moved = 0
    if cfg.plane_floor_line_correct:
        planes, moved = correct_walls(line, directions, planes, threshold, pixel_tolerance=cfg.plane_line_pixels,
                                      sightlines=sightlines)
    found = floor_line_walls(line, directions, planes, threshold, pixel_tolerance=cfg.plane_line_pixels)
    planes, kept = add_walls(planes, scene.cameras, labels, line, found, n, max_height, threshold, sightlines)
    return planes, {"floor_line_walls": kept, "floor_line_moved": moved, "floor_line_observations": int(len(line))}


def _ceiling_plane(scene: Scene, frames, labels, planes, up, stuff, cfg: ImageDepthConfig, diag: float,
                   min_points: int, sightlines: tuple[np.ndarray, np.ndarray]):
    """The planes and, when the labels' ceiling-on-wall boundaries and the walls found give the ceiling's height,
    a horizontal ceiling plane there over the points where the ceiling pixels' rays meet it (docs/sfm.md)."""
    # here, not at module level: keeps `import lift3d.train` cheap (lift3d.sfm loads OpenCV)
    from lift3d.sfm.planes import ceiling_height, floor_plane, most_walls_hold

    floor = floor_plane(planes, up)
    if floor is None:
        return planes, {}
    _, n, d = floor
    # Stuff no level plane holds (a ceiling with enough texture has its plane from stereo already) and fewer than
    # half the walls: the points along a wall's top edge that the labels call ceiling can make one wall's plane
    # hold the ceiling class (tuning room 7). Each class on its own, so that a window above a wall cannot pull a
    # ceiling's height.
    found: dict[str, Any] = {"ceiling_boundary_points": 0, "ceiling_height": None, "ceiling_contradicted": 0}
    vertical = planes.vertical(n)
    if cfg.plane_ceiling_extend:
        planes, found["ceiling_extended"] = _extend_level_ceilings(scene, frames, labels, planes, n, d, stuff, cfg,
                                                                   diag, sightlines)
        vertical = planes.vertical(n)
    for c in [c for c in stuff if not any(c in k for k, v in zip(planes.classes, vertical) if not v)
              and not most_walls_hold(planes, vertical, c)]:
        top, count = ceiling_height(scene.cameras, frames, labels, planes, n, d, [c],
                                    threshold=cfg.plane_threshold * diag, min_points=min_points)
        found["ceiling_boundary_points"] += count
        if top is None:
            continue
        grown = _level_plane_over_pixels(scene, frames, labels, planes, n, d - top, c, cfg, diag, sightlines)
        if grown is None:
            found["ceiling_contradicted"] += 1
            continue
        planes = grown
        found["ceiling_height"] = round(top, 4)
    return planes, found


def _level_plane_over_pixels(scene: Scene, frames, labels, planes, normal: np.ndarray, offset: float, class_id: int,
                             cfg: ImageDepthConfig, diag: float, sightlines: tuple[np.ndarray, np.ndarray]):
    """The planes and one more, ``normal · x + offset = 0``, over the points where the rays of the pixels the
    labels call ``class_id`` meet it (:func:`lift3d.sfm.planes.ceiling_points`), holding that class; None when
    the views see through it there."""
    # here, not at module level: keeps `import lift3d.train` cheap (lift3d.sfm loads OpenCV)
    from lift3d.sfm.planes import ceiling_points, contradicted

    xyz, cls, _ = ceiling_points(scene.cameras, frames, labels, normal, offset, [class_id],
                                 stride=max(1, int(cfg.plane_stride)))
    # The views see through a level plane at a window's sill, to the wall above it: a test room's window, cut
    # by the top of every view that shows its sill, made a level plane at 1.67 m in a room 3.2 m high, which
    # 30 × as many sight lines cross as end on. A real ceiling's share is what stray points above it make:
    # 0–0.21 on tuning rooms 6–10, so the share allowed is 1 (more crossing it than ending on it). Fewer than
    # three points, or points along a line, count as contradicted too.
    if contradicted(sightlines, normal, offset, xyz, cfg.plane_threshold * diag, max_crossing_share=1.0):
        return None
    return planes.with_plane(normal, offset, xyz, cls, cfg.plane_threshold * diag)


def _extend_level_ceilings(scene: Scene, frames, labels, planes, n: np.ndarray, d: float, stuff, cfg: ImageDepthConfig,
                           diag: float, sightlines: tuple[np.ndarray, np.ndarray]):
    """The planes with each level plane above the cameras that stereo found for a ceiling class reaching over
    every pixel the labels give that class (docs/sfm.md), and how many classes got that.

    A textured ceiling gets its level plane from the stereo points, but only over the few it matched: on a
    tuning room, 141 points of an 8 × 8 m ceiling with a repeating grid, and 70 % of the ceiling's GT points
    were out of the export's reach (its pixels got no target, and the field left the ceiling half
    transparent). The rays of the pixels of that class meet the plane where the ceiling is, as for a plain
    ceiling (:func:`_ceiling_plane`), and those points become one more plane at the same place holding the
    class. A class that half the walls hold or more is not a ceiling's; a plane that more sight lines cross
    than end on over that reach is not added."""
    # here, not at module level: keeps `import lift3d.train` cheap (lift3d.sfm loads OpenCV)
    from lift3d.sfm.planes import most_walls_hold

    vertical = planes.vertical(n)
    eye = float(np.median(scene.cameras.centers[np.asarray(frames, np.int64)] @ n + d))
    extended = 0
    for k in np.flatnonzero(~vertical):
        if float(planes.origin[k] @ n + d) <= eye:
            continue
        for c in sorted(int(c) for c in planes.classes[k] if c in stuff):
            if most_walls_hold(planes, vertical, c):
                continue
            grown = _level_plane_over_pixels(scene, frames, labels, planes, planes.normal[k], float(planes.offset[k]),
                                             c, cfg, diag, sightlines)
            if grown is not None:
                extended += len(grown) > len(planes)
                planes = grown
    return planes, extended


# ------------------------------------------------------------------------------------------ dense maps
def _dense_maps(scene: Scene, frames: np.ndarray, sparse: SparsePoints, cache: Path | None,
                progress: bool) -> tuple[DenseDepth, str]:
    names = [scene.frames[int(i)].name for i in frames]
    if all(scene.frames[int(i)].mvs_depth_path is not None for i in frames):
        maps = [scene.mvs_depth(int(i)) for i in frames]
        supports = [scene.mvs_support(int(i)) for i in frames]
        return DenseDepth(names, [m[0] for m in maps], [m[1] for m in maps],
                          support=supports if all(n is not None for n in supports) else None), \
            "scene (mvs_depth_file_path)"
    path = None if cache is None else cache / "mvs.npz"
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
    if path is not None:
        buf = io.BytesIO()
        np.savez_compressed(buf, names=np.asarray(names, dtype=str), depth=np.stack(dense.depth),
                            sigma=np.stack(dense.sigma), support=np.stack(dense.support))
        write_bytes_atomic(path, buf.getvalue())
    return dense, "plane sweep"


def _dense_rows(scene: Scene, dense: DenseDepth, targets_for: np.ndarray):
    index = {f.name: k for k, f in enumerate(scene.frames)}
    wanted = set(int(i) for i in targets_for)
    out = []
    for name, d, s in zip(dense.frame_names, dense.depth, dense.sigma):
        i = index[name]
        if i not in wanted:
            continue
        r, c = np.nonzero(np.asarray(d) > 0)
        out.append((np.full(len(r), i, np.int64), c.astype(np.float32), r.astype(np.float32),
                    np.asarray(d)[r, c].astype(np.float32), np.asarray(s)[r, c].astype(np.float32),
                    np.ones(len(r), bool)))
    if not out:
        f = np.zeros(0, np.float32)
        return np.zeros(0, np.int64), f, f, f, f, np.zeros(0, bool)
    return tuple(np.concatenate(a) for a in zip(*out))


def _pixels(scene: Scene, frames: np.ndarray) -> int:
    return int(sum(int(scene.cameras.width[i]) * int(scene.cameras.height[i]) for i in frames))
