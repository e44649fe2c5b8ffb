"""``lift3d synth``: synthetic scenes (geometry, cameras, GT) and the simulated 2D segmenter."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lift3d.cli.main import main as cli_main
from lift3d.data.scene import Category, load_scene
from lift3d.errors import InputError
from lift3d.synth import make_scene
from lift3d.synth.geometry import INDOOR_CONFUSABLE, OUTDOOR_CONFUSABLE, RayCaster, build_indoor
from lift3d.synth.make import indoor_cameras, render_view
from lift3d.synth.noise import PRESETS, NoiseConfig, NoiseStats, simulate_segmenter


# --------------------------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def indoor(tmp_path_factory) -> tuple[Path, dict]:
    root = tmp_path_factory.mktemp("synth") / "indoor"
    return root, make_scene(root, kind="indoor", seed=3, noise="moderate", n_views=10, width=48, height=48,
                            progress=False)


@pytest.fixture(scope="module")
def outdoor(tmp_path_factory) -> tuple[Path, dict]:
    root = tmp_path_factory.mktemp("synth") / "outdoor"
    return root, make_scene(root, kind="outdoor", seed=5, noise="moderate", n_views=10, width=64, height=48,
                            progress=False)


@pytest.fixture(scope="module")
def outdoor_gt(outdoor) -> list[tuple[np.ndarray, dict[int, int]]]:
    """The outdoor fixture's GT panoptic maps with their segment → category tables (many things per frame)."""
    scene = load_scene(outdoor[0])
    frames = []
    for i in range(len(scene)):
        gt = scene.gt_labels(i)
        table = {s.id: s.category_id for s in scene.frames[i].gt_segments.values()}
        frames.append((gt.segment.astype(np.int64), table))
    return frames


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


# --------------------------------------------------------------------------------------------- folder
@pytest.mark.parametrize("which", ["indoor", "outdoor"])
def test_scene_folder_loads_and_validates(which, indoor, outdoor):
    root, report = indoor if which == "indoor" else outdoor
    scene = load_scene(root)
    scene.validate()
    assert len(scene) == 10 and scene.has_gt and scene.has_depth
    assert all(c.id >= 1 for c in scene.categories)
    train, test = set(scene.split("train").tolist()), set(scene.split("test").tolist())
    assert test and train and not (train & test), "test views must be held out from training"
    assert set(scene.split("val").tolist()) <= test
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


def test_same_seed_same_bytes_other_seed_other_scene(tmp_path):
    kwargs = dict(kind="indoor", n_views=4, width=32, height=24, progress=False)
    make_scene(tmp_path / "a", seed=7, **kwargs)
    make_scene(tmp_path / "b", seed=7, **kwargs)
    make_scene(tmp_path / "c", seed=8, **kwargs)
    a, b, c = _files(tmp_path / "a"), _files(tmp_path / "b"), _files(tmp_path / "c")
    assert a.keys() == b.keys() and len(a) > 10
    assert [k for k in a if a[k] != b[k]] == []
    assert a["images/frame_0000.png"] != c["images/frame_0000.png"]
    assert a["panoptic/frame_0000.png"] != c["panoptic/frame_0000.png"]


def test_noise_level_changes_only_pseudo_labels(tmp_path):
    kwargs = dict(kind="indoor", seed=2, n_views=3, width=32, height=32, progress=False)
    make_scene(tmp_path / "m", noise="moderate", **kwargs)
    make_scene(tmp_path / "h", noise="hard", **kwargs)
    m, h = _files(tmp_path / "m"), _files(tmp_path / "h")
    for key in m:
        if key.startswith(("images/", "gt/", "depth/")):
            assert m[key] == h[key], key
    assert m["panoptic.json"] != h["panoptic.json"]


def test_refuses_a_foreign_folder_and_bad_arguments(tmp_path):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep me")
    with pytest.raises(InputError, match="not empty"):
        make_scene(tmp_path / "mine", n_views=2, width=16, height=16, progress=False)
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep me"
    for bad in (dict(kind="forest"), dict(noise="extreme"), dict(n_views=1), dict(width=8), dict(seed=-1)):
        args = dict(n_views=2, width=16, height=16, progress=False) | bad
        with pytest.raises(InputError):
            make_scene(tmp_path / "new", **args)
    # An earlier synthetic scene is replaced, with no stale frames left behind.
    make_scene(tmp_path / "s", n_views=3, width=16, height=16, progress=False)
    make_scene(tmp_path / "s", n_views=2, width=16, height=16, progress=False)
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
        uv, z = scene.cameras.project(i, xyz)
        h, w = int(scene.cameras.height[i]), int(scene.cameras.width[i])
        px = np.floor(uv).astype(np.int64)
        inside = np.flatnonzero((z > 0) & (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h))
        in_view += len(inside)
        depth = scene.depth(i)
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


def test_gt_depth_back_projects_onto_gt_points(indoor):
    from scipy.spatial import cKDTree

    scene = load_scene(indoor[0])
    tree = cKDTree(scene.gt_points()["xyz"])
    for i in (0, 5):
        depth = scene.depth(i)
        v, u = np.nonzero(depth > 0)
        origins, dirs = scene.cameras.rays(i, u, v)
        t = depth[v, u] / (dirs @ scene.cameras.forward[i])  # z-depth → distance along the ray
        dist, _ = tree.query(origins + t[:, None] * dirs)
        assert np.mean(dist < 0.05) > 0.95


def test_indoor_content_is_a_furnished_room():
    from scipy.spatial import ConvexHull

    for seed in range(4):
        content = build_indoor(np.random.default_rng(seed))
        things = content.things
        assert len(things) >= 8 and len({o.category_id for o in things}) >= 5
        assert len(things) <= 15
        (x0, y0, _), (x1, y1, z1) = content.aabb
        for o in things:
            lo, hi = o.mesh.bounds
            assert abs(lo[2]) < 1e-6, "objects rest on the floor"
            assert lo[0] > x0 and lo[1] > y0 and hi[0] < x1 and hi[1] < y1 and hi[2] < z1
        # No object reaches into another's floor footprint (convex hull of its vertices seen from above).
        hulls = [ConvexHull(o.mesh.vertices[:, :2]).equations for o in things]  # rows: n_x, n_y, offset
        for a, obj in enumerate(things):
            xy1 = np.column_stack([obj.mesh.vertices[:, :2], np.ones(len(obj.mesh.vertices))])
            for b, planes in enumerate(hulls):
                if a != b:
                    inside = np.all(xy1 @ planes.T <= 1e-9, axis=1)
                    assert not inside.any(), (obj.name, things[b].name)


def test_indoor_scene_sees_its_objects(indoor):
    scene = load_scene(indoor[0])
    seen = {}
    for i in range(len(scene)):
        gt = scene.gt_labels(i)
        assert np.all(gt.semantic > 0), "every ray hits the room (no void indoors)"
        for inst in np.unique(gt.instance[gt.instance > 0]):
            seen[int(inst)] = int(gt.semantic[gt.instance == inst][0])
    assert len(seen) >= 8 and len(set(seen.values())) >= 5


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
    assert np.all(scene.depth(0)[gt.semantic == sky] == 0), "sky has no depth"
    assert scene.depth(0).max() > 100.0, "far content is in the depth maps"


@pytest.mark.parametrize("which", ["indoor", "outdoor"])
def test_images_are_finite_and_textured(which, indoor, outdoor):
    scene = load_scene((indoor if which == "indoor" else outdoor)[0])
    for i in range(len(scene)):
        img = scene.image(i).astype(np.float64)
        assert img.std() > 8.0 and 10 < img.mean() < 245
    content = build_indoor(np.random.default_rng(0))
    from lift3d.data.cameras import Cameras

    c2w = indoor_cameras(content, 2, np.random.default_rng(1))
    cams = Cameras(c2w=c2w, fx=30.0, fy=30.0, cx=16.0, cy=16.0, width=32, height=32)
    caster = RayCaster(content)
    origins, dirs = cams.rays(0, np.arange(32.0), np.full(32, 16.0))
    rgb = caster.shade(caster.cast(origins, dirs), dirs, 1 / 30.0)
    assert np.all(np.isfinite(rgb)) and rgb.min() >= 0 and rgb.max() <= 1
    view = render_view(caster, cams, 0)
    assert view["rgb"].dtype == np.uint8 and np.all(np.isfinite(view["depth"]))


# --------------------------------------------------------------------------------------------- noise model
def _majority(values: np.ndarray) -> int:
    ids, counts = np.unique(values, return_counts=True)
    return int(ids[np.argmax(counts)])


def test_pseudo_ids_differ_across_views(indoor):
    scene = load_scene(indoor[0])
    ids_of: dict[int, list[int]] = {}
    for i in range(len(scene)):
        gt, ps = scene.gt_labels(i), scene.pseudo_labels(i)
        for g in np.unique(gt.segment[gt.segment > 0]):
            ids_of.setdefault(int(g), []).append(_majority(ps.segment[gt.segment == g]))
    same = pairs = 0
    for ids in ids_of.values():
        ids = [x for x in ids if x != 0]
        for a in range(len(ids)):
            for b in range(a + 1, len(ids)):
                pairs += 1
                same += ids[a] == ids[b]
    assert pairs > 50 and same / pairs < 0.02


def test_clean_noise_is_gt_up_to_renaming(tmp_path):
    make_scene(tmp_path / "c", kind="outdoor", noise="clean", n_views=3, width=48, height=32, progress=False)
    scene = load_scene(tmp_path / "c")
    renamed = 0
    for i in range(len(scene)):
        gt, ps = scene.gt_labels(i), scene.pseudo_labels(i)
        assert np.array_equal(gt.semantic, ps.semantic)
        pairs = np.unique(np.stack([gt.segment.ravel(), ps.segment.ravel()]), axis=1)
        # A bijection between GT and pseudo segment ids: each id pairs with exactly one of the other.
        assert len(np.unique(pairs[0])) == len(np.unique(pairs[1])) == pairs.shape[1]
        renamed += int(np.sum(pairs[0] != pairs[1]))
        assert all(s.score == 1.0 for s in scene.frames[i].segments.values())
    assert renamed > 0, "pseudo ids are per-frame ids, not the GT ids"


def _run(frames, config: NoiseConfig, repeats: int = 1, confusable=OUTDOOR_CONFUSABLE):
    from lift3d.synth.geometry import OUTDOOR_CATEGORIES

    outs = []
    for r in range(repeats):
        for k, (seg, cats) in enumerate(frames):
            out = simulate_segmenter(seg, cats, OUTDOOR_CATEGORIES, confusable, config,
                                     np.random.default_rng([r, k]))
            outs.append((seg, cats, out))
    return outs


def _thing_outcomes(outs, min_area: int = 6):
    """Per visible GT thing: the share of its pixels that keep its class, and the majority pseudo class."""
    from lift3d.synth.geometry import OUTDOOR_CATEGORIES

    thing = {c.id for c in OUTDOOR_CATEGORIES if c.isthing}
    keep, major = [], []
    for seg, cats, out in outs:
        sem = np.zeros(seg.shape, np.int64)
        for s in out.segments:
            sem[out.panoptic == s.id] = s.category_id
        for g in np.unique(seg):
            if g == 0 or cats[int(g)] not in thing or np.sum(seg == g) < min_area:
                continue
            m = seg == g
            keep.append(np.mean(sem[m] == cats[int(g)]))
            major.append((cats[int(g)], _majority(sem[m])))
    return np.asarray(keep), major


def test_missed_instances_at_the_requested_rate(outdoor_gt):
    outs = _run(outdoor_gt, NoiseConfig(p_miss=0.3, p_miss_void=1.0), repeats=3)
    keep, _ = _thing_outcomes(outs)
    assert len(keep) > 300
    assert abs(np.mean(keep < 0.5) - 0.3) < 0.07
    counts = sum(o.counts["missed"] for _, _, o in outs) / sum(o.counts["gt_things"] for _, _, o in outs)
    assert abs(counts - 0.3) < 0.05


def test_class_confusion_rate_and_plausibility(outdoor_gt):
    outs = _run(outdoor_gt, NoiseConfig(p_confuse=0.3, p_cross_kind=0.0), repeats=3)
    keep, major = _thing_outcomes(outs)
    wrong = [(g, p) for g, p in major if g != p]
    assert abs(len(wrong) / len(major) - 0.3) < 0.07
    assert all(p in OUTDOOR_CONFUSABLE[g] for g, p in wrong), "thing confusions stay plausible"


def test_merge_and_split():
    cats = [Category(1, "floor", False), Category(2, "chair", True)]
    seg = np.ones((64, 64), np.int64)
    seg[10:40, 8:30] = 101
    seg[10:40, 30:52] = 102  # touches 101
    table = {1: 1, 101: 2, 102: 2}
    merged = simulate_segmenter(seg, table, cats, {}, NoiseConfig(p_merge=1.0), np.random.default_rng(0))
    assert len(np.unique(merged.panoptic[seg > 1])) == 1 and merged.counts["merged"] == 1
    apart = simulate_segmenter(seg, table, cats, {}, NoiseConfig(p_merge=0.0), np.random.default_rng(0))
    assert len(np.unique(apart.panoptic[seg > 1])) == 2
    split = simulate_segmenter(seg, table, cats, {}, NoiseConfig(p_split=1.0), np.random.default_rng(0))
    for g in (101, 102):
        ids, n = np.unique(split.panoptic[seg == g], return_counts=True)
        assert len(ids) == 2 and n.min() > 0.2 * n.sum()
    by_id = {s.id: s for s in split.segments}
    assert all(by_id[i].score <= 0.8 for i in np.unique(split.panoptic[seg > 1]))


def test_boundary_abstention_and_spurious():
    cats = [Category(1, "wall", False), Category(2, "ball", True)]
    seg = np.ones((128, 128), np.int64)
    seg[30:90, 30:90] = 101
    table = {1: 1, 101: 2}
    rng = np.random.default_rng(0)
    # Boundary shifts: the ball's area changes from frame to frame, both ways around the true 60x60.
    areas = []
    for _ in range(20):
        out = simulate_segmenter(seg, table, cats, {}, NoiseConfig(boundary_px=3), rng)
        ball = next(s.id for s in out.segments if s.category_id == 2)
        areas.append(int(np.sum(out.panoptic == ball)))
    assert len(set(areas)) > 3 and min(areas) < 3600 < max(areas)
    void = [np.mean(simulate_segmenter(seg, table, cats, {}, NoiseConfig(p_boundary_void=1.0), rng).panoptic == 0)
            for _ in range(3)]
    assert all(v > 0.01 for v in void)
    n_spurious = [simulate_segmenter(seg, table, cats, {}, NoiseConfig(spurious_per_frame=2.0), rng).counts["spurious"]
                  for _ in range(200)]
    assert abs(np.mean(n_spurious) - 2.0) < 0.3


def test_presets_rates_scores_and_miou(outdoor_gt):
    from lift3d.synth.geometry import OUTDOOR_CATEGORIES

    miou = {}
    for name in ("moderate", "hard"):
        cfg = PRESETS[name]
        stats = NoiseStats(OUTDOOR_CATEGORIES)
        for seg, cats, out in _run(outdoor_gt, cfg, repeats=3):
            gt_sem = np.vectorize(lambda g: cats.get(int(g), 0))(seg)
            sem = np.zeros(seg.shape, np.int64)
            for s in out.segments:
                sem[out.panoptic == s.id] = s.category_id
            stats.add(out.counts, gt_sem, sem)
            assert len({s.id for s in out.segments}) == len(out.segments)
            assert all(1 <= s.id <= 65535 and 0 <= s.score <= 1 for s in out.segments)
        summary = stats.summary()
        rates = summary["rates"]
        assert abs(rates["missed"] - cfg.p_miss) < 0.04
        assert abs(rates["confused"] - cfg.p_confuse) < 0.05
        assert abs(rates["merged"] - cfg.p_merge) < 0.1
        assert summary["mean_score"]["correct"] > summary["mean_score"]["corrupted"] + 0.15
        miou[name] = summary["semantic_miou"]
    assert 0.5 < miou["moderate"] < 0.9
    assert miou["hard"] < miou["moderate"] - 0.05


def test_noise_is_deterministic_per_seed(outdoor_gt):
    from lift3d.synth.geometry import OUTDOOR_CATEGORIES

    seg, cats = outdoor_gt[0]
    runs = [simulate_segmenter(seg, cats, OUTDOOR_CATEGORIES, OUTDOOR_CONFUSABLE, PRESETS["hard"],
                               np.random.default_rng(s)) for s in (1, 1, 2)]
    assert np.array_equal(runs[0].panoptic, runs[1].panoptic) and runs[0].segments == runs[1].segments
    assert not np.array_equal(runs[0].panoptic, runs[2].panoptic)


def test_indoor_confusion_table_is_consistent():
    from lift3d.synth.geometry import INDOOR_CATEGORIES

    kind = {c.id: c.isthing for c in INDOOR_CATEGORIES}
    for c, similar in INDOOR_CONFUSABLE.items():
        assert similar and all(kind[s] == kind[c] and s != c for s in similar)


# --------------------------------------------------------------------------------------------- CLI
def test_cli_writes_a_scene_and_prints_noise_statistics(tmp_path, capsys):
    rc = cli_main(["synth", "--out", str(tmp_path / "s"), "--views", "3", "--width", "24", "--height", "16",
                   "--kind", "outdoor", "--noise", "hard", "--seed", "4"])
    out = capsys.readouterr().out
    assert rc == 0
    assert "missed" in out and "mIoU" in out and "synth_noise.json" in out
    scene = load_scene(tmp_path / "s")
    assert len(scene) == 3 and scene.cameras.width[0] == 24 and scene.cameras.height[0] == 16
    assert json.loads((tmp_path / "s" / "transforms.json").read_text())["lift3d_synth"]["noise"] == "hard"


def test_cli_bad_input_is_one_line_exit_2(tmp_path, capsys):
    assert cli_main(["synth", "--out", str(tmp_path / "s"), "--views", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--views" in err
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "x").write_text("x")
    assert cli_main(["synth", "--out", str(tmp_path / "busy"), "--views", "2"]) == 2
    assert "not empty" in capsys.readouterr().err
