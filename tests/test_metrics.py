"""Tests of lift3d.eval.metrics: PQ^scene, mIoU, confusion matrix, PSNR, depth errors."""

from __future__ import annotations

import json
import math
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from lift3d.eval import confusion_matrix, depth_error, miou, pq_scene, psnr
from lift3d.eval.metrics import benchmark_pq_scene, psnr_per_image

FIXTURES = Path(__file__).resolve().parent / "fixtures" / "pq_scene_cases"  # see fixtures/README.md
CASES = sorted(FIXTURES.glob("case_*.npz"))
F32 = 1e-6  # the reference computes per-segment IoU in float32


def _load(path):
    d = np.load(path)
    ref = json.loads(path.with_suffix(".json").read_text())
    return d, ref


# --------------------------------------------------------------------------- fixtures


def test_fixture_cases_exist():
    assert len(CASES) > 0, f"no fixture cases found in {FIXTURES}"
    for c in CASES:
        assert c.with_suffix(".json").exists(), f"{c} has no reference json"


@pytest.mark.parametrize("min_area", [0.005, 0.0])
@pytest.mark.parametrize("case", CASES, ids=[c.stem for c in CASES])
def test_fixture_agrees_with_panoptic_lifting(case, min_area):
    d, ref = _load(case)
    exp = ref[f"robust_{min_area}"]
    things = set(d["things"].tolist())
    stuff = set(d["stuff"].tolist())
    r = pq_scene(d["pred_sem"], d["pred_inst"], d["gt_sem"], d["gt_inst"], things, stuff, min_area=min_area)
    m = miou(d["pred_sem"], d["gt_sem"], min_area=min_area)
    for k in ("pq", "sq", "rq"):
        assert abs(r[k] - exp[k]) <= 1e-6, (k, r[k], exp[k])
    assert abs(m["miou"] - exp["miou"]) <= 1e-6, (m["miou"], exp["miou"])


# --------------------------------------------------------------------------- naive reference


def naive_pq(ps, pi, gs, gi, things, stuff, min_area=0.005, void=0):
    """The rules of docs/metrics.md, written pixel by pixel (slow, obviously correct)."""
    P, G = [], []
    for a, b, c, d in zip(ps.ravel().tolist(), pi.ravel().tolist(), gs.ravel().tolist(), gi.ravel().tolist()):
        if c != void:
            P.append((a, b))
            G.append((c, d))
    n = len(P)
    pc, gc = Counter(c for c, _ in P), Counter(c for c, _ in G)
    kept = {c for c in things | stuff if c in pc or c in gc}
    if min_area > 0:
        thr, tot = np.float32(min_area), np.float32(n)
        small = {c for c in kept if (c in pc and np.float32(pc[c]) / tot < thr) or (c in gc and np.float32(gc[c]) / tot < thr)}
        kept -= small

    def seg(c, i):
        if c not in kept:
            return None  # void
        return (c, i if c in things else 0)

    P = [seg(*x) for x in P]
    G = [seg(*x) for x in G]
    ap, ag, inter = Counter(P), Counter(G), Counter(zip(P, G))
    stats = {c: dict(iou=0.0, tp=0, fp=0, fn=0) for c in kept}
    mp, mg = set(), set()
    for (p, g), i in inter.items():
        if p is None or g is None or p[0] != g[0]:
            continue
        union = ap[p] - inter.get((p, None), 0) + ag[g] - inter.get((None, g), 0) - i
        iou = np.float32(i) / np.float32(union)
        if iou > 0.5:
            mp.add(p)
            mg.add(g)
            stats[g[0]]["iou"] += float(iou)
            stats[g[0]]["tp"] += 1
    for g in ag:
        if g is not None and g not in mg and not np.float32(inter.get((None, g), 0)) / np.float32(ag[g]) > 0.5:
            stats[g[0]]["fn"] += 1
    for p in ap:
        if p is not None and p not in mp and not np.float32(inter.get((p, None), 0)) / np.float32(ap[p]) > 0.5:
            stats[p[0]]["fp"] += 1
    pq, sq, rq = [], [], []
    for s in stats.values():
        den = s["tp"] + 0.5 * s["fp"] + 0.5 * s["fn"]
        pq.append(s["iou"] / den if den else 0.0)
        sq.append(s["iou"] / s["tp"] if s["tp"] else 0.0)
        rq.append(s["tp"] / den if den else 0.0)
    mean = lambda v: float(np.mean(v)) if v else float("nan")  # noqa: E731
    return dict(pq=mean(pq), sq=mean(sq), rq=mean(rq), n_classes=len(stats), stats=stats)


def _random_case(seed, frames=3, size=12):
    rng = np.random.default_rng(seed)
    coarse = lambda hi: np.kron(rng.integers(0, hi, (frames, 4, 4)), np.ones((1, size // 4, size // 4), int))  # noqa: E731
    gs = coarse(6)  # 0 = void, 1-3 things, 4-5 stuff
    gi = coarse(3)
    ps, pi = gs.copy(), gi.copy()
    # perturb: class confusions, extra / wrong instances, classes outside things ∪ stuff, pred void
    flip = rng.random(gs.shape) < 0.15
    ps[flip] = rng.integers(0, 8, flip.sum())
    jump = rng.random(gs.shape) < 0.1
    pi[jump] = rng.integers(0, 5, jump.sum())
    if seed % 2:
        pi[1] = (pi[1] + 1) % 4  # inconsistent ids in one frame
    return ps, pi, gs, gi


@pytest.mark.parametrize("min_area", [0.0, 0.005, 0.03, 0.08])
@pytest.mark.parametrize("seed", range(12))
def test_matches_naive_rules_on_random_cases(seed, min_area):
    ps, pi, gs, gi = _random_case(seed)
    things, stuff = {1, 2, 3}, {4, 5}
    r = pq_scene(ps, pi, gs, gi, things, stuff, min_area=min_area)
    e = naive_pq(ps, pi, gs, gi, things, stuff, min_area=min_area)
    assert r["n_classes"] == e["n_classes"]
    for k in ("pq", "sq", "rq"):
        assert r[k] == pytest.approx(e[k], abs=1e-12, nan_ok=True)
    for c, s in e["stats"].items():
        got = r["per_class"][c]
        assert (got["tp"], got["fp"], got["fn"]) == (s["tp"], s["fp"], s["fn"])
        assert got["iou_sum"] == pytest.approx(s["iou"], abs=1e-12)


def test_random_cases_exercise_class_dropping():
    """Guard that the random sweep above really covers the min_area filter."""
    dropped = 0
    for seed in range(12):
        ps, pi, gs, gi = _random_case(seed)
        dropped += len(pq_scene(ps, pi, gs, gi, {1, 2, 3}, {4, 5}, min_area=0.08)["dropped_classes"])
    assert dropped > 0


# --------------------------------------------------------------------------- hand-made PQ cases


def _scene_two_things():
    """3 frames 10×12: stuff 4 background, thing 1 with ids 7 and 8, stuff 5 strip, a void corner."""
    gs = np.full((3, 10, 12), 4)
    gi = np.zeros_like(gs)
    gs[:, 1:4, 1:4] = 1
    gi[:, 1:4, 1:4] = 7
    gs[:, 5:9, 6:10] = 1
    gi[:, 5:9, 6:10] = 8
    gs[:, 9, :] = 5
    gs[:, 0, 10:] = 0
    return gs, gi


def test_perfect_prediction():
    gs, gi = _scene_two_things()
    # consistently renamed instance ids are still a perfect prediction
    pi = np.where(gi == 7, 100, np.where(gi == 8, 3, 0))
    r = pq_scene(gs.copy(), pi, gs, gi, things={1}, stuff={4, 5})
    assert (r["pq"], r["sq"], r["rq"]) == (1.0, 1.0, 1.0)
    assert r["things"]["pq"] == 1.0 and r["stuff"]["pq"] == 1.0
    assert r["per_class"][1]["tp"] == 2 and r["per_class"][1]["fp"] == 0 and r["per_class"][1]["fn"] == 0
    assert r["n_classes"] == 3


def _box_scene(shift):
    """10×10 stuff 2; GT thing 1 = 4×4 box; prediction = the box shifted by `shift` columns."""
    gs = np.full((10, 10), 2)
    gi = np.zeros_like(gs)
    gs[2:6, 2:6] = 1
    gi[2:6, 2:6] = 1
    ps = np.full((10, 10), 2)
    pi = np.zeros_like(ps)
    ps[2:6, 2 + shift : 6 + shift] = 1
    pi[2:6, 2 + shift : 6 + shift] = 5
    return ps, pi, gs, gi


def test_shifted_thing_known_iou():
    ps, pi, gs, gi = _box_scene(1)  # intersection 12, union 20 -> IoU 0.6
    r = pq_scene(ps, pi, gs, gi, things={1}, stuff={2}, min_area=0)
    stuff_iou = 80 / 88  # 100 - 20 outside both boxes, 84 + 84 - 80
    assert r["per_class"][1]["pq"] == pytest.approx(0.6, abs=F32)
    assert r["per_class"][2]["pq"] == pytest.approx(stuff_iou, abs=F32)
    assert r["pq"] == pytest.approx((0.6 + stuff_iou) / 2, abs=F32)
    assert r["rq"] == 1.0
    # shifted by 3: IoU 4/28 < 0.5 -> one FP and one FN, thing PQ 0
    r = pq_scene(*_box_scene(3), things={1}, stuff={2}, min_area=0)
    c1 = r["per_class"][1]
    assert (c1["tp"], c1["fp"], c1["fn"], c1["pq"]) == (0, 1, 1, 0.0)
    assert r["pq"] == pytest.approx((0 + 72 / 96) / 2, abs=F32)
    assert r["things"]["pq"] == 0.0 and r["stuff"]["pq"] == pytest.approx(0.75, abs=F32)


def test_iou_exactly_half_is_not_a_match():
    gs2 = np.zeros((4, 4), int)
    gs2[:, :] = 1
    gi2 = np.ones_like(gs2)
    ps2 = gs2.copy()
    pi2 = gi2.copy()
    pi2[:, 2:] = 2  # each half of the GT object is its own predicted segment: IoU 0.5 each
    r = pq_scene(ps2, pi2, gs2, gi2, things={1}, stuff=set(), min_area=0)
    assert r["per_class"][1]["tp"] == 0
    assert r["per_class"][1]["fp"] == 2 and r["per_class"][1]["fn"] == 1


def test_permuted_instance_ids_across_frames_are_different_segments():
    gs, gi = _scene_two_things()
    consistent = pq_scene(gs.copy(), gi.copy(), gs, gi, things={1}, stuff={4, 5})
    assert consistent["per_class"][1]["tp"] == 2
    # per-frame ids: object 7 is called 1, 2, 3 in the three frames, object 8 is 11, 12, 13
    pi = gi.copy()
    for f in range(3):
        pi[f][gi[f] == 7] = 1 + f
        pi[f][gi[f] == 8] = 11 + f
    r = pq_scene(gs.copy(), pi, gs, gi, things={1}, stuff={4, 5})
    c1 = r["per_class"][1]
    assert (c1["tp"], c1["fp"], c1["fn"]) == (0, 6, 2)  # each piece covers 1/3 of its object
    assert c1["pq"] == 0.0
    assert r["pq"] == pytest.approx(2 / 3)  # the two stuff classes are still perfect


def test_swapped_ids_between_frames_mix_objects():
    gs, gi = _scene_two_things()
    pi = gi.copy()
    # frame 2 swaps the two ids: each predicted segment is 2/3 of one object + 1/3 of the other
    pi[2][gi[2] == 7] = 8
    pi[2][gi[2] == 8] = 7
    r = pq_scene(gs.copy(), pi, gs, gi, things={1}, stuff={4, 5}, min_area=0)
    c1 = r["per_class"][1]
    # object 7 (9 px/frame) vs pred 7 (2 frames of object 7 + 1 frame of object 8 = 18 + 16): IoU 18/43
    # object 8 (16 px/frame) vs pred 8 (32 + 9): IoU 32/57 = 0.561 -> match; object 7 is a FN, pred 7 a FP
    assert c1["tp"] == 1 and c1["fn"] == 1 and c1["fp"] == 1
    assert c1["iou_sum"] == pytest.approx(32 / 57, abs=F32)


def test_stuff_instance_ids_are_ignored():
    gs, gi = _scene_two_things()
    rng = np.random.default_rng(0)
    noisy_gt_inst = gi.copy()
    stuff_pix = np.isin(gs, [4, 5])
    noisy_gt_inst[stuff_pix] = rng.integers(0, 50, stuff_pix.sum())
    pi = gi.copy()
    pi[stuff_pix] = rng.integers(0, 50, stuff_pix.sum())
    r = pq_scene(gs.copy(), pi, gs, noisy_gt_inst, things={1}, stuff={4, 5})
    assert r["pq"] == 1.0
    # the same labels with 4 declared a thing are far from perfect: the test can fail
    r = pq_scene(gs.copy(), pi, gs, noisy_gt_inst, things={1, 4}, stuff={5})
    assert r["per_class"][4]["pq"] < 0.5


def test_prediction_on_gt_void_is_ignored():
    gs, gi = _scene_two_things()
    ps, pi = gs.copy(), gi.copy()
    void = gs == 0
    ps[void] = 1  # a new thing segment entirely on GT void
    pi[void] = 99
    r = pq_scene(ps, pi, gs, gi, things={1}, stuff={4, 5})
    assert r["pq"] == 1.0 and r["per_class"][1]["fp"] == 0
    # the same predicted segment on valid GT background is a false positive
    ps2, pi2 = gs.copy(), gi.copy()
    ps2[:, 0, 6:8] = 1
    pi2[:, 0, 6:8] = 99
    r2 = pq_scene(ps2, pi2, gs, gi, things={1}, stuff={4, 5})
    assert r2["per_class"][1]["fp"] == 1


def test_predicted_void_and_the_special_union():
    ps, pi, gs, gi = _box_scene(0)
    # a quarter of the GT box predicted void: union = 12 - 0 + 16 - 4 - 12 = 12, IoU 1
    ps[2:6, 5] = 0
    pi[2:6, 5] = 0
    r = pq_scene(ps, pi, gs, gi, things={1}, stuff={2}, min_area=0)
    assert r["per_class"][1]["sq"] == 1.0 and r["per_class"][1]["tp"] == 1
    # a class outside things ∪ stuff is void as well
    ps[2:6, 5] = 7
    assert pq_scene(ps, pi, gs, gi, things={1}, stuff={2}, min_area=0)["per_class"][1]["sq"] == 1.0
    # ... while the same pixels predicted as stuff 2 are not: IoU 12/16
    ps[2:6, 5] = 2
    assert pq_scene(ps, pi, gs, gi, things={1}, stuff={2}, min_area=0)["per_class"][1]["sq"] == pytest.approx(0.75)


def test_gt_segment_mostly_predicted_void_is_not_a_false_negative():
    ps, pi, gs, gi = _box_scene(0)
    ps[2:6, 2:6] = 0  # the whole object predicted void
    r = pq_scene(ps, pi, gs, gi, things={1}, stuff={2}, min_area=0)
    c1 = r["per_class"][1]
    assert (c1["tp"], c1["fp"], c1["fn"]) == (0, 0, 0)
    assert c1["pq"] == 0.0  # kept class without TP/FP/FN still counts, as 0, in the mean
    assert r["n_classes"] == 2
    assert r["pq"] == 0.5 and r["rq"] == 0.5 and r["things"]["pq"] == 0.0
    ps[2:6, 2:4] = 2  # exactly half void (not more than half), the other half called stuff -> FN
    c1 = pq_scene(ps, pi, gs, gi, things={1}, stuff={2}, min_area=0)["per_class"][1]
    assert (c1["tp"], c1["fp"], c1["fn"]) == (0, 0, 1)
    ps[2:6, 2] = 0  # 12 of 16 void -> ignored again
    c1 = pq_scene(ps, pi, gs, gi, things={1}, stuff={2}, min_area=0)["per_class"][1]
    assert c1["fn"] == 0


def _tiny_class_scene():
    gs = np.full((40, 50), 2)
    gi = np.zeros_like(gs)
    gs[10:20, 10:20] = 1
    gi[10:20, 10:20] = 4
    ps, pi = gs.copy(), gi.copy()
    ps[0, :5] = 3  # 5 px = 0.25 % of stuff class 3 that the GT does not have
    return ps, pi, gs, gi


def test_tiny_spurious_class_dropped_at_min_area():
    ps, pi, gs, gi = _tiny_class_scene()
    r = pq_scene(ps, pi, gs, gi, things={1}, stuff={2, 3}, min_area=0.005)
    assert r["dropped_classes"] == [3]
    assert r["n_classes"] == 2
    assert r["pq"] == 1.0  # the 5 px become void: not FP, and out of the stuff union
    strict = pq_scene(ps, pi, gs, gi, things={1}, stuff={2, 3}, min_area=0.0)
    assert strict["dropped_classes"] == [] and strict["n_classes"] == 3
    assert strict["per_class"][3]["fp"] == 1
    assert strict["pq"] == pytest.approx((1 + 1895 / 1900 + 0) / 3, abs=F32)
    assert strict["rq"] == pytest.approx(2 / 3)
    # mIoU: class 3 is under 0.5 % in both prediction and GT -> ignored at 0.005, IoU 0 when strict
    assert miou(ps, gs, min_area=0.005)["miou"] == pytest.approx((1 + 1895 / 1900) / 2)
    assert miou(ps, gs, min_area=0.0)["miou"] == pytest.approx((1 + 1895 / 1900 + 0) / 3)


def test_prediction_on_dropped_gt_class_is_not_a_false_positive():
    ps, pi, gs, gi = _tiny_class_scene()
    ps, gs = gs.copy(), ps.copy()  # the GT has 5 px of stuff class 3 (0.25 %)
    ps[gs == 3] = 1  # ... and a thing segment is predicted exactly there
    pi[gs == 3] = 9
    r = pq_scene(ps, pi, gs, gi, things={1}, stuff={2, 3}, min_area=0.005)
    # class 3 is dropped, its GT pixels are void: the thing segment lies entirely on GT void
    assert r["dropped_classes"] == [3]
    assert r["per_class"][1]["fp"] == 0 and r["pq"] == 1.0
    strict = pq_scene(ps, pi, gs, gi, things={1}, stuff={2, 3}, min_area=0)
    assert strict["per_class"][1]["fp"] == 1 and strict["per_class"][3]["fn"] == 1


def test_small_class_in_gt_only_is_dropped_too():
    ps, pi, gs, gi = _tiny_class_scene()
    ps, gs = gs.copy(), ps.copy()  # now the GT has the tiny class and the prediction misses it
    r = pq_scene(ps, pi, gs, gi, things={1}, stuff={2, 3}, min_area=0.005)
    assert r["dropped_classes"] == [3] and r["pq"] == 1.0
    assert pq_scene(ps, pi, gs, gi, things={1}, stuff={2, 3}, min_area=0)["per_class"][3]["fn"] == 1


@pytest.mark.parametrize("dtype", [np.uint8, np.int8, np.uint16, np.int16, np.int32, np.uint32, np.int64])
def test_any_integer_dtype_gives_the_same_result(dtype):
    d, _ = _load(CASES[0]) if CASES else pytest.fail("no fixtures")
    args = [d[k] for k in ("pred_sem", "pred_inst", "gt_sem", "gt_inst")]
    things, stuff = set(d["things"].tolist()), set(d["stuff"].tolist())
    ref = pq_scene(*args, things, stuff)
    got = pq_scene(*[a.astype(dtype) for a in args], things, stuff)
    assert (got["pq"], got["sq"], got["rq"]) == (ref["pq"], ref["sq"], ref["rq"])
    assert got["per_class"] == ref["per_class"]
    assert miou(args[0].astype(dtype), args[2].astype(dtype))["miou"] == miou(args[0], args[2])["miou"]


def test_sparse_huge_ids_and_negative_instances():
    ps, pi, gs, gi = _random_case(3)
    things, stuff = {1, 2, 3}, {4, 5}
    ref = pq_scene(ps, pi, gs, gi, things, stuff, min_area=0)
    # instance ids far apart (np.unique path) and negative ids give the same segments
    big = pq_scene(ps, pi * 1_000_000_007, gs, gi.astype(np.int64) * 999_999_937 - 5, things, stuff, min_area=0)
    assert (big["pq"], big["sq"], big["rq"]) == (ref["pq"], ref["sq"], ref["rq"])
    # class ids shifted far out (sparse class path)
    off = 10**12
    shift = lambda a: np.where(a > 0, a + off, 0)  # noqa: E731
    r = pq_scene(shift(ps), pi, shift(gs), gi, {c + off for c in things}, {c + off for c in stuff}, min_area=0)
    assert (r["pq"], r["sq"], r["rq"]) == (ref["pq"], ref["sq"], ref["rq"])


def test_single_frame_input_equals_stack_of_one():
    ps, pi, gs, gi = _box_scene(1)
    a = pq_scene(ps, pi, gs, gi, {1}, {2}, min_area=0)
    b = pq_scene(ps[None], pi[None], gs[None], gi[None], {1}, {2}, min_area=0)
    assert a == b
    assert a["pq"] != 1.0


def test_empty_subsets_are_nan_and_counts_zero():
    ps, pi, gs, gi = _box_scene(0)
    r = pq_scene(ps, pi, gs, gi, things={1}, stuff={9}, min_area=0)  # stuff 9 absent everywhere
    assert r["stuff"]["n"] == 0 and math.isnan(r["stuff"]["pq"]) and math.isnan(r["stuff"]["rq"])
    assert r["things"]["n"] == 1 and r["things"]["pq"] == 1.0
    everything_void = pq_scene(ps, pi, np.zeros_like(gs), gi, {1}, {2})
    assert everything_void["n_classes"] == 0 and math.isnan(everything_void["pq"])


def test_bad_class_sets_raise():
    ps, pi, gs, gi = _box_scene(0)
    with pytest.raises(ValueError, match="both"):
        pq_scene(ps, pi, gs, gi, things={1, 2}, stuff={2})
    with pytest.raises(ValueError, match="void"):
        pq_scene(ps, pi, gs, gi, things={1}, stuff={0, 2})
    with pytest.raises(ValueError, match="shape"):
        pq_scene(ps[:5], pi, gs, gi, things={1}, stuff={2})


# --------------------------------------------------------------------------- mIoU, confusion


def test_confusion_matrix_rows_gt_columns_pred():
    cm = confusion_matrix(np.array([0, 1, 1, 2, 2, 2], np.uint8), np.array([0, 1, 2, 2, 2, 0], np.int16), 4)
    expected = np.zeros((4, 4), int)
    expected[0, 0] = 1
    expected[1, 1] = 1
    expected[2, 1] = 1
    expected[2, 2] = 2
    expected[0, 2] = 1
    np.testing.assert_array_equal(cm, expected)
    with pytest.raises(ValueError):
        confusion_matrix([0, 5], [0, 1], 4)


def test_miou_known_values_and_predicted_void_is_a_class():
    gt = np.array([[0, 1, 1, 1], [2, 2, 2, 2]])
    pred = np.array([[2, 1, 1, 0], [2, 2, 2, 1]])
    r = miou(pred, gt, min_area=0)
    # valid: 7 pixels. class 1: inter 2, gt 3, pred 3 -> 2/4. class 2: inter 3, gt 4, pred 3 -> 3/4.
    # class 0 (void) predicted once on a valid pixel -> IoU 0, counted.
    assert r["per_class_iou"][1] == pytest.approx(0.5)
    assert r["per_class_iou"][2] == pytest.approx(0.75)
    assert r["per_class_iou"][0] == 0.0
    assert r["classes"] == [0, 1, 2]
    assert r["miou"] == pytest.approx(1.25 / 3)
    assert r["confusion"].sum() == 7 and r["n_pixels"] == 7
    assert miou(pred, gt, min_area=0.005)["miou"] == pytest.approx(1.25 / 3)  # 1/7 of void is not rare
    # at min_area 0.2 the predicted void (1/7 in prediction, 0 in GT) is ignored
    assert miou(pred, gt, min_area=0.2)["miou"] == pytest.approx(0.625)
    assert miou(pred, gt, min_area=0.2)["ignored"] == [0]


def test_miou_num_classes_and_absent_classes():
    r = miou([1, 1], [1, 1], min_area=0, num_classes=6)
    assert r["confusion"].shape == (6, 6)
    assert r["miou"] == 1.0 and r["classes"] == [1]
    assert np.isnan(r["per_class_iou"][3])
    with pytest.raises(ValueError):
        miou([1, 7], [1, 1], num_classes=6)


# --------------------------------------------------------------------------- PSNR, depth


def test_psnr_known_values():
    gt = np.zeros((2, 8, 8, 3))
    pred = gt + 0.1
    assert psnr(pred, gt) == pytest.approx(20.0)
    assert psnr(pred * 10, gt * 10, max_val=10.0) == pytest.approx(20.0)
    assert psnr(gt, gt) == math.inf
    half = gt.copy()
    half[1] += 0.01
    np.testing.assert_allclose(psnr_per_image(half, gt), [np.inf, 40.0])
    assert psnr(np.full(10, 0.5, np.float32), np.full(10, 0.25, np.float32)) == pytest.approx(
        10 * math.log10(1 / 0.0625)
    )


def test_depth_error_known_values():
    gt = np.array([[2.0, 4.0], [0.0, np.nan]])
    pred = np.array([[3.0, 3.0], [5.0, 1.0]])
    r = depth_error(pred, gt)
    assert r["n_valid"] == 2
    assert r["abs_rel"] == pytest.approx((0.5 + 0.25) / 2)
    assert r["mae"] == pytest.approx(1.0)
    assert r["rmse"] == pytest.approx(1.0)
    r = depth_error(pred, gt, valid=np.array([[True, False], [True, True]]))
    assert r["n_valid"] == 1 and r["abs_rel"] == pytest.approx(0.5)
    r = depth_error(pred, np.zeros_like(gt))
    assert r["n_valid"] == 0 and math.isnan(r["rmse"])


def test_benchmark_helper_runs_small():
    r = benchmark_pq_scene(n_frames=2, size=32, seed=1)
    assert r["n_pixels"] == 2 * 32 * 32
    assert r["seconds"] > 0 and 0.0 <= r["pq"] <= 1.0
