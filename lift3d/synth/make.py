"""``make_scene``: build a synthetic scene, place cameras, ray cast every view, simulate the 2D segmenter and
write the scene folder (DESIGN.md section 1).

Random streams are separate and seeded from ``seed`` alone, so a scene is reproducible byte for byte and the
noise level does not change the geometry, cameras or images (``moderate`` and ``hard`` scenes of one seed
differ only in their pseudo-labels):

* layout (room, objects, street) ``SeedSequence([seed, 0, kind])``,
* cameras ``SeedSequence([seed, 1, kind])``,
* the segmenter of frame ``i`` ``SeedSequence([seed, 2, kind, i])`` — one stream per frame, which is what
  makes the errors independent across views.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import numpy as np

from lift3d.data.cameras import Cameras, look_at
from lift3d.data.scene import Segment, SceneWriter
from lift3d.errors import InputError
from lift3d.synth.geometry import (
    GRASS_END,
    RayCaster,
    SceneContent,
    build_indoor,
    build_outdoor,
)
from lift3d.synth.noise import PRESETS, NoiseConfig, NoiseStats, noise_config, simulate_segmenter
from lift3d.utils.atomic import write_json_atomic
from lift3d.utils.progress import progress_bar

KINDS = ("indoor", "outdoor")
#: Marker in transforms.json: a folder holding it may be overwritten by a new ``lift3d synth`` run.
SYNTH_META_KEY = "lift3d_synth"
#: What ``make_scene`` writes, and so what it may remove when it overwrites an earlier synthetic scene.
_OWNED = ("images", "panoptic", "gt", "depth", "transforms.json", "panoptic.json", "synth_noise.json")
#: Rotated-grid supersampling offsets (pixels from the centre): anti-aliased colour with 4 rays per pixel.
_SUBPIXEL = np.array([[-0.125, -0.375], [0.375, -0.125], [0.125, 0.375], [-0.375, 0.125]])


def _check_args(out, kind, seed, noise, n_views, width, height) -> NoiseConfig:
    if not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**63:
        raise InputError("--seed", f"must be a non-negative integer, got {seed!r}")
    if kind not in KINDS:
        raise InputError("--kind", f"{kind!r} is not one of {', '.join(KINDS)}")
    try:
        cfg = noise_config(noise)
    except KeyError:
        raise InputError("--noise", f"{noise!r} is not one of {', '.join(PRESETS)}") from None
    if not isinstance(n_views, (int, np.integer)) or n_views < 2:
        raise InputError("--views", f"need at least 2 views (one to train on, one to test), got {n_views}")
    if n_views > 10000:
        raise InputError("--views", f"{n_views} views is more than the 10000 supported")
    for flag, size in (("--width", width), ("--height", height)):
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


# --------------------------------------------------------------------------------------------- cameras
def _intrinsics(width: int, height: int, hfov_deg: float) -> tuple[float, float, float, float]:
    fx = 0.5 * width / np.tan(np.radians(hfov_deg) / 2)
    return fx, fx, width / 2.0, height / 2.0


def indoor_cameras(content: SceneContent, n_views: int, rng: np.random.Generator) -> np.ndarray:
    """``[n, 4, 4]`` OpenGL camera-to-world matrices circling the room's middle, at varied heights, looking at
    the furniture (an object's centre or a point near the room's centre)."""
    (x0, y0, _), (x1, y1, z1) = content.aabb
    hx, hy = (x1 - x0) / 2, (y1 - y0) / 2
    things = content.things
    c2ws = []
    for k in range(n_views):
        # Free floor positions (out of the furniture: a camera inside an object would see only its inside);
        # keep the one closest to this view's place on an ellipse around the room's middle, so consecutive
        # views circle the room like a video.
        cand = np.column_stack([rng.uniform(-1, 1, 400) * (hx - 0.35), rng.uniform(-1, 1, 400) * (hy - 0.35)])
        free = np.ones(len(cand), bool)
        for c, r in content.footprints:
            free &= np.linalg.norm(cand - c, axis=1) > r + 0.35
        if not free.any():
            raise RuntimeError("no free camera position found in the room")
        cand = cand[free]
        base = 2 * np.pi * k / n_views + rng.uniform(-0.15, 0.15)
        radius = rng.uniform(0.55, 0.85)
        goal = np.array([radius * (hx - 0.35) * np.cos(base), radius * (hy - 0.35) * np.sin(base)])
        xy = cand[np.argmin(np.linalg.norm(cand - goal, axis=1))]
        eye = np.array([xy[0], xy[1], rng.uniform(0.9, min(2.2, z1 - 0.4))])
        if rng.random() < 0.5 and things:
            obj = things[int(rng.integers(len(things)))]
            lo, hi = obj.mesh.bounds
            target = (lo + hi) / 2
        else:
            target = np.array([rng.uniform(-0.3, 0.3) * hx, rng.uniform(-0.3, 0.3) * hy, rng.uniform(0.2, 0.9)])
        if np.linalg.norm((target - eye)[:2]) < 1.0:  # too close to frame it: look across the room instead
            target = np.array([0.0, 0.0, 0.5]) - 0.5 * np.append(eye[:2], 0.0)
        c2ws.append(look_at(eye, target))
    return np.stack(c2ws)


def outdoor_cameras(n_views: int, rng: np.random.Generator, path_length: float = 6.0) -> np.ndarray:
    """``[n, 4, 4]`` camera-to-world matrices driving forward (+y) down the street for ``path_length`` metres,
    at eye height, with a gentle lateral weave and small yaw/pitch changes (so views are not all collinear)."""
    c2ws = []
    phase = rng.uniform(0, 2 * np.pi)
    for k in range(n_views):
        s = k / max(n_views - 1, 1)
        eye = np.array([-0.3 + 0.5 * np.sin(2 * np.pi * s + phase), path_length * s,
                        1.6 + 0.08 * np.sin(4 * np.pi * s + phase)])
        yaw = np.radians(8.0) * np.sin(2 * np.pi * 1.5 * s + phase) + np.radians(rng.uniform(-1.5, 1.5))
        pitch = np.radians(1.0 + rng.uniform(-1.5, 1.5))  # horizon a little below the image centre
        fwd = np.array([np.sin(yaw) * np.cos(pitch), np.cos(yaw) * np.cos(pitch), np.sin(pitch)])
        c2ws.append(look_at(eye, eye + fwd))
    return np.stack(c2ws)


def split_names(names: list[str]) -> dict[str, list[str]]:
    """Every 8th view (from the 5th) is a test view, held out from training; every other test view is also
    a validation view. With fewer than 5 views the last view is the test view."""
    n = len(names)
    test = [i for i in range(n) if i % 8 == 4] or [n - 1]
    val = test[::2]
    train = [i for i in range(n) if i not in set(test)]
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


# --------------------------------------------------------------------------------------------- main
def make_scene(
    out: str | Path,
    kind: str = "indoor",
    seed: int = 0,
    noise: str | NoiseConfig = "moderate",
    n_views: int = 60,
    width: int = 128,
    height: int = 128,
    progress: bool = True,
) -> dict:
    """Write a synthetic labelled scene folder with simulated 2D segmenter noise.

    Parameters
    ----------
    out : str or Path
        Output folder (created; an earlier synthetic scene there is replaced, any other non-empty folder
        is refused).
    kind : {"indoor", "outdoor"}
        A furnished room (bounded) or a long street with sky (unbounded).
    seed : int
        Seed of everything random; the same arguments give the same bytes.
    noise : {"clean", "moderate", "hard"} or NoiseConfig
        Error rates of the simulated segmenter (``docs/synth.md``).
    n_views : int
        Number of frames.
    width, height : int
        Image size in pixels.
    progress : bool
        Show a progress bar.

    Returns
    -------
    dict
        A report: arguments, content (object counts, extent), noise statistics (also written to
        ``<out>/synth_noise.json``), pseudo-label mIoU, paths, and wall time in seconds.

    Examples
    --------
    >>> import tempfile
    >>> rep = make_scene(tempfile.mkdtemp() + "/s", n_views=4, width=32, height=32, progress=False)
    >>> rep["n_views"], rep["noise"]["name"]
    (4, 'moderate')
    """
    started = time.perf_counter()
    cfg = _check_args(out, kind, seed, noise, n_views, width, height)
    n_views, width, height, seed = int(n_views), int(width), int(height), int(seed)
    out = Path(out)
    kind_code = KINDS.index(kind)
    layout_rng = np.random.default_rng(np.random.SeedSequence([seed, 0, kind_code]))
    camera_rng = np.random.default_rng(np.random.SeedSequence([seed, 1, kind_code]))

    content = build_indoor(layout_rng) if kind == "indoor" else build_outdoor(layout_rng)
    if kind == "indoor":
        c2w = indoor_cameras(content, n_views, camera_rng)
        fx, fy, cx, cy = _intrinsics(width, height, 70.0)
    else:
        c2w = outdoor_cameras(n_views, camera_rng)
        fx, fy, cx, cy = _intrinsics(width, height, 75.0)
    cameras = Cameras(c2w=c2w, fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height)
    caster = RayCaster(content)
    gt_category = {o.segment_id: o.category_id for o in content.objects}
    if content.sky_category is not None:
        gt_category[content.sky_category] = content.sky_category

    if out.is_dir():  # an earlier synthetic scene (checked above): remove only what make_scene writes
        for name in _OWNED:
            p = out / name
            if p.is_dir():
                shutil.rmtree(p)
            elif p.exists():
                p.unlink()

    meta = {SYNTH_META_KEY: {"kind": kind, "seed": seed, "noise": cfg.name, "n_views": n_views,
                             "width": width, "height": height}}
    stats = NoiseStats(content.categories)
    pts, pt_sem, pt_inst, pt_rgb = [], [], [], []
    names: list[str] = []
    seen_segments: set[int] = set()
    thing_ids = {c.id for c in content.categories if c.isthing}
    with SceneWriter(out, content.categories, depth_unit_scale_factor=content.depth_unit_scale_factor,
                     extra_meta=meta) as writer:
        for i in progress_bar(range(n_views), desc=f"synth {kind}", disable=not progress, unit="view"):
            view = render_view(caster, cameras, i)
            seg = view["segment"]
            frame_rng = np.random.default_rng(np.random.SeedSequence([seed, 2, kind_code, i]))
            pseudo = simulate_segmenter(seg, gt_category, content.categories, content.confusable, cfg, frame_rng)
            present = [int(s) for s in np.unique(seg) if s != 0]
            seen_segments.update(present)
            gt_segments = [Segment(s, gt_category[s], 1.0) for s in present]
            pseudo_sem = np.zeros(seg.shape, np.int64)
            for s in pseudo.segments:
                pseudo_sem[pseudo.panoptic == s.id] = s.category_id
            stats.add(pseudo.counts, view["category"], pseudo_sem)
            name = f"frame_{i:04d}"
            names.append(writer.add_frame(
                name, view["rgb"], c2w[i], (fx, fy, cx, cy), panoptic=pseudo.panoptic, segments=pseudo.segments,
                gt_panoptic=seg, gt_segments=gt_segments, depth=view["depth"],
            ))
            hit = view["hit"]
            pts.append(view["points"])
            pt_sem.append(view["category"][hit])
            pt_inst.append(np.where(np.isin(view["category"][hit], list(thing_ids)), seg[hit], 0))
            pt_rgb.append(view["point_rgb"])

        splits = split_names(names)
        writer.set_splits(splits["train"], splits["val"], splits["test"])
        centres = cameras.centers
        if content.scene_box_type == "bounded":
            scene_box = content.aabb + np.array([[-0.01] * 3, [0.01] * 3])
        else:
            # Foreground box: the near street around the camera path; everything beyond is contracted.
            lo, hi = centres.min(0), centres.max(0)
            scene_box = np.array([[-GRASS_END - 3.0, lo[1] - 4.0, -0.5], [GRASS_END + 3.0, hi[1] + 16.0, 8.0]])
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
    baseline = float(np.max(np.linalg.norm(centres[:, None] - centres[None], axis=-1)))
    gt_xyz = xyz[keep]
    extent = float(np.linalg.norm(gt_xyz.max(0) - gt_xyz.min(0))) if len(gt_xyz) else 0.0
    cats = {c.id: c for c in content.categories}
    things = content.things
    noise_json = {
        "kind": kind, "seed": seed, "n_views": n_views, "width": width, "height": height,
        "config": cfg.to_json(), **summary,
    }
    write_json_atomic(out / "synth_noise.json", noise_json)
    return {
        "out": str(out), "kind": kind, "seed": seed, "n_views": n_views, "width": width, "height": height,
        "noise": {"name": cfg.name, **summary},
        "content": {
            "n_things": len(things),
            "thing_classes": sorted({cats[o.category_id].name for o in things}),
            "n_thing_classes": len({o.category_id for o in things}),
            "segments_seen": len(seen_segments),
            "extent_m": round(extent, 3),
            "camera_baseline_m": round(baseline, 3),
            "extent_over_baseline": round(extent / baseline, 2) if baseline > 0 else None,
            "scene_box": {"type": content.scene_box_type, "aabb": np.round(scene_box, 4).tolist()},
            "gt_points": int(len(keep)),
            "gt_points_voxel_m": round(voxel, 4),
        },
        "splits": {k: len(v) for k, v in splits.items()},
        "paths": {
            "scene": str(out), "transforms": str(out / "transforms.json"), "pseudo_labels": str(out / "panoptic.json"),
            "gt_points": str(out / "gt" / "points.ply"), "noise_stats": str(out / "synth_noise.json"),
        },
        "seconds": round(time.perf_counter() - started, 3),
    }
