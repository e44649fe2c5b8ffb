"""Tests of lift3d.eval.points3d: label transfer, point mIoU / PQ, Chamfer and F-score."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from lift3d.eval import points3d
from lift3d.eval.points3d import nearest_distances


def _scene():
    """GT: a 10×10 floor (stuff 3, z=0) and two 4×5 objects of thing class 1 (ids 1, 2) at z=5 and z=10.

    Points are 1 apart, so every nearest neighbour below is unambiguous.
    """
    gx, gy = np.meshgrid(np.arange(10.0), np.arange(10.0), indexing="ij")
    floor = np.stack([gx.ravel(), gy.ravel(), np.zeros(100)], 1)
    ox, oy = np.meshgrid(np.arange(4.0), np.arange(5.0), indexing="ij")
    a = np.stack([ox.ravel(), oy.ravel(), np.full(20, 5.0)], 1)
    b = np.stack([ox.ravel() + 5, oy.ravel() + 4, np.full(20, 10.0)], 1)
    xyz = np.concatenate([floor, a, b])
    sem = np.array([3] * 100 + [1] * 40)
    inst = np.array([0] * 100 + [1] * 20 + [2] * 20)
    return xyz, sem, inst


def test_perfect_prediction():
    xyz, sem, inst = _scene()
    renamed = np.where(inst == 1, 77, np.where(inst == 2, 5, 0))  # any consistent ids
    r = points3d(xyz, sem, renamed, xyz, sem, inst)
    assert r["miou"] == 1.0 and r["pq"] == 1.0 and r["sq"] == 1.0 and r["rq"] == 1.0
    assert r["fscore"] == 1.0 and r["precision"] == 1.0 and r["recall"] == 1.0
    assert r["chamfer"] == 0.0 and r["accuracy"] == 0.0 and r["completeness"] == 0.0
    assert r["tau"] == pytest.approx(0.01 * math.sqrt(9**2 + 9**2 + 10**2))
    assert r["things"] == [1] and r["stuff"] == [3]


def test_shift_smaller_than_tau():
    xyz, sem, inst = _scene()
    r = points3d(xyz + [0.05, 0, 0], sem, inst, xyz, sem, inst, tau=0.1)
    assert r["precision"] == 1.0 and r["recall"] == 1.0 and r["fscore"] == 1.0
    assert r["accuracy"] == pytest.approx(0.05) and r["completeness"] == pytest.approx(0.05)
    assert r["chamfer"] == pytest.approx(0.05)
    assert r["miou"] == 1.0 and r["pq"] == 1.0


def test_shift_larger_than_tau():
    xyz, sem, inst = _scene()
    r = points3d(xyz + [0, 0.2, 0], sem, inst, xyz, sem, inst, tau=0.1)
    assert (r["precision"], r["recall"], r["fscore"]) == (0.0, 0.0, 0.0)
    assert r["chamfer"] == pytest.approx(0.2)
    # nothing in reach: every GT point gets a void prediction
    assert r["miou"] == 0.0
    assert r["pq"] == 0.0 and r["pq_detail"]["per_class"][1]["fn"] == 0  # mostly-void GT is not a FN


def test_distance_equal_to_tau_is_within():
    xyz, sem, inst = _scene()
    r = points3d(xyz + [0.25, 0, 0], sem, inst, xyz, sem, inst, tau=0.25)
    assert r["recall"] == 1.0 and r["precision"] == 1.0 and r["pq"] == 1.0


def test_extra_far_points_lower_precision_only():
    xyz, sem, inst = _scene()
    far = xyz[:35] - [0, 0, 3.0]  # 35 points 3 below the floor
    pred = np.concatenate([xyz, far])
    psem = np.concatenate([sem, np.full(35, 3)])
    pinst = np.concatenate([inst, np.zeros(35, int)])
    r = points3d(pred, psem, pinst, xyz, sem, inst, tau=0.1)
    assert r["precision"] == pytest.approx(140 / 175)
    assert r["recall"] == 1.0
    assert r["fscore"] == pytest.approx(2 * 0.8 / 1.8)
    assert r["accuracy"] == pytest.approx(35 * 3 / 175)
    assert r["completeness"] == 0.0
    assert r["chamfer"] == pytest.approx(0.3)
    assert r["pq"] == 1.0  # the far points are nobody's nearest neighbour


def test_object_labelled_as_floor_is_a_false_negative():
    xyz, sem, inst = _scene()
    psem, pinst = sem.copy(), inst.copy()
    psem[inst == 2] = 3
    pinst[inst == 2] = 0
    r = points3d(xyz, psem, pinst, xyz, sem, inst)
    c1 = r["pq_detail"]["per_class"][1]
    assert (c1["tp"], c1["fp"], c1["fn"]) == (1, 0, 1)
    # class 1: PQ = 1 / (1 + 1/2) = 2/3; floor: IoU 100/120 = 5/6 (TP)
    assert r["pq"] == pytest.approx((2 / 3 + 5 / 6) / 2, abs=1e-6)
    assert r["rq"] == pytest.approx((2 / 3 + 1) / 2)
    assert r["sq"] == pytest.approx((1 + 5 / 6) / 2, abs=1e-6)
    assert r["fscore"] == 1.0
    # mIoU: class 1 = 20/40, class 3 = 100/120
    assert r["miou"] == pytest.approx((0.5 + 5 / 6) / 2)


def test_geometrically_missing_object():
    xyz, sem, inst = _scene()
    keep = inst != 2
    r = points3d(xyz[keep], sem[keep], inst[keep], xyz, sem, inst)
    assert r["recall"] == pytest.approx(120 / 140) and r["precision"] == 1.0
    assert r["fscore"] == pytest.approx(12 / 13)
    # its GT points get void predictions: by the PQ rules a mostly-void GT segment is no FN ...
    assert r["pq_detail"]["per_class"][1]["fn"] == 0 and r["pq"] == 1.0
    # ... but mIoU sees predicted void as a class of its own (IoU 0) and class 1 at 20/40
    assert r["miou"] == pytest.approx((0 + 0.5 + 1) / 3)
    assert r["completeness"] > 0


def test_empty_prediction():
    xyz, sem, inst = _scene()
    for pred in (np.zeros((0, 3)), []):
        r = points3d(pred, [], [], xyz, sem, inst)
        assert (r["precision"], r["recall"], r["fscore"]) == (0.0, 0.0, 0.0)
        assert r["accuracy"] == math.inf and r["completeness"] == math.inf and r["chamfer"] == math.inf
        assert r["miou"] == 0.0 and r["pq"] == 0.0
        assert r["n_pred"] == 0 and r["n_gt"] == 140


def test_given_class_sets_and_bad_input():
    xyz, sem, inst = _scene()
    r = points3d(xyz, sem, inst, xyz, sem, inst, things={1})
    assert r["things"] == [1] and r["stuff"] == [3]
    r = points3d(xyz, sem, inst, xyz, sem, inst, stuff={3, 1})  # objects scored as one stuff segment
    assert r["things"] == [] and r["pq_detail"]["per_class"][1]["isthing"] is False
    with pytest.raises(ValueError, match="empty"):
        points3d(xyz, sem, inst, np.zeros((0, 3)), [], [])
    with pytest.raises(ValueError, match="labels"):
        points3d(xyz, sem[:-1], inst, xyz, sem, inst)


def test_chunked_queries_match_one_query():
    rng = np.random.default_rng(0)
    ref = rng.random((500, 3))
    q = rng.random((1000, 3))
    tree = cKDTree(ref)
    d1, i1 = nearest_distances(q, tree)
    d2, i2 = nearest_distances(q, tree, chunk=7)
    np.testing.assert_array_equal(d1, d2)
    np.testing.assert_array_equal(i1, i2)
    brute = np.sqrt(((q[:, None] - ref[None]) ** 2).sum(-1)).min(1)
    np.testing.assert_allclose(d1, brute)


def test_instance_recall_counts_found_missing_and_merged_objects():
    from lift3d.eval.points3d import points3d

    rng = np.random.default_rng(0)
    # Four objects of 600 points each on a floor of 2000 points; object 4 has only 100 points (not scored).
    blobs = [rng.normal(c, 0.05, (n, 3)) for c, n in (((0, 0, 0), 600), ((1, 0, 0), 600), ((2, 0, 0), 600),
                                                      ((3, 0, 0), 600), ((4, 0, 0), 100))]
    floor = np.c_[rng.uniform(-1, 5, (2000, 2)), np.full(2000, -1.0)]
    xyz = np.concatenate(blobs + [floor])
    sem = np.r_[np.full(2500, 3), np.full(2000, 1)]
    inst = np.r_[np.repeat([1, 2, 3, 4, 5], [600, 600, 600, 600, 100]), np.zeros(2000, int)]
    perfect = points3d(xyz, sem, inst, xyz, sem, inst, things={3}, stuff={1})
    assert perfect["instance_recall"] == 1.0 and perfect["n_instances"] == 4
    # Drop object 1 from the prediction, merge objects 2 and 3 into one id, relabel object 4 (ids need not match).
    keep = inst != 1
    pred_inst = np.where(inst == 3, 2, np.where(inst == 4, 77, inst))[keep]
    r = points3d(xyz[keep], sem[keep], pred_inst, xyz, sem, inst, things={3}, stuff={1})
    # found: only object 4 (IoU 1); object 1 is missing, 2 and 3 share a prediction with IoU exactly 0.5.
    assert r["n_instances"] == 4 and r["instance_recall"] == 0.25
