"""Stuff planes carried to the edges where they meet (lift3d.export.stuff.complete_stuff_corners)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

from lift3d.export.stuff import complete_stuff_corners

WALL, FLOOR, CEILING, CHAIR = 1, 2, 3, 7
STUFF = [WALL, FLOOR, CEILING]
UP = np.array([0.0, 0.0, 1.0])
W, D, H, ROUND = 4.0, 3.0, 2.5, 0.15  # room size and the radius of the isosurface's rounded edges


def _grid(u0, u1, v0, v1, step=0.03):
    a, b = np.meshgrid(np.arange(u0, u1, step), np.arange(v0, v1, step))
    return a.ravel(), b.ravel()


def _rounded_room(rng):
    """A W x D x H room as a density isosurface exports it: its floor, ceiling and walls stop ROUND short of
    each edge, and quarter-cylinders of radius ROUND join them. The field labels the arcs along the ceiling
    wall (it bleeds), and those along the floor floor. Returns points, labels and the exact surfaces' points
    (GT) with their classes."""
    parts, labels = [], []

    def add(p, label):
        parts.append(p + rng.normal(0, 0.003, p.shape))
        labels.append(np.full(len(p), label))

    a, b = _grid(ROUND, W - ROUND, ROUND, D - ROUND)
    add(np.c_[a, b, np.zeros_like(a)], FLOOR)
    add(np.c_[a, b, np.full_like(a, H)], CEILING)
    for x0, sx in ((0.0, 1.0), (W, -1.0)):  # walls x = 0 and x = W
        a, b = _grid(ROUND, D - ROUND, ROUND, H - ROUND)
        add(np.c_[np.full_like(a, x0), a, b], WALL)
        t, y = np.meshgrid(np.linspace(0, np.pi / 2, 8), np.arange(ROUND, D - ROUND, 0.03))
        t, y = t.ravel(), y.ravel()
        arc_x = x0 + sx * ROUND * (1 - np.cos(t))
        add(np.c_[arc_x, y, ROUND * (1 - np.sin(t))], FLOOR)  # floor edge
        add(np.c_[arc_x, y, H - ROUND * (1 - np.sin(t))], WALL)  # ceiling edge: the wall's label bleeds
    for y0 in (0.0, D):  # walls y = 0 and y = D (their vertical edges are left square)
        a, b = _grid(ROUND, W - ROUND, ROUND, H - ROUND)
        add(np.c_[a, np.full_like(a, y0), b], WALL)
    a, b = _grid(0.3, 0.7, 0.2, 0.6)  # a chair's back against the wall x = 0: a thing, never moved
    add(np.c_[np.full_like(a, 0.1), a + 1.0, b], CHAIR)
    a, b = _grid(0, W, 0, D, 0.02)
    gt = [np.c_[a, b, np.zeros_like(a)], np.c_[a, b, np.full_like(a, H)]]
    gt_cls = [np.full(len(a), FLOOR), np.full(len(a), CEILING)]
    a, b = _grid(0, D, 0, H, 0.02)
    for x0 in (0.0, W):
        gt.append(np.c_[np.full_like(a, x0), a, b])
        gt_cls.append(np.full(len(a), WALL))
    return np.concatenate(parts), np.concatenate(labels), np.concatenate(gt), np.concatenate(gt_cls)


@pytest.fixture(scope="module")
def room():
    return _rounded_room(np.random.default_rng(0))


def _completed(xyz, sem, **kw):
    keep, source, new_xyz, new_sem, stats = complete_stuff_corners(xyz, sem, STUFF, radius=0.3, threshold=0.03,
                                                                   up=UP, **kw)
    return np.r_[xyz[keep], new_xyz], np.r_[sem[keep], new_sem], keep, source, stats


def _edge_scores(xyz, sem, gt, gt_cls):
    """Share of the GT points within 10 cm of the wall-ceiling edges whose nearest cloud point has their class,
    and the largest distance from such a GT point to the cloud."""
    near_edge = (np.minimum(gt[:, 0], W - gt[:, 0]) < 0.1) & (gt[:, 2] > H - 0.1) & (np.abs(gt[:, 1] - D / 2) < 1)
    d, nn = cKDTree(xyz).query(gt[near_edge])
    return float((sem[nn] == gt_cls[near_edge]).mean()), float(d.max())


def test_the_rounded_ceiling_edge_becomes_a_ceiling_and_a_wall_that_meet(room):
    xyz, sem, gt, gt_cls = room
    before, gap_before = _edge_scores(xyz, sem, gt, gt_cls)
    new_xyz, new_sem, keep, source, stats = _completed(xyz, sem)
    after, gap_after = _edge_scores(new_xyz, new_sem, gt, gt_cls)
    assert stats["corner_planes"] >= 5 and stats["corner_points"] > 0 and stats["relabelled"] > 0
    assert before < 0.6 and after > 0.9, (before, after)
    assert gap_before > 0.04 and gap_after < 0.03, (gap_before, gap_after)
    # every projection lies on a wall, the floor or the ceiling
    on_surface = np.minimum.reduce([np.abs(new_xyz[:, 0]), np.abs(W - new_xyz[:, 0]), np.abs(new_xyz[:, 1]),
                                    np.abs(D - new_xyz[:, 1]), np.abs(new_xyz[:, 2]), np.abs(H - new_xyz[:, 2])])
    assert np.quantile(on_surface[len(new_xyz) - len(source):], 0.99) < 0.01


def test_things_never_move_and_points_away_from_edges_stay(room):
    xyz, sem, _, _ = room
    _, _, keep, source, _ = _completed(xyz, sem)
    assert keep[sem == CHAIR].all()  # a chair 10 cm from a wall is not stuff
    assert np.isin(sem[source], STUFF).all()
    mid = (np.minimum(xyz[:, 0], W - xyz[:, 0]) > 0.5) & (np.minimum(xyz[:, 1], D - xyz[:, 1]) > 0.5)
    assert keep[mid].all()  # the middle of the floor and ceiling


def test_small_planes_and_parallel_planes_make_no_corner():
    rng = np.random.default_rng(1)
    a, b = _grid(0, 3, 0, 3)
    floor = np.c_[a, b, np.zeros_like(a)]
    a2, b2 = _grid(0, 3, 0, 2.5)
    wall = np.c_[np.full_like(a2, 3.0), a2, b2]
    fog = np.c_[np.full(60, 1.0), rng.uniform(1.0, 1.5, 60), rng.uniform(0.0, 0.3, 60)]  # a slab of "wall"
    xyz = np.r_[floor, wall, fog]
    sem = np.r_[np.full(len(floor), FLOOR), np.full(len(wall), WALL), np.full(60, WALL)]
    _, _, keep, source, stats = _completed(xyz, sem)
    assert stats["corner_planes"] == 2  # floor and wall; the slab holds under 2 % of the points, a sliver of wall
    slab = np.arange(len(xyz) - 60, len(xyz))
    assert keep[slab].all() and not np.isin(source, slab).any() and stats["corner_points"] > 0
    _, _, keep, source, stats = _completed(xyz, sem, min_plane_share=0.0)
    assert stats["corner_points"] > 0  # the same slab, allowed to take part, makes a corner
    two = np.r_[floor, floor + [0, 0, 2.5]]  # floor and ceiling only: parallel
    _, _, keep, source, stats = _completed(two, np.r_[np.full(len(floor), FLOOR), np.full(len(floor), CEILING)])
    assert stats["corner_planes"] == 2 and stats["corner_points"] == 0 and keep.all()


def test_a_window_along_the_ceiling_keeps_its_class_on_the_wall(room):
    xyz, sem, _, _ = room
    sem = sem.copy()
    window = (xyz[:, 0] < 0.02) & (np.abs(xyz[:, 1] - 1.5) < 0.3) & (xyz[:, 2] > 1.0) & (xyz[:, 2] < H - ROUND)
    sem[window] = 5  # a window in the wall x = 0 reaching up to the rounded edge
    keep, source, new_xyz, new_sem, _ = complete_stuff_corners(xyz, sem, STUFF + [5], radius=0.3, threshold=0.03,
                                                               up=UP)
    from_window = sem[source] == 5
    on_wall = new_xyz[:, 2] < H - 0.05  # the window ends ROUND below the ceiling
    assert from_window.any()
    assert (new_sem[from_window & on_wall] == 5).all()  # the wall's plane holds the window's class
    assert (new_sem[from_window & ~on_wall] != 5).all()  # on the ceiling it is ceiling (or floor)


def test_export_records_the_step_and_can_skip_it(tiny_run, tmp_path):
    from lift3d.cli.main import main

    for flag, out in (([], tmp_path / "on"), (["--no-complete-corners"], tmp_path / "off")):
        assert main(["export", "--run", str(tiny_run), "--pointcloud", "--num-points", "4000", "--output-dir",
                     str(out), "--quiet", *flag]) == 0
    on, off = ({r["name"]: r for r in json.loads((tmp_path / k / "metadata.json").read_text())["steps"]["points"]}
               for k in ("on", "off"))
    step = on["stuff-corners"]
    assert step["ran"] and step["needs"] == ["room"] and step["settings"]["plane_threshold"] == 0.004
    assert {"planes", "corner_planes", "corner_points", "added", "radius", "threshold"} <= set(step["counts"])
    assert not off["stuff-corners"]["ran"] and off["stuff-corners"]["why"] == "off"


def test_a_ceiling_the_views_barely_see_still_takes_its_edge(room):
    """A sparse ceiling: its plane holds under 2 % of the points but all of the ceiling, and the wall's rounded
    edges make over a quarter of its inliers, so the fit says it holds wall too. Wall points moved onto it are
    still ceiling: wall is the walls' own class."""
    from lift3d.sfm.planes import fit_planes

    xyz, sem, gt, gt_cls = room
    rng = np.random.default_rng(2)
    sparse = (sem != CEILING) | (rng.random(len(sem)) < 0.02)
    xyz, sem = xyz[sparse], sem[sparse]
    planes = fit_planes(xyz, sem, STUFF, threshold=0.03, min_points=max(50, len(xyz) // 200), up=UP)
    level = -planes.offset / np.where(np.abs(planes.normal[:, 2]) > 0.9, planes.normal[:, 2], np.nan)
    ceiling = int(np.nanargmin(np.abs(level - H)))  # the plane z = H
    assert planes.inliers[ceiling] < 0.02 * len(xyz) and WALL in planes.classes[ceiling]
    before, _ = _edge_scores(xyz, sem, gt, gt_cls)
    new_xyz, new_sem, _, _, stats = _completed(xyz, sem, max_points=len(xyz))  # the fit above, unsubsampled
    after, _ = _edge_scores(new_xyz, new_sem, gt, gt_cls)
    assert stats["corner_planes"] == 6 and before < 0.6 and after > 0.85, (stats, before, after)


def test_projections_respect_the_crop_box_and_the_voxel_size(tiny_run, monkeypatch):
    """The step adds points after the crop and the voxel grid: its projections must honour both. A stand-in
    step projects every stuff point twice, once far outside the box and once beside itself."""
    import lift3d.export.pointcloud as pc
    import lift3d.export.steps.stuff as stuff_steps
    from lift3d.model.run import load_run

    def stand_in(xyz, semantic, stuff_ids, radius, threshold, **kw):
        idx = np.flatnonzero(np.isin(semantic, list(stuff_ids)))
        new = np.r_[xyz[idx] + 100.0, xyz[idx] + 1e-4]
        return (np.ones(len(xyz), bool), np.r_[idx, idx], new, np.r_[semantic[idx], semantic[idx]],
                {"corner_points": len(idx)})

    monkeypatch.setattr(stuff_steps, "complete_stuff_corners", stand_in)
    loaded = load_run(tiny_run, device="cpu")
    scene = loaded.scene()
    lo, hi = np.asarray(loaded.norm.aabb_world, np.float64)
    box = {"center": ((lo + hi) / 2).tolist(), "R": np.eye(3).tolist(), "scale": (hi - lo).tolist()}
    voxel = 0.05
    # (the tiny run's 15 steps of geometry do not meet its depth maps: the sensor's step would leave no stuff)
    pts = pc.extract_labelled_points(loaded, scene, num_points=3000, obb=box, voxel_size=voxel, view_vote=False,
                                     sensor_surface=False)
    assert pts.record("stuff-corners")["counts"]["corner_points"] > 0
    assert pc.OrientedBox.coerce(box).contains(pts.xyz).all()
    keys = np.floor(pts.xyz / voxel).astype(np.int64)
    assert len(np.unique(keys, axis=0)) == len(keys)
