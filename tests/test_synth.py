"""``lift3d synth``: synthetic scenes (content, variety, cameras, splits, GT, options, CLI).

The simulated segmenter and the sensor models are tested in ``test_synth_noise.py``; the eval warning about
trained frames in ``test_synth_eval.py``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lift3d.cli.main import main as cli_main
from lift3d.data.cameras import Cameras
from lift3d.data.scene import load_scene
from lift3d.errors import InputError
from lift3d.synth import SynthOptions, make_scene
from lift3d.synth.cameras import MIN_CLEARANCE, PATHS_OF_KIND, camera_path
from lift3d.synth.geometry import RayCaster
from lift3d.synth.indoor import CATALOGUE, INDOOR_CONFUSABLE, build_indoor, inside_polygon
from lift3d.synth.make import render_view, split_names
from lift3d.synth.outdoor import OUTDOOR_CONFUSABLE, build_outdoor
from lift3d.synth.sensors import DepthSensor


# --------------------------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def indoor(tmp_path_factory) -> tuple[Path, dict]:
    root = tmp_path_factory.mktemp("synth") / "indoor"
    return root, make_scene(root,
                            SynthOptions(kind="indoor", seed=3, noise="moderate", n_views=12, width=48, height=48),
                            progress=False)


@pytest.fixture(scope="module")
def outdoor(tmp_path_factory) -> tuple[Path, dict]:
    root = tmp_path_factory.mktemp("synth") / "outdoor"
    return root, make_scene(root,
                            SynthOptions(kind="outdoor", seed=5, noise="moderate", n_views=10, width=64, height=48),
                            progress=False)


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _meta(root: Path) -> dict:
    return json.loads((root / "transforms.json").read_text())


# --------------------------------------------------------------------------------------------- folder
@pytest.mark.parametrize("which", ["indoor", "outdoor"])
def test_scene_folder_loads_and_validates(which, indoor, outdoor):
    root, report = indoor if which == "indoor" else outdoor
    scene = load_scene(root)
    scene.validate()
    assert len(scene) == report["n_views"] and scene.has_gt and scene.has_depth
    assert all(f.gt_depth_path is not None and f.gt_c2w is not None for f in scene.frames)
    assert all(c.id >= 1 for c in scene.categories)
    if which == "indoor":
        assert scene.scene_box.type == "bounded"
        assert scene.depth_unit_scale_factor == pytest.approx(1e-3)
        # The bounded box holds every camera and every GT point.
        lo, hi = scene.scene_box.aabb
        assert np.all(scene.cameras.centers >= lo) and np.all(scene.cameras.centers <= hi)
        xyz = scene.gt_points()["xyz"]
        assert np.all(xyz >= lo - 1e-3) and np.all(xyz <= hi + 1e-3)
    else:
        assert scene.scene_box.type == "unbounded"
        assert scene.depth_unit_scale_factor == pytest.approx(1e-2)  # cm: 655 m fit in uint16
        lo, hi = scene.scene_box.aabb
        assert np.all(scene.cameras.centers > lo) and np.all(scene.cameras.centers < hi)
        assert "sky" in {c.name for c in scene.categories}
    stats = json.loads((root / "synth_noise.json").read_text())
    assert stats["counts"] == report["noise"]["counts"]
    assert stats["semantic_miou"] == report["noise"]["semantic_miou"]
    assert 0.0 < report["noise"]["test_views"]["miou"] <= 1.0


def test_every_option_is_recorded_in_transforms_json(tmp_path):
    make_scene(tmp_path / "s", SynthOptions(kind="indoor", seed=4, noise="hard", n_views=4, width=24, height=24,
                                            camera_path="handheld", depth="exact", pose_noise=(0.5, 2.0),
                                            view_confusion=0.2, score_informativeness=0.6), progress=False)
    a = _meta(tmp_path / "s")["lift3d_synth"]
    assert (a["kind"], a["seed"], a["noise"], a["n_views"], a["width"], a["height"]) == ("indoor", 4, "hard", 4, 24, 24)
    assert (a["camera_path"], a["camera_path_option"], a["depth"]) == ("handheld", "handheld", "exact")
    assert (a["view_confusion"], a["score_informativeness"]) == (0.2, 0.6)
    assert a["noise_config"]["view_confusion"] == 0.2 and a["noise_config"]["p_miss"] == 0.16
    assert (a["pose_noise"]["deg"], a["pose_noise"]["cm"]) == (0.5, 2.0) and a["pose_noise"]["rms_cm"] > 0
    assert {"room", "wall_texture", "floor_texture", "lighting", "objects"} <= set(a["scene"])
    assert "hfov_deg" in a and "splits" in a and a["version"] >= 2


# --------------------------------------------------------------------------------------------- splits
@pytest.mark.parametrize("n", [2, 3, 4, 7, 10, 12, 13, 24, 59, 60, 61, 100])
def test_splits_are_disjoint_and_spread(n):
    names = [f"frame_{i:04d}" for i in range(n)]
    s = split_names(names)
    train, val, test = (set(s[k]) for k in ("train", "val", "test"))
    assert test and train and val
    assert not test & train and not test & val, "test views are never trained on nor validated on"
    assert train | test | val == set(names)
    if n >= 12:
        assert not val & train, "val views are held out from training"
    else:
        assert len(val) == 1 and val <= train
    idx = sorted(names.index(x) for x in test)
    assert all(b - a >= 2 for a, b in zip(idx, idx[1:])), "no two test views are neighbours"
    if n == 60:
        assert len(test) >= 12 and len(val) >= 4
        assert idx[0] < 6 and idx[-1] > 53, "test views spread along the whole path"


def test_written_scene_splits_are_disjoint(indoor):
    scene = load_scene(indoor[0])
    train, val, test = (set(scene.split(k).tolist()) for k in ("train", "val", "test"))
    assert train and val and test
    assert not train & test and not val & test and not val & train
    meta = _meta(indoor[0])
    assert set(meta["val_filenames"]).isdisjoint(meta["test_filenames"])


# --------------------------------------------------------------------------------------------- determinism
def test_same_seed_same_bytes_other_seed_other_scene(tmp_path):
    kwargs = dict(kind="indoor", n_views=4, width=32, height=24, noise="view-correlated", pose_noise=(0.5, 1.0))
    make_scene(tmp_path / "a", SynthOptions(seed=7, **kwargs), progress=False)
    make_scene(tmp_path / "b", SynthOptions(seed=7, **kwargs), progress=False)
    make_scene(tmp_path / "c", SynthOptions(seed=8, **kwargs), progress=False)
    a, b, c = _files(tmp_path / "a"), _files(tmp_path / "b"), _files(tmp_path / "c")
    assert a.keys() == b.keys() and len(a) > 10
    assert [k for k in a if a[k] != b[k]] == []
    assert a["images/frame_0000.png"] != c["images/frame_0000.png"]
    assert a["panoptic/frame_0000.png"] != c["panoptic/frame_0000.png"]


def test_each_option_changes_only_what_it_is_about(tmp_path):
    kwargs = dict(kind="indoor", seed=2, n_views=3, width=32, height=32)
    make_scene(tmp_path / "m", SynthOptions(noise="moderate", **kwargs), progress=False)
    make_scene(tmp_path / "v", SynthOptions(noise="view-correlated", **kwargs), progress=False)
    make_scene(tmp_path / "e", SynthOptions(depth="exact", **kwargs), progress=False)
    make_scene(tmp_path / "p", SynthOptions(pose_noise=(1.0, 3.0), **kwargs), progress=False)
    m, v, e, p = (_files(tmp_path / k) for k in "mvep")
    for key in m:
        if key.startswith(("images/", "gt/", "depth/")):
            assert m[key] == v[key], key  # noise: only the pseudo-labels
        if key.startswith(("images/", "gt/", "panoptic")):
            assert m[key] == e[key] == p[key], key  # depth and pose noise leave images, GT and labels alone
    assert m["panoptic.json"] != v["panoptic.json"]
    assert m["depth/frame_0000.png"] != e["depth/frame_0000.png"]
    assert e["depth/frame_0000.png"] == e["gt/depth/frame_0000.png"], "exact depth is the GT depth"
    tm, tp = _meta(tmp_path / "m"), _meta(tmp_path / "p")
    for fm, fp in zip(tm["frames"], tp["frames"]):
        assert fm["gt_transform_matrix"] == fp["gt_transform_matrix"] == fm["transform_matrix"]
        assert fp["transform_matrix"] != fp["gt_transform_matrix"]


def test_depth_none_writes_no_input_depth(tmp_path):
    make_scene(tmp_path / "n", SynthOptions(depth="none", n_views=3, width=24, height=24), progress=False)
    scene = load_scene(tmp_path / "n")
    assert not scene.has_depth and all(f.depth_path is None for f in scene.frames)
    assert not (tmp_path / "n" / "depth").exists()
    assert scene.gt_depth(0) is not None and scene.gt_depth(0).max() > 0


def test_refuses_a_foreign_folder_and_bad_arguments(tmp_path):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep me")
    with pytest.raises(InputError, match="not empty"):
        make_scene(tmp_path / "mine", SynthOptions(n_views=2, width=16, height=16), progress=False)
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep me"
    bad_args = [
        (dict(kind="forest"), "--kind"), (dict(noise="extreme"), "--noise"), (dict(n_views=1), "--views"),
        (dict(width=8), "--width"), (dict(seed=-1), "--seed"), (dict(camera_path="fly"), "--camera-path"),
        (dict(kind="outdoor", camera_path="orbit"), "--camera-path"), (dict(depth="lidar"), "--depth"),
        (dict(pose_noise=(-1.0, 2.0)), "--pose-noise"), (dict(pose_noise=(1.0, -2.0)), "--pose-noise"),
        (dict(pose_noise=(0.0, 100.0), n_views=12), "--pose-noise"),  # 1 m RMS: cameras end up behind surfaces
        (dict(view_confusion=-0.1), "--view-confusion"), (dict(score_informativeness=1.5), "--score-informativeness"),
    ]
    for bad, flag in bad_args:
        args = dict(n_views=3, width=16, height=16) | bad
        with pytest.raises(InputError) as err:
            make_scene(tmp_path / "new", SynthOptions(**args), progress=False)
        assert str(err.value).startswith(flag) and "\n" not in str(err.value)
        assert not (tmp_path / "new").exists() or not any((tmp_path / "new").iterdir()), "nothing half-written"
    # An earlier synthetic scene is replaced, with no stale frames left behind.
    make_scene(tmp_path / "s", SynthOptions(n_views=3, width=16, height=16), progress=False)
    make_scene(tmp_path / "s", SynthOptions(n_views=2, width=16, height=16), progress=False)
    assert sorted(p.name for p in (tmp_path / "s" / "images").iterdir()) == ["frame_0000.png", "frame_0001.png"]


# --------------------------------------------------------------------------------------------- ground truth
@pytest.mark.parametrize("which", ["indoor", "outdoor"])
def test_gt_points_project_onto_matching_gt_labels(which, indoor, outdoor):
    scene = load_scene((indoor if which == "indoor" else outdoor)[0])
    pts = scene.gt_points()
    xyz = pts["xyz"].astype(np.float64)
    things = np.isin(pts["semantic"], scene.thing_ids)
    assert things.any() and (~things).any()
    assert np.all(pts["instance"][~things] == 0) and np.all(pts["instance"][things] > 0)
    agree = checked = in_view = 0
    for i in range(len(scene)):
        # GT points, GT labels and GT depth belong to the true cameras.
        cams = Cameras(c2w=scene.frames[i].gt_c2w[None], fx=scene.cameras.fx[i], fy=scene.cameras.fy[i],
                       cx=scene.cameras.cx[i], cy=scene.cameras.cy[i], width=scene.cameras.width[i],
                       height=scene.cameras.height[i])
        uv, z = cams.project(0, xyz)
        h, w = int(scene.cameras.height[i]), int(scene.cameras.width[i])
        px = np.floor(uv).astype(np.int64)
        inside = np.flatnonzero((z > 0) & (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h))
        in_view += len(inside)
        depth = scene.gt_depth(i)
        d = depth[px[inside, 1], px[inside, 0]]
        # Depth test: the point is the surface this pixel sees (quantisation + 1 % slack).
        visible = inside[(d > 0) & (np.abs(z[inside] - d) < 0.01 * d + 2 * scene.depth_unit_scale_factor)]
        gt = scene.gt_labels(i)
        r, c = px[visible, 1], px[visible, 0]
        ok = (gt.semantic[r, c] == pts["semantic"][visible]) & (gt.instance[r, c] == pts["instance"][visible])
        agree += int(ok.sum())
        checked += len(visible)
    assert checked > 0.2 * in_view, "GT depth must be z-depth consistent with Cameras.project"
    assert agree / checked >= 0.98


@pytest.mark.parametrize("source", ["gt_depth", "depth"])
def test_depth_back_projects_onto_gt_points(indoor, source):
    from scipy.spatial import cKDTree

    scene = load_scene(indoor[0])
    tree = cKDTree(scene.gt_points()["xyz"])
    for i in (0, 5):
        depth = scene.gt_depth(i) if source == "gt_depth" else scene.depth(i)
        v, u = np.nonzero(depth > 0)
        origins, dirs = scene.cameras.rays(i, u, v)
        t = depth[v, u] / (dirs @ scene.cameras.forward[i])  # z-depth → distance along the ray
        dist, _ = tree.query(origins + t[:, None] * dirs)
        # Exact depth lands on the points; sensor depth (noise of millimetres to centimetres) nearly so.
        assert np.mean(dist < 0.05) > (0.95 if source == "gt_depth" else 0.9)


# --------------------------------------------------------------------------------------------- content
def test_indoor_content_is_a_furnished_room():
    from scipy.spatial import ConvexHull

    for seed in range(6):
        content = build_indoor(np.random.default_rng(seed))
        things = content.things
        assert 6 <= len(things) <= 16 and len({o.category_id for o in things}) >= 3
        poly = content.room_polygon
        z1 = content.aabb[1, 2]
        by_id = {o.segment_id: o for o in things}
        for o in things:
            lo, hi = o.mesh.bounds
            assert np.all(inside_polygon(o.mesh.vertices[:, :2], poly)), o.name
            assert hi[2] < z1
            if o.rests_on == 0:
                assert abs(lo[2]) < 1e-6, f"{o.name} rests on the floor"
            else:  # on its support's top, inside its footprint
                s_lo, s_hi = by_id[o.rests_on].mesh.bounds
                assert abs(lo[2] - s_hi[2]) < 1e-6, f"{o.name} rests on {by_id[o.rests_on].name}"
                assert np.all((lo[:2] >= s_lo[:2] - 1e-6) & (hi[:2] <= s_hi[:2] + 1e-6))
        # No floor object reaches into another's footprint (convex hull of its vertices seen from above).
        floor = content.floor_things
        hulls = [ConvexHull(o.mesh.vertices[:, :2]).equations for o in floor]  # rows: n_x, n_y, offset
        for a, obj in enumerate(floor):
            xy1 = np.column_stack([obj.mesh.vertices[:, :2], np.ones(len(obj.mesh.vertices))])
            for b, planes in enumerate(hulls):
                if a != b:
                    assert not np.all(xy1 @ planes.T <= 1e-9, axis=1).any(), (obj.name, floor[b].name)


def test_seeds_vary_the_scene():
    rooms = [build_indoor(np.random.default_rng(s)) for s in range(12)]
    sizes = [tuple(r.description["room"]["size_m"]) for r in rooms]
    assert len(set(sizes)) == len(sizes), "every seed draws its own room size"
    assert {r.description["room"]["shape"] for r in rooms} == {"rectangle", "L"}
    assert min(s[0] * s[1] for s in sizes) < 25 < max(s[0] * s[1] for s in sizes)
    sets = [sorted(o["class"] for o in r.description["objects"]) for r in rooms]
    assert len({tuple(x) for x in sets}) == len(sets), "object sets differ"
    assert len({c for x in sets for c in x}) >= 12, "the catalogue is used"
    assert any(o["on"] != "floor" for r in rooms for o in r.description["objects"]), "things stand on others"
    levels = [r.description["wall_texture"]["level"] for r in rooms]
    assert min(levels) < 0.25 and max(levels) > 0.7, "near-textureless to strongly textured walls"
    kelvins = [r.description["lighting"]["kelvin"] for r in rooms]
    assert max(kelvins) - min(kelvins) > 1500
    streets = [build_outdoor(np.random.default_rng(s)).description for s in range(4)]
    assert len({s["street"]["road_half_width_m"] for s in streets}) == 4
    assert len({tuple(sorted(s["object_counts"].items())) for s in streets}) == 4
    assert set(CATALOGUE) >= {"chair", "lamp", "toy_plane", "figurine", "book", "cup"}


def test_small_and_thin_things_are_in_the_catalogue():
    from lift3d.synth.geometry import MaterialBank
    from lift3d.synth.indoor import build_thing

    rng = np.random.default_rng(0)
    mats = MaterialBank(rng)
    cup = build_thing("cup", rng, mats, small=True).mesh.bounds
    assert np.all(cup[1] - cup[0] < 0.2)
    chair = build_thing("chair", rng, mats).mesh
    legs = chair.vertices[chair.vertices[:, 2] < 0.2]  # below the seat: four legs 2.4-6 cm thick
    assert np.ptp(legs[:, 0]) > 0.3 and len(legs) > 0


def test_indoor_scene_sees_its_objects(indoor):
    scene = load_scene(indoor[0])
    seen = {}
    for i in range(len(scene)):
        gt = scene.gt_labels(i)
        assert np.all(gt.semantic > 0), "every ray hits the room (no void indoors)"
        for inst in np.unique(gt.instance[gt.instance > 0]):
            seen[int(inst)] = int(gt.semantic[gt.instance == inst][0])
    assert len(seen) >= 4 and len(set(seen.values())) >= 3


def test_outdoor_content_spans_50_baselines(outdoor):
    scene = load_scene(outdoor[0])
    xyz = scene.gt_points()["xyz"]
    extent = np.linalg.norm(xyz.max(0) - xyz.min(0))
    centres = scene.cameras.centers
    baseline = np.max(np.linalg.norm(centres[:, None] - centres[None], axis=-1))
    assert baseline > 1.0 and extent >= 50 * baseline
    sky = next(c.id for c in scene.categories if c.name == "sky")
    gt = scene.gt_labels(0)
    assert np.any(gt.semantic == sky)
    assert np.all(scene.gt_depth(0)[gt.semantic == sky] == 0), "sky has no depth"
    assert scene.gt_depth(0).max() > 100.0, "far content is in the GT depth maps"
    assert scene.depth(0).max() <= 10.0 + 4 * DepthSensor().sigma(10.0), "the depth sensor's range ends at 10 m"


@pytest.mark.parametrize("which", ["indoor", "outdoor"])
def test_images_are_finite_and_textured(which, indoor, outdoor):
    scene = load_scene((indoor if which == "indoor" else outdoor)[0])
    stds = []
    for i in range(len(scene)):
        img = scene.image(i).astype(np.float64)
        assert 10 < img.mean() < 245
        stds.append(img.std())
    assert min(stds) > 3.0 and np.mean(stds) > 8.0  # a view of a plain wall can be nearly uniform
    content = build_indoor(np.random.default_rng(0))
    caster = RayCaster(content)
    c2w = camera_path(content, caster, "orbit", 2, np.random.default_rng(1))
    cams = Cameras(c2w=c2w, fx=30.0, fy=30.0, cx=16.0, cy=16.0, width=32, height=32)
    origins, dirs = cams.rays(0, np.arange(32.0), np.full(32, 16.0))
    rgb = caster.shade(caster.cast(origins, dirs), dirs, 1 / 30.0)
    assert np.all(np.isfinite(rgb)) and rgb.min() >= 0 and rgb.max() <= 1
    view = render_view(caster, cams, 0)
    assert view["rgb"].dtype == np.uint8 and np.all(np.isfinite(view["depth"]))


def test_confusion_tables_are_consistent():
    from lift3d.synth.indoor import INDOOR_CATEGORIES
    from lift3d.synth.outdoor import OUTDOOR_CATEGORIES

    for cats, table in ((INDOOR_CATEGORIES, INDOOR_CONFUSABLE), (OUTDOOR_CATEGORIES, OUTDOOR_CONFUSABLE)):
        kind = {c.id: c.isthing for c in cats}
        assert set(table) == set(kind)
        for c, similar in table.items():
            assert similar and all(kind[s] == kind[c] and s != c for s in similar)


# --------------------------------------------------------------------------------------------- cameras
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_camera_paths_keep_clear_of_geometry(seed):
    content = build_indoor(np.random.default_rng(seed))
    caster = RayCaster(content)
    for name in PATHS_OF_KIND["indoor"]:
        c2w = camera_path(content, caster, name, 24, np.random.default_rng(seed))
        centres = c2w[:, :3, 3]
        assert caster.distance(centres).min() >= MIN_CLEARANCE - 1e-3, name
        assert np.all(inside_polygon(centres[:, :2], content.room_polygon)), name
        assert np.all((centres[:, 2] > 0) & (centres[:, 2] < content.aabb[1, 2])), name
        step = np.linalg.norm(np.diff(centres, axis=0), axis=1)
        if name != "orbit":  # a path, not a cloud: consecutive views are close
            assert np.median(step) < 1.0, name
        rot = c2w[:, :3, :3]
        assert np.allclose(np.einsum("nji,njk->nik", rot, rot), np.eye(3), atol=1e-9)
    street = build_outdoor(np.random.default_rng(seed))
    caster = RayCaster(street)
    for name in PATHS_OF_KIND["outdoor"]:
        c2w = camera_path(street, caster, name, 12, np.random.default_rng(seed))
        assert caster.distance(c2w[:, :3, 3]).min() >= MIN_CLEARANCE - 1e-3


def test_auto_camera_path_follows_the_seed(tmp_path):
    picked = set()
    for seed in range(6):
        rep = make_scene(tmp_path / f"s{seed}", SynthOptions(seed=seed, n_views=2, width=16, height=16), progress=False)
        picked.add(rep["options"]["camera_path"])
        make_scene(tmp_path / f"e{seed}",
                   SynthOptions(seed=seed, n_views=2, width=16, height=16, camera_path=rep["options"]["camera_path"]),
                   progress=False)
        a, b = (_files(tmp_path / f"{k}{seed}")["images/frame_0001.png"] for k in "se")
        assert a == b
    assert len(picked) >= 2


def test_handheld_passes_close_to_furniture():
    near = []
    for seed in range(3):
        content = build_indoor(np.random.default_rng(seed))
        caster = RayCaster(content)
        walk = camera_path(content, caster, "walk", 40, np.random.default_rng(seed))
        hand = camera_path(content, caster, "handheld", 40, np.random.default_rng(seed))
        near.append((np.median(caster.distance(hand[:, :3, 3])), np.median(caster.distance(walk[:, :3, 3]))))
        # The camera's x axis (first column) leaves the floor plane when the view rolls.
        assert np.abs(hand[:, 2, 0]).max() > np.sin(np.radians(0.5)), "hand-held views roll"
        assert np.allclose(walk[:, 2, 0], 0.0, atol=1e-9), "walking views stay level"
    assert np.mean([h for h, _ in near]) < np.mean([w for _, w in near])


# --------------------------------------------------------------------------------------------- CLI
def test_cli_writes_a_scene_and_prints_statistics(tmp_path, capsys):
    rc = cli_main(["synth", "--out", str(tmp_path / "s"), "--views", "3", "--width", "24", "--height", "16",
                   "--kind", "outdoor", "--noise", "view-correlated", "--seed", "4", "--camera-path", "handheld",
                   "--depth", "exact", "--pose-noise", "0.5", "2", "--score-informativeness", "0.5"])
    out = capsys.readouterr().out
    assert rc == 0
    assert "missed" in out and "mIoU" in out and "synth_noise.json" in out and "handheld" in out
    assert "view-correlated" in out and "pose noise" in out
    scene = load_scene(tmp_path / "s")
    assert len(scene) == 3 and scene.cameras.width[0] == 24 and scene.cameras.height[0] == 16
    a = _meta(tmp_path / "s")["lift3d_synth"]
    assert (a["noise"], a["camera_path"], a["depth"], a["score_informativeness"]) == \
        ("view-correlated", "handheld", "exact", 0.5)
    assert a["view_confusion"] == 0.4 and a["pose_noise"]["cm"] == 2.0


def test_cli_bad_input_is_one_line_exit_2(tmp_path, capsys):
    assert cli_main(["synth", "--out", str(tmp_path / "s"), "--views", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--views" in err
    assert cli_main(["synth", "--out", str(tmp_path / "s"), "--views", "2", "--view-confusion", "-0.5"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--view-confusion" in err
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "x").write_text("x")
    assert cli_main(["synth", "--out", str(tmp_path / "busy"), "--views", "2"]) == 2
    assert "not empty" in capsys.readouterr().err
