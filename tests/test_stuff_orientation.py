"""Stuff labels that follow the surface's orientation (lift3d.export.stuff) on a synthetic room."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lift3d.export.stuff import orient_stuff_labels, surface_axes

WALL, FLOOR, CEILING, RUG, CHAIR = 1, 2, 3, 4, 7
STUFF = [WALL, FLOOR, CEILING, RUG]


def _plane(origin, u, v, nu, nv):
    a, b = np.meshgrid(np.linspace(0, 1, nu), np.linspace(0, 1, nv))
    return np.asarray(origin) + a.reshape(-1, 1) * np.asarray(u) + b.reshape(-1, 1) * np.asarray(v)


def _room(rng):
    """A 4 x 3 x 2.5 room sampled every ~3 cm, with labels as the field would bleed them.

    Returns points, the true labels and the field's labels: a 20 cm band of the ceiling along the x = 0 wall
    called wall, a band of the x = 4 wall's foot called floor, a rug on the floor, a chair (a thing) whose
    side faces like a wall.
    """
    parts, truth = [], []
    step = 0.03

    def add(points, label):
        parts.append(points + rng.normal(0, 0.002, points.shape))
        truth.append(np.full(len(points), label))

    add(_plane([0, 0, 0], [4, 0, 0], [0, 3, 0], int(4 / step), int(3 / step)), FLOOR)
    add(_plane([0, 0, 2.5], [4, 0, 0], [0, 3, 0], int(4 / step), int(3 / step)), CEILING)
    for origin, u in (([0, 0, 0], [0, 3, 0]), ([4, 0, 0], [0, 3, 0]), ([0, 0, 0], [4, 0, 0]), ([0, 3, 0], [4, 0, 0])):
        add(_plane(origin, u, [0, 0, 2.5], int(np.linalg.norm(u) / step), int(2.5 / step)), WALL)
    xyz, true = np.concatenate(parts), np.concatenate(truth)
    field = true.copy()
    field[(true == CEILING) & (xyz[:, 0] < 0.2)] = WALL  # the wall bleeds onto the ceiling
    field[(true == WALL) & (xyz[:, 0] > 3.99) & (xyz[:, 2] < 0.12)] = FLOOR  # the floor bleeds up a wall
    rug = (true == FLOOR) & (np.abs(xyz[:, 0] - 2) < 0.6) & (np.abs(xyz[:, 1] - 1.5) < 0.4)
    true[rug] = field[rug] = RUG
    chair = _plane([1, 1, 0.45], [0.4, 0, 0], [0, 0, 0.4], 14, 14)  # its back: a vertical face, a thing
    xyz = np.concatenate([xyz, chair])
    true = np.concatenate([true, np.full(len(chair), CHAIR)])
    field = np.concatenate([field, np.full(len(chair), CHAIR)])
    return xyz, true, field


@pytest.fixture(scope="module")
def room():
    return _room(np.random.default_rng(0))


def test_surface_axes_are_the_normals_of_planar_patches():
    xyz = _plane([0, 0, 0], [1, 0, 0], [0, 1, 0], 30, 30)
    axes, curvature = surface_axes(xyz)
    assert np.allclose(np.abs(axes[:, 2]), 1.0, atol=1e-6) and curvature.max() < 1e-6


def test_the_band_of_wall_on_the_ceiling_becomes_ceiling(room):
    xyz, true, field = room
    new, stats = orient_stuff_labels(xyz, field, STUFF, radius=0.25)
    band = (true == CEILING) & (field == WALL)
    # All but the row along the edge itself, whose neighbourhood bends onto the wall.
    assert band.sum() > 300 and (new[band] == CEILING).mean() > 0.6
    assert stats["moves"].get(f"{WALL}->{CEILING}", 0) == int((new[band] == CEILING).sum())
    # Nothing that was right is made wrong.
    assert not ((field == true) & (new != true)).any()


def test_walls_facing_several_ways_take_no_points(room):
    """A strip of wall called floor faces sideways; walls face two ways, so no single axis holds most of them
    and the strip keeps the field's label rather than be guessed."""
    xyz, true, field = room
    new, _ = orient_stuff_labels(xyz, field, STUFF, radius=0.25)
    foot = (true == WALL) & (field == FLOOR)
    assert foot.sum() > 100 and (new[foot] == FLOOR).all()


def test_classes_that_face_alike_and_things_never_move(room):
    xyz, true, field = room
    new, _ = orient_stuff_labels(xyz, field, STUFF, radius=0.25)
    assert np.array_equal(new == RUG, field == RUG)  # a rug faces like the floor: never exchanged
    assert (new[field == CHAIR] == CHAIR).all() and not (new[field != CHAIR] == CHAIR).any()


def test_a_subsample_gives_nearly_the_same_answer(room):
    """Measured on half the points, the rest following their nearest measured point: the band is fixed as
    well, and the few points that follow a neighbour across the edge stay a small fraction of the fix."""
    xyz, true, field = room
    full, _ = orient_stuff_labels(xyz, field, STUFF, radius=0.25)
    sub, _ = orient_stuff_labels(xyz, field, STUFF, radius=0.25, max_points=len(xyz) // 2)
    band = (true == CEILING) & (field == WALL)
    fixed = int((sub[band] == CEILING).sum())
    assert fixed > 0.6 * band.sum() and (sub != full).mean() < 0.01
    assert ((field == true) & (sub != true)).sum() < 0.05 * fixed


def test_nothing_to_do_with_one_stuff_class():
    xyz = _plane([0, 0, 0], [1, 0, 0], [0, 1, 0], 20, 20)
    sem = np.ones(len(xyz), int)
    new, stats = orient_stuff_labels(xyz, sem, [1, 2], radius=0.1)
    assert np.array_equal(new, sem) and stats["moved"] == 0 and new is not sem


def test_export_records_the_step_for_points_and_mesh_and_can_skip_it(tiny_run, tmp_path):
    from lift3d.cli.main import main

    for flag, out in (([], tmp_path / "on"), (["--no-orient-stuff"], tmp_path / "off")):
        assert main(["export", "--run", str(tiny_run), "--pointcloud", "--mesh", "--resolution", "32",
                     "--num-points", "4000", "--output-dir", str(out), "--quiet", *flag]) == 0
    on = json.loads((tmp_path / "on" / "metadata.json").read_text())
    off = json.loads((tmp_path / "off" / "metadata.json").read_text())
    step = next(r for r in on["steps"]["points"] if r["name"] == "stuff-orientation")
    assert step["ran"] and {"moved", "moves", "radius", "cone_degrees"} <= set(step["counts"])
    mesh_step = on["thresholds"]["mesh"]["stuff_orientation"]
    # The mesh labels its edges over the point cloud's distance, whatever its own resolution.
    assert mesh_step["radius"] == pytest.approx(step["counts"]["radius"], rel=1e-6)
    assert next(r for r in off["steps"]["points"] if r["name"] == "stuff-orientation")["why"] == "off"
    assert "stuff_orientation" not in off["thresholds"]["mesh"]
