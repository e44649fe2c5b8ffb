"""Export formats for robot stacks and other tools, each read back by the library or tool that consumes it.

A hand-made room (floor, a wall, a table with a cup on it, a chair beside the table, a lamp hanging above
the obstacle band) goes through the registered writers; the files are read back with rosbags, pyoctomap,
Nav2's own occupancy rule, PCL's ``pcl_pcd2ply`` and CloudCompare (clients from ``tests/interop.py``: a
missing one skips the test, or fails it under CI). One tiny trained run checks ``lift3d export --format ...``
end to end.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import lift3d
from lift3d.data.ply import read_labelled_ply
from lift3d.errors import InputError
from lift3d.export.instances import instance_records
from lift3d.export.scene_graph import build_scene_graph
from lift3d.export.writers import WRITERS, ExportContext, ExportOptions, ExportWriter, check_formats, get_writer
from interop import require_module, require_tool

CLASSES = [{"id": 1, "name": "floor-wood", "isthing": False, "color": [80, 60, 40]},
           {"id": 2, "name": "wall", "isthing": False, "color": [120, 120, 120]},
           {"id": 3, "name": "table", "isthing": True, "color": [30, 30, 200]},
           {"id": 4, "name": "cup", "isthing": True, "color": [200, 30, 30]},
           {"id": 5, "name": "chair", "isthing": True, "color": [30, 200, 30]},
           {"id": 6, "name": "lamp", "isthing": True, "color": [250, 250, 0]}]
RES = 0.05


def _box_surface(lo, hi, step, rng):
    """Points on the six faces of an axis-aligned box, about ``step`` apart."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    area = 2 * sum(a * b for a, b in [(hi - lo)[[0, 1]], (hi - lo)[[1, 2]], (hi - lo)[[0, 2]]])
    p = rng.uniform(lo, hi, (int(area / step**2) + 8, 3))
    axis = rng.integers(0, 3, len(p))
    side = rng.integers(0, 2, len(p))
    p[np.arange(len(p)), axis] = np.where(side == 1, hi[axis], lo[axis])
    return p


def make_room(up: str = "z"):
    """Floor z=0 over [0, 3]x[0, 2], a wall at x=0, a table (top 0.7) with a cup on it, a chair beside the
    table, a lamp hanging at 2.0-2.2 (above the obstacle band). Returns points and the instance ids."""
    rng = np.random.default_rng(0)
    floor = np.stack(np.meshgrid(np.arange(0.01, 3, 0.04), np.arange(0.01, 2, 0.04), [0.0]), -1).reshape(-1, 3)
    # No floor under the table and chair (the cameras cannot see there either).
    hidden = ((floor[:, 0] > 1.0) & (floor[:, 0] < 1.8) & (floor[:, 1] > 0.6) & (floor[:, 1] < 1.4)) | \
             ((floor[:, 0] > 1.9) & (floor[:, 0] < 2.3) & (floor[:, 1] > 0.8) & (floor[:, 1] < 1.2))
    floor = floor[~hidden]
    wall = np.stack(np.meshgrid([0.0], np.arange(0.01, 2, 0.04), np.arange(0.01, 2.5, 0.04)), -1).reshape(-1, 3)
    table = _box_surface([1.0, 0.6, 0.0], [1.8, 1.4, 0.7], 0.03, rng)
    cup = _box_surface([1.35, 0.95, 0.7], [1.45, 1.05, 0.82], 0.01, rng)
    chair = _box_surface([1.9, 0.8, 0.0], [2.3, 1.2, 0.9], 0.03, rng)
    lamp = _box_surface([0.5, 0.9, 2.0], [0.7, 1.1, 2.2], 0.02, rng)
    parts = [(floor, 1, 0), (wall, 2, 0), (table, 3, 1), (cup, 4, 2), (chair, 5, 3), (lamp, 6, 4)]
    xyz = np.concatenate([p for p, _, _ in parts]).astype(np.float32)
    semantic = np.concatenate([np.full(len(p), c) for p, c, _ in parts]).astype(np.int32)
    instance = np.concatenate([np.full(len(p), i) for p, _, i in parts]).astype(np.int32)
    rgb = rng.integers(0, 256, (len(xyz), 3)).astype(np.uint8)
    confidence = rng.uniform(0.3, 1.0, len(xyz)).astype(np.float32)
    up_vec = np.array([0.0, 0.0, 1.0])
    if up == "y":  # the same room in a y-up frame: (x, y, z) -> (x, z, -y)
        xyz = np.stack([xyz[:, 0], xyz[:, 2], -xyz[:, 1]], -1)
        up_vec = np.array([0.0, 1.0, 0.0])
    return SimpleNamespace(xyz=xyz, semantic=semantic, instance=instance, rgb=rgb, confidence=confidence,
                           field_semantic=None, field_channel=None), up_vec


def make_context(out: Path, up: str = "z", **options) -> ExportContext:
    pts, up_vec = make_room(up)
    names = {c["id"]: c["name"] for c in CLASSES}
    records = instance_records(pts.xyz, pts.semantic, pts.instance, pts.confidence, names)
    return ExportContext(out=out, points=pts, mesh=None, classes=CLASSES, records=records, frame="world",
                         units="metres", transform=np.eye(4), up=up_vec, default_resolution=RES,
                         options=ExportOptions(**options), comments=["lift3d test"])


@pytest.fixture
def ctx(tmp_path) -> ExportContext:
    return make_context(tmp_path)


# ------------------------------------------------------------------------------------------ registry
def test_cli_format_choices_come_from_the_registry(monkeypatch):
    from lift3d.cli.main import build_parser

    class Dummy(ExportWriter):
        name = "dummy-test-format"
        help = "nothing"

    def choices():
        parser = build_parser()
        sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
        fmt = next(a for a in sub.choices["export"]._actions if a.dest == "format")
        return tuple(fmt.choices)

    assert choices() == tuple(WRITERS)
    assert {"ply", "ply-cloudcompare", "pcd", "label", "ros2bag", "octomap", "nav2"} <= set(WRITERS)
    monkeypatch.setitem(WRITERS, Dummy.name, Dummy)
    assert Dummy.name in choices()
    with pytest.raises(InputError, match="unknown format 'obj'"):
        get_writer("obj")


@pytest.mark.parametrize("fmt, extra, module", [("ros2bag", "ros", "rosbags.rosbag2"), ("octomap", "octomap", "pyoctomap")])
def test_missing_extra_is_a_one_line_error_naming_pip_install(fmt, extra, module, monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, module, None)  # import fails as if not installed
    with pytest.raises(InputError, match=rf"pip install 'lift3d\[{extra}\]'"):
        check_formats(["ply", fmt])
    from lift3d.cli.main import main

    # The CLI fails before loading anything (the run folder does not even exist).
    assert main(["export", "--run", str(tmp_path / "nope"), "--pointcloud", "--format", fmt]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"pip install 'lift3d[{extra}]'" in err


# ------------------------------------------------------------------------------------------ PCL / CloudCompare
def test_pcd_header_and_our_reader(ctx):
    from lift3d.export.writers.pcd import read_pcd

    for ascii_ in (False, True):
        ctx.options.pcd_ascii = ascii_
        assert get_writer("pcd").write(ctx) == ["points.pcd"]
        header = (ctx.out / "points.pcd").read_bytes()[:400].decode("ascii", "replace")
        assert "FIELDS x y z rgba label instance confidence" in header and "TYPE F F F U U U F" in header
        ours = read_pcd(ctx.out / "points.pcd")
        np.testing.assert_array_equal(ours["rgb"], ctx.points.rgb)
        assert (ours["rgba"] >> 24 == 255).all()


def test_pcd_reads_back_exactly_through_pcl_pcd2ply(ctx, tmp_path):
    from plyfile import PlyData

    tool = require_tool("pcl_pcd2ply")
    for ascii_ in (False, True):
        ctx.options.pcd_ascii = ascii_
        assert get_writer("pcd").write(ctx) == ["points.pcd"]
        out = tmp_path / f"pcl_{ascii_}.ply"
        subprocess.run([tool, str(ctx.out / "points.pcd"), str(out)], check=True, capture_output=True)
        v = PlyData.read(str(out))["vertex"].data
        p = ctx.points
        np.testing.assert_array_equal(np.stack([v["x"], v["y"], v["z"]], -1), p.xyz)
        np.testing.assert_array_equal(np.stack([v["red"], v["green"], v["blue"]], -1), p.rgb)
        assert (v["alpha"] == 255).all()
        np.testing.assert_array_equal(v["label"], p.semantic)
        np.testing.assert_array_equal(v["instance"], p.instance)
        np.testing.assert_array_equal(v["confidence"], p.confidence)


def test_cloudcompare_flavour_names_the_scalar_fields(ctx):
    from plyfile import PlyData

    assert get_writer("ply-cloudcompare").write(ctx) == ["points.cloudcompare.ply"]
    path = ctx.out / "points.cloudcompare.ply"
    names = PlyData.read(str(path))["vertex"].data.dtype.names
    assert {"scalar_semantic", "scalar_instance", "scalar_confidence"} <= set(names)
    mine = read_labelled_ply(path)
    np.testing.assert_array_equal(mine["semantic"], ctx.points.semantic)


def test_cloudcompare_keeps_the_labels(ctx, tmp_path):
    cc = require_tool("CloudCompare")
    get_writer("ply-cloudcompare").write(ctx)
    path = ctx.out / "points.cloudcompare.ply"
    mine = read_labelled_ply(path)
    # Load it in CloudCompare and save it back: the scalar fields survive (plain names would be dropped).
    back = tmp_path / "cc_back.ply"
    subprocess.run([cc, "-SILENT", "-AUTO_SAVE", "OFF", "-O", str(path), "-C_EXPORT_FMT", "PLY",
                    "-PLY_EXPORT_FMT", "BINARY_LE", "-SAVE_CLOUDS", "FILE", str(back)], check=True,
                   capture_output=True, timeout=120, env={"QT_QPA_PLATFORM": "offscreen", "PATH": "/usr/bin:/bin"})
    again = read_labelled_ply(back)
    for key in ("semantic", "instance", "rgb", "xyz"):
        np.testing.assert_array_equal(again[key], mine[key])
    np.testing.assert_allclose(again["confidence"], mine["confidence"], rtol=1e-6)


# ------------------------------------------------------------------------------------------ ROS 2
def read_bag(folder: Path) -> dict:
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    msgs = {}
    with Reader(folder) as reader:
        for conn, _, raw in reader.messages():
            msgs[conn.topic] = (conn.msgtype, typestore.deserialize_cdr(raw, conn.msgtype))
    return msgs


def test_ros2bag_pointcloud2_equals_the_ply_and_markers_are_the_boxes(ctx):
    require_module("rosbags", pip="pip install 'lift3d[ros]'")
    from scipy.spatial.transform import Rotation

    from lift3d.export.api import OrientedBox3D
    from lift3d.export.writers.ros2bag import read_pointcloud2

    ctx.options.frame_id = "odom"
    get_writer("ply").write(ctx)
    assert get_writer("ros2bag").write(ctx) == ["rosbag2/"]
    assert sorted(p.name for p in (ctx.out / "rosbag2").iterdir()) == ["metadata.yaml", "rosbag2.mcap"]
    msgs = read_bag(ctx.out / "rosbag2")
    kind, cloud = msgs["/lift3d/points"]
    assert kind == "sensor_msgs/msg/PointCloud2" and cloud.header.frame_id == "odom"
    assert [(f.name, f.offset, f.datatype) for f in cloud.fields] == [
        ("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("rgb", 12, 7), ("label", 16, 6), ("instance", 20, 6),
        ("confidence", 24, 7)]
    got, ply = read_pointcloud2(cloud), read_labelled_ply(ctx.out / "points.ply")
    np.testing.assert_array_equal(got["xyz"], ply["xyz"])
    np.testing.assert_array_equal(got["rgb"], ply["rgb"])
    np.testing.assert_array_equal(got["label"], ply["semantic"])
    np.testing.assert_array_equal(got["instance"], ply["instance"])
    np.testing.assert_array_equal(got["confidence"], ply["confidence"])
    kind, array = msgs["/lift3d/instances"]
    assert kind == "visualization_msgs/msg/MarkerArray"
    boxes = {m.id: m for m in array.markers if m.ns == "boxes"}
    texts = {m.id: m.text for m in array.markers if m.ns == "labels"}
    assert array.markers[0].action == 3  # DELETEALL first
    assert sorted(boxes) == sorted(texts) == [r["id"] for r in ctx.records]
    for r in ctx.records:
        m = boxes[r["id"]]
        assert m.type == 1 and m.header.frame_id == "odom" and texts[r["id"]] == f"{r['id']} {r['class_name']}"
        np.testing.assert_allclose([m.pose.position.x, m.pose.position.y, m.pose.position.z], r["obb"]["center"])
        q = [m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w]
        box = OrientedBox3D(np.asarray(r["obb"]["center"]), Rotation.from_quat(q).as_matrix(),
                                              np.array([m.scale.x, m.scale.y, m.scale.z]))
        members = ctx.points.xyz[ctx.points.instance == r["id"]]
        assert box.contains(members, margin=1e-4).all()  # the marker box holds the object's points


# ------------------------------------------------------------------------------------------ OctoMap
def _leaf_voxels(tree, res: float) -> dict[tuple, object]:
    """Occupied leaves of a read tree, expanded to voxels of side ``res`` (pruned leaves are bigger)."""
    out = {}
    for leaf in tree.begin_leafs():
        if leaf.current_node.getOccupancy() <= 0.5:
            continue
        size, c = leaf.getSize(), np.asarray(leaf.getCoordinate(), float)
        k = int(round(size / res))
        offs = (np.arange(k) - (k - 1) / 2) * res
        for dx in offs:
            for dy in offs:
                for dz in offs:
                    key = tuple(np.floor((c + [dx, dy, dz]) / res).astype(int))
                    out[key] = leaf
    return out


def test_octomap_reads_back_occupied_voxels_and_class_colours(ctx):
    pyoctomap = require_module("pyoctomap", pip="pip install 'lift3d[octomap]'")
    from lift3d.export.writers.octomap import occupied_voxels

    ctx.options.map_resolution = 0.1
    assert get_writer("octomap").write(ctx) == ["map.bt", "map.ot"]
    centers, classes = occupied_voxels(ctx.points.xyz, ctx.points.semantic, 0.1)
    expected = {tuple(np.floor(c / 0.1).astype(int)) for c in centers}
    assert len(expected) > 500
    bt = pyoctomap.OcTree(0.1)
    assert bt.readBinary(str(ctx.out / "map.bt"))
    assert bt.getResolution() == pytest.approx(0.1)
    assert set(_leaf_voxels(bt, 0.1)) == expected
    ot = pyoctomap.ColorOcTree(0.1).read(str(ctx.out / "map.ot"))
    assert ot is not None and ot.getResolution() == pytest.approx(0.1)
    leaves = _leaf_voxels(ot, 0.1)
    assert set(leaves) == expected
    colour = {c["id"]: tuple(c["color"]) for c in CLASSES}
    for center, cls in zip(centers, classes):
        node = ot.search(center)
        assert node is not None and tuple(node.getColor()) == colour[int(cls)]
    assert json.dumps(ctx.notes["octomap"])  # recorded for metadata.json


# ------------------------------------------------------------------------------------------ Nav2
def nav2_load(yaml_path: Path) -> tuple[np.ndarray, dict]:
    """What Nav2's map_server makes of map.yaml + image: an OccupancyGrid (row 0 = smallest y) with 100
    occupied, 0 free, -1 unknown, by its rule p = (255 - v) / 255 (negate 0) in trinary mode."""
    import cv2
    import yaml

    meta = yaml.safe_load(yaml_path.read_text())
    img = cv2.imread(str(yaml_path.parent / meta["image"]), cv2.IMREAD_UNCHANGED).astype(np.float64)
    assert meta["mode"] == "trinary" and meta["negate"] == 0
    p = (255.0 - img) / 255.0
    grid = np.full(img.shape, -1, np.int8)
    grid[p > meta["occupied_thresh"]] = 100
    grid[p < meta["free_thresh"]] = 0
    return grid[::-1], meta  # map_server flips: the image's last row is the map's first


def _cell(meta, x, y):
    res, (ox, oy, _) = meta["resolution"], meta["origin"]
    return int(np.floor((y - oy) / res)), int(np.floor((x - ox) / res))


@pytest.mark.parametrize("up", ["z", "y"])
def test_nav2_map_reads_as_intended_through_nav2s_rule(tmp_path, up):
    ctx = make_context(tmp_path, up=up)
    written = get_writer("nav2").write(ctx)
    assert {"map.pgm", "map.yaml"} <= set(written)
    grid, meta = nav2_load(tmp_path / "map.yaml")
    assert meta["free_thresh"] < 205 and (255 - 205) / 255 > meta["free_thresh"]  # unknown is not free
    # In a y-up room the map frame is (z, x, y) of the export: map x = -y_room... use the map frame.
    from lift3d.export.ground import map_frame

    to_map = map_frame(ctx.up) @ (np.eye(3) if up == "z" else np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0.0]]))

    def at(x, y):  # room coordinates (z-up room) -> cell value
        mx, my, _ = to_map @ [x, y, 0.0]
        return grid[_cell(meta, mx, my)]

    assert at(2.6, 0.3) == 0, "open floor is free"
    assert at(1.4, 1.0) == 100 and at(1.05, 0.65) == 100, "the table is an obstacle"
    assert at(2.1, 1.0) == 100, "the chair is an obstacle"
    assert at(0.02, 1.0) == 100, "the wall is an obstacle"
    assert at(0.6, 1.0) == 0, "the lamp hangs above the band: the floor under it stays free"
    values, counts = np.unique(grid, return_counts=True)
    assert set(values.tolist()) == {-1, 0, 100}
    counts_by = dict(zip(values.tolist(), counts.tolist()))
    assert counts_by[-1] == ctx.notes["nav2"]["cells"]["unknown"]
    layer = tmp_path / "map_layers" / "5_chair.png"
    import cv2

    chair = cv2.imread(str(layer), cv2.IMREAD_UNCHANGED)[::-1]
    assert chair.shape == grid.shape and chair[_cell(meta, *(to_map @ [2.1, 1.0, 0])[:2])] == 255
    assert set(np.unique(chair).tolist()) == {0, 255}


def test_nav2_height_band_and_floor_classes_are_overridable(tmp_path):
    ctx = make_context(tmp_path, height_band=(0.1, 2.5), floor_classes=("floor-wood",))
    get_writer("nav2").write(ctx)
    grid, meta = nav2_load(tmp_path / "map.yaml")
    assert grid[_cell(meta, 0.6, 1.0)] == 100, "a band up to 2.5 m catches the lamp"
    with pytest.raises(InputError, match="--floor-classes.*carpet"):
        get_writer("nav2").write(make_context(tmp_path, floor_classes=("carpet",)))


# ------------------------------------------------------------------------------------------ scene graph
@pytest.mark.parametrize("up", ["z", "y"])
def test_scene_graph_relations_from_geometry(tmp_path, up):
    ctx = make_context(tmp_path, up=up)
    p = ctx.points
    graph = build_scene_graph(p.xyz, p.semantic, p.instance, p.confidence, ctx.records, CLASSES, up=ctx.up,
                              contact=RES)
    rel = {(r["subject"], r["relation"], r["object"]) for r in graph["relations"]}
    ids = {r["class_name"]: f"object:{r['id']}" for r in ctx.records}
    assert (ids["table"], "on", "stuff:1") in rel
    assert (ids["cup"], "on", ids["table"]) in rel
    assert (ids["chair"], "on", "stuff:1") in rel
    assert not any(s == ids["lamp"] and r == "on" for s, r, _ in rel), "the lamp floats"
    assert (ids["table"], "next_to", ids["chair"]) in rel or (ids["chair"], "next_to", ids["table"]) in rel
    assert not any(r == "next_to" and ids["cup"] in (s, o) and ids["table"] in (s, o) for s, r, o in rel)
    assert all((ids[c], "inside", "room") in rel for c in ("table", "cup", "chair", "lamp"))
    assert not any(o == "stuff:2" for _, r, o in rel if r == "on"), "nothing stands on the wall"
    nodes = {n["node"]: n for n in graph["nodes"]}
    assert nodes[ids["cup"]]["stands_on"] == {"node": ids["table"], "class_name": "table"}
    assert nodes[ids["lamp"]]["stands_on"] is None
    assert nodes["stuff:1"]["floor_like"] and not nodes["stuff:2"]["floor_like"]
    assert nodes[ids["cup"]]["count"] == int((p.instance == 2).sum())


# ------------------------------------------------------------------------------------------ end to end
def test_cli_writes_every_format_from_a_trained_run(tiny_run, tmp_path, capsys):
    require_module("rosbags", pip="pip install 'lift3d[ros]'")
    require_module("pyoctomap", pip="pip install 'lift3d[octomap]'")
    from lift3d.cli.main import main
    from lift3d.export.writers.ros2bag import read_pointcloud2

    out = tmp_path / "export"
    rc = main(["export", "--run", str(tiny_run), "--pointcloud", "--format", *WRITERS, "--num-points", "3000",
               "--map-resolution", "0.1", "--frame-id", "world", "--output-dir", str(out), "--quiet"])
    assert rc == 0, capsys.readouterr().err
    meta = json.loads((out / "metadata.json").read_text())
    for name in ("points.ply", "points.cloudcompare.ply", "points.pcd", "points.label", "rosbag2/", "map.bt",
                 "map.ot", "map.pgm", "map.yaml", "scene_graph.json", "instances.json"):
        assert name in meta["files"] and (out / name).exists(), name
    assert meta["formats"]["map_resolution"] == 0.1 and meta["formats"]["ros2bag"]["frame_id"] == "world"
    assert meta["up"]["axis"] == [0.0, 0.0, 1.0]  # synthetic scenes are z-up; found from the cameras
    cloud = read_pointcloud2(read_bag(out / "rosbag2")["/lift3d/points"][1])
    pts = lift3d.load_labelled_points(out)
    np.testing.assert_array_equal(cloud["label"], pts.semantic)
    np.testing.assert_array_equal(cloud["instance"], pts.instance)
    graph = json.loads((out / "scene_graph.json").read_text())
    assert len([n for n in graph["nodes"] if n["kind"] == "object"]) == len(lift3d.instances(out))
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")], "no temporary files left"


def test_z_up_turns_every_file_and_says_so(tiny_run, tmp_path, capsys):
    from lift3d.cli.main import main
    from lift3d.export.ground import map_frame

    as_is, turned = tmp_path / "as_is", tmp_path / "turned"
    common = ["export", "--run", str(tiny_run), "--pointcloud", "--mesh", "--resolution", "24", "--num-points",
              "3000", "--up", "y", "--quiet"]
    assert main([*common, "--output-dir", str(as_is)]) == 0, capsys.readouterr().err
    assert main([*common, "--z-up", "--output-dir", str(turned)]) == 0, capsys.readouterr().err
    rotation = map_frame(np.array([0.0, 1.0, 0.0]))  # a scene whose up were +y: (x, y, z) -> (z, x, y)
    meta, meta0 = (json.loads((d / "metadata.json").read_text()) for d in (turned, as_is))
    assert np.allclose(meta["rotation"], rotation) and "rotation" not in meta0
    assert meta["up"]["axis"] == [0.0, 0.0, 1.0] and meta0["up"]["axis"] == [0.0, 1.0, 0.0]
    a, b = lift3d.load_labelled_points(as_is), lift3d.load_labelled_points(turned)
    np.testing.assert_allclose(b.xyz, a.xyz @ rotation.T, atol=1e-5)
    np.testing.assert_array_equal(b.semantic, a.semantic)
    from plyfile import PlyData

    mesh, mesh0 = (PlyData.read(str(d / "mesh.ply"))["vertex"].data for d in (turned, as_is))
    xyz = lambda v: np.stack([v["x"], v["y"], v["z"]], -1)  # noqa: E731
    np.testing.assert_allclose(xyz(mesh), xyz(mesh0) @ rotation.T, atol=1e-5)
    boxes, boxes0 = (lift3d.instances(d) for d in (turned, as_is))
    assert len(boxes) == len(boxes0)
