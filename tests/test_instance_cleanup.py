"""3D instance clean-up of exports (lift3d.export.cleanup): fragments of one object merge, neighbours stay
apart, crumbs fold into their neighbour."""

import numpy as np
import pytest

from lift3d.data.cameras import Cameras, look_at
from lift3d.export.cleanup import CleanupRules, clean_instances, merge_fragments, segment_votes

W = H = 64


def _plate(x0, x1, n, rng, y=0.0):
    """Points on a vertical plate (x in [x0, x1], z in [0, 1]) facing the cameras at y < 0."""
    return np.c_[rng.uniform(x0, x1, n), np.full(n, y), rng.uniform(0, 1, n)]


def _views():
    eyes = [np.array([x, -4.0, 0.5]) for x in (-0.4, 0.0, 0.4)]
    c2w = np.stack([look_at(e, np.array([e[0], 0.0, 0.5])) for e in eyes])
    return Cameras(c2w, 60.0, 60.0, W / 2, H / 2, W, H)


def _segment_maps(cams, boxes):
    """Per view a 2D segment map: each (id, x0, x1) box of world x projected as the columns it covers."""
    maps = []
    for f in range(len(cams)):
        m = np.zeros((H, W), np.int64)
        for seg_id, x0, x1 in boxes:
            uv, _ = cams.project(f, np.array([[x0, 0.0, 0.5], [x1, 0.0, 0.5]]))
            c0, c1 = np.clip(np.floor(uv[:, 0]).astype(int), 0, W - 1)
            m[:, c0:c1 + 1] = seg_id
        maps.append(m)
    return maps


def test_fragments_one_2d_segment_covers_merge_and_neighbours_stay_apart():
    rng = np.random.default_rng(0)
    # One object split into fragments 1 and 2 (the field used two channels); a second object of the same
    # class (3) next to it with its own 2D segment; stuff (0) behind everything.
    xyz = np.concatenate([_plate(-1.0, -0.3, 800, rng), _plate(-0.25, 0.2, 600, rng), _plate(0.35, 1.0, 800, rng),
                          _plate(-2, 2, 3000, rng, y=1.0)])
    instance = np.array([1] * 800 + [2] * 600 + [3] * 800 + [0] * 3000)
    semantic = np.array([7] * 2200 + [1] * 3000)
    cams = _views()
    maps = _segment_maps(cams, [(11, -1.0, 0.2), (12, 0.35, 1.0)])
    votes = segment_votes(xyz, instance, cams, np.arange(3), lambda f: maps[f])
    assert set(np.unique(votes[:, 1])) == {1, 2, 3}
    merged, n = merge_fragments(instance, np.array([0, 7, 7, 7]), votes, min_views=2)
    assert n == 1
    assert (merged[:1400] == 1).all() and (merged[1400:2200] == 3).all() and (merged[2200:] == 0).all()
    # A class boundary is kept: the same geometry with fragment 2 of another class does not merge.
    _, n_other = merge_fragments(instance, np.array([0, 7, 8, 7]), votes, min_views=2)
    assert n_other == 0


def _side_by_side():
    """Two objects (instances 1 and 2) side by side, the three views, and each view's 2D segments with the
    two apart and joined."""
    rng = np.random.default_rng(1)
    xyz = np.concatenate([_plate(-1.0, -0.1, 800, rng), _plate(0.1, 1.0, 800, rng)])
    instance = np.array([1] * 800 + [2] * 800)
    cams = _views()
    apart = _segment_maps(cams, [(11, -1.0, -0.1), (12, 0.1, 1.0)])
    joined = _segment_maps(cams, [(13, -1.0, 1.0)])
    return xyz, instance, cams, apart, joined


def test_a_2d_segment_over_both_objects_in_a_minority_of_views_does_not_merge_them():
    xyz, instance, cams, apart, joined = _side_by_side()
    maps = [joined[0], apart[1], apart[2]]  # the segmenter merged the two objects in one view of three
    votes = segment_votes(xyz, instance, cams, np.arange(3), lambda f: maps[f])
    _, n = merge_fragments(instance, np.array([0, 7, 7]), votes, min_views=2)
    assert n == 0


@pytest.mark.parametrize("joined_views, merged", [(1, False), (2, True), (3, True)])
def test_a_view_that_shows_two_objects_apart_outweighs_two_that_join_them(joined_views, merged):
    # Two cabinets side by side in three views: the segmenter joins them in 1, 2 or 3 of them. Half of the
    # views is not enough (segmenters join touching objects more often than they split one); two thirds is.
    xyz, instance, cams, apart, joined = _side_by_side()
    maps = [joined[f] if f < joined_views else apart[f] for f in range(3)]
    votes = segment_votes(xyz, instance, cams, np.arange(3), lambda f: maps[f])
    _, n = merge_fragments(instance, np.array([0, 7, 7]), votes, min_views=2)
    assert n == int(merged)
    # At the old share of one half, one joining view of two would have merged them.
    votes2 = segment_votes(xyz, instance, cams, np.arange(2), lambda f: [joined[0], apart[1]][f])
    assert merge_fragments(instance, np.array([0, 7, 7]), votes2, min_views=2, min_share=0.5)[1] == 1
    assert merge_fragments(instance, np.array([0, 7, 7]), votes2, min_views=2)[1] == 0


def test_occluded_points_do_not_vote():
    rng = np.random.default_rng(2)
    front = _plate(-1.0, 1.0, 4000, rng)  # instance 1 hides instance 2 behind it
    back = _plate(-0.5, 0.5, 1000, rng, y=0.5)
    xyz = np.concatenate([front, back])
    instance = np.array([1] * 4000 + [2] * 1000)
    cams = _views()
    maps = _segment_maps(cams, [(11, -1.0, 1.0)])
    votes = segment_votes(xyz, instance, cams, np.arange(3), lambda f: maps[f])
    assert 2 not in votes[:, 1]


def test_crumbs_fold_into_their_neighbour_and_counts_are_reported():
    rng = np.random.default_rng(3)
    big = rng.uniform(0, 1, (3000, 3))
    crumb = np.array([0.5, 0.5, 1.0]) + rng.uniform(0, 0.02, (6, 3))  # another channel, on top of `big`
    far = np.array([9.0, 9.0, 9.0]) + rng.uniform(0, 0.02, (5, 3))  # alone in space
    xyz = np.concatenate([big, crumb, far])
    semantic = np.array([7] * 3000 + [8] * 6 + [7] * 5)
    instance = np.array([1] * 3000 + [2] * 6 + [3] * 5)
    cams = _views()
    sem, inst, keep, stats = clean_instances(xyz, xyz, semantic, instance, cameras=cams, frames=np.arange(3),
                                             segments_of=lambda f: np.zeros((H, W), np.int64), link_radius=0.1,
                                             crumb_points=10)
    assert (inst[3000:3006] == 1).all() and (sem[3000:3006] == 7).all(), "the crumb joins the object it lies on"
    assert not keep[3006:].any(), "an isolated crumb is dropped"
    assert stats["instances_before"] == 3 and stats["instances_after"] == 1
    assert stats["crumbs_folded"] == 1 and stats["crumbs_dropped"] == 1
    _, inst0, keep0, stats0 = clean_instances(xyz, xyz, semantic, instance, cameras=cams, frames=np.arange(3),
                                              segments_of=lambda f: np.zeros((H, W), np.int64), link_radius=0.1,
                                              crumb_points=0)
    assert keep0.all() and stats0["instances_after"] == 3


def test_an_instance_the_field_is_unsure_of_folds_into_the_surface_it_lies_on():
    # A patch of a thing class painted on a wall (what one spurious 2D segment leaves in the field: the wall
    # keeps much of its class probability) folds into the wall; a confident object of the same size stays.
    rng = np.random.default_rng(4)
    wall = _plate(-2, 2, 4000, rng, y=1.0)
    patch = _plate(-0.2, 0.2, 200, rng, y=1.0)
    obj = _plate(-1.0, -0.6, 200, rng, y=0.0)
    xyz = np.concatenate([wall, patch, obj])
    semantic = np.array([1] * 4000 + [9] * 200 + [7] * 200)
    instance = np.array([0] * 4000 + [1] * 200 + [2] * 200)
    confidence = np.concatenate([np.full(4000, 0.9), np.full(200, 0.62), np.full(200, 0.85)])
    cams = _views()
    kwargs = dict(cameras=cams, frames=np.arange(3), segments_of=lambda f: np.zeros((H, W), np.int64),
                  link_radius=0.1, crumb_points=10, confidence=confidence)
    sem, inst, keep, stats = clean_instances(xyz, xyz, semantic, instance, rules=CleanupRules(min_confidence=0.7),
                                             **kwargs)
    assert keep.all()
    assert (inst[4000:4200] == 0).all() and (sem[4000:4200] == 1).all(), "the unsure patch becomes wall"
    assert (inst[4200:] == 1).all() and (sem[4200:] == 7).all(), "the confident object stays, renumbered 1"
    assert stats["unsure"] == 1 and stats["instances_after"] == 1
    _, inst_off, _, stats_off = clean_instances(xyz, xyz, semantic, instance, rules=CleanupRules(min_confidence=0.0),
                                                **kwargs)
    assert stats_off["unsure"] == 0 and stats_off["instances_after"] == 2


def test_votes_from_a_subset_of_a_large_cloud_agree_with_all_points():
    rng = np.random.default_rng(5)
    xyz = np.concatenate([_plate(-1.0, -0.3, 8000, rng), _plate(-0.25, 0.2, 6000, rng), _plate(-2, 2, 20000, rng,
                                                                                               y=1.0)])
    instance = np.array([1] * 8000 + [2] * 6000 + [0] * 20000)
    cams = _views()
    maps = _segment_maps(cams, [(11, -1.0, 0.2)])
    full = segment_votes(xyz, instance, cams, np.arange(3), lambda f: maps[f], max_points=0)
    sub = segment_votes(xyz, instance, cams, np.arange(3), lambda f: maps[f], max_points=5000)
    assert sub[:, 4].sum() < full[:, 4].sum() / 3, "the subset votes with fewer points"
    for votes in (full, sub):
        merged, n = merge_fragments(instance, np.array([0, 7, 7]), votes, min_views=2)
        assert n == 1 and (merged[:14000] == 1).all()


def test_unsure_instances_with_nothing_sure_around_them_stay():
    # An undertrained field is unsure of everything: its instances have no sure neighbour to fold into and
    # must not be dropped (the export would be empty).
    rng = np.random.default_rng(6)
    xyz = np.concatenate([_plate(-1.0, -0.1, 300, rng), _plate(0.1, 1.0, 300, rng)])
    semantic = np.array([7] * 300 + [8] * 300)
    instance = np.array([1] * 300 + [2] * 300)
    sem, inst, keep, stats = clean_instances(
        xyz, xyz, semantic, instance, cameras=_views(), frames=np.arange(3),
        segments_of=lambda f: np.zeros((H, W), np.int64), link_radius=0.1, crumb_points=10,
        confidence=np.full(600, 0.3), rules=CleanupRules(min_confidence=0.7))
    assert keep.all() and stats["unsure"] == 2 and stats["instances_after"] == 2
    assert (sem == semantic).all()


def test_a_fragment_whose_labels_spill_onto_stuff_still_merges():
    # Fragment 2 of the object has more of its points on the floor beside it (stuff pixels in 2D, where the
    # field's label spilled) than on the object: of its points on 2D *thing* segments, the object's segment
    # holds the majority, so it merges.
    rng = np.random.default_rng(7)
    xyz = np.concatenate([_plate(-1.0, -0.3, 800, rng), _plate(-0.25, 0.2, 300, rng), _plate(0.2, 0.9, 500, rng),
                          _plate(-2, 2, 3000, rng, y=1.0)])
    instance = np.array([1] * 800 + [2] * 800 + [0] * 3000)
    cams = _views()
    maps = _segment_maps(cams, [(11, -1.0, 0.2)])
    votes = segment_votes(xyz, instance, cams, np.arange(3), lambda f: maps[f])
    merged, n = merge_fragments(instance, np.array([0, 7, 7]), votes, min_views=2)
    assert n == 1 and (merged[:1600] == 1).all()


def test_an_instance_no_2d_thing_segment_confirms_folds_and_a_confirmed_one_stays():
    # A confident patch of a thing class on a wall that the 2D labels show as wall in every view (fog or a
    # label that leaked in 3D) folds into the wall; an object its 2D segment covers in every view stays.
    rng = np.random.default_rng(8)
    wall = _plate(-2, 2, 4000, rng, y=1.0)
    patch = _plate(0.4, 0.8, 200, rng, y=1.0)
    obj = _plate(-1.0, -0.6, 200, rng, y=0.0)
    xyz = np.concatenate([wall, patch, obj])
    semantic = np.array([1] * 4000 + [9] * 200 + [7] * 200)
    instance = np.array([0] * 4000 + [1] * 200 + [2] * 200)
    cams = _views()
    maps = _segment_maps(cams, [(11, -1.0, -0.6)])
    kwargs = dict(cameras=cams, frames=np.arange(3), segments_of=lambda f: maps[f], link_radius=0.1,
                  crumb_points=10, confidence=np.full(4400, 0.95))
    sem, inst, keep, stats = clean_instances(xyz, xyz, semantic, instance, **kwargs,
                                             rules=CleanupRules(min_support_views=1, min_confidence=0.7))
    assert keep.all()
    assert (inst[4000:4200] == 0).all() and (sem[4000:4200] == 1).all(), "the unconfirmed patch becomes wall"
    assert (inst[4200:] == 1).all() and (sem[4200:] == 7).all(), "the confirmed object stays, renumbered 1"
    assert stats["min_support_views"] == 1 and stats["unsupported"] == 1 and stats["instances_after"] == 1
    # Asking for more confirming views than the object has (3) folds it too, but with nothing around it
    # to fold into it keeps its points and its id.
    _, inst4, keep4, stats4 = clean_instances(xyz, xyz, semantic, instance, **kwargs,
                                              rules=CleanupRules(min_support_views=4, min_confidence=0.7))
    assert stats4["unsupported"] == 2 and stats4["instances_after"] == 1 and keep4.all()
    assert (inst4[4000:4200] == 0).all() and (inst4[4200:] == 1).all()
    _, _, _, stats_off = clean_instances(xyz, xyz, semantic, instance, **kwargs,
                                         rules=CleanupRules(min_support_views=0, min_confidence=0.7))
    assert stats_off["unsupported"] == 0 and stats_off["instances_after"] == 2


def test_support_is_counted_for_merged_fragments_together():
    from lift3d.export.cleanup import supporting_views

    # Pieces 1 and 2 (merged into 1) each hold half of the group's visible points in view 0, both on segment
    # 5: together they are confirmed there; alone neither reaches a majority of the group in view 1.
    votes = np.array([[0, 1, 5, 4, 8], [0, 2, 5, 4, 8], [1, 1, 5, 3, 8], [1, 2, 6, 3, 8]])
    assert supporting_views(votes, np.array([1, 2]), np.array([1, 1])).tolist() == [0, 1]
    assert supporting_views(votes, np.array([1, 2]), np.array([1, 2])).tolist() == [0, 1, 1]


def test_instances_mostly_of_filled_points_join_the_nearest_instance_of_their_class():
    from lift3d.export.instances import join_filled_instances

    rng = np.random.default_rng(0)
    table = rng.uniform(0, 1, (200, 3))                                    # instance 1, isosurface points
    crumb = rng.uniform(0, 0.1, (30, 3)) + [1.1, 0, 0]                     # instance 2: 5 isosurface + 25 filled
    far = rng.uniform(0, 0.1, (30, 3)) + [5.0, 0, 0]                       # instance 3: filled, far away
    chair = rng.uniform(0, 0.1, (30, 3)) + [1.1, 0.5, 0]                   # instance 4: filled, another class
    xyz = np.r_[table, crumb, far, chair]
    semantic = np.r_[np.full(200, 6), np.full(60, 6), np.full(30, 7)]
    instance = np.r_[np.full(200, 1), np.full(30, 2), np.full(30, 3), np.full(30, 4)]
    filled = np.r_[np.zeros(205, bool), np.ones(85, bool)]
    out, joined = join_filled_instances(xyz, semantic, instance, filled, radius=0.3)
    assert joined == 1
    assert (out[:230] == out[0]).all()                                    # the crumb joined the table
    assert len({out[0], out[230], out[260]}) == 3                         # the far patch and the chair stay apart
    assert sorted(np.unique(out)) == [1, 2, 3]                            # contiguous ids
    # nothing filled: nothing changes
    same, joined = join_filled_instances(xyz, semantic, instance, np.zeros(290, bool), radius=0.3)
    assert joined == 0 and (same == instance).all()


def test_a_whole_object_of_mostly_filled_points_does_not_join_a_smaller_neighbour_of_its_class():
    from lift3d.export.instances import join_filled_instances

    # Two tables 0.8 m apart, a few stray points of fog 0.25 m beside the first: the first table's points are
    # mostly filled (images only), the second's are not. The first is the larger: it is an object, not a patch
    # of the second, and stays apart; a small filled patch beside the second still joins it.
    rng = np.random.default_rng(1)
    first = rng.uniform(0, 1, (240, 3))                                   # instance 1: 140 of 240 filled
    second = rng.uniform(0, 1, (200, 3)) + [1.8, 0, 0]                    # instance 2: not filled
    patch = rng.uniform(0, 0.1, (20, 3)) + [2.9, 0, 0]                    # instance 3: filled, beside the second
    fog = np.array([[1.25, 0.5, 0.5]])                                    # instance 1's, 0.25 m from it
    xyz = np.r_[first, fog, second, patch]
    instance = np.r_[np.full(241, 1), np.full(200, 2), np.full(20, 3)]
    filled = np.r_[np.arange(241) < 140, np.zeros(200, bool), np.ones(20, bool)]
    # the fog is within the radius of the second table
    out, joined = join_filled_instances(xyz, np.full(len(xyz), 6), instance, filled, radius=0.6)
    assert joined == 1
    assert out[0] != out[241] and (out[:241] == out[0]).all()             # the two tables stay apart
    assert (out[441:] == out[241]).all()                                  # the patch joined the second table


def test_a_mostly_filled_object_of_its_own_instance_channel_does_not_join_its_neighbour():
    from lift3d.export.instances import join_filled_instances

    # Two boxes 0.2 m apart (images only): the isosurface reaches the second barely, so its points are mostly
    # filled and within reach of the first. The field gives it a channel of its own: it is another box, not a patch
    # of the first. A filled patch on the first box's channel still joins it.
    rng = np.random.default_rng(2)
    first = rng.uniform(0, 0.4, (300, 3))                                 # instance 1, channel 4
    second = rng.uniform(0, 0.3, (120, 3)) + [0.6, 0, 0]                  # instance 2, channel 9, 100 of 120 filled
    patch = rng.uniform(0, 0.05, (20, 3)) + [0.45, 0.35, 0]               # instance 3, channel 4, filled
    xyz = np.r_[first, second, patch]
    instance = np.r_[np.full(300, 1), np.full(120, 2), np.full(20, 3)]
    channel = np.r_[np.full(300, 4), np.full(120, 9), np.full(20, 4)]
    filled = np.r_[np.zeros(300, bool), np.arange(120) < 100, np.ones(20, bool)]
    semantic = np.full(len(xyz), 8)
    out, joined = join_filled_instances(xyz, semantic, instance, filled, radius=0.3, channel=channel)
    assert joined == 1
    assert (out[300:420] == out[300]).all() and out[300] != out[0]       # the second box stays apart
    assert (out[420:] == out[0]).all()                                    # the patch joined the first box
    # Without the channels the second box joins the first.
    merged, joined = join_filled_instances(xyz, semantic, instance, filled, radius=0.3)
    assert joined == 2 and len(np.unique(merged)) == 1


def test_a_small_thing_the_views_confirm_keeps_its_class_instead_of_folding_into_the_table():
    # A figurine (class 20, 40 points: a crumb at crumb_points 100) stands in front of a table (class 6). The
    # table's segment covers the views everywhere but where the figurine's own class-20 segment is. Folding it
    # would make it table; confirmed in all three views, it stays a figurine. Unconfirmed (its 2D segment says
    # table), it folds as before.
    from lift3d.export.cleanup import SEGMENT_CLASS_SHIFT, class_segments

    rng = np.random.default_rng(9)
    table = _plate(-1.0, 1.0, 4000, rng, y=0.2)
    figurine = np.c_[rng.uniform(-0.1, 0.1, 40), np.zeros(40), rng.uniform(0.3, 0.7, 40)]
    xyz = np.concatenate([table, figurine])
    semantic = np.array([6] * 4000 + [20] * 40)
    instance = np.array([1] * 4000 + [2] * 40)
    cams = _views()

    def maps_with(figurine_class):
        out = []
        for m in _segment_maps(cams, [(5, -1.0, 1.0)]):
            fig = _segment_maps(cams, [(7, -0.1, 0.1)])[len(out)] > 0
            sem = np.where(fig, figurine_class, 6)
            out.append(class_segments(sem, np.where(fig, 7, m)))
        return out

    kwargs = dict(cameras=cams, frames=np.arange(3), link_radius=0.1, crumb_points=100)
    confirmed = maps_with(20)
    assert (confirmed[0][confirmed[0] > 0] >> SEGMENT_CLASS_SHIFT).min() == 6
    sem, inst, keep, stats = clean_instances(xyz, xyz, semantic, instance, segments_of=lambda f: confirmed[f],
                                             rules=CleanupRules(keep_confirmed_views=2), **kwargs)
    assert keep.all() and (sem[4000:] == 20).all() and len(np.unique(inst[4000:])) == 1
    assert inst[4000] != inst[0] and stats["confirmed_kept"] == 1 and stats["instances_after"] == 2
    sem_off, inst_off, _, stats_off = clean_instances(xyz, xyz, semantic, instance,
                                                      segments_of=lambda f: confirmed[f], **kwargs)
    assert (sem_off[4000:] == 6).all() and stats_off["confirmed_kept"] == 0, "off (the default rule): it folds"
    unconfirmed = maps_with(6)
    sem_u, _, _, stats_u = clean_instances(xyz, xyz, semantic, instance, segments_of=lambda f: unconfirmed[f],
                                           rules=CleanupRules(keep_confirmed_views=2), **kwargs)
    assert (sem_u[4000:] == 6).all() and stats_u["confirmed_kept"] == 0, "the views call it table: it folds"
