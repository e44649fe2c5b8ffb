"""Every loss on a hand-computed case, and the instance assignment."""

import math

import pytest
import torch

from lift3d.model.assignment import instance_cost_matrix, linear_assign_instances
from lift3d.model.losses import (
    charbonnier_loss,
    depth_loss,
    disparity_loss,
    distortion_loss,
    distortion_loss_reference,
    feature_loss,
    instance_loss,
    segment_consistency_loss,
    segment_groups,
    semantic_loss,
    weighted_cross_entropy,
)


def test_charbonnier_hand_case():
    pred = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    target = torch.tensor([[0.3, 0.3, 0.3], [1.0, 1.0, 1.0]])
    eps = 1e-4
    expected = (3 * math.sqrt(0.09 + eps**2) + 3 * eps) / 6
    assert abs(float(charbonnier_loss(pred, target, eps)) - expected) < 1e-7


def test_weighted_cross_entropy_hand_case():
    logits = torch.tensor([[0.0, math.log(3.0)], [0.0, 0.0], [5.0, 1.0]])
    target = torch.tensor([1, 0, -1])  # the last ray is ignored
    weight = torch.tensor([0.5, 1.0, 1.0])
    # p(1 | ray 0) = 3/4, p(0 | ray 1) = 1/2
    expected = (0.5 * -math.log(0.75) + 1.0 * -math.log(0.5)) / 2
    assert abs(float(weighted_cross_entropy(logits, target, weight)) - expected) < 1e-6


def test_confidence_zero_and_probability_zero_stay_finite():
    logits = torch.tensor([[-1e4, 1e4], [0.0, 0.0]], requires_grad=True)
    loss = weighted_cross_entropy(logits, torch.tensor([0, 1]), torch.tensor([0.0, 0.0]))
    loss.backward()
    assert float(loss) == 0.0 and torch.isfinite(logits.grad).all()
    loss2 = weighted_cross_entropy(logits, torch.tensor([0, 1]), torch.tensor([1.0, 1.0]))
    assert math.isfinite(float(loss2))  # log(p≈0) is taken in log-softmax space: large but finite


def test_semantic_loss_ignores_void_and_all_void_batches():
    logits = torch.tensor([[0.0, 2.0, 0.0], [0.0, 0.0, 2.0]])
    only_first = semantic_loss(logits, torch.tensor([1, 0]), None)
    assert abs(float(only_first) - float(weighted_cross_entropy(logits[:1], torch.tensor([1])))) < 1e-7
    assert float(semantic_loss(logits, torch.tensor([0, 0]), None)) == 0.0


def test_linear_assignment_picks_the_best_channels_per_image():
    probs = torch.tensor([
        [0.1, 0.8, 0.1], [0.2, 0.7, 0.1],  # image 0, 2D id 40 → channel 1
        [0.6, 0.3, 0.1],                     # image 0, 2D id 7  → channel 0
        [0.1, 0.8, 0.1],                     # image 1, 2D id 40 (a different object) → channel 1
    ])
    ids = torch.tensor([40, 40, 7, 40])
    images = torch.tensor([0, 0, 0, 1])
    assert linear_assign_instances(probs, ids, images).tolist() == [1, 1, 0, 1]


def test_linear_assignment_more_2d_ids_than_channels():
    probs = torch.tensor([[0.9, 0.1], [0.8, 0.2], [0.3, 0.7]])
    target = linear_assign_instances(probs, torch.tensor([1, 2, 3]))
    # Two channels for three ids: one id stays unmatched (-1); the matched ones use distinct channels.
    assert sorted(target.tolist()) == [-1, 0, 1]
    assert target[0] == 0 and target[2] == 1


def test_cost_matrix_is_negative_mean_probability():
    probs = torch.tensor([[0.2, 0.8], [0.4, 0.6], [1.0, 0.0]])
    cost, ids = instance_cost_matrix(probs, torch.tensor([5, 5, 9]))
    assert ids.tolist() == [5, 9]
    assert torch.allclose(cost, torch.tensor([[-0.3, -0.7], [-1.0, 0.0]]))


def test_instance_loss_is_permutation_invariant_over_2d_ids():
    logits = torch.tensor([[4.0, 0.0, 0.0], [0.0, 4.0, 0.0], [0.0, 0.0, 0.0]])
    image = torch.tensor([0, 0, 0])
    a = instance_loss(logits, torch.tensor([3, 8, 0]), image, None)
    b = instance_loss(logits, torch.tensor([8, 3, 0]), image, None)  # renamed 2D ids: same loss
    assert abs(float(a) - float(b)) < 1e-7
    # Hand value: each thing ray matches its own peaked channel: -log softmax([4,0,0])[0].
    expected = -math.log(math.exp(4) / (math.exp(4) + 2))
    assert abs(float(a) - expected) < 1e-6


def test_instance_loss_without_thing_pixels_is_zero_with_gradient_graph():
    logits = torch.zeros(3, 4, requires_grad=True)
    loss = instance_loss(logits, torch.zeros(3, dtype=torch.long), torch.zeros(3, dtype=torch.long), None)
    loss.backward()
    assert float(loss) == 0.0


def test_segment_groups_and_consistency_target_is_dominant_predicted_class():
    image = torch.tensor([0, 0, 0, 0, 1, 1, 0])
    segment = torch.tensor([5, 5, 5, 5, 5, 5, 0])
    groups = segment_groups(image, segment, min_rays=3)
    # Image 0 / segment 5 has 4 rays (kept); image 1 / segment 5 has 2 (too small); void is never grouped.
    assert groups.tolist()[:4] == [0, 0, 0, 0] and groups.tolist()[4:] == [-1, -1, -1]
    logits = torch.tensor([[0.0, 3.0, 0.0], [0.0, 3.0, 0.0], [0.0, 3.0, 0.0], [0.0, 0.0, 2.0],
                           [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    loss = segment_consistency_loss(logits, groups, None)
    # Dominant class of the group is channel 1: CE of every group ray to channel 1.
    expected = float(weighted_cross_entropy(logits[:4], torch.tensor([1, 1, 1, 1])))
    assert abs(float(loss) - expected) < 1e-6


def test_segment_loss_single_ray_segments_give_zero():
    groups = segment_groups(torch.tensor([0, 1, 2]), torch.tensor([1, 1, 1]), min_rays=2)
    assert (groups == -1).all()
    assert float(segment_consistency_loss(torch.zeros(3, 4), groups, None)) == 0.0


def test_disparity_loss_hand_case():
    w = torch.tensor([[0.5, 0.5], [1.0, 0.0]])
    t = torch.tensor([[1.0, 2.0], [4.0, 8.0]])
    assert abs(float(disparity_loss(w, t)) - (0.75 + 0.25) / 2) < 1e-7


def test_distortion_loss_hand_case_and_reference():
    # Two intervals [0, .5], [.5, 1] with weights .5 each: pairwise 2·(.25·.5) = .25, own 1/3·2·(.25·.5) = 1/12.
    w = torch.tensor([[0.5, 0.5]])
    s = torch.tensor([[0.0, 0.5, 1.0]])
    assert abs(float(distortion_loss(w, s)) - (0.25 + 1 / 12)) < 1e-7
    # A compact ray costs less than the same opacity spread out (what the loss is for).
    compact = torch.tensor([[0.0, 1.0, 0.0, 0.0]])
    spread = torch.tensor([[0.25, 0.25, 0.25, 0.25]])
    edges = torch.linspace(0, 1, 5)[None]
    assert float(distortion_loss(compact, edges)) < float(distortion_loss(spread, edges))
    g = torch.Generator().manual_seed(0)
    w = torch.rand(7, 24, generator=g, dtype=torch.float64)
    w = w / w.sum(-1, keepdim=True) * torch.rand(7, 1, generator=g, dtype=torch.float64)
    s = torch.sort(torch.rand(7, 25, generator=g, dtype=torch.float64), -1).values
    torch.testing.assert_close(distortion_loss(w, s), distortion_loss_reference(w, s))
    w.requires_grad_(True)
    distortion_loss(w, s).backward()
    assert torch.isfinite(w.grad).all()


def test_depth_loss_hand_case_ignores_unknown_depth():
    w = torch.tensor([[0.5, 0.5, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    t = torch.tensor([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [1.0, 2.0, 3.0]])
    d = torch.tensor([2.0, 2.0, 0.0])  # the third ray has no measurement
    # ray 0: |1.5 - 2| + 0.5 (the weight at t = 1 is off the surface); ray 1: 0 + 0
    assert abs(float(depth_loss(w, t, d, margin=0.1)) - (0.5 + 0.5) / 2) < 1e-7
    assert float(depth_loss(w, t, torch.zeros(3), margin=0.1)) == 0.0
    # a per-ray margin: ray 0's band now takes in t = 1
    assert abs(float(depth_loss(w, t, d, margin=torch.tensor([1.5, 0.1, 0.1]))) - 0.5 / 2) < 1e-7


def test_depth_loss_charges_a_ray_that_does_not_end_at_the_surface():
    """A fog in front of the wall that leaves the ray half transparent pays for the fog and for the light
    that falls through; density at the measured depth is the cheapest way to opacity."""
    t = torch.tensor([[1.0, 2.0, 3.0]])
    d = torch.tensor([3.0])
    fog = torch.tensor([[0.3, 0.3, 0.0]], requires_grad=True)  # 0.6 in front, 0.4 falls through
    loss = depth_loss(fog, t, d, margin=0.1)
    assert abs(float(loss) - (abs(0.9 - 3.0) + 1.0)) < 1e-6
    loss.backward()
    # more weight at the wall lowers the loss, more weight in the fog does not
    assert fog.grad[0, 2] < 0 and fog.grad[0, 0] >= fog.grad[0, 2] and fog.grad[0, 1] >= fog.grad[0, 2]
    assert float(depth_loss(torch.tensor([[0.0, 0.0, 1.0]]), t, d, 0.1)) == 0.0


def test_feature_loss_hand_case():
    a = [torch.zeros(1, 2, 2, 2)]
    b = [torch.zeros(1, 2, 2, 2)]
    b[0][:, 0] = 3.0
    b[0][:, 1] = 4.0
    assert abs(float(feature_loss(a, b)) - 5.0) < 1e-5


@pytest.mark.slow
def test_perceptual_prior_loads_offline_and_is_frozen():
    from lift3d.model.perceptual import build_perceptual_prior

    net = build_perceptual_prior()
    x = torch.rand(2, 3, 16, 16, requires_grad=True)
    feats = net(x)
    assert [f.shape[1] for f in feats] == [16, 24]
    assert all(not p.requires_grad for p in net.parameters())
    # Unit-normalised features: L_feat of a patch with itself is 0, against another patch in (0, 2].
    assert float(feature_loss(feats, net(x.detach()))) < 1e-5
    other = feature_loss(feats, net(torch.rand(2, 3, 16, 16)))
    assert 0 < float(other) <= 2.0
    other.backward()
    assert x.grad is not None and torch.isfinite(x.grad).all()
