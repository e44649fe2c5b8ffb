"""``lift3d synth --room-shape`` and ``--clutter``: rooms that are not boxes, cluttered rooms, ``gt/objects.json``,
and the scenes of the defaults left as they were."""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from lift3d.data.scene import load_scene
from lift3d.errors import InputError
from lift3d.synth import SynthOptions, make_scene
from lift3d.synth.cameras import MIN_CLEARANCE, camera_path
from lift3d.synth.catalogue import INDOOR_CATEGORIES
from lift3d.synth.geometry import RayCaster
from lift3d.synth.indoor import build_indoor
from lift3d.synth.make import THIN_PART, build_content
from lift3d.synth.polygons import (
    convex_gap,
    convex_hull,
    distance_to_outline,
    distance_to_segments,
    inside_polygon,
    interior_angles,
    yawed_box,
)

#: (shape, seed) giving each shape and variant: round 0 is a cylinder, round 1 has a curved wall, open 0 opens
#: onto a dark space, open 2 is two rooms through a doorway.
SHAPE_SEEDS = [("polygon", 2), ("hexagon", 1), ("sloped", 0), ("vaulted", 0), ("round", 0), ("round", 1),
               ("open", 0), ("open", 2)]
NEW_SHAPES = ["polygon", "hexagon", "sloped", "vaulted", "round", "open"]
TOL = 0.02  # metres: GT points on the described surfaces (curved walls and vaults are meshed to a few mm)


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _meta(root: Path) -> dict:
    return json.loads((root / "transforms.json").read_text())["lift3d_synth"]


def ceiling_from_description(ceiling: dict):
    """The ceiling height above floor points, from ``lift3d_synth.scene.room.ceiling`` alone."""
    kind = ceiling["type"]
    if kind == "flat":
        return lambda xy: np.full(len(xy), ceiling["height_m"])
    if kind == "plane":
        a, b, c = ceiling["z_equals_ax_by_c"]
        return lambda xy: a * xy[:, 0] + b * xy[:, 1] + c
    if kind == "barrel_vault":
        r, crown = ceiling["radius_m"], ceiling["crown_m"]
        return lambda xy: crown - r + np.sqrt(np.maximum(r**2 - (xy @ np.array(ceiling["across"]) -
                                                                  ceiling["crown_at"]) ** 2, 0.0))
    assert kind == "flat_regions"

    def regions(xy):
        out = np.full(len(xy), np.nan)
        for reg in ceiling["regions"]:
            out[np.isnan(out) & inside_polygon(xy, np.array(reg["outline"]))] = reg["height_m"]
        return out
    return regions


def wall_distance(xy: np.ndarray, z: np.ndarray, room: dict) -> np.ndarray:
    """Distance of wall points to the walls the description names: the outline's edges (a curved wall as its
    circle) and the inner walls' boxes."""
    outline = np.array(room["outline"])
    curved = set(room.get("curved_walls", []))
    straight = [k for k in range(len(outline)) if k not in curved]
    d = np.full(len(xy), np.inf)
    if straight:
        a = outline[straight]
        b = np.roll(outline, -1, axis=0)[straight]
        d = distance_to_segments(xy, a, b)
    if curved:
        d = np.minimum(d, np.abs(np.linalg.norm(xy - np.array(room["centre"]), axis=1) - room["radius_m"]))
    for wall in room.get("inner_walls", []):
        lo, hi = (np.array(v) for v in wall["box"])
        inside = np.all((xy >= lo[:2] - TOL) & (xy <= hi[:2] + TOL), axis=1) & (z >= lo[2] - TOL) & (z <= hi[2] + TOL)
        d[inside] = 0.0
    return d


# --------------------------------------------------------------------------------------------- scenes
@pytest.fixture(scope="module")
def shape_scenes(tmp_path_factory) -> dict[tuple[str, int], Path]:
    root = tmp_path_factory.mktemp("shapes")
    out = {}
    for shape, seed in SHAPE_SEEDS:
        out[(shape, seed)] = root / f"{shape}{seed}"
        make_scene(out[(shape, seed)], SynthOptions(seed=seed, room_shape=shape, n_views=8, width=40, height=32),
                   progress=False)
    return out


@pytest.mark.parametrize("shape,seed", SHAPE_SEEDS)
def test_each_shape_makes_a_valid_scene_on_its_described_surfaces(shape, seed, shape_scenes):
    root = shape_scenes[(shape, seed)]
    scene = load_scene(root)
    scene.validate()
    meta = _meta(root)
    room = meta["scene"]["room"]
    assert meta["room_shape"] == shape and room["shape"] == shape
    if shape in ("round", "open"):
        assert room["variant"] == {("round", 0): "cylinder", ("round", 1): "curved_wall", ("open", 0): "dark_space",
                                   ("open", 2): "doorway"}[(shape, seed)]
    ceiling = ceiling_from_description(room["ceiling"])
    outline = np.array(room["outline"])
    # The scene box is the room's axis-aligned bounding box, what a user who knows the room's extent gives.
    top = max(room["size_m"][2], 0.0)
    lo, hi = scene.scene_box.aabb
    np.testing.assert_allclose(lo, [*outline.min(0), 0.0], atol=0.011)
    np.testing.assert_allclose(hi, [*outline.max(0), top], atol=0.011)
    # GT points lie on the surfaces the description names.
    pts = scene.gt_points()
    xyz, sem = pts["xyz"].astype(np.float64), pts["semantic"]
    assert np.all(inside_polygon(xyz[:, :2], outline) | (distance_to_outline(xyz[:, :2], outline) < TOL))
    floor, ceil, wall = xyz[sem == 2], xyz[sem == 3], xyz[sem == 1]
    assert len(floor) and len(wall) and (len(ceil) or shape not in ("sloped", "vaulted"))
    assert np.abs(floor[:, 2]).max() < 1e-3
    if len(ceil):
        assert np.abs(ceil[:, 2] - ceiling(ceil[:, :2])).max() < TOL, "the ceiling is where the description puts it"
    assert wall_distance(wall[:, :2], wall[:, 2], room).max() < TOL, "the walls are where the description puts them"
    if room["ceiling"]["type"] != "flat_regions":  # (a wall between two ceiling heights has both)
        assert np.all(wall[:, 2] <= ceiling(wall[:, :2]) + TOL)
    # Cameras (true poses) inside the room, at least 0.5 m from its walls, floor and ceiling.
    content, _ = build_content("indoor", seed, shape)
    assert content.description == meta["scene"], "build_content gives the scene make_scene wrote"
    centres = np.array([f.gt_c2w[:3, 3] for f in scene.frames])
    assert np.all(inside_polygon(centres[:, :2], content.room.camera_region))
    assert np.all((centres[:, 2] > 0.5) & (centres[:, 2] < ceiling(centres[:, :2]) - 0.45))
    stuff = RayCaster(replace(content, objects=[o for o in content.objects if o.segment_id < 1000]))
    assert stuff.distance(centres).min() >= content.room.clearance - 1e-3
    assert RayCaster(content).distance(centres).min() >= MIN_CLEARANCE - 1e-3


@pytest.mark.parametrize("shape", NEW_SHAPES)
def test_shape_geometry_things_and_cameras(shape):
    for seed in (3, 4):
        content = build_indoor(np.random.default_rng(seed), room_shape=shape)
        room = content.description["room"]
        outline = np.array(room["outline"])
        edges = np.roll(outline, -1, axis=0) - outline
        off_axis = np.degrees(np.arctan2(edges[:, 1], edges[:, 0])) % 90.0
        angles = interior_angles(outline)
        if shape == "polygon":
            assert 5 <= len(outline) <= 8 and (angles > 180).sum() <= 1
            assert np.all(np.abs(angles - 90) >= 8), "no right angles"
            assert np.all((off_axis >= 6) & (off_axis <= 84)), "no wall along an axis"
        if shape == "hexagon":
            assert len(outline) == 6 and np.allclose(angles, 120.0, atol=0.05)
            assert np.ptp(np.linalg.norm(edges, axis=1)) < 1e-3
            assert np.all((off_axis >= 6) & (off_axis <= 84))
        if shape == "sloped":
            c = room["ceiling"]
            assert c["type"] == "plane" and c["high_m"] - c["low_m"] >= 0.6 and c["low_m"] >= 2.2
        if shape == "vaulted":
            c = room["ceiling"]
            assert c["type"] == "barrel_vault" and c["crown_m"] > c["springline_m"] >= 2.4
        ceiling = ceiling_from_description(room["ceiling"])
        # Things inside the room and under its ceiling; floor footprints apart; small things on their support.
        things = content.things
        assert len(things) >= 6
        by_id = {o.segment_id: o for o in things}
        for o in things:
            v = o.mesh.vertices
            assert np.all(inside_polygon(v[:, :2], outline)), o.name
            assert np.all(v[:, 2] < ceiling(v[:, :2])), o.name
            if o.rests_on:
                s_lo, s_hi = by_id[o.rests_on].mesh.bounds
                assert abs(v[:, 2].min() - s_hi[2]) < 1e-6 and np.all(v[:, :2].min(0) >= s_lo[:2] - 1e-6)
        floor = [convex_hull(o.mesh.vertices[:, :2]) for o in content.floor_things]
        for a in range(len(floor)):
            for b in range(a):
                assert convex_gap(floor[a], floor[b]) > 0, (shape, seed, a, b)
        for w in room.get("inner_walls", []):  # nothing stands in an inner wall
            lo, hi = (np.array(p)[:2] for p in w["box"])
            for h in floor:
                box = np.array([lo, [hi[0], lo[1]], hi, [lo[0], hi[1]]])
                if w["box"][0][2] < 1.0:  # the stubs, not the lintel or beam overhead
                    assert convex_gap(h, box) > 0
        # Every camera path: inside the cameras' region, 0.5 m from the room (orbit, walk: from everything).
        caster = RayCaster(content)
        stuff = RayCaster(replace(content, objects=[o for o in content.objects if o.segment_id < 1000]))
        for name in ("orbit", "walk", "handheld"):
            c2w = camera_path(content, caster, name, 16, np.random.default_rng(seed))
            centres = c2w[:, :3, 3]
            assert np.all(inside_polygon(centres[:, :2], content.room.camera_region)), name
            assert stuff.distance(centres).min() >= 0.5 - 1e-3, name
            assert caster.distance(centres).min() >= (0.5 if name != "handheld" else MIN_CLEARANCE) - 1e-3, name
            assert np.all(centres[:, 2] < ceiling(centres[:, :2]) - 0.45), name


# --------------------------------------------------------------------------------------------- clutter
def _flat(o) -> bool:
    ext = yawed_box(o.mesh.vertices, o.yaw)["extent"]
    return bool(ext[2] <= 0.1 and ext[2] <= 0.3 * ext[0])


@pytest.mark.parametrize("shape,seed", [("auto", 0), ("hexagon", 1), ("open", 2), ("vaulted", 3)])
def test_dense_clutter_holds_thirty_things_side_by_side_thin_and_flat(shape, seed):
    content, level = build_content("indoor", seed, shape, "dense")
    assert level == "dense"
    things = content.things
    assert len(things) >= 30
    ids = {c.id: c.name for c in content.categories}
    assert all(ids[c.id] == c.name for c in INDOOR_CATEGORIES) and ids[22] == "mat", "existing ids unchanged"
    assert sum(o.thin is not None and o.thin < THIN_PART for o in things) >= 3
    assert sum(_flat(o) for o in things) >= 2 and any(ids[o.category_id] == "mat" for o in things)
    names = {ids[o.category_id] for o in things}
    assert {"figurine", "toy_plane", "ball", "chair", "table"} <= names
    desc = content.description
    groups = {g["group"] for g in desc["clutter"]["groups"]}
    assert "row_of_balls" in groups
    # Several of a class side by side: the row of balls, footprints 1-6 cm apart.
    by_id = {o.segment_id: o for o in things}
    row = [by_id[d["id"]] for d in desc["objects"] if d.get("group") == "row_of_balls"]
    assert len(row) >= 3
    hulls = [convex_hull(o.mesh.vertices[:, :2]) for o in row]
    assert all(0.0 < convex_gap(a, b) < 0.1 for a, b in zip(hulls, hulls[1:]))
    # A table with chairs around it.
    table_set = [d for d in desc["objects"] if d.get("group") == "table_set"]
    assert len(table_set) in (0, 3, 5) and (not table_set or sum(d["class"] == "chair" for d in table_set) >= 2)
    # Nothing intersects: floor footprints apart and inside, small things inside their support's top.
    outline = content.room_polygon
    ceiling = ceiling_from_description(desc["room"].get("ceiling", {"type": "flat", "height_m": content.aabb[1, 2]}))
    floor = [(o, convex_hull(o.mesh.vertices[:, :2])) for o in content.floor_things]
    for k, (a, ha) in enumerate(floor):
        assert np.all(inside_polygon(a.mesh.vertices[:, :2], outline)), a.name
        assert np.all(a.mesh.vertices[:, 2] < ceiling(a.mesh.vertices[:, :2]))
        for b, hb in floor[:k]:
            assert convex_gap(ha, hb) > 0, (a.name, b.name)
    on_top = {}
    for o in things:
        if o.rests_on:
            s_lo, s_hi = by_id[o.rests_on].mesh.bounds
            lo, hi = o.mesh.bounds
            assert abs(lo[2] - s_hi[2]) < 1e-6
            assert np.all(lo[:2] >= s_lo[:2] - 1e-6) and np.all(hi[:2] <= s_hi[:2] + 1e-6)
            on_top.setdefault(o.rests_on, []).append(o)
    for group in on_top.values():  # small things on one top do not overlap
        hulls = [ConvexHull(o.mesh.vertices[:, :2]) for o in group]
        for a in range(len(group)):
            for b in range(a):
                assert convex_gap(group[a].mesh.vertices[hulls[a].vertices][:, :2],
                                  group[b].mesh.vertices[hulls[b].vertices][:, :2]) > 0
    # The clutter has its own random stream: the room, its own things and its lighting are those of `none`.
    plain, _ = build_content("indoor", seed, shape, "none")
    p = plain.description
    assert (desc["room"], desc["lighting"], desc["wall_texture"]) == (p["room"], p["lighting"], p["wall_texture"])
    assert desc["objects"][:len(p["objects"])] == p["objects"]


def test_clutter_scene_records_and_shows_its_things(tmp_path):
    rep = make_scene(tmp_path / "c", SynthOptions(seed=0, clutter="dense", n_views=24, width=64, height=48),
                     progress=False)
    meta = _meta(tmp_path / "c")
    assert (meta["clutter"], meta["clutter_level"]) == ("dense", "dense") and "room_shape" not in meta
    assert meta["scene"]["clutter"]["things"] >= 30
    scene = load_scene(tmp_path / "c")
    assert any(c.name == "mat" for c in scene.categories)
    table = json.loads((tmp_path / "c" / "gt" / "objects.json").read_text())
    objects = table["objects"]
    assert len(objects) >= 30 and rep["content"]["n_things"] == len(objects)
    keys = {"id", "class", "name", "on", "centre_m", "yaw_deg", "extent_m", "max_dim_m", "thinnest_part_m", "thin",
            "flat", "views", "pixels", "gt_points"}
    assert all(set(o) == keys for o in objects)
    assert sum(o["thin"] for o in objects) >= 3 and sum(o["flat"] for o in objects) >= 2
    # Small things are the point: nearly all are seen in several views, even in 24 small ones.
    views = np.array([o["views"] for o in objects])
    assert np.mean(views >= 2) >= 0.9
    # Their ids are the GT points' instance ids, and their sizes are their meshes'.
    inst = scene.gt_points()["instance"]
    assert set(np.unique(inst[inst > 0]).tolist()) <= {o["id"] for o in objects}
    content, _ = build_content("indoor", 0, "auto", "dense")
    for o, thing in zip(objects, content.things):
        assert o["id"] == thing.segment_id
        ext = np.array(o["extent_m"])
        assert ext[0] >= ext[1] and o["max_dim_m"] == pytest.approx(ext.max(), abs=1e-4)
        aabb = np.ptp(thing.mesh.vertices, axis=0)
        assert ext[2] == pytest.approx(aabb[2], abs=1e-3) and ext[0] <= np.hypot(aabb[0], aabb[1]) + 1e-3
        assert o["gt_points"] == int(np.sum(inst == o["id"]))


# --------------------------------------------------------------------------------------------- determinism
def test_new_options_same_args_same_bytes(tmp_path):
    kw = dict(n_views=3, width=24, height=20, room_shape="polygon", clutter="dense")
    make_scene(tmp_path / "a", SynthOptions(seed=5, **kw), progress=False)
    make_scene(tmp_path / "b", SynthOptions(seed=5, **kw), progress=False)
    make_scene(tmp_path / "c", SynthOptions(seed=6, **kw), progress=False)
    a, b, c = _files(tmp_path / "a"), _files(tmp_path / "b"), _files(tmp_path / "c")
    assert a.keys() == b.keys() and [k for k in a if a[k] != b[k]] == []
    assert a["images/frame_0000.png"] != c["images/frame_0000.png"]


#: sha256 (first 16 hex digits) of ``lift3d_synth.scene`` of indoor seeds 0-5 as written before --room-shape and
#: --clutter existed: the default options must keep giving these rooms.
BEFORE = {0: "a5feb30449887f31", 1: "eb1a2fbc9f268f0a", 2: "5c3599ba8a70920c", 3: "b95f67386c53087f",
          4: "7dbffd6fff26159f", 5: "2d64dde56c3e292c"}


def test_existing_seeds_are_unchanged(tmp_path):
    for seed, digest in BEFORE.items():
        content, level = build_content("indoor", seed)
        assert level == "none" and content.room is None, "the original rooms keep the original camera planning"
        assert hashlib.sha256(json.dumps(content.description).encode()).hexdigest()[:16] == digest, seed
        assert [c.id for c in content.categories] == list(range(1, 22))
    # The defaults write no new keys; forcing the shape a seed has anyway, or `auto` clutter that stays
    # `none`, changes no file but the recorded option.
    auto_none = next(s for s in range(20) if build_content("indoor", s, clutter="auto")[1] == "none")
    rect = next(s for s in range(20) if build_content("indoor", s)[0].description["room"]["shape"] == "rectangle")
    kw = dict(n_views=3, width=24, height=20)
    for seed, option in ((rect, dict(room_shape="box")), (1, dict(room_shape="l")), (auto_none, dict(clutter="auto"))):
        make_scene(tmp_path / f"d{seed}", SynthOptions(seed=seed, **kw), progress=False)
        make_scene(tmp_path / f"o{seed}", SynthOptions(seed=seed, **kw, **option), progress=False)
        d, o = _files(tmp_path / f"d{seed}"), _files(tmp_path / f"o{seed}")
        assert d.keys() == o.keys() and [k for k in d if d[k] != o[k]] == ["transforms.json"], option
        md, mo = _meta(tmp_path / f"d{seed}"), _meta(tmp_path / f"o{seed}")
        assert not {"room_shape", "clutter", "clutter_level"} & set(md)
        extra = {k: mo.pop(k) for k in ("room_shape", "clutter", "clutter_level") if k in mo}
        assert extra and md == mo, option


def test_options_are_checked():
    for bad, flag in ((dict(room_shape="dome"), "--room-shape"), (dict(clutter="lots"), "--clutter"),
                      (dict(kind="outdoor", room_shape="polygon"), "--room-shape"),
                      (dict(kind="outdoor", clutter="dense"), "--clutter")):
        with pytest.raises(InputError) as err:
            make_scene("/nonexistent/never", SynthOptions(n_views=3, width=16, height=16, **bad), progress=False)
        assert str(err.value).startswith(flag) and "\n" not in str(err.value)


def test_cli_takes_room_shape_and_clutter(tmp_path, capsys):
    from lift3d.cli.main import main as cli_main

    rc = cli_main(["synth", "--out", str(tmp_path / "s"), "--views", "3", "--width", "24", "--height", "16",
                   "--room-shape", "hexagon", "--clutter", "dense", "--seed", "2"])
    out = capsys.readouterr().out
    assert rc == 0 and "hexagon room" in out and "dense clutter" in out and " thin, " in out
    meta = _meta(tmp_path / "s")
    assert (meta["room_shape"], meta["clutter"]) == ("hexagon", "dense")
