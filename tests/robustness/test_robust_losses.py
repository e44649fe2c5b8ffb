"""Losses and the per-image instance assignment at their edges (docs/robustness.md, section 1).

log(0) must never be reached (confidence 0, probability 0), and the label losses must stay finite and
correct with more 2D ids than channels, no thing pixels, one instance, single-ray segments and all-void
batches. References are computed independently here (float64 numpy, brute-force assignment).
"""

from __future__ import annotations

import itertools
import math
from collections import Counter

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from lift3d.model.assignment import instance_cost_matrix, linear_assign_instances
from lift3d.model.losses import (
    charbonnier_loss,
    disparity_loss,
    feature_loss,
    instance_loss,
    segment_consistency_loss,
    segment_groups,
    semantic_loss,
    weighted_cross_entropy,
)

PROPS = settings(max_examples=40, deadline=None, derandomize=True, database=None,
                 suppress_health_check=[HealthCheck.too_slow])

#: Logits from ordinary to saturated: a probability of exactly 0 in float32 is exp(-104) away.
LOGIT = st.one_of(st.floats(-10, 10), st.sampled_from([-1e4, 1e4, -200.0, 200.0, 0.0]))
CONFIDENCE = st.one_of(st.just(0.0), st.just(1.0), st.floats(0.0, 1.0))


def _nll_reference(logits: np.ndarray, target: np.ndarray, weight: np.ndarray | None) -> float:
    """float64: −1/|P| Σ λ_p log softmax(l_p)[t_p] over t_p ≥ 0 (0 when none), via a stable logsumexp."""
    valid = target >= 0
    if not valid.any():
        return 0.0
    lg = logits[valid].astype(np.float64)
    m = lg.max(1, keepdims=True)
    lse = (m + np.log(np.exp(lg - m).sum(1, keepdims=True)))[:, 0]
    nll = lse - lg[np.arange(len(lg)), target[valid]]
    if weight is not None:
        nll = nll * weight[valid]
    return float(nll.mean())


@st.composite
def labelled_rays(draw, max_rays: int = 24, max_channels: int = 6):
    r = draw(st.integers(1, max_rays))
    c = draw(st.integers(2, max_channels))
    logits = draw(hnp.arrays(np.float32, (r, c), elements=LOGIT))
    target = draw(hnp.arrays(np.int64, r, elements=st.integers(-1, c - 1)))
    weight = draw(hnp.arrays(np.float32, r, elements=CONFIDENCE))
    return logits, target, weight


@PROPS
@given(labelled_rays(), st.booleans())
def test_cross_entropy_never_takes_log_zero(rays, use_weight):
    """Target probabilities that underflow to 0 (logit gaps of 1e4), confidences of 0: the loss is finite,
    ≥ 0, equals a float64 logsumexp reference, and its gradient is finite."""
    logits, target, weight = rays
    lt = torch.from_numpy(logits).requires_grad_(True)
    w = torch.from_numpy(weight) if use_weight else None
    loss = weighted_cross_entropy(lt, torch.from_numpy(target), w)
    assert math.isfinite(float(loss)) and float(loss) >= 0
    ref = _nll_reference(logits, target, weight if use_weight else None)
    assert float(loss) == pytest.approx(ref, rel=1e-4, abs=1e-3)
    loss.backward()
    assert torch.isfinite(lt.grad).all()


def test_zero_confidence_everywhere_gives_zero_loss_and_zero_gradient():
    logits = torch.tensor([[-1e4, 1e4, 0.0], [3.0, -3.0, 0.0]], requires_grad=True)
    loss = semantic_loss(logits, torch.tensor([1, 2]), torch.zeros(2))
    loss.backward()
    assert float(loss) == 0.0 and (logits.grad == 0).all()


def test_segment_target_is_never_void_even_when_void_saturates():
    """Void ahead by 1e4 (every other probability underflows to 0 in float32): the group's target is still
    its dominant non-void class, the one an exact (float64, renormalised) computation picks."""
    logits = torch.tensor([[1e4, -3.0, 2.0, 0.5], [1e4, -1.0, 1.0, 3.0], [1e4, 0.0, 2.5, 0.0],
                           [0.0, 5.0, -2.0, 1.0]], requires_grad=True)
    segments = torch.tensor([7, 7, 7, 9])
    groups = segment_groups(torch.zeros(4, dtype=torch.long), segments, 1)
    loss = segment_consistency_loss(logits, groups, None)
    loss.backward()
    lg = logits.detach().double()
    exact = torch.softmax(lg[:, 1:], -1)  # the non-void distribution, free of void's saturation
    want = [1 + int(exact[:3].sum(0).argmax()), 1 + int(exact[3:].sum(0).argmax())]
    assert want == [2, 1]
    target = torch.tensor([want[0]] * 3 + [want[1]])
    assert float(loss) == pytest.approx(_nll_reference(lg.numpy(), target.numpy(), None), rel=1e-4)
    assert torch.isfinite(logits.grad).all()


@pytest.mark.parametrize("fn", ["semantic", "segment", "instance"])
def test_all_void_batch_gives_zero_loss_that_still_backpropagates(fn):
    """Every ray void (semantic 0, segment 0, instance 0): 0, finite, and ``backward`` works (the trainer
    sums every term and calls backward once)."""
    logits = torch.randn(16, 5, requires_grad=True)
    zeros = torch.zeros(16, dtype=torch.long)
    if fn == "semantic":
        loss = semantic_loss(logits, zeros, torch.ones(16))
    elif fn == "segment":
        loss = segment_consistency_loss(logits, segment_groups(zeros, zeros, 1), torch.ones(16))
    else:
        loss = instance_loss(logits, zeros, zeros, torch.ones(16))
    loss.backward()
    assert float(loss) == 0.0 and torch.isfinite(logits.grad).all() and (logits.grad == 0).all()


# ------------------------------------------------------------------------------------------ assignment
@st.composite
def instance_batches(draw):
    """Several images, each with up to 7 2D ids (arbitrary numbers, possibly more than channels)."""
    v = draw(st.integers(1, 4))
    n_images = draw(st.integers(1, 3))
    probs, ids, images = [], [], []
    for img in range(n_images):
        k = draw(st.integers(1, 7))
        id_values = draw(st.lists(st.integers(1, 60000), min_size=k, max_size=k, unique=True))
        for i in id_values:
            n_pix = draw(st.integers(1, 4))
            for _ in range(n_pix):
                row = draw(hnp.arrays(np.float64, v, elements=st.one_of(st.just(0.0), st.floats(0.0, 1.0))))
                probs.append(row / row.sum() if row.sum() > 0 else np.full(v, 1.0 / v))
                ids.append(i)
                images.append(img * 7 + 3)  # image ids need not be 0..n-1
    return np.array(probs), np.array(ids), np.array(images), v


def _best_cost(cost: np.ndarray) -> float:
    """Brute force: the cheapest injective matching of min(K, V) rows to columns."""
    k, v = cost.shape
    best = math.inf
    if k <= v:
        for cols in itertools.permutations(range(v), k):
            best = min(best, sum(cost[r, c] for r, c in enumerate(cols)))
    else:
        for rows in itertools.permutations(range(k), v):
            best = min(best, sum(cost[r, c] for c, r in enumerate(rows)))
    return best


@PROPS
@given(instance_batches())
def test_assignment_is_optimal_per_image_even_with_more_ids_than_channels(batch):
    probs, ids, images, v = batch
    target = linear_assign_instances(torch.from_numpy(probs), torch.from_numpy(ids), torch.from_numpy(images))
    assert target.shape == (len(ids),)
    for img in np.unique(images):
        sel = images == img
        uniq = np.unique(ids[sel])
        t = target.numpy()[sel]
        per_id = {i: set(t[ids[sel] == i].tolist()) for i in uniq}
        assert all(len(s) == 1 for s in per_id.values()), "all pixels of one 2D id get one channel"
        chosen = {i: s.pop() for i, s in per_id.items()}
        matched = {i: c for i, c in chosen.items() if c >= 0}
        assert len(matched) == min(len(uniq), v), "as many ids matched as channels allow"
        assert len(set(matched.values())) == len(matched), "distinct channels within an image"
        assert all(0 <= c < v for c in matched.values())
        cost, cost_ids = instance_cost_matrix(torch.from_numpy(probs[sel]), torch.from_numpy(ids[sel]))
        cost = cost.numpy()
        row = {int(i): r for r, i in enumerate(cost_ids.tolist())}
        total = sum(cost[row[int(i)], c] for i, c in matched.items())
        assert total == pytest.approx(_best_cost(cost), abs=1e-9)


@PROPS
@given(instance_batches())
def test_instance_loss_finite_for_any_batch(batch):
    probs, ids, images, v = batch
    logits = torch.log(torch.from_numpy(probs).float().clamp_min(1e-30)).requires_grad_(True)
    loss = instance_loss(logits, torch.from_numpy(ids), torch.from_numpy(images), torch.rand(len(ids)))
    assert math.isfinite(float(loss)) and float(loss) >= 0
    loss.backward()
    assert torch.isfinite(logits.grad).all()


def test_one_instance_goes_to_its_most_probable_channel():
    logits = torch.tensor([[0.0, 2.0, 0.0], [0.0, 1.0, 0.5], [5.0, 0.0, 0.0]])
    ids = torch.tensor([42, 42, 0])  # one thing (id 42) and a stuff pixel
    loss = instance_loss(logits, ids, torch.zeros(3, dtype=torch.long), None)
    expected = float(weighted_cross_entropy(logits[:2], torch.tensor([1, 1])))
    assert float(loss) == pytest.approx(expected, rel=1e-6)


def test_assignment_survives_nan_probabilities():
    """A diverging field: NaN probabilities must not crash the Hungarian matching (the trainer then skips
    the step on the non-finite loss)."""
    probs = torch.tensor([[float("nan"), 0.5], [0.2, float("inf")], [0.3, 0.7]])
    target = linear_assign_instances(probs, torch.tensor([1, 2, 3]), torch.zeros(3, dtype=torch.long))
    assert sorted(target.tolist()) == [-1, 0, 1]


# ------------------------------------------------------------------------------------------ segments
@PROPS
@given(hnp.arrays(np.int64, st.integers(1, 40), elements=st.integers(0, 3)),
       st.data(), st.integers(1, 5))
def test_segment_groups_match_a_counting_reference(images, data, min_rays):
    segments = data.draw(hnp.arrays(np.int64, len(images), elements=st.integers(0, 4)))
    groups = segment_groups(torch.from_numpy(images), torch.from_numpy(segments), min_rays).numpy()
    counts = Counter(zip(images.tolist(), segments.tolist()))
    kept = [(i, s) for (i, s), n in counts.items() if s > 0 and n >= min_rays]
    for r, (i, s) in enumerate(zip(images.tolist(), segments.tolist())):
        assert (groups[r] >= 0) == ((i, s) in kept)
    assert sorted(set(groups[groups >= 0].tolist())) == list(range(len(kept))), "dense group ids"
    for (i, s) in kept:
        members = (images == i) & (segments == s)
        assert len(set(groups[members].tolist())) == 1
    logits = torch.randn(len(images), 4, requires_grad=True)
    loss = segment_consistency_loss(logits, torch.from_numpy(groups), torch.rand(len(images)))
    assert math.isfinite(float(loss))
    loss.backward()
    assert torch.isfinite(logits.grad).all()


def test_single_ray_segments_and_void_never_become_targets():
    # Single-ray segments: no group → zero loss.
    groups = segment_groups(torch.arange(6), torch.full((6,), 9), min_rays=2)
    assert (groups == -1).all()
    assert float(segment_consistency_loss(torch.randn(6, 3), groups, None)) == 0.0
    # A group whose predictions favour void (channel 0) by e^50 still gets a non-void target, finitely.
    # (At a gap of ~104 and more every non-void probability underflows to 0 in float32 and void does
    # become the target: reported in docs/robustness.md, "known gaps", for lift3d/model/losses.py.)
    logits = torch.tensor([[50.0, 1.0, 0.0], [50.0, 0.0, 2.0], [50.0, 0.0, 2.5]], requires_grad=True)
    groups = segment_groups(torch.zeros(3, dtype=torch.long), torch.full((3,), 4), min_rays=3)
    loss = segment_consistency_loss(logits, groups, None)
    expected = float(weighted_cross_entropy(logits.detach(), torch.tensor([2, 2, 2])))
    assert float(loss) == pytest.approx(expected, rel=1e-6) and math.isfinite(expected)
    loss.backward()
    assert torch.isfinite(logits.grad).all()


# ------------------------------------------------------------------------------------------ the others
def test_other_losses_at_their_singular_points_have_finite_gradients():
    """sqrt at 0 (Charbonnier with pred = target, L_feat with equal features) and 1/t at t = 0 (L_disp)."""
    pred = torch.full((4, 3), 0.5, requires_grad=True)
    charbonnier_loss(pred, pred.detach().clone()).backward()
    assert torch.isfinite(pred.grad).all() and (pred.grad == 0).all()
    big = torch.full((2, 3), 1e4, requires_grad=True)
    loss = charbonnier_loss(big, -big.detach())
    loss.backward()
    assert math.isfinite(float(loss)) and torch.isfinite(big.grad).all()
    w = torch.tensor([[1.0, 0.0], [0.5, 0.5]], requires_grad=True)
    d = disparity_loss(w, torch.zeros(2, 2))
    d.backward()
    assert math.isfinite(float(d)) and torch.isfinite(w.grad).all()
    feats = [torch.ones(2, 4, 3, 3, requires_grad=True)]
    f = feature_loss(feats, [feats[0].detach().clone()])
    f.backward()
    assert float(f) < 1e-5 and torch.isfinite(feats[0].grad).all()
