"""``triangulate_scene``: sparse 3D points of a scene from its images and known poses.

features (per view) -> pair selection (poses) -> matching (ratio test + epipolar check) -> tracks
(connected components of the match graph, i.e. union-find over (view, keypoint)) -> triangulation,
outlier removal, filters and per-observation depth uncertainty (:mod:`lift3d.sfm.triangulation`).
"""

from __future__ import annotations

import time
from typing import Sequence

import numpy as np

from lift3d.data.scene import Scene
from lift3d.data.stereo import SparsePoints
from lift3d.sfm.config import SfmConfig
from lift3d.sfm.features import Features, detect
from lift3d.sfm.geometry import fundamental, ideal_pixels, intrinsics, world_to_camera
from lift3d.sfm.matching import match_pair
from lift3d.sfm.pairs import select_pairs
from lift3d.sfm.tracks import build_tracks
from lift3d.sfm.triangulation import DROP_REASONS, triangulate_tracks
from lift3d.utils.progress import progress_bar

#: Fewer points than this is reported as a warning (depth supervision would be too thin to help).
MIN_USEFUL_POINTS = 100


def default_frames(scene: Scene, split: str = "train") -> np.ndarray:
    """The frames to triangulate from: a split's frames (``all`` = every frame)."""
    return np.arange(len(scene)) if split == "all" else np.asarray(scene.split(split))


def detect_all(scene: Scene, frames: Sequence[int], config: SfmConfig, progress: bool = False) -> list[Features]:
    """Features of each frame (``scene.mask`` restricts detection when the frame has one)."""
    out = []
    for i in progress_bar(frames, desc="features", unit="view", disable=not progress):
        out.append(detect(scene.image(int(i)), config.features, scene.mask(int(i))))
    return out


def triangulate_scene(scene: Scene, frames: Sequence[int] | None = None, config: SfmConfig | None = None,
                      progress: bool = False) -> SparsePoints:
    """Triangulate sparse points from a scene's images with its known poses.

    Parameters
    ----------
    scene : Scene
        A loaded scene folder (poses and intrinsics are trusted).
    frames : sequence of int, optional
        Frame indices to use (default: the ``train`` split, so held-out views stay held out).
    config : SfmConfig, optional
        Every knob (defaults are tuned on the synthetic scenes, docs/sfm.md).
    progress : bool
        Progress bars on stderr.

    Returns
    -------
    SparsePoints
        Observations refer to the scene's frame names; ``info`` holds the counts (keypoints, pairs,
        matches, points dropped per reason), seconds per stage and ``warnings`` (too few points, no
        usable view pairs). Never raises for too little texture or baseline: it returns few or no points.
    """
    cfg = (config or SfmConfig()).check()
    frames = default_frames(scene) if frames is None else np.asarray(frames, np.int64)
    cams = scene.cameras[frames]
    seconds: dict[str, float] = {}
    warnings: list[str] = []
    t0 = time.perf_counter()
    feats = detect_all(scene, frames, cfg, progress)
    ideal = [ideal_pixels(cams, v, f.uv) for v, f in enumerate(feats)]
    seconds["features"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    box = scene.scene_box
    graph = select_pairs(cams, cfg.pairs, aabb=None if box is None else box.aabb)
    r, t = world_to_camera(cams)
    k = intrinsics(cams)
    offsets = np.concatenate([[0], np.cumsum([len(f) for f in feats])])
    edges, quality = [], []
    for i, j in progress_bar(graph.pairs, desc="matching", unit="pair", disable=not progress):
        f_ij = fundamental(r, t, k, int(i), int(j))
        m, q = match_pair(feats[i].descriptors, feats[j].descriptors, ideal[i], ideal[j], f_ij, cfg.matching)
        edges.append(np.column_stack([m[:, 0] + offsets[i], m[:, 1] + offsets[j]]))
        quality.append(q)
    edges_arr = np.concatenate(edges) if edges else np.zeros((0, 2), np.int64)
    quality_arr = np.concatenate(quality) if quality else np.zeros(0)
    seconds["matching"] = time.perf_counter() - t0
    if len(graph.pairs) == 0:
        warnings.append("no view pairs with enough overlap and baseline (cameras too close together, or "
                        "looking in different directions)")

    t0 = time.perf_counter()
    n_nodes = int(offsets[-1])
    node_view = np.repeat(np.arange(len(feats)), np.diff(offsets))
    label, conflicts = build_tracks(edges_arr, quality_arr, node_view)
    matched = np.zeros(n_nodes, bool)
    matched[edges_arr.ravel()] = True
    nodes = np.flatnonzero(matched)
    view = (np.searchsorted(offsets, nodes, side="right") - 1).astype(np.int64)
    kp = nodes - offsets[view]
    p = np.concatenate(ideal)[nodes] if len(nodes) else np.zeros((0, 2))
    aabb = None if box is None else box.aabb
    tri = triangulate_tracks(r, t, k, view, p, label[nodes], cfg.tracks, aabb=aabb,
                             bounded=box is not None and box.type == "bounded")
    seconds["triangulation"] = time.perf_counter() - t0

    obs_view, obs_kp = view[tri.obs_index], kp[tri.obs_index]
    uv = np.concatenate([f.uv for f in feats])[offsets[obs_view] + obs_kp] if len(obs_view) else np.zeros((0, 2))
    rgb_obs = np.concatenate([f.rgb for f in feats])[offsets[obs_view] + obs_kp] if len(obs_view) else np.zeros((0, 3))
    n_pts = len(tri.xyz)
    count = np.bincount(tri.obs_point, minlength=n_pts)
    rgb = np.stack([np.bincount(tri.obs_point, weights=rgb_obs[:, c], minlength=n_pts) for c in range(3)], -1)
    rgb = np.round(rgb / np.maximum(count, 1)[:, None]).astype(np.uint8)
    if n_pts < MIN_USEFUL_POINTS:
        warnings.append(f"only {n_pts} points were triangulated (too little texture, overlap or baseline)")
    info = {
        "source": "lift3d triangulate",
        "frames": int(len(frames)),
        "keypoints_median": int(np.median([len(f) for f in feats])) if feats else 0,
        "pairs": int(len(graph.pairs)),
        "matches": int(len(edges_arr)),
        "tracks": int(len(np.unique(label[nodes]))) if len(nodes) else 0,
        "split_tracks": int(conflicts),
        "dropped": {reason: int(tri.dropped[reason]) for reason in DROP_REASONS},
        "seconds": {key: round(v, 3) for key, v in seconds.items()},
        "warnings": warnings,
    }
    names = [scene.frames[int(i)].name for i in frames]
    return SparsePoints(
        xyz=tri.xyz, rgb=rgb, error=tri.error.astype(np.float32), track_length=count.astype(np.int32),
        frame_names=names, obs_frame=obs_view.astype(np.int32), obs_point=tri.obs_point.astype(np.int32),
        obs_uv=uv.astype(np.float32), obs_depth=tri.obs_depth.astype(np.float32),
        obs_sigma=tri.obs_sigma.astype(np.float32), info=info,
    )
