"""Stuff planes fitted to triangulated points (lift3d.sfm.planes) and the depth targets they give training."""

from __future__ import annotations

import numpy as np
import pytest

from lift3d.data.scene import load_scene
from lift3d.data.stereo import SparsePoints, write_sparse_points
from lift3d.model.config import ImageDepthConfig
from lift3d.data.cameras import Cameras
from lift3d.sfm.planes import (FitSettings, NewWalls, add_walls, ceiling_boundary_points, ceiling_height,
                               ceiling_points, corner_cutters, correct_walls, fit_planes, floor_boundary_points,
                               floor_line, floor_line_walls, point_classes, sloped_ceiling)
from lift3d.synth import SynthOptions, make_scene
from lift3d.train.image_depth import flat_info, image_depth_targets

WALL, FLOOR = 1, 2
UP = np.array([0.0, 0.0, 1.0])


def _box_room(rng, n_floor=150, n_wall=12, n_slab=40):
    """Points of a 6 × 4 × 3 m box room (floor z = 0, walls x = ±3, y = ±2) with 1 cm noise, plus object
    points 0.3 m above the floor that the labels call floor (a slab), and cameras at 1.5 m looking at them."""
    floor = np.c_[rng.uniform(-2.8, 2.8, n_floor), rng.uniform(-1.8, 1.8, n_floor), np.zeros(n_floor)]
    walls = []
    for axis, value in ((0, 3.0), (0, -3.0), (1, 2.0), (1, -2.0)):
        p = np.c_[rng.uniform(-2.8, 2.8, n_wall), rng.uniform(-1.8, 1.8, n_wall), rng.uniform(0.2, 2.8, n_wall)]
        p[:, axis] = value
        walls.append(p)
    slab = np.c_[rng.uniform(-2.5, 2.5, n_slab), rng.uniform(-1.5, 1.5, n_slab), np.full(n_slab, 0.3)]
    pts = np.r_[floor, *walls, slab] + rng.normal(0, 0.01, (n_floor + 4 * n_wall + n_slab, 3))
    cls = np.r_[np.full(n_floor, FLOOR), np.full(4 * n_wall, WALL), np.full(n_slab, FLOOR)]
    cams = np.c_[rng.uniform(-1.5, 1.5, 8), rng.uniform(-1, 1, 8), np.full(8, 1.5)]
    # every camera sees every point (enough for the free-space test)
    sight = (np.repeat(cams, len(pts), 0), np.tile(pts, (len(cams), 1)))
    return pts, cls, sight


def test_box_room_gives_its_floor_and_walls_and_sight_lines_reject_a_slab_of_objects():
    pts, cls, sight = _box_room(np.random.default_rng(0))
    planes = fit_planes(pts, cls, [WALL, FLOOR], threshold=0.05, min_points=8, margin=0.3, up=UP, sightlines=sight)
    heights = [-d for n, d in zip(planes.normal, planes.offset) if abs(n @ UP) > 0.99]
    walls = [(n, d) for n, d in zip(planes.normal, planes.offset) if abs(n @ UP) < 0.01]
    assert heights and all(abs(h) < 0.03 for h in heights)  # the floor, not the slab at 0.3 m
    assert len(walls) == 4 and planes.classes[0] == frozenset({FLOOR})
    # A ray from the middle of the room looking down and along +x meets the floor at 1.5 / tan(30°) ≈ 2.6 m,
    # one looking along +x at the wall x = 3.
    o = np.array([[0.0, 0.0, 1.5], [0.0, 0.0, 1.5]])
    d = np.array([[np.cos(np.radians(30)), 0.0, -np.sin(np.radians(30))], [1.0, 0.0, 0.0]])
    t, k = planes.first_hit(o, d)
    assert t[0] == pytest.approx(3.0, abs=0.05) and t[1] == pytest.approx(3.0, abs=0.05)
    assert planes.holds(k, np.array([FLOOR, WALL])).all() and not planes.holds(k, np.array([WALL, FLOOR])).any()
    # Without the sight lines the slab of objects is a floor plane above the floor (what the test guards).
    blind = fit_planes(pts, cls, [WALL, FLOOR], threshold=0.05, min_points=8, up=UP)
    assert any(abs(-d - 0.3) < 0.03 for n, d in zip(blind.normal, blind.offset) if abs(n @ UP) > 0.99)


def test_a_sparsely_seen_wall_is_found_among_horizontal_clutter_at_its_points_heights():
    # The wall x = 3 has points at three heights only, and at each height clutter the labels call wall
    # (shelves, pictures) makes a horizontal candidate with more points than the wall. Those slabs are crossed
    # by the sight lines to the floor; the wall is not and must still be found: candidates are distinct from
    # each kept one, not from their union (which covers every point of the wall).
    rng = np.random.default_rng(3)
    floor = np.c_[rng.uniform(-2.8, 2.8, 400), rng.uniform(-1.8, 1.8, 400), np.zeros(400)]
    heights = np.repeat([0.8, 1.4, 2.0], 8)
    wall = np.c_[np.full(24, 3.0), rng.uniform(-1.8, 1.8, 24), heights]
    clutter = np.c_[rng.uniform(-2.5, 2.5, 90), rng.uniform(-1.5, 1.5, 90), np.repeat([0.8, 1.4, 2.0], 30)]
    pts = np.r_[floor, wall, clutter] + rng.normal(0, 0.005, (514, 3))
    cls = np.r_[np.full(400, FLOOR), np.full(114, WALL)]
    cams = np.c_[rng.uniform(-1.5, 1.5, 8), rng.uniform(-1, 1, 8), np.full(8, 2.5)]
    seen = np.r_[floor, wall]
    sight = (np.repeat(cams, len(seen), 0), np.tile(seen, (len(cams), 1)))
    planes = fit_planes(pts, cls, [WALL, FLOOR], threshold=0.05, min_points=8, margin=0.3, up=UP, sightlines=sight)
    found = [(n, d) for n, d in zip(planes.normal, planes.offset) if abs(n[0]) > 0.99]
    assert len(found) == 1 and abs(abs(found[0][1]) - 3.0) < 0.03
    assert not any(abs(-d - h) < 0.05 for n, d in zip(planes.normal, planes.offset) if abs(n @ UP) > 0.99
                   for h in (0.8, 1.4, 2.0))


def _labelled_box_views(size=96, f=80.0, pitch_deg=10.0, ceiling=None):
    """Four views from the middle of a 6 × 4 × 2.5 m box room (floor z = 0, walls x = ±3, y = ±2), looking
    along ±x and ±y and ``pitch_deg`` down, with exact labels (wall 1, floor 2, ceiling 3) from ray casting.
    ``ceiling = (normal, offset)``: a tilted ceiling ``normal · x + offset = 0`` instead of the level one."""
    c2ws, labels = [], {}
    pitch = np.radians(pitch_deg)
    for k, yaw in enumerate(np.radians([0, 90, 180, 270])):
        fwd = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), -np.sin(pitch)])
        right = np.cross(fwd, UP)
        right /= np.linalg.norm(right)
        cam_up = np.cross(right, fwd)
        c2w = np.eye(4)
        c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, cam_up, -fwd, [0.2, -0.1, 1.5]  # OpenGL axes
        c2ws.append(c2w)
    cams = Cameras(np.array(c2ws), fx=f, fy=f, cx=size / 2, cy=size / 2, width=size, height=size)
    r, c = np.mgrid[0:size, 0:size]
    faces = [(0, 3.0, 1), (0, -3.0, 1), (1, 2.0, 1), (1, -2.0, 1), (2, 0.0, 2)]
    faces += [(2, 2.5, 3)] if ceiling is None else []
    for k in range(4):
        o, d = cams.rays(k, c.ravel(), r.ravel())
        best, cls = np.full(len(d), np.inf), np.zeros(len(d), np.int64)
        for axis, value, label in faces:
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (value - o[:, axis]) / d[:, axis]
            hit = np.isfinite(t) & (t > 1e-6) & (t < best)
            best[hit], cls[hit] = t[hit], label
        if ceiling is not None:
            with np.errstate(divide="ignore", invalid="ignore"):
                t = -(o @ ceiling[0] + ceiling[1]) / (d @ ceiling[0])
            hit = np.isfinite(t) & (t > 1e-6) & (t < best)
            best[hit], cls[hit] = t[hit], 3
        labels[k] = cls.reshape(size, size)
    return cams, labels


def test_walls_without_texture_come_from_where_the_labels_put_them_on_the_floor():
    cams, labels = _labelled_box_views()
    xyz, cls, centres = floor_boundary_points(cams, range(4), labels, UP, 0.0, [FLOOR], [WALL], step=0.1,
                                              max_height=2.5, tolerance=0.15)
    assert (cls == WALL).all() and len(centres) == len(xyz)
    off = np.min(np.abs(np.c_[np.abs(xyz[:, 0]) - 3.0, np.abs(xyz[:, 1]) - 2.0]), axis=1)
    assert len(xyz) > 100 and np.quantile(off, 0.95) < 0.15
    assert xyz[:, 2].max() > 2.0 and xyz[:, 2].max() <= 2.5 + 1e-6  # up the wall, not into the ceiling
    # every wall is seen standing on the floor, and planes fitted to these points alone are the four walls
    floor = np.c_[np.random.default_rng(0).uniform([-2.9, -1.9], [2.9, 1.9], (3000, 2)), np.zeros(3000)]
    planes = fit_planes(np.r_[xyz, floor], np.r_[cls, np.full(3000, FLOOR)], [WALL, FLOOR], threshold=0.1,
                        min_points=8, up=UP)
    walls = sorted(round(float(abs(d)), 1) for n, d in zip(planes.normal, planes.offset) if abs(n @ UP) < 0.01)
    assert walls == [2.0, 2.0, 3.0, 3.0]
    # a boundary far away grazes the floor: a one-pixel slip moves its foot too far, so it is left out
    strict, _, _ = floor_boundary_points(cams, range(4), labels, UP, 0.0, [FLOOR], [WALL], step=0.1,
                                         max_height=2.5, tolerance=0.04)
    assert len(strict) < len(xyz)


def _corridor_views(shifts, size=96, f=80.0, start=(-3.0, -1.0), pitch_deg=10.0):
    """Views from one end of a 12 × 4 m room (floor z = 0, walls x = ±6 and y = ±2), 1.5 m up, looking along +x
    and 10° down, yawed so each sees a side wall near by and the far wall x = 6 five to nine metres away (from x
    in ``start``). Labels
    (wall 1, floor 2) by ray casting; view ``k``'s wall is then drawn ``shifts[k]`` rows too fat (negative: too
    thin) all along it, as a segmenter does to a whole image."""
    rng = np.random.default_rng(5)
    c2ws, labels = [], {}
    for _ in shifts:
        yaw, pitch = rng.uniform(-0.5, 0.5), np.radians(pitch_deg)
        fwd = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), -np.sin(pitch)])
        right = np.cross(fwd, UP)
        right /= np.linalg.norm(right)
        c2w = np.eye(4)
        c2w[:3, 0], c2w[:3, 1], c2w[:3, 2] = right, np.cross(right, fwd), -fwd
        c2w[:3, 3] = [rng.uniform(*start), rng.uniform(-1, 1), 1.5]
        c2ws.append(c2w)
    cams = Cameras(np.array(c2ws), fx=f, fy=f, cx=size / 2, cy=size / 2, width=size, height=size)
    r, c = np.mgrid[0:size, 0:size]
    for k, shift in enumerate(shifts):
        o, d = cams.rays(k, c.ravel(), r.ravel())
        best, cls = np.full(len(d), np.inf), np.zeros(len(d), np.int64)
        for axis, value, label in [(0, 6.0, WALL), (0, -6.0, WALL), (1, 2.0, WALL), (1, -2.0, WALL), (2, 0.0, FLOOR)]:
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (value - o[:, axis]) / d[:, axis]
            hit = np.isfinite(t) & (t > 1e-6) & (t < best)
            best[hit], cls[hit] = t[hit], label
        sem = cls.reshape(size, size)
        wall = sem == WALL
        for _ in range(abs(shift)):  # grow the wall down into the floor, or the floor up into the wall
            grow = np.zeros_like(wall)
            if shift > 0:
                grow[1:] = wall[:-1] & (sem[1:] == FLOOR)
            else:
                grow[:-1] = (sem[1:] == FLOOR) & wall[:-1]
            sem = np.where(grow, WALL if shift > 0 else FLOOR, sem)
            wall = sem == WALL
        labels[k] = sem
    return cams, labels


def _side_walls_and_floor():
    rng = np.random.default_rng(0)
    floor = np.c_[rng.uniform(-5.8, 5.8, 400), rng.uniform(-1.8, 1.8, 400), np.zeros(400)]
    sides = [np.c_[rng.uniform(-5.8, 5.8, 60), np.full(60, y), rng.uniform(0.2, 2.4, 60)] for y in (2.0, -2.0)]
    pts = np.r_[floor, *sides]
    cls = np.r_[np.full(400, FLOOR), np.full(120, WALL)]
    return fit_planes(pts, cls, [WALL, FLOOR], threshold=0.05, min_points=8, margin=0.3, up=UP), pts


def test_a_far_plain_wall_is_found_where_the_views_floor_lines_agree_in_pixels():
    # The far wall x = 6 is 5-9 m from every camera: one label row there moves its foot by 0.2-0.7 m, so its feet
    # do not make a plane in metres. Fitted in pixels, the views agree on it. Every view draws its wall 1 or 2
    # rows too fat; measured on the side walls (whose planes are known), that is taken out again.
    shifts = [2, 1, 2, 1, 2, 1, 2, 1]
    cams, labels = _corridor_views(shifts)
    known, _ = _side_walls_and_floor()
    line = floor_line(cams, range(len(shifts)), labels, UP, 0.0, [FLOOR], [WALL])
    walls = floor_line_walls(line, np.array([[1.0, 0, 0], [0, 1.0, 0]]), known, threshold=0.1)
    assert len(walls) == 1
    n, e, obs = walls[0]
    assert abs(n[0]) == 1.0 and -e * n[0] == pytest.approx(6.0, abs=0.1) and len(np.unique(line.frame[obs])) >= 6
    # each view's shift was measured against the side walls: without them the wall comes out far too near
    blind = floor_line_walls(line, np.array([[1.0, 0, 0]]), fit_planes(np.zeros((0, 3)), np.zeros(0, int), [WALL],
                                                                        threshold=0.1), threshold=0.1)
    far = [-e * n[0] for n, e, _ in blind if abs(n[0]) == 1.0 and -e * n[0] > 4]
    assert far and abs(far[0] - 6.0) > 0.3
    calibrated = line.calibrated(known)
    assert np.allclose(calibrated.shift[np.isin(calibrated.frame, [0, 2])], -2.0, atol=0.1)  # drawn 2 rows too fat


def test_floor_line_walls_are_added_only_where_the_views_do_not_see_through_them():
    cams, labels = _corridor_views([0] * 8)
    known, pts = _side_walls_and_floor()
    line = floor_line(cams, range(8), labels, UP, 0.0, [FLOOR], [WALL])
    walls = floor_line_walls(line, np.array([[1.0, 0, 0]]), known, threshold=0.1)
    sight = (np.repeat(cams.centers, len(pts), 0), np.tile(pts, (8, 1)))
    planes, added = add_walls(known, cams, labels, line, walls, UP, 2.5, 0.1, sight)
    assert added == 1 and len(planes) == len(known) + 1
    t, k = planes.first_hit(np.array([[0.0, 0.0, 1.2]]), np.array([[1.0, 0.0, 0.0]]))
    assert t[0] == pytest.approx(6.0, abs=0.1) and planes.holds(k, np.array([WALL]))[0]
    # The same wall 2 m nearer, where the cameras see the floor beyond it: the sight lines cross it, not added.
    n, e, obs = walls[0]
    near = [(n, e - 2.0 * np.sign(e), obs)]  # x = 4
    beyond = np.c_[np.random.default_rng(1).uniform(4.2, 5.8, 300), np.random.default_rng(2).uniform(-1.8, 1.8, 300),
                   np.zeros(300)]
    sight = (np.repeat(cams.centers, len(beyond), 0), np.tile(beyond, (8, 1)))
    assert add_walls(known, cams, labels, line, near, UP, 2.5, 0.1, sight)[1] == 0



def test_a_far_wall_whose_foot_the_views_see_at_their_top_edge_is_added_up_to_the_wall_height():
    # Views looking 38 degrees down see the far wall x = 6 only in their top rows: its vertical lines leave the
    # image a few rows above the foot. The view does not say the wall ends there; without going on past the edge
    # the wall's points lie along a line and it is not added (an L-shaped tuning room's inner wall).
    cams, labels = _corridor_views([0] * 8, pitch_deg=38.0)
    known, pts = _side_walls_and_floor()
    line = floor_line(cams, range(8), labels, UP, 0.0, [FLOOR], [WALL])
    walls = [w for w in floor_line_walls(line, np.array([[1.0, 0, 0]]), known, threshold=0.1) if abs(w[0][0]) == 1]
    assert len(walls) == 1 and -walls[0][1] * walls[0][0][0] == pytest.approx(6.0, abs=0.1)
    sight = (np.repeat(cams.centers, len(pts), 0), np.tile(pts, (8, 1)))
    assert add_walls(known, cams, labels, line, walls, UP, 2.5, 0.1, sight, NewWalls(past_edge=False))[1] == 0
    planes, added = add_walls(known, cams, labels, line, walls, UP, 2.5, 0.1, sight)
    assert added == 1
    t, k = planes.first_hit(np.array([[0.0, 0.0, 2.2]]), np.array([[1.0, 0.0, 0.0]]))  # above what any view shows
    assert t[0] == pytest.approx(6.0, abs=0.1) and planes.holds(k, np.array([WALL]))[0]


def test_a_floor_line_wall_settles_onto_the_stereo_points_behind_its_foot():
    # Labels a row off put a far wall's foot several centimetres inside the room; the stereo points on the wall
    # say where it is, and the wall moves there before the views' sight lines test it.
    cams, labels = _corridor_views([0] * 8)
    known, pts = _side_walls_and_floor()
    line = floor_line(cams, range(8), labels, UP, 0.0, [FLOOR], [WALL])
    n, e, obs = floor_line_walls(line, np.array([[1.0, 0, 0]]), known, threshold=0.1)[0]
    inside = [(n, -5.93 * n[0], obs)]  # the wall x = 5.93
    rng = np.random.default_rng(4)
    on_wall = np.c_[6.0 + rng.normal(0, 0.02, 200), rng.uniform(-1.8, 1.8, 200), rng.uniform(0.1, 2.4, 200)]
    seen = np.r_[pts, on_wall]
    sight = (np.repeat(cams.centers, len(seen), 0), np.tile(seen, (8, 1)))
    for settle, x in [(True, 6.0), (False, 5.93)]:
        planes, added = add_walls(known, cams, labels, line, inside, UP, 2.5, 0.1, sight, NewWalls(settle=settle))
        t, _ = planes.first_hit(np.array([[0.0, 0.0, 1.2]]), np.array([[1.0, 0.0, 0.0]]))
        assert added == 1 and t[0] == pytest.approx(x, abs=0.015)


def test_walls_turn_onto_the_room_directions_only_while_their_points_still_fit():
    from lift3d.sfm.planes import square_walls, wall_directions

    rng = np.random.default_rng(6)
    floor = np.c_[rng.uniform(-4, 4, 400), rng.uniform(-3, 3, 400), np.zeros(400)]
    walls = [np.c_[np.full(150, x), rng.uniform(-3, 3, 150), rng.uniform(0, 2.5, 150)] for x in (-4.0, 4.0)]
    walls.append(np.c_[rng.uniform(-4, 4, 150), np.full(150, 3.0), rng.uniform(0, 2.5, 150)])
    # a fourth wall really at 8° to the others (a bay)
    a = np.radians(8.0)
    y = rng.uniform(-4, 4, 150)
    bay = np.c_[y, -3.0 + np.tan(a) * y, rng.uniform(0, 2.5, 150)]
    pts = np.r_[floor, *walls, bay]
    planes = fit_planes(pts, np.r_[np.full(400, FLOOR), np.full(600, WALL)], [WALL, FLOOR], threshold=0.05,
                        up=UP)
    b = np.radians(2.0)
    directions = wall_directions(planes, UP)
    assert np.abs(directions @ np.array([1.0, 0, 0])).max() == pytest.approx(1.0, abs=1e-3)
    # the three square walls were fitted straight: nothing to turn; the bay is 8° off, beyond the 5° allowed
    squared, turned = square_walls(planes, directions, pts, 0.05)
    assert turned == 0
    # with the bay allowed to turn (10°), its points would not fit any more: it stays as it is
    squared, turned = square_walls(planes, directions, pts, 0.05, max_turn_deg=10.0)
    assert turned == 0 and np.allclose(squared.normal, planes.normal)
    # a square wall's plane turned 2° by stereo comes back onto its direction, through its points
    j = int(np.argmax(np.abs(planes.normal[:, 0])))
    turned_n = np.array([np.cos(b), np.sin(b), 0.0]) * np.sign(planes.normal[j, 0])
    tilted = planes._moved(j, turned_n, -float(turned_n @ planes.origin[j]))
    squared, turned = square_walls(tilted, directions, pts, 0.05)
    assert turned == 1 and abs(squared.normal[j] @ np.array([1.0, 0, 0])) == pytest.approx(1.0, abs=1e-3)
    assert np.abs(pts[np.abs(pts @ squared.normal[j] + squared.offset[j]) < 0.05] @ squared.normal[j]
                  + squared.offset[j]).max() < 0.05


def _with_far_wall(known, x: float, tilt_deg: float = 0.0):
    """``known`` and a far wall through x at y = 0, turned ``tilt_deg`` about the vertical, over y ±1.8, z 0.2–2.4."""
    rng = np.random.default_rng(3)
    a = np.radians(tilt_deg)
    n = np.array([np.cos(a), np.sin(a), 0.0])
    y, z = rng.uniform(-1.8, 1.8, 80), rng.uniform(0.2, 2.4, 80)
    pts = np.c_[x - np.tan(a) * y, y, z]
    return known.with_plane(n, -x, pts, np.full(80, WALL), threshold=0.1)


@pytest.mark.parametrize("x, tilt", [(5.8, 0.0), (6.25, 0.0), (5.8, 3.0)])
def test_a_stereo_wall_the_floor_lines_contradict_moves_to_where_they_put_it(x, tilt):
    # Stereo placed the far wall x = 6 20 cm inside the room, 25 cm outside, or 20 cm inside and turned 3°; each view,
    # 3-5 m from it, draws its wall up to 2 rows fat or thin, measured on the side walls. The floor lines move it back.
    cams, labels = _corridor_views([2, 1, -1, 0, 2, -2, 1, 0], start=(1.0, 3.0))
    known, _ = _side_walls_and_floor()
    planes = _with_far_wall(known, x, tilt)
    line = floor_line(cams, range(8), labels, UP, 0.0, [FLOOR], [WALL])
    moved, count = correct_walls(line, np.array([[1.0, 0, 0], [0, 1.0, 0]]), planes, threshold=0.1)
    assert count == 1
    k = len(planes) - 1
    assert np.allclose(moved.normal[k], [1.0, 0, 0], atol=1e-9) and -moved.offset[k] == pytest.approx(6.0, abs=0.05)
    assert np.array_equal(moved.normal[:k], planes.normal[:k]) and np.array_equal(moved.offset[:k], planes.offset[:k])
    # it keeps its extent: a ray along the room meets it at 6 m, one beyond its side (y = 2.5) does not
    t, hit = moved.first_hit(np.array([[0.0, 0.0, 1.2], [0.0, 2.5, 1.2]]), np.array([[1.0, 0, 0], [1.0, 0, 0]]))
    assert hit[0] == k and t[0] == pytest.approx(6.0, abs=0.05) and hit[1] != k


def test_a_wall_where_the_floor_lines_put_it_stays_and_one_no_other_wall_calibrates_stays_too():
    cams, labels = _corridor_views([2, 1, -1, 0, 2, -2, 1, 0], start=(1.0, 3.0))
    known, _ = _side_walls_and_floor()
    line = floor_line(cams, range(8), labels, UP, 0.0, [FLOOR], [WALL])
    dirs = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    right = _with_far_wall(known, 6.0)
    assert correct_walls(line, dirs, right, threshold=0.1)[1] == 0
    # Without the side walls no view's label shift can be measured: a boundary drawn 2 rows fat cannot be told
    # from a wall 20 cm nearer, so the wall is left where stereo put it.
    floor_only = known.subset(~known.vertical(UP))
    alone = _with_far_wall(floor_only, 5.8)
    fixed, count = correct_walls(line, dirs, alone, threshold=0.1)
    assert count == 0 and np.array_equal(fixed.offset, alone.offset)


def _box_room_walls():
    """Wall points the labels' floor line gives in the views of :func:`_labelled_box_views` (``xyz``, ``cls``)
    and 3000 floor points of that room."""
    cams, labels = _labelled_box_views()
    xyz, cls, _ = floor_boundary_points(cams, range(4), labels, UP, 0.0, [FLOOR], [WALL], step=0.1, max_height=2.5,
                                        tolerance=0.15)
    floor = np.c_[np.random.default_rng(0).uniform([-2.9, -1.9], [2.9, 1.9], (3000, 2)), np.zeros(3000)]
    return xyz, cls, floor


CEILING, WINDOW = 3, 5


def test_a_plain_ceiling_gets_its_plane_from_where_the_labels_put_it_on_the_walls():
    xyz, cls, floor = _box_room_walls()
    planes = fit_planes(np.r_[xyz, floor], np.r_[cls, np.full(3000, FLOOR)], [WALL, FLOOR, CEILING], threshold=0.1,
                        min_points=8, up=UP, margin=0.3)
    # views that look up a little see the ceiling meet the walls
    cams, labels = _labelled_box_views(pitch_deg=-15.0)
    top, count = ceiling_height(cams, range(4), labels, planes, UP, 0.0, [CEILING], threshold=0.1, min_points=8)
    assert count > 50 and top == pytest.approx(2.5, abs=0.05)
    # its pixels' rays on that plane, and with it the plane set gives them their depth
    pts, pcls, _ = ceiling_points(cams, range(4), labels, UP, -top, [CEILING], stride=4)
    assert len(pts) > 20 and (pcls == CEILING).all() and np.allclose(pts[:, 2], top)
    with_ceiling = planes.with_plane(UP, -top, pts, pcls, 0.1)
    eye, seen = np.array([[0.2, -0.1, 1.5]]), pts[len(pts) // 2]
    t, k = with_ceiling.first_hit(eye, (seen - eye) / np.linalg.norm(seen - eye))
    assert with_ceiling.holds(k, np.array([CEILING]))[0] and t[0] == pytest.approx(np.linalg.norm(seen - eye), abs=1e-6)
    # A window above a wall (its sill 1.2 m high, below the cameras' eyes) is no ceiling: no height for it.
    windows = {k: np.where((lab == CEILING), WINDOW, lab) for k, lab in labels.items()}
    for k, lab in windows.items():
        o, d = cams.rays(k, *np.mgrid[0:96, 0:96][::-1].reshape(2, -1))
        t_wall = np.min([np.where(d[:, a] != 0, (np.sign(d[:, a]) * v - o[:, a]) / d[:, a], np.inf)
                         for a, v in ((0, 3.0), (1, 2.0))], axis=0)
        z = (o[:, 2] + t_wall * d[:, 2]).reshape(96, 96)
        windows[k] = np.where((lab == WALL) & (z > 1.2) | (lab == WINDOW), WINDOW, lab)
    assert ceiling_height(cams, range(4), windows, planes, UP, 0.0, [WINDOW], threshold=0.1, min_points=8)[0] is None


def test_a_sloped_ceiling_gets_a_tilted_plane_through_the_lines_where_it_meets_the_walls():
    # An attic: the ceiling falls from 2.8 m at x = -3 to 2.2 m at x = 3 (5.7°). It meets the walls at different
    # heights, so there is no level height; all those lines lie in its plane.
    xyz, cls, floor = _box_room_walls()
    planes = fit_planes(np.r_[xyz, floor], np.r_[cls, np.full(3000, FLOOR)], [WALL, FLOOR, CEILING], threshold=0.1,
                        min_points=8, up=UP, margin=0.3)
    normal = np.array([0.1, 0.0, 1.0]) / np.linalg.norm([0.1, 0.0, 1.0])
    offset = -2.5 * normal[2]
    cams, labels = _labelled_box_views(pitch_deg=-15.0, ceiling=(normal, offset))
    top, count = ceiling_height(cams, range(4), labels, planes, UP, 0.0, [CEILING], threshold=0.1, min_points=8)
    assert top is None and count > 50
    points, eyes = ceiling_boundary_points(cams, range(4), labels, planes, UP, [CEILING])
    assert len(points) == count and len(eyes) == 4
    found = sloped_ceiling(points, cams.centers, UP, 0.1, 8)
    assert found is not None
    n, d = found
    assert np.degrees(np.arccos(np.clip(n @ normal, -1, 1))) < 1.0 and abs(d - offset) < 0.05
    # its pixels' rays meet it where the ceiling is
    pts, _, _ = ceiling_points(cams, range(4), labels, n, d, [CEILING], stride=4)
    assert len(pts) > 20 and np.abs(pts @ normal + offset).max() < 0.05
    # A level ceiling's boundaries give no tilted plane (the level height holds them), nor do the top edges of
    # one wall alone (every plane through that line fits them), nor a plane below a camera.
    level_cams, level = _labelled_box_views(pitch_deg=-15.0)
    flat, _ = ceiling_boundary_points(level_cams, range(4), level, planes, UP, [CEILING])
    assert sloped_ceiling(flat, level_cams.centers, UP, 0.1, 8) is None
    one_wall = points[np.abs(points[:, 0] - 3.0) < 0.05]
    assert len(one_wall) >= 8 and sloped_ceiling(one_wall, cams.centers, UP, 0.1, 8) is None
    assert sloped_ceiling(points, np.r_[cams.centers, [[0.0, 0.0, 2.7]]], UP, 0.1, 8) is None


def test_a_window_whose_sill_is_above_the_eyes_is_no_ceiling_because_its_wall_goes_on_above_it():
    # Windows from 1.7 to 2.2 m in every wall, cameras at 1.5 m: the sill is above the eyes, a level plane there
    # would cut the room in two. Above the sill there is the window's lintel, wall: a ceiling has none above it.
    xyz, cls, floor = _box_room_walls()
    planes = fit_planes(np.r_[xyz, floor], np.r_[cls, np.full(3000, FLOOR)], [WALL, FLOOR, CEILING, WINDOW],
                        threshold=0.1, min_points=8, up=UP, margin=0.3)
    cams, labels = _labelled_box_views(pitch_deg=-15.0)
    windowed = {}
    for k, lab in labels.items():
        o, d = cams.rays(k, *np.mgrid[0:96, 0:96][::-1].reshape(2, -1))
        t_wall = np.min([np.where(d[:, a] != 0, (np.sign(d[:, a]) * v - o[:, a]) / d[:, a], np.inf)
                         for a, v in ((0, 3.0), (1, 2.0))], axis=0)
        z = (o[:, 2] + t_wall * d[:, 2]).reshape(96, 96)
        windowed[k] = np.where((lab == WALL) & (z > 1.7) & (z < 2.2), WINDOW, lab)
    assert sum(int((lab == WINDOW).sum()) for lab in windowed.values()) > 500
    top, count = ceiling_height(cams, range(4), windowed, planes, UP, 0.0, [WINDOW], threshold=0.1, min_points=8)
    assert top is None and count == 0
    # the ceiling above the same walls keeps its height
    top, _ = ceiling_height(cams, range(4), windowed, planes, UP, 0.0, [CEILING], threshold=0.1, min_points=8)
    assert top == pytest.approx(2.5, abs=0.05)


def test_a_textured_ceiling_that_stereo_matched_in_one_spot_reaches_over_all_its_pixels():
    # Stereo found the ceiling's level plane from a 1 m patch of it (a repeating grid matches in few places);
    # the pixels the labels call ceiling elsewhere met no plane, so they got no depth target.
    from types import SimpleNamespace

    from lift3d.train.target_steps import CeilingBoundary, PlaneSettings, TargetContext, TargetState

    xyz, cls, floor = _box_room_walls()
    rng = np.random.default_rng(1)
    patch = np.c_[rng.uniform([1.0, 0.2], [2.0, 1.2], (60, 2)), np.full(60, 2.5)]
    table = np.c_[rng.uniform([-1.0, -0.5], [-0.4, 0.1], (60, 2)), np.full(60, 0.8)]  # below the eyes: no ceiling
    rooms = fit_planes(np.r_[xyz, floor], np.r_[cls, np.full(3000, FLOOR)], [WALL, FLOOR], threshold=0.1,
                       min_points=8, up=UP, margin=0.3)
    planes = rooms.with_plane(UP, -2.5, patch, np.full(60, CEILING), 0.1).with_plane(UP, -0.8, table,
                                                                                       np.full(60, RUG), 0.1)
    cams, labels = _labelled_box_views(pitch_deg=-15.0)
    labels = {k: np.where((lab == FLOOR), RUG, lab) for k, lab in labels.items()}  # never seen from above
    eye, far = np.array([[0.2, -0.1, 1.5]]), np.array([-2.5, -1.5, 2.5])  # a corner of the ceiling, 2 m off the patch
    ray = (far - eye) / np.linalg.norm(far - eye)
    assert not planes.holds(planes.first_hit(eye, ray)[1], np.array([CEILING]))[0]
    scene = SimpleNamespace(cameras=cams, stuff_ids=[WALL, FLOOR, CEILING, RUG])
    context = TargetContext(scene, np.arange(4), np.arange(4), None, labels=labels,
                            plane=PlaneSettings(threshold=0.01, stride=4))
    context.diag = 10.0
    step = CeilingBoundary()
    grown, count = step.extended(planes, UP, 0.0, TargetState(sightlines=(np.zeros((0, 3)), np.zeros((0, 3)))), context)
    assert count == 1 and len(grown) == len(planes) + 1 and grown.classes[-1] == frozenset({CEILING})
    t, k = grown.first_hit(eye, ray)
    assert grown.holds(k, np.array([CEILING]))[0] and t[0] == pytest.approx(np.linalg.norm(far - eye), abs=1e-6)
    # A level plane that the sight lines cross (to the ceiling above it) more often than they end on it stays as
    # it was: a window's sill above the eyes is no ceiling.
    through = (np.tile(eye, (200, 1)), np.c_[rng.uniform([-1.0, -0.8], [1.0, 0.6], (200, 2)), np.full(200, 2.5)])
    crossed = rooms.with_plane(UP, -2.0, patch - [0, 0, 0.5], np.full(60, CEILING), 0.1)
    assert step.extended(crossed, UP, 0.0, TargetState(sightlines=through), context)[1] == 0


def test_a_window_no_plane_holds_takes_the_depth_of_the_wall_around_it_and_sky_above_a_wall_does_not():
    from lift3d.sfm.planes import enclosed_segments

    cams, labels = _labelled_box_views()
    xyz, cls, floor = _box_room_walls()
    planes = fit_planes(np.r_[xyz, floor], np.r_[cls, np.full(3000, FLOOR)], [WALL, FLOOR, WINDOW], threshold=0.1,
                        min_points=8, up=UP, margin=0.3)
    assert not any(WINDOW in c for c in planes.classes)
    sem = labels[0].copy()  # view 0 looks along +x at the wall x = 3 (rows 0-35 are wall)
    assert (sem[5:35, 30:66] == WALL).all()
    sem[10:25, 35:60] = WINDOW  # inside the wall
    r, c, t, k = enclosed_segments(cams, 0, sem, [WINDOW], planes, stride=4)
    assert len(r) == len(np.arange(10, 25)[np.arange(10, 25) % 4 == 2]) * len(np.arange(35, 60)[np.arange(35, 60) % 4 == 2])
    hit = cams.rays(0, c, r)[0] + t[:, None] * cams.rays(0, c, r)[1]
    assert np.allclose(hit[:, 0], 3.0, atol=0.05) and (sem[r, c] == WINDOW).all()
    # half its ring hidden by a chair (a thing no plane holds): not enough of it meets the wall
    chair = sem.copy()
    chair[8:27, 33:47] = 7
    chair[10:25, 35:60] = WINDOW
    assert len(enclosed_segments(cams, 0, chair, [WINDOW], planes, stride=4)[0]) == 0
    # Sky above a building's face: the ring (the face just below) meets the face's plane, but the sky's rays meet
    # it above the face's points, out of its hull. Here the "face" is the wall with points up to 1.5 m only.
    o, d = cams.rays(0, *np.mgrid[0:96, 0:96][::-1].reshape(2, -1))
    z = (o[:, 2] + (3.0 - o[:, 0]) / d[:, 0] * d[:, 2]).reshape(96, 96)
    sky = np.where((labels[0] == CEILING) | ((labels[0] == WALL) & (z > 1.6)), WINDOW, labels[0])
    low = xyz[:, 2] < 1.5
    face = fit_planes(np.r_[xyz[low], floor], np.r_[cls[low], np.full(3000, FLOOR)], [WALL, FLOOR, WINDOW],
                      threshold=0.1, min_points=8, up=UP, margin=0.3)
    assert len(enclosed_segments(cams, 0, sky, [WINDOW], face, stride=4)[0]) == 0
    assert len(enclosed_segments(cams, 0, sky, [WINDOW], planes, stride=4)[0]) > 20  # the wall up to 2.5 m
    # In a room (margin=True) a window high on a wall whose points stop below it takes the wall's depth as far
    # as the plane's margin (0.3 m) reaches: up to 1.8 m here, not above.
    r, c, t, _ = enclosed_segments(cams, 0, sky, [WINDOW], face, stride=4, margin=True)
    hit = cams.rays(0, c, r)[0] + t[:, None] * cams.rays(0, c, r)[1]
    assert len(r) > 5 and hit[:, 2].max() <= 1.5 + 0.3 + 0.1 and np.allclose(hit[:, 0], 3.0, atol=0.05)


def test_a_window_in_a_second_wall_is_enclosed_but_pixels_with_targets_and_mostly_targeted_segments_are_not():
    # The plane that holds the window class can be another wall's: the caller then passes held classes too,
    # with the pixels that already have a target.
    from lift3d.sfm.planes import enclosed_segments

    cams, labels = _labelled_box_views()
    xyz, cls, floor = _box_room_walls()
    planes = fit_planes(np.r_[xyz, floor], np.r_[cls, np.full(3000, FLOOR)], [WALL, FLOOR, WINDOW], threshold=0.1,
                        min_points=8, up=UP, margin=0.3)
    sem = labels[0].copy()
    sem[10:25, 35:60] = WINDOW
    everything = enclosed_segments(cams, 0, sem, [WINDOW], planes, stride=4)
    none_yet = enclosed_segments(cams, 0, sem, [WINDOW], planes, stride=4, targeted=np.zeros(sem.shape, bool))
    assert len(everything[0]) > 20 and all(np.array_equal(a, b) for a, b in zip(everything, none_yet))
    # a few of its pixels met a plane holding them already: they keep that target, the rest are enclosed
    few = np.zeros(sem.shape, bool)
    few[14, 38] = few[18, 42] = True
    r, c, _, _ = enclosed_segments(cams, 0, sem, [WINDOW], planes, stride=4, targeted=few)
    assert len(r) == len(everything[0]) - 2 and not few[r, c].any()
    # most of the segment has targets (a floor segment a wall happens to surround): left alone
    most = np.zeros(sem.shape, bool)
    most[10:25, 35:55] = True
    assert len(enclosed_segments(cams, 0, sem, [WINDOW], planes, stride=4, targeted=most)[0]) == 0


def test_a_plane_reaches_only_a_margin_beyond_its_points():
    rng = np.random.default_rng(1)
    pts = np.c_[rng.uniform(0, 1, 50), rng.uniform(0, 1, 50), np.zeros(50)]
    planes = fit_planes(pts, np.full(50, FLOOR), [FLOOR], threshold=0.02, margin=0.2)
    o = np.array([[0.5, 0.5, 1.0], [1.1, 0.5, 1.0], [1.5, 0.5, 1.0]])
    t, k = planes.first_hit(o, np.tile([0.0, 0.0, -1.0], (3, 1)))
    assert k.tolist() == [0, 0, -1] and np.isinf(t[2]) and t[0] == pytest.approx(1.0, abs=0.02)


RUG = 4


def test_a_small_class_lying_on_a_plane_is_held_by_it():
    # A rug 6 mm above the floor with 10 of the floor's 300 points: far below a quarter of the plane's inliers,
    # but all of the rug's points. Without the cover rule the rug's pixels got no target.
    rng = np.random.default_rng(2)
    floor = np.c_[rng.uniform(-3, 3, 300), rng.uniform(-2, 2, 300), np.zeros(300)]
    rug = np.c_[rng.uniform(-0.5, 0.5, 10), rng.uniform(-0.5, 0.5, 10), np.full(10, 0.006)]
    pts, cls = np.r_[floor, rug], np.r_[np.full(300, FLOOR), np.full(10, RUG)]
    planes = fit_planes(pts, cls, [FLOOR, RUG], threshold=0.05, min_points=8, up=UP)
    assert len(planes) == 1 and planes.classes[0] == frozenset({FLOOR, RUG})
    assert fit_planes(pts, cls, [FLOOR, RUG], threshold=0.05, min_points=8, up=UP,
                      settings=FitSettings(min_class_cover=1.01)).classes[0] == frozenset({FLOOR})


def _l_room(rng):
    """Points of an L-shaped room: the square [-3, 3]² without its corner x < -1, y < -1 (floor z = 0, walls
    3 m high), 20 points per metre of wall, and cameras in the room at 1.5 m seeing every point."""
    outline = [(-3, 3), (3, 3), (3, -3), (-1, -3), (-1, -1), (-3, -1)]
    walls = []
    for (x0, y0), (x1, y1) in zip(outline, outline[1:] + outline[:1]):
        n = int(20 * np.hypot(x1 - x0, y1 - y0))
        s = rng.uniform(0.05, 0.95, n)
        walls.append(np.c_[x0 + s * (x1 - x0), y0 + s * (y1 - y0), rng.uniform(0.1, 2.9, n)])
    floor = np.c_[rng.uniform(-3, 3, 2000), rng.uniform(-3, 3, 2000), np.zeros(2000)]
    floor = floor[~((floor[:, 0] < -1) & (floor[:, 1] < -1))]
    pts = np.r_[np.concatenate(walls), floor]
    cls = np.r_[np.full(sum(map(len, walls)), WALL), np.full(len(floor), FLOOR)]
    cams = np.array([[1.5, 1.5, 1.5], [-2.0, 2.0, 1.5], [1.5, -2.0, 1.5], [0.0, 0.0, 1.5], [2.0, 0.0, 1.5]])
    cam, pt = np.repeat(cams, len(pts), 0), np.tile(pts, (len(cams), 1))
    # a camera sees a point when the sight line stays out of the missing corner
    s = np.linspace(0.0, 0.98, 50)[None, :, None]
    on_line = cam[:, None, :] + s * (pt - cam)[:, None, :]
    seen = ~np.any((on_line[..., 0] < -1.01) & (on_line[..., 1] < -1.01), axis=1)
    return pts, cls, (cam[seen], pt[seen])


def test_an_inner_wall_of_an_l_shaped_room_is_found_and_does_not_reach_across_the_room():
    pts, cls, sight = _l_room(np.random.default_rng(4))
    planes = fit_planes(pts, cls, [WALL, FLOOR], threshold=0.05, min_points=8, margin=1.0, up=UP, sightlines=sight)
    walls = {(int(np.argmax(np.abs(n[:2]))), round(float(-d / n[np.argmax(np.abs(n[:2]))]), 1))
             for n, d in zip(planes.normal, planes.offset) if abs(n @ UP) < 0.01}
    # the inner walls x = -1 and y = -1 too: only their points' hull counts against the sight lines, not the
    # margin by which targets may reach beyond it (that margin runs into the room, where sight lines cross it)
    assert walls == {(0, 3.0), (0, -3.0), (1, 3.0), (1, -3.0), (0, -1.0), (1, -1.0)}
    # A ray from (1, -0.5) looking along -x passes x = -1 half a metre beyond the inner wall's end, inside its
    # margin, and must go on to the wall x = -3; one looking along -x at y = -2 meets the inner wall x = -1.
    o = np.array([[1.0, -0.5, 1.5], [1.0, -2.0, 1.5]])
    t, k = planes.first_hit(o, np.tile([-1.0, 0.0, 0.0], (2, 1)))
    assert t == pytest.approx([4.0, 2.0], abs=0.05)
    # The margin still fills a corner where two walls' points stop short of it.
    t, _ = planes.first_hit(np.array([[0.0, 0.0, 1.5]]), np.array([[1.0, 1.0, 0.0]]) / np.sqrt(2))
    assert t[0] == pytest.approx(3.0 * np.sqrt(2), abs=0.1)


def test_a_plane_cutting_a_corner_through_its_walls_ends_is_dropped_and_no_wall_of_an_l_shaped_room_is():
    # Seed 1's failure: a plane through the ends of two walls that meet in a corner, and a stray cluster
    # between them the labels call wall, cut the corner off. The room's own walls, including the inner walls
    # of the L whose corner points into the room, are kept.
    rng = np.random.default_rng(4)
    pts, cls, sight = _l_room(rng)
    planes = fit_planes(pts, cls, [WALL, FLOOR], threshold=0.05, min_points=8, margin=1.0, up=UP, sightlines=sight)
    eye = np.array([1.0, 0.5, 1.5])
    assert not corner_cutters(planes, pts, cls, 0.05, UP, eye).any()
    n = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)  # x + y = 4.5: from (3, 1.5) to (1.5, 3), the corner (3, 3) behind
    # textured patches of the two walls where the plane passes them, and the stray cluster half-way
    heights = rng.uniform(0.2, 2.8, 8)
    ends = np.r_[np.c_[np.full(8, 3.0), rng.uniform(1.48, 1.52, 8), heights],
                 np.c_[rng.uniform(1.48, 1.52, 8), np.full(8, 3.0), heights]]
    stray = np.c_[rng.uniform(2.2, 2.3, 12), np.zeros(12), rng.uniform(0.3, 0.9, 12)]
    stray[:, 1] = 4.5 - stray[:, 0]
    pts, cls = np.r_[pts, ends, stray], np.r_[cls, np.full(len(ends) + len(stray), WALL)]
    cut = planes.with_plane(n, -4.5 / np.sqrt(2), np.r_[ends, stray], np.full(len(ends) + len(stray), WALL), 0.05)
    assert len(cut) == len(planes) + 1
    drop = corner_cutters(cut, pts, cls, 0.05, UP, eye)
    assert drop.tolist() == [False] * len(planes) + [True]
    # A ray into the corner meets the cutting plane; without it, the wall x = 3.
    o, d = np.array([[1.0, 1.0, 1.5]]), np.array([[1.0, 0.6, 0.0]]) / np.hypot(1.0, 0.6)
    assert cut.first_hit(o, d)[1][0] == len(planes)
    t, _ = cut.subset(~drop).first_hit(o, d)
    assert (o + t[:, None] * d)[0, 0] == pytest.approx(3.0, abs=0.06)
    # The extra points do not make any of the room's own walls a corner cutter.
    assert not corner_cutters(planes, pts, cls, 0.05, UP, eye).any()


def test_a_cut_corner_with_its_own_points_along_it_is_kept():
    # A real chamfer: a wall across the corner (3, 3) with points all along it, not only where it meets the two
    # walls. Few of its points lie near them, so it is no corner cutter.
    rng = np.random.default_rng(5)
    pts, cls, sight = _l_room(rng)
    s = rng.uniform(0.0, 1.0, 60)[:, None]
    chamfer = np.array([3.0, 1.5, 0.0]) + s * np.array([-1.5, 1.5, 0.0]) + np.c_[0 * s, 0 * s, rng.uniform(0.1, 2.9, 60)]
    pts, cls = np.r_[pts, chamfer], np.r_[cls, np.full(len(chamfer), WALL)]
    planes = fit_planes(pts, cls, [WALL, FLOOR], threshold=0.05, min_points=8, margin=1.0, up=UP)
    n = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    diagonal = np.abs(np.abs(planes.normal @ n) - 1.0) < 0.01
    assert diagonal.sum() == 1
    assert not corner_cutters(planes, pts, cls, 0.05, UP, np.array([1.0, 0.5, 1.5])).any()


def _l_room_open_wing():
    """The L-shaped room without the points of its inner wall x = -1, its planes (threshold 0.05, margin 1 m), and
    the sight lines: the room's, and views from the top of the room through the gap to the far wall y = -3 (a
    plane sweep's points on it)."""
    pts, cls, (cam, seen) = _l_room(np.random.default_rng(4))
    inner = (np.abs(pts[:, 0] + 1) < 0.02) & (pts[:, 1] < -1) & (cls == WALL)
    drop = np.isin(seen, pts[inner]).all(axis=1)
    planes = fit_planes(pts[~inner], cls[~inner], [WALL, FLOOR], threshold=0.05, min_points=8, margin=1.0, up=UP,
                        sightlines=(cam[~drop], seen[~drop]))
    xz = np.stack(np.meshgrid(np.linspace(-0.95, -0.05, 19), np.linspace(0.1, 2.9, 29)), -1).reshape(-1, 2)
    far = np.c_[xz[:, 0], np.full(len(xz), -3.0), xz[:, 1]]
    eyes = np.tile([-0.5, 2.5, 1.5], (len(far), 1))
    return planes, (np.r_[cam[~drop], eyes], np.r_[seen[~drop], far])


def test_a_margin_the_views_see_through_does_not_stop_a_ray():
    # The L-shaped room without the points of its inner wall x = -1: nothing separates the other inner wall
    # (y = -1, x from -3 to -1) from the open wing x > -1, and its 1 m margin reached across it. A ray along -y
    # at x = -0.5 passed y = -1 inside that margin and stopped there instead of at the wall y = -3.
    planes, sightlines = _l_room_open_wing()
    assert not any(abs(n[0]) > 0.99 and abs(d - 1.0) < 0.05 for n, d in zip(planes.normal, planes.offset))
    o, d = np.array([[-0.5, 2.0, 1.5], [-2.0, 2.0, 1.5]]), np.tile([0.0, -1.0, 0.0], (2, 1))
    assert planes.first_hit(o, d)[0] == pytest.approx([3.0, 3.0], abs=0.05)
    seen_through = planes.with_seen_through(*sightlines, threshold=0.05)
    # the ray past the wall's end goes on to the far wall; the one in front of the wall still meets it
    assert seen_through.first_hit(o, d)[0] == pytest.approx([5.0, 3.0], abs=0.05)
    # and the margin still fills the room's corners, where no sight line passes
    corner = np.array([[0.0, 0.0, 1.5]]), np.array([[1.0, 1.0, 0.0]]) / np.sqrt(2)
    assert seen_through.first_hit(*corner)[0][0] == pytest.approx(3.0 * np.sqrt(2), abs=0.1)


CEILING = 3


def test_a_class_a_wall_holds_for_a_few_points_does_not_reach_past_them_in_its_margin():
    # The L-shaped room without the points of its inner wall x = -1, and a few ceiling-labelled points along the
    # top of the other inner wall (y = -1, x from -3 to -1): too few to make a quarter of its inliers, but more
    # than half of the class's points (a plain ceiling has few), so the wall holds ceiling. A ceiling pixel's ray
    # that passes y = -1 in the wall's 1 m margin, where the wall has ended (a reported room: 22 % of its ceiling
    # targets were such), goes on to the ceiling; a wall pixel's ray there still ends on the margin.
    rng = np.random.default_rng(4)
    pts, cls, (cam, seen) = _l_room(rng)
    inner = (np.abs(pts[:, 0] + 1) < 0.02) & (pts[:, 1] < -1) & (cls == WALL)
    drop = np.isin(seen, pts[inner]).all(axis=1)
    edge = np.c_[rng.uniform(-2.9, -1.1, 12), np.full(12, -1.0), np.full(12, 2.98)]
    ceiling = np.c_[[2.9, -2.9, 2.9, -0.9, -0.9, 0.0, 1.0, 2.0, -2.0, 1.0], [2.9, 2.9, -2.9, -2.9, -0.9, 1.0, -2.0, 0.0, 0.0, 2.0],
                    np.full(10, 3.0)]
    pts = np.r_[pts[~inner], edge, ceiling]
    cls = np.r_[cls[~inner], np.full(12 + 10, CEILING)]
    planes = fit_planes(pts, cls, [WALL, FLOOR, CEILING], threshold=0.05, min_points=8, margin=1.0, up=UP,
                        sightlines=(cam[~drop], seen[~drop]))
    holder = [k for k, n in enumerate(planes.normal) if abs(n[1]) > 0.99 and abs(planes.offset[k] * np.sign(n[1]) - 1.0) < 0.05]
    assert len(holder) == 1 and planes.classes[holder[0]] == frozenset({WALL, CEILING})
    assert planes.margin_classes[holder[0]] == frozenset({WALL})
    # from (-0.5, 2, 1.5) along -y and up: passes y = -1 at x = -0.5 (0.5 m past the wall's end) at z = 2.85
    d = np.array([[0.0, -1.0, 0.45]]) / np.hypot(1.0, 0.45)
    o = np.array([[-0.5, 2.0, 1.5]])
    t_wall, k_wall = planes.first_hit(o, d, classes=np.array([WALL]))
    assert k_wall[0] == holder[0] and t_wall[0] == pytest.approx(3.0 * np.hypot(1.0, 0.45), abs=0.05)
    t_ceiling, k_ceiling = planes.first_hit(o, d, classes=np.array([CEILING]))
    assert CEILING in planes.classes[k_ceiling[0]] and (o + t_ceiling[:, None] * d)[0, 2] == pytest.approx(3.0, abs=0.05)
    # without the pixels' classes the margin stops every ray, as before
    assert planes.first_hit(o, d)[1][0] == holder[0]


def test_point_class_is_the_majority_of_its_observations_when_they_agree():
    obs_point = np.array([0, 0, 0, 1, 1, 2, 2, 2, 2])
    obs_class = np.array([1, 1, 2, 3, 4, 0, 5, 5, 5])
    assert point_classes(obs_point, obs_class, 4).tolist() == [1, 0, 5, 0]


@pytest.fixture(scope="module")
def floor_room(tmp_path_factory):
    """A small synthetic room without depth maps whose sparse points are lifted from its exact depth at pixels
    its ground truth calls floor or wall (each seen in two frames, labelled by the pseudo-labels there)."""
    root = tmp_path_factory.mktemp("scenes") / "room"
    make_scene(root,
               SynthOptions(kind="indoor", seed=102, noise="moderate", n_views=10, width=48, height=48, depth="none"),
               progress=False)
    scene = load_scene(root)
    rng = np.random.default_rng(0)
    xyz, obs_f, obs_p, obs_uv, obs_z = [], [], [], [], []
    frames = [int(i) for i in scene.split("train")]
    for i in frames:
        z, sem = scene.gt_depth(i), scene.gt_labels(i).semantic
        r, c = np.nonzero(np.isin(sem, scene.stuff_ids) & (z > 0))
        for k in rng.choice(len(r), min(30, len(r)), replace=False):
            x, y = scene.cameras.normalized_coords(i, np.array([c[k]]), np.array([r[k]]))
            c2w = scene.cameras.c2w_opencv[i]
            p = c2w[:3, :3] @ (np.array([x[0], y[0], 1.0]) * z[r[k], c[k]]) + c2w[:3, 3]
            for j in (i, frames[(frames.index(i) + 1) % len(frames)]):
                uv, zz = scene.cameras.project(j, p[None])
                if zz[0] > 0 and (uv[0] >= 0).all() and (uv[0] < 48).all():
                    obs_f.append(j), obs_p.append(len(xyz)), obs_uv.append(uv[0]), obs_z.append(zz[0])
            xyz.append(p)
    n, m = len(xyz), len(obs_f)
    sparse = SparsePoints(xyz=np.array(xyz), rgb=np.zeros((n, 3), np.uint8), error=np.full(n, 0.2, np.float32),
                          track_length=np.bincount(obs_p, minlength=n).astype(np.int32), frame_names=[f.name for f in scene.frames],
                          obs_frame=np.array(obs_f, np.int32), obs_point=np.array(obs_p, np.int32),
                          obs_uv=np.array(obs_uv, np.float32), obs_depth=np.array(obs_z, np.float32),
                          obs_sigma=np.full(m, 0.02, np.float32), info={"source": "test"})
    write_sparse_points(root, sparse)
    return root


def test_plane_targets_give_stuff_pixels_their_depth_and_are_recorded(floor_room):
    scene = load_scene(floor_room)
    frames = scene.split("train")
    targets = image_depth_targets(scene, frames, ImageDepthConfig(source="planes", plane_stride=2))
    flat = flat_info(targets.info)
    info = flat["planes"]
    assert targets.info["source"] == "planes" and info["planes"] >= 2 and info["targets"] > 0
    dense = targets.dense  # plane targets, then the plane sweep's depths on thing-labelled pixels
    on_things = flat["dense_on_things"]
    assert on_things > 0 and dense.sum() == info["targets"] + on_things
    assert (~dense).sum() == flat["observations"]
    plane = np.zeros_like(dense)
    plane[np.flatnonzero(dense)[:info["targets"]]] = True
    err, floor = [], []
    for f in np.unique(targets.frame[plane]):
        m = plane & (targets.frame == f)
        r, c = targets.v[m].astype(int), targets.u[m].astype(int)
        err.append(np.abs(targets.z[m] - scene.gt_depth(int(f))[r, c]))
        floor.append(scene.gt_labels(int(f)).semantic[r, c] == FLOOR)
    err, floor = np.concatenate(err), np.concatenate(floor)
    diag = np.linalg.norm(np.diff(scene.scene_box.aabb, axis=0))
    # Exact points: a pixel's target is off only where the 2D labels are wrong (the labels are noisy).
    assert floor.sum() > 100 and np.mean(err[floor] < 0.01 * diag) > 0.9
    assert np.mean(err < 0.01 * diag) > 0.9
    # The training summary says what the planes gave.
    from lift3d.train.trainer import image_depth_lines

    line = image_depth_lines(targets.info)[0]
    assert f"{info['planes']} stuff planes giving {info['targets']} targets" in line
    assert f"{on_things} plane-sweep depths on objects" in line
    one = flat["dense_on_things_one_source"]
    assert 0 <= one < on_things and (f"({one} confirmed by one source view)" in line) == (one > 0)
    # Sparse and plane sources differ only by the plane targets (and the sweep's depths on things).
    sparse = image_depth_targets(scene, frames, ImageDepthConfig(source="sparse"))
    assert len(sparse) == (~dense).sum()
    planes_only = image_depth_targets(scene, frames, ImageDepthConfig(source="planes", plane_stride=2,
                                                                      plane_dense_things=False))
    assert "dense_on_things" not in flat_info(planes_only.info) and planes_only.dense.sum() == info["targets"]


def test_a_thing_one_view_labels_wall_gets_no_wall_depth_when_the_other_views_see_it(floor_room, monkeypatch):
    # One view's segmenter calls every object wall: without the other views' vote those pixels get the depth
    # of the wall behind the object; the views that look at that spot of the wall see the object in front.
    from dataclasses import replace

    scene = load_scene(floor_room)
    frames = scene.split("train")
    things = list(scene.thing_ids)
    per_frame = {int(i): np.isin(scene.gt_labels(int(i)).semantic, things).sum() for i in frames}
    wrong = max(per_frame, key=per_frame.get)
    original = scene.pseudo_labels

    def labels(i):
        lab = original(i)
        if int(i) != wrong:
            return lab
        thing = np.isin(scene.gt_labels(int(i)).semantic, things)
        return replace(lab, semantic=np.where(thing, WALL, lab.semantic).astype(lab.semantic.dtype))

    monkeypatch.setattr(scene, "pseudo_labels", labels)

    def on_things(share):
        t = image_depth_targets(scene, frames, ImageDepthConfig(source="planes", plane_stride=1,
                                                                plane_label_support=share))
        m = t.dense & (t.frame == wrong)
        gt = scene.gt_labels(wrong).semantic[t.v[m].astype(int), t.u[m].astype(int)]
        return int(np.isin(gt, things).sum()), int((~np.isin(gt, things)).sum()), flat_info(t.info)

    thing_off, stuff_off, info_off = on_things(0.0)
    thing_on, stuff_on, info_on = on_things(0.5)
    refuted = info_on["planes"]["refuted_by_other_views"]
    assert "refuted_by_other_views" not in info_off["planes"] and refuted > 0
    from lift3d.train.trainer import image_depth_lines

    assert f"({refuted} refuted by other views' labels)" in image_depth_lines(info_on)[0]
    assert thing_off >= 20 and thing_on <= 0.5 * thing_off
    # the wall and floor around the objects keep most of their targets
    assert stuff_on >= 0.8 * stuff_off


def _steps(targets) -> dict:
    """The step records of ``targets.info`` by name."""
    return {r["name"]: r for r in targets.info["steps"]}


def test_the_ceiling_step_runs_with_or_without_the_floor_line(floor_room):
    # The ceiling plane needs walls, not the floor-line points: turning the floor line off must not turn the
    # ceiling step off with it (it used to run only inside the floor-line step).
    scene = load_scene(floor_room)
    frames = scene.split("train")

    def steps(**flags):
        return _steps(image_depth_targets(scene, frames, ImageDepthConfig(source="planes", plane_stride=2, **flags)))

    for floor_line in (True, False):
        ran = steps(plane_floor_boundary=floor_line)
        assert ran["floor-boundary"]["ran"] == floor_line
        assert ran["floor-boundary"].get("counts", {}).get("floor_boundary_points", 0) > 0 or not floor_line
        assert "ceiling_boundary_points" in ran["ceiling-boundary"]["counts"]
    off = steps(plane_ceiling_boundary=False)
    assert off["ceiling-boundary"] == {"name": "ceiling-boundary", "ran": False, "why": "off"}
    # the far-wall step is recorded, and its switch turns it off
    assert {"floor_line_walls", "floor_line_observations"} <= set(off["floor-line-walls"]["counts"])
    no_far = steps(plane_floor_line_walls=False)
    assert not no_far["floor-line-walls"]["ran"]
    # so are the textured-ceiling, enclosed-segment and standing-thing steps, each with its switch
    assert "ceiling_extended" in no_far["ceiling-boundary"]["counts"]
    assert "enclosed" in no_far["enclosed-segments"]["counts"]
    assert {"standing_faces", "standing_faces_refuted"} <= set(no_far["standing-things"]["counts"])
    neither = steps(plane_ceiling_extend=False, plane_enclosed=False, plane_standing=False)
    assert "ceiling_extended" not in neither["ceiling-boundary"]["counts"]
    assert not neither["enclosed-segments"]["ran"] and not neither["standing-things"]["ran"]
    # squaring the walls is recorded (the scene's walls are square already) and has a switch
    assert "walls_squared" in neither["square-walls"]["counts"]
    unsquared = steps(plane_square_walls=False)
    assert not unsquared["square-walls"]["ran"]
    # so is the walls' reach past their margin (a bounded room)
    assert "wall_reach" in unsquared["wall-reach"]["counts"]
    assert not steps(plane_wall_reach=False)["wall-reach"]["ran"]


def test_rules_the_scene_does_not_show_the_premises_of_are_skipped_and_say_so(floor_room):
    # An open scene (no premises): the plane fit and the pixel targets run, the room's rules do not. Its
    # targets are those of the room with every room rule switched off.
    scene = load_scene(floor_room)
    frames = scene.split("train")
    cfg = ImageDepthConfig(source="planes", plane_stride=2)
    open_ = image_depth_targets(scene, frames, cfg, premises=[])
    ran = _steps(open_)
    assert open_.info["premises"] == []
    assert ran["fit-planes"]["ran"] and ran["plane-hits"]["ran"] and ran["enclosed-segments"]["ran"]
    for name, missing in [("floor-boundary", "room"), ("corner-cutters", "manhattan, room"),
                          ("floor-line-walls", "manhattan, room"), ("square-walls", "manhattan, room"),
                          ("ceiling-boundary", "room"), ("wall-reach", "box, room"), ("standing-things", "room")]:
        assert ran[name] == {"name": name, "ran": False, "why": f"premise not shown: {missing}"}
    switched_off = image_depth_targets(scene, frames, ImageDepthConfig(
        source="planes", plane_stride=2, plane_floor_boundary=False, plane_corner_cutters=False,
        plane_floor_line_walls=False, plane_square_walls=False, plane_ceiling_boundary=False, plane_wall_reach=False,
        plane_standing=False, plane_enclosed_margin=False))
    assert all(np.array_equal(getattr(open_, k), getattr(switched_off, k)) for k in ("frame", "u", "v", "z", "sigma"))
    # without premises the source auto resolves as before: planes in a bounded scene
    assert image_depth_targets(scene, frames, ImageDepthConfig(plane_stride=2), premises=[]).info["source"] == "planes"


def test_label_boundary_finds_where_rows_of_one_class_sit_on_another():
    from lift3d.sfm.planes import label_boundary

    sem = np.array([[3, 3, 3], [3, 3, 1], [1, 3, 1], [1, 1, 1], [1, 1, 1]])
    # column 0: ceiling rows 0-1 on wall rows 2-3; column 1: rows 1-2 on 3-4; column 2 has one ceiling row only
    r, c = label_boundary(sem, [3], [1], min_rows=2, same="lower")
    assert sorted(zip(r.tolist(), c.tolist())) == [(1, 0), (2, 1)]
    with pytest.raises(ValueError, match="same must be"):
        label_boundary(sem, [3], [1], same="left")


def test_a_wall_reaches_along_its_line_past_a_wall_elsewhere_but_not_past_one_across_it_or_over_seen_floor():
    from lift3d.sfm.planes import wall_reach

    rng = np.random.default_rng(3)
    # The long left wall x = -3 has points on y in [-4, -1.6] only (the rest two views see end-on); a short wall
    # y = -1.3 stands on the right, x in [0.3, 3] (the inner wall of an L-shaped room).
    left = np.c_[np.full(60, -3.0), rng.uniform(-4, -1.6, 60), rng.uniform(0, 2.5, 60)]
    short = np.c_[rng.uniform(0.3, 3, 60), np.full(60, -1.3), rng.uniform(0, 2.5, 60)]
    planes = fit_planes(np.r_[left, short], np.full(120, WALL), [WALL], threshold=0.05, margin=0.5, up=UP)
    none = (np.zeros((0, 3)), np.zeros((0, 3)))
    box = np.array([[-3.1, -4.4, -0.1], [3.1, 4.4, 2.9]])
    eye = np.array([-1.0, -2.0, 1.5])
    spot = np.array([-3.0, 2.0, 1.2])
    d = ((spot - eye) / np.linalg.norm(spot - eye))[None]
    # the view sees the room's floor past the short wall's line: the short wall does not reach across
    g = np.mgrid[-2.9:2.91:0.1, -1.2:4.3:0.1].reshape(2, -1).T
    seen = np.c_[g, np.zeros(len(g))]
    room = (np.tile(eye, (len(seen), 1)), seen)
    # the planes alone: 3 m past the points, the margin is 0.5 m, and the short wall's plane (taken as
    # unbounded) separates the spot from the left wall's points
    assert planes.first_hit(eye[None], d)[1][0] == -1
    without_floor = wall_reach(planes, none, none, UP, 0.05, box).first_hit(eye[None], d)[1][0]
    assert abs(planes.normal[without_floor][1]) > 0.99  # the short wall's line, 1.7 m past its points
    t, k = wall_reach(planes, none, room, UP, 0.05, box).first_hit(eye[None], d)
    assert k[0] >= 0 and np.allclose(eye + t[0] * d[0], spot, atol=1e-6)
    assert abs(planes.offset[k[0]] * planes.normal[k[0]][0] - 3.0) < 0.05  # x = -3
    # a wall across the room at y = -1.3 (points over its whole width) does stop it
    across = np.c_[rng.uniform(-3, 3, 80), np.full(80, -1.3), rng.uniform(0, 2.5, 80)]
    walled = fit_planes(np.r_[left, across], np.full(140, WALL), [WALL], threshold=0.05, margin=0.5, up=UP)
    assert wall_reach(walled, none, room, UP, 0.05, box).first_hit(eye[None], d)[1][0] == -1

    def also(cam, point):
        return np.r_[room[0], [cam]], np.r_[room[1], [point]]

    # floor seen behind the wall's line at that place along it: the wall is not there (an opening)
    floor = also([-1.0, 2.0, 1.5], [-5.0, 2.0, 0.0])
    assert wall_reach(planes, none, floor, UP, 0.05, box).first_hit(eye[None], d)[1][0] == -1
    # ...but floor seen behind it 1 m further along does not stop it here
    elsewhere = also([-1.0, 3.0, 1.5], [-5.0, 3.0, 0.0])
    assert wall_reach(planes, none, elsewhere, UP, 0.05, box).first_hit(eye[None], d)[1][0] == k[0]
    # a sight line through the spot (a point seen beyond it), or the spot outside the box: no reach
    through = (eye[None], (eye + 1.5 * (spot - eye))[None])
    assert wall_reach(planes, through, room, UP, 0.05, box).first_hit(eye[None], d)[1][0] == -1
    assert wall_reach(planes, none, room, UP, 0.05, box - [[0, 0, 0], [0, 3, 0]]).first_hit(eye[None], d)[1][0] == -1


def test_a_wall_does_not_move_where_the_views_see_through_it():
    # The floor lines put the far wall at x = 6, and stereo at 6.25. When the views see points at 6.25 (the wall's
    # texture, through where the move would put it), the labels' boundary is what is off, and the wall stays.
    cams, labels = _corridor_views([2, 1, -1, 0, 2, -2, 1, 0], start=(1.0, 3.0))
    known, _ = _side_walls_and_floor()
    planes = _with_far_wall(known, 6.25)
    line = floor_line(cams, range(8), labels, UP, 0.0, [FLOOR], [WALL])
    dirs = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    rng = np.random.default_rng(5)
    eyes = cams.centers[rng.integers(0, 8, 200)]
    on = np.c_[np.zeros(200), rng.uniform(-1.5, 1.5, 200), rng.uniform(0.3, 2.2, 200)]
    k = len(planes) - 1
    stay, _ = correct_walls(line, dirs, planes, threshold=0.1, sightlines=(eyes, on + [6.25, 0, 0]))
    assert stay.offset[k] == planes.offset[k] and np.array_equal(stay.normal[k], planes.normal[k])
    # points at 6.0 (where the floor lines put it) agree with the move, and so does having no sight lines at all
    for sightlines in ((eyes, on + [6.0, 0, 0]), None):
        moved, _ = correct_walls(line, dirs, planes, threshold=0.1, sightlines=sightlines)
        assert -moved.offset[k] == pytest.approx(6.0, abs=0.05)
