"""The simulated 2D segmenter (independent and view-correlated errors, scores) and the sensor models (depth,
poses) of ``lift3d synth``: their statistics on small inputs."""

from __future__ import annotations

import numpy as np
import pytest

from lift3d.data.scene import Category, load_scene
from lift3d.synth import SynthOptions, make_scene
from lift3d.synth.noise import (
    PRESETS,
    Confuser,
    NoiseConfig,
    NoiseStats,
    ViewConfusers,
    simulate_segmenter,
)
from lift3d.synth.outdoor import OUTDOOR_CATEGORIES, OUTDOOR_CONFUSABLE
from lift3d.synth.sensors import DepthSensor, perturb_poses, pose_error


# --------------------------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def outdoor_gt(tmp_path_factory) -> list[tuple[np.ndarray, dict[int, int]]]:
    """GT panoptic maps of a small street (many things per frame) with their segment → category tables."""
    root = tmp_path_factory.mktemp("synth_noise") / "outdoor"
    make_scene(root, SynthOptions(kind="outdoor", seed=5, noise="clean", n_views=14, width=64, height=48),
               progress=False)
    scene = load_scene(root)
    frames = []
    for i in range(len(scene)):
        gt = scene.gt_labels(i)
        table = {s.id: s.category_id for s in scene.frames[i].gt_segments.values()}
        frames.append((gt.segment.astype(np.int64), table))
    return frames


def _majority(values: np.ndarray) -> int:
    ids, counts = np.unique(values, return_counts=True)
    return int(ids[np.argmax(counts)])


def _run(frames, config: NoiseConfig, repeats: int = 1, confusable=OUTDOOR_CONFUSABLE):
    outs = []
    for r in range(repeats):
        for k, (seg, cats) in enumerate(frames):
            out = simulate_segmenter(seg, cats, OUTDOOR_CATEGORIES, confusable, config, np.random.default_rng([r, k]))
            outs.append((seg, cats, out))
    return outs


def _semantic(out) -> np.ndarray:
    sem = np.zeros(out.panoptic.shape, np.int64)
    for s in out.segments:
        sem[out.panoptic == s.id] = s.category_id
    return sem


def _thing_outcomes(outs, min_area: int = 6):
    """Per visible GT thing: the share of its pixels that keep its class, and (GT class, majority pseudo class)."""
    thing = {c.id for c in OUTDOOR_CATEGORIES if c.isthing}
    keep, major = [], []
    for seg, cats, out in outs:
        sem = _semantic(out)
        for g in np.unique(seg):
            if g == 0 or cats[int(g)] not in thing or np.sum(seg == g) < min_area:
                continue
            m = seg == g
            keep.append(np.mean(sem[m] == cats[int(g)]))
            major.append((cats[int(g)], _majority(sem[m])))
    return np.asarray(keep), major


# --------------------------------------------------------------------------------------------- independent errors
def test_pseudo_ids_differ_across_views(tmp_path):
    make_scene(tmp_path / "s", SynthOptions(kind="indoor", seed=3, n_views=10, width=48, height=48), progress=False)
    scene = load_scene(tmp_path / "s")
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
    make_scene(tmp_path / "c", SynthOptions(kind="outdoor", noise="clean", n_views=3, width=48, height=32),
               progress=False)
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
    assert list(PRESETS) == ["clean", "moderate", "hard", "view-correlated"]
    miou = {}
    for name in ("moderate", "hard"):
        cfg = PRESETS[name]
        stats = NoiseStats(OUTDOOR_CATEGORIES)
        for seg, cats, out in _run(outdoor_gt, cfg, repeats=3):
            gt_sem = np.vectorize(lambda g: cats.get(int(g), 0))(seg)
            stats.add(out.counts, gt_sem, _semantic(out))
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
    seg, cats = outdoor_gt[0]
    runs = [simulate_segmenter(seg, cats, OUTDOOR_CATEGORIES, OUTDOOR_CONFUSABLE, PRESETS["hard"],
                               np.random.default_rng(s)) for s in (1, 1, 2)]
    assert np.array_equal(runs[0].panoptic, runs[1].panoptic) and runs[0].segments == runs[1].segments
    assert not np.array_equal(runs[0].panoptic, runs[2].panoptic)


def test_bad_noise_configurations_are_named():
    assert NoiseConfig().problems() == [] and all(not c.problems() for c in PRESETS.values())
    fields = [f for f, _ in NoiseConfig(p_merge=-0.2, spurious_per_frame=-1, score_informativeness=2.0,
                                        score_correct=(0.9, 0.5)).problems()]
    assert fields == ["p_merge", "score_informativeness", "spurious_per_frame", "score_correct"]


# --------------------------------------------------------------------------------------------- scores
def test_score_informativeness(outdoor_gt):
    base = NoiseConfig(p_confuse=0.3, p_split=0.2, boundary_px=1)
    gaps = {}
    for s_inf in (0.0, 0.5, 1.0):
        stats = NoiseStats(OUTDOOR_CATEGORIES)
        for seg, cats, out in _run(outdoor_gt, NoiseConfig(**{**base.to_json(), "score_informativeness": s_inf}),
                                   repeats=2):
            stats.add(out.counts, np.zeros(seg.shape, np.int64), np.zeros(seg.shape, np.int64))
        m = stats.summary()["mean_score"]
        gaps[s_inf] = m["correct"] - m["corrupted"]
    assert abs(gaps[0.0]) < 0.03, "scores drawn independently of correctness"
    assert gaps[1.0] > 0.2 and 0.5 * gaps[1.0] - 0.05 < gaps[0.5] < 0.5 * gaps[1.0] + 0.05


# --------------------------------------------------------------------------------------------- view-correlated
def _ring(n: int = 72, radius: float = 3.0) -> np.ndarray:
    ang = 2 * np.pi * np.arange(n) / n
    return np.column_stack([radius * np.cos(ang), radius * np.sin(ang), np.full(n, 1.5)])


def test_view_confuser_cone_holds_its_share_of_the_views():
    eyes = _ring()
    cfg = NoiseConfig(view_confusion=1.0, view_win=1.0, view_share=0.25)
    conf = ViewConfusers.build([(1001, 6, np.zeros(3))], {}, lambda p: np.ones((len(p), len(eyes)), bool), eyes,
                               {6: [7]}, cfg, np.random.default_rng(0))
    (c,) = conf.confusers
    assert c.category == 7 and c.is_thing
    wins = np.array([c.sees(e) for e in eyes])
    assert abs(wins.mean() - 0.25) < 0.03
    # One contiguous arc of directions: nearby views agree, the opposite side is never confused.
    assert np.sum(wins != np.roll(wins, 1)) == 2
    axis_view = int(np.argmax(eyes @ c.axis))
    assert wins[axis_view] and not wins[(axis_view + len(eyes) // 2) % len(eyes)]


def test_view_confuser_repeats_across_frames():
    """A thing seen from a ring of cameras is read as its confuser in the same views every time, and only
    there; without ``view_confusion`` nothing changes."""
    cats = [Category(1, "wall", False), Category(6, "car", True), Category(7, "van", True)]
    seg = np.ones((32, 32), np.int64)
    seg[8:24, 8:24] = 1001
    xyz = np.zeros((32, 32, 3))
    eyes = _ring(36)
    cfg = NoiseConfig(view_confusion=1.0, view_win=1.0, view_share=0.3)
    conf = ViewConfusers.build([(1001, 6, np.zeros(3))], {}, lambda p: np.ones((len(p), len(eyes)), bool), eyes,
                               {6: [7]}, cfg, np.random.default_rng(3))
    labels = []
    for rep in range(2):
        row = []
        for k, eye in enumerate(eyes):
            errs = conf.for_view(seg, np.where(seg > 1000, 6, 1), xyz, eye, np.random.default_rng([rep, k]))
            out = simulate_segmenter(seg, {1: 1, 1001: 6}, cats, {6: [7]}, cfg, np.random.default_rng([rep, k, 1]),
                                     view_errors=errs)
            row.append(_majority(_semantic(out)[seg == 1001]))
        labels.append(row)
    labels = np.array(labels)
    assert np.array_equal(labels[0], labels[1]), "the same views are wrong every time"
    wrong = labels[0] == 7
    assert 0.2 < wrong.mean() < 0.4 and set(labels[0]) == {6, 7}
    assert np.sum(wrong != np.roll(wrong, 1)) == 2, "wrong in one range of directions"
    off = ViewConfusers(conf.confusers, NoiseConfig(view_confusion=0.0))
    assert not off.for_view(seg, np.where(seg > 1000, 6, 1), xyz, eyes[0], np.random.default_rng(0)).things


def test_view_confused_stuff_patch_is_local():
    cats = [Category(1, "floor", False), Category(2, "rug", False)]
    seg = np.ones((40, 40), np.int64)
    xs, ys = np.meshgrid(np.linspace(-2, 2, 40), np.linspace(-2, 2, 40))
    xyz = np.stack([xs, ys, np.zeros_like(xs)], -1)
    patch = Confuser(1, 2, np.zeros(3), np.array([0.0, 0.0, 1.0]), 60.0, 0.5, 0.0)
    conf = ViewConfusers([patch], NoiseConfig(view_confusion=1.0, view_win=1.0))
    above = conf.for_view(seg, seg, xyz, np.array([0.0, 0.5, 2.0]), np.random.default_rng(0))
    aside = conf.for_view(seg, seg, xyz, np.array([3.0, 0.0, 0.2]), np.random.default_rng(0))
    assert aside.stuff is None
    inside = np.linalg.norm(xyz[..., :2], axis=-1) <= 0.5
    assert np.array_equal(above.stuff == 2, inside)
    out = simulate_segmenter(seg, {1: 1}, cats, {1: [2]}, NoiseConfig(), np.random.default_rng(0), view_errors=above)
    assert np.array_equal(_semantic(out) == 2, inside) and out.counts["view_confused_patches"] == 1


def test_view_correlated_scene_repeats_its_mistakes(tmp_path):
    """In a written scene, a thing's wrong class under view-correlated noise alone is one class, and the frames
    where it is wrong look at it from directions close to each other."""
    cfg = NoiseConfig("view-only", view_confusion=1.0, view_win=1.0, view_share=0.4)
    make_scene(tmp_path / "v",
               SynthOptions(kind="indoor", seed=1, noise=cfg, n_views=24, width=48, height=48, camera_path="orbit"),
               progress=False)
    scene = load_scene(tmp_path / "v")
    per_thing: dict[int, list[tuple[int, int, int]]] = {}
    for i in range(len(scene)):
        gt, ps = scene.gt_labels(i), scene.pseudo_labels(i)
        for g in np.unique(gt.instance[gt.instance > 0]):
            m = gt.instance == g
            if m.sum() >= 20:
                per_thing.setdefault(int(g), []).append((i, int(gt.semantic[m][0]), _majority(ps.semantic[m])))
    wrong_things = 0
    for g, rows in per_thing.items():
        wrong = {p for _, c, p in rows if p != c}
        assert len(wrong) <= 1, f"thing {g} is read as one wrong class, not {wrong}"
        if wrong and len(rows) >= 4:
            wrong_things += 1
            assert any(p == c for _, c, p in rows), "from other directions it is right"
    assert wrong_things >= 2


def test_view_correlated_preset_is_harder_than_moderate(tmp_path):
    kw = dict(kind="indoor", seed=1, n_views=24, width=48, height=48)
    m = make_scene(tmp_path / "m", SynthOptions(noise="moderate", **kw), progress=False)["noise"]
    v = make_scene(tmp_path / "v", SynthOptions(noise="view-correlated", **kw), progress=False)["noise"]
    assert m["rates"]["view_confused_things"] == 0 and v["rates"]["view_confused_things"] > 0.05
    assert v["semantic_miou"] < m["semantic_miou"] - 0.03
    assert v["mean_score"]["correct"] - v["mean_score"]["corrupted"] < m["mean_score"]["correct"] - \
        m["mean_score"]["corrupted"] - 0.1, "view-correlated scores say less about correctness"


# --------------------------------------------------------------------------------------------- depth sensor
def test_depth_noise_follows_sigma_of_z():
    sensor = DepthSensor(random_holes=(0.0, 0.0))
    rng = np.random.default_rng(0)
    stds = {}
    for z in (0.8, 2.0, 4.0):
        noisy, _ = sensor.apply(np.full((200, 200), z), rng)
        stds[z] = float(np.std(noisy[noisy > 0] - z))
        assert abs(stds[z] - sensor.sigma(z)) < 0.1 * sensor.sigma(z) + 0.0005, (z, stds[z])
    assert stds[0.8] < stds[2.0] < stds[4.0], "noise grows with depth"
    assert sensor.sigma(0.4) == pytest.approx(0.0012) and sensor.sigma(1.4) == pytest.approx(0.0031)


def test_depth_is_quantised_to_millimetres():
    noisy, _ = DepthSensor().apply(np.random.default_rng(1).uniform(0.5, 5.0, (64, 64)), np.random.default_rng(2))
    mm = noisy[noisy > 0] * 1000.0
    assert np.allclose(mm, np.round(mm), atol=1e-6)


def test_depth_holes_concentrate_at_depth_edges():
    # A step: a box at 1 m in front of a wall at 3 m; the far side of the step is the shadow band.
    depth = np.full((128, 128), 3.0)
    depth[32:96, 32:96] = 1.0
    sensor = DepthSensor()
    band = sensor.edges(depth)
    assert band.any() and np.all(depth[band] == 3.0), "the band lies on the far side"
    holes = []
    for seed in range(5):
        noisy, stats = sensor.apply(depth, np.random.default_rng(seed))
        holes.append(noisy == 0)
        assert 0.02 <= stats["random_holes"] <= 0.045
    hole = np.mean(holes, axis=0)
    assert hole[band].mean() > 0.7, "most of the band is missing"
    far = ~band
    assert hole[far].mean() < 0.05, "elsewhere only the random few percent"
    assert hole[band].mean() > 10 * hole[far].mean()
    # Beyond the sensor's range there is no depth.
    noisy, stats = sensor.apply(np.full((16, 16), 12.0), np.random.default_rng(0))
    assert np.all(noisy == 0) and stats["out_of_range"] == 1.0


def test_sensor_depth_in_a_written_scene(tmp_path):
    rep = make_scene(tmp_path / "s", SynthOptions(kind="indoor", seed=2, n_views=4, width=64, height=64),
                     progress=False)
    scene = load_scene(tmp_path / "s")
    assert 0.02 < rep["depth"]["holes"] < 0.2 and rep["depth"]["edge_holes"] > 0
    for i in range(len(scene)):
        d, g = scene.depth(i), scene.gt_depth(i)
        ok = (d > 0) & (g > 0)
        err = d[ok] - g[ok]
        assert np.mean(d == 0) > np.mean(g == 0) + 0.01, "the sensor has holes"
        assert np.abs(np.median(err)) < 0.003
        assert np.mean(np.abs(err) < 4 * DepthSensor().sigma(g[ok]) + 0.001) > 0.99
        assert np.std(err) > 0.0005, "and noise"


# --------------------------------------------------------------------------------------------- poses
def test_pose_noise_statistics():
    c2w = np.repeat(np.eye(4)[None], 3000, axis=0)
    c2w[:, :3, 3] = np.random.default_rng(0).normal(size=(3000, 3))
    noisy = perturb_poses(c2w, 1.0, 5.0, np.random.default_rng(1))
    rot, trans = pose_error(c2w, noisy)
    assert abs(np.sqrt(np.mean(rot**2)) - 1.0) < 0.05 and abs(np.sqrt(np.mean(trans**2)) - 0.05) < 0.003
    rr = noisy[:, :3, :3]
    assert np.allclose(np.einsum("nji,njk->nik", rr, rr), np.eye(3), atol=1e-9) and np.allclose(np.linalg.det(rr), 1)


def test_pose_noise_in_a_written_scene(tmp_path):
    kw = dict(kind="indoor", seed=6, n_views=6, width=32, height=32)
    rep = make_scene(tmp_path / "p", SynthOptions(pose_noise=(1.0, 4.0), **kw), progress=False)
    make_scene(tmp_path / "q", SynthOptions(**kw), progress=False)
    noisy, clean = load_scene(tmp_path / "p"), load_scene(tmp_path / "q")
    true = np.stack([f.gt_c2w for f in noisy.frames])
    assert np.allclose(true, clean.cameras.c2w), "the true poses are kept"
    rot, trans = pose_error(true, noisy.cameras.c2w)
    assert np.all(rot > 0) and np.all(trans > 0)
    assert rep["pose_noise"]["rms_cm"] == pytest.approx(100 * np.sqrt(np.mean(trans**2)), abs=1e-3)
    for i in range(len(noisy)):  # rendered from the true poses
        assert np.array_equal(noisy.image(i), clean.image(i))
