"""Depth from the images in training: targets from sparse points, the rays through them, DS-NeRF's loss,
triangulation at the start of training (cached), and what happens when there is too little to triangulate."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import yaml

from lift3d.data.scene import load_scene
from lift3d.data.stereo import SparsePoints, write_sparse_points
from lift3d.model.config import ImageDepthConfig
from lift3d.model.losses import depth_loss, ds_depth_loss
from lift3d.model.normalization import infer_normalization
from lift3d.render.rays import RayGenerator
from lift3d.synth import SynthOptions, make_scene
from lift3d.train.data import TrainingData
from lift3d.train.image_depth import image_depth_targets
from lift3d.train.trainer import train
from test_device import checked_draws  # noqa: F401  (a fixture: draws checked against the generator's device)
from test_sfm import textured_plane_scene

TINY = {
    "field": {"grid": {"resolution_cap": 32, "min_resolution": 16, "head_hidden_dim": 16}},
    "sampling": {"proposal_resolutions": [24], "proposal_samples": [24], "num_samples": 12},
    "data": {"images_per_batch": 2, "rays_per_image": 32, "patch_size": 4},
    "losses": {"image_depth": 0.1, "feature": 0.0},
    "image_depth": {"rays_per_image": 8},
    "optim": {"steps": 4, "warmup_steps": 2},
    "trainer": {"eval_every": 0, "eval_images": 1, "checkpoint_every": 0},
}


# ------------------------------------------------------------------------------------------ losses
def _ray(n=64, far=4.0):
    edges = torch.linspace(0.0, far, n + 1)[None]
    return 0.5 * (edges[:, 1:] + edges[:, :-1]), edges.diff(dim=-1)


def test_ds_depth_loss_prefers_a_surface_at_the_point_to_fog_or_a_wrong_surface():
    t, dt = _ray()
    d, s = torch.tensor([2.0]), torch.tensor([0.06])
    g = torch.exp(-0.5 * ((t - 2.0) / 0.06) ** 2)
    at_point = g / g.sum()
    fog = torch.full_like(t, 1.0 / t.shape[1])
    wrong = torch.exp(-0.5 * ((t - 1.0) / 0.06) ** 2)
    wrong = wrong / wrong.sum()
    losses = [float(ds_depth_loss(w, t, dt, d, s)) for w in (at_point, fog, wrong)]
    entropy = float(-(at_point * torch.log((at_point + 1e-3) / (1 + 1e-3))).sum())
    assert losses[0] == pytest.approx(entropy, rel=1e-4) and losses[0] + 1.0 < losses[1] < losses[2]
    assert losses[2] <= np.log(1.0 + 1e3) + 1e-4  # a contradicted target costs at most log((1 + eps) / eps)
    # Unknown depth (0) is ignored; gradients raise the weight at the point and lower it elsewhere.
    assert float(ds_depth_loss(fog, t, dt, torch.zeros(1), s)) == 0.0
    w = fog.clone().requires_grad_(True)
    ds_depth_loss(w, t, dt, d, s).backward()
    k = int((t - 2.0).abs().argmin())
    assert float(w.grad[0, k]) < 0 and float(w.grad[0, 0]) == pytest.approx(0.0, abs=1e-6)


def test_depth_loss_takes_a_margin_per_ray():
    t, _ = _ray(8, 8.0)  # midpoints 0.5, 1.5, ...
    w = torch.zeros(2, 8)
    w[:, 3] = 1.0  # all weight at 3.5
    target = torch.tensor([3.0, 3.0])
    loose, tight = depth_loss(w, t.expand(2, 8), target, torch.tensor([1.0, 0.1])), depth_loss(
        w, t.expand(2, 8), target, 0.1)
    assert float(loose) == pytest.approx((0.5 + 0.5 + 1.0) / 2) and float(tight) == pytest.approx(1.5)


# ------------------------------------------------------------------------------------------ targets and rays
@pytest.fixture(scope="module")
def room(tmp_path_factory):
    """A small synthetic room without depth maps, with hand-made sparse points lifted from its exact depth."""
    root = tmp_path_factory.mktemp("scenes") / "room"
    make_scene(root,
               SynthOptions(kind="indoor", seed=101, noise="moderate", n_views=8, width=40, height=40, depth="none"),
               progress=False)
    scene = load_scene(root)
    train_frames = np.asarray(scene.split("train"))
    rng = np.random.default_rng(0)
    xyz, obs_f, obs_p, obs_uv, obs_z = [], [], [], [], []
    for i in train_frames[:3]:
        z = scene.gt_depth(int(i))
        for _ in range(5):
            c, r = rng.integers(5, 35, 2)
            x, y = scene.cameras.normalized_coords(int(i), np.array([c]), np.array([r]))  # (the centre)
            p_cam = np.array([x[0], y[0], 1.0]) * z[r, c]
            c2w = scene.cameras.c2w_opencv[int(i)]
            xyz.append(c2w[:3, :3] @ p_cam + c2w[:3, 3])
            obs_f.append(int(i))
            obs_p.append(len(xyz) - 1)
            obs_uv.append([c + 0.5, r + 0.5])
            obs_z.append(z[r, c])
    n = len(xyz)
    names = [f.name for f in scene.frames]
    sparse = SparsePoints(xyz=np.array(xyz), rgb=np.zeros((n, 3), np.uint8), error=np.full(n, 0.2, np.float32),
                          track_length=np.ones(n, np.int32), frame_names=names, obs_frame=np.array(obs_f, np.int32),
                          obs_point=np.array(obs_p, np.int32), obs_uv=np.array(obs_uv, np.float32),
                          obs_depth=np.array(obs_z, np.float32), obs_sigma=np.full(n, 0.02, np.float32),
                          info={"source": "test"})
    write_sparse_points(root, sparse)
    return root


def test_target_rays_end_at_the_points_and_carry_their_sigma(room):
    scene = load_scene(room)
    frames = scene.split("train")
    targets = image_depth_targets(scene, frames, ImageDepthConfig(source="sparse"))
    assert len(targets) == 15 and targets.info["points_from"] == "scene (test)"
    assert targets.info["steps"] == [{"name": "sparse-points", "ran": True, "why": "on",
                                      "seconds": targets.info["steps"][0]["seconds"], "counts": {"observations": 15}}]
    assert targets.info["frames_with_targets"] == 3
    norm, _ = infer_normalization(scene)
    rays = RayGenerator(scene.cameras, norm.c2w_normalized(scene.cameras.c2w))
    data = TrainingData(scene, frames, rays, progress=False, targets=targets, target_scale=norm.scale,
                        target_min_sigma=0.001)
    assert data.depth is None and data.num_targets == 15
    batch = data.sample(len(frames), 16, 4, torch.Generator().manual_seed(0), target_rays_per_image=6)
    has = batch.depth_sigma > 0
    assert int(has.sum()) == 3 * 6 and bool((batch.depth[~has] == 0).all())
    assert bool(has[-18:].all())  # target rays come last
    ends = norm.to_world((batch.origins[has] + batch.dirs[has] * batch.depth[has, None]).numpy())
    pts = scene.sparse_points().xyz
    dist = np.linalg.norm(ends[:, None] - pts[None], axis=-1).min(1)
    assert dist.max() < 1e-3
    # sigma along the ray: the z sigma (0.02 m) in normalised units, divided by the cosine to the axis (>= 1x)
    s = batch.depth_sigma[has].numpy()
    assert np.all(s >= 0.02 * norm.scale - 1e-6) and np.all(s < 0.02 * norm.scale * 1.3)
    # Pixels, labels and colour of a target ray are those of the pixel it goes through.
    assert batch.rgb.shape[0] == batch.origins.shape[0] == batch.semantic.shape[0]


def test_points_the_caller_triangulated_are_used_as_they_are_and_cached(room, tmp_path):
    # The caller triangulated the training frames (observations index those frames, as triangulate_scene's do):
    # they give the targets the scene's own points give, and land in the cache as if triangulated here.
    import dataclasses

    from lift3d.data.stereo import read_sparse_points

    scene = load_scene(room)
    frames = np.asarray(scene.split("train"))
    own = scene.sparse_points()
    position = {int(f): k for k, f in enumerate(frames)}
    theirs = dataclasses.replace(own, frame_names=[scene.frames[int(i)].name for i in frames],
                                 obs_frame=np.array([position[int(f)] for f in own.obs_frame], np.int32),
                                 info={"source": "lift3d triangulate", "warnings": ["few points"]})
    cfg = ImageDepthConfig(source="sparse")
    given = image_depth_targets(scene, frames, cfg, cache=tmp_path, sparse=theirs)
    mine = image_depth_targets(scene, frames, cfg)
    assert given.info["points_from"] == "given (lift3d triangulate)" and given.info["warnings"][0] == "few points"
    assert all(np.array_equal(getattr(given, k), getattr(mine, k)) for k in ("frame", "u", "v", "z", "sigma"))
    assert np.array_equal(theirs.obs_frame, [position[int(f)] for f in own.obs_frame])  # the caller's, untouched
    cached = read_sparse_points(tmp_path / "sparse" / "points3D.ply", tmp_path / "sparse" / "observations.npz",
                                frame_names=[f.name for f in scene.frames])
    assert np.array_equal(cached.obs_frame, own.obs_frame) and len(cached) == len(own)


def test_without_premises_the_targets_assume_what_they_did_before_profiles(room):
    from lift3d.train.image_depth import auto_source, default_premises, resolve_source, shown_premises

    scene = load_scene(room)
    assert scene.scene_box.type == "bounded"
    assert default_premises(scene) == {"room", "manhattan", "box"} == shown_premises(scene)
    assert shown_premises(scene, ["room"]) == {"room"}
    assert auto_source(scene, []) == resolve_source("auto", scene) == "planes"  # auto: planes iff bounded, still
    scene.scene_box = None
    assert default_premises(scene) == {"room", "manhattan"} == shown_premises(scene, ["room", "manhattan", "box"])
    assert resolve_source("auto", scene, {"room", "manhattan"}) == "sparse" and resolve_source("planes", scene) == "planes"


def test_point_share_draws_that_share_of_target_rays_among_the_points(room):
    # 5 point targets per frame beside 200 dense ones (as plane targets outnumber points): uniformly drawn,
    # points get ~2 % of the target rays; with point_share 0.5, half of them.
    import dataclasses

    scene = load_scene(room)
    frames = scene.split("train")
    pts = image_depth_targets(scene, frames, ImageDepthConfig(source="sparse"))
    rng = np.random.default_rng(0)
    w, h = int(scene.cameras.width[0]), int(scene.cameras.height[0])
    f = np.repeat(pts.frame[np.unique(pts.frame, return_index=True)[1]], 200)
    dense = dataclasses.replace(pts, frame=np.r_[pts.frame, f], u=np.r_[pts.u, rng.uniform(0, w - 1, len(f))].astype(np.float32),
                                v=np.r_[pts.v, rng.uniform(0, h - 1, len(f))].astype(np.float32),
                                z=np.r_[pts.z, np.full(len(f), 3.0, np.float32)], sigma=np.r_[pts.sigma, np.full(len(f), 0.5, np.float32)],
                                dense=np.r_[np.zeros(len(pts), bool), np.ones(len(f), bool)])
    norm, _ = infer_normalization(scene)
    rays = RayGenerator(scene.cameras, norm.c2w_normalized(scene.cameras.c2w))
    data = TrainingData(scene, frames, rays, progress=False, targets=dense, target_scale=norm.scale)
    for share, lo, hi in ((0.0, 0.0, 0.1), (0.5, 0.5, 0.5)):
        batch = data.sample(len(frames), 4, 0, torch.Generator().manual_seed(1), target_rays_per_image=40,
                            point_share=share)
        has = batch.depth_sigma > 0
        is_point = batch.depth_sigma[has] < 0.1 * norm.scale  # points carry 2 cm, the fake dense ones 50 cm
        assert int(has.sum()) == 3 * 40 and lo <= float(is_point.float().mean()) <= hi


def test_target_rays_are_drawn_on_the_generators_device(room, tmp_path, checked_draws):
    """The rays through the points are drawn like every other batch ray (CUDA rejects a CPU draw there)."""
    res = train(room, preset="fast", output_dir=tmp_path / "runs", overrides=TINY, progress=False,
                print_summary=False)
    assert res.summary["image_depth"]["targets"] > 0
    assert ("rand", "cpu") in checked_draws


def test_source_none_and_frames_with_depth_maps_get_no_targets(room):
    scene = load_scene(room)
    none = image_depth_targets(scene, scene.split("train"), ImageDepthConfig(source="none"))
    assert len(none) == 0 and none.info["source"] == "none"


# ------------------------------------------------------------------------------------------ training
def _strip_depth(root):
    meta = json.loads((root / "transforms.json").read_text())
    for fr in meta["frames"]:
        fr.pop("depth_file_path", None)
    (root / "transforms.json").write_text(json.dumps(meta))


def test_training_triangulates_at_the_start_caches_and_records_it(tmp_path):
    textured_plane_scene(tmp_path / "plane", n=5)
    _strip_depth(tmp_path / "plane")
    res = train(tmp_path / "plane", preset="fast", output_dir=tmp_path / "runs", overrides=TINY, progress=False,
                print_summary=False)
    info = res.summary["image_depth"]
    # one textured plane is no room: auto is the plane sweep, which assumes nothing of the scene
    profile = yaml.safe_load((res.run.path / "config.yml").read_text())["scene"]["profile"]
    assert "room" not in profile["premises"], profile
    assert info["source"] == "dense" and "plane-sweep" in [s["name"] for s in info["steps"]]
    assert info["points_from"] == "triangulated"
    assert info["points"] > 50 and info["targets"] > 100 and info["median_error_px"] < 1.0
    assert res.summary["inputs"] == "RGB + SfM points"
    assert (res.run.path / "image_depth" / "sparse" / "points3D.ply").is_file()
    cfg = yaml.safe_load((res.run.path / "config.yml").read_text())
    assert cfg["scene"]["inputs"] == "RGB + SfM points" and cfg["scene"]["image_depth"]["points"] == info["points"]
    logged = [json.loads(x) for x in (res.run.path / "log.jsonl").read_text().splitlines()]
    assert any("image_depth" in r for r in logged if "eval" not in r)
    # A resumed run reads its own cache instead of triangulating again.
    res2 = train(resume=res.run.path, overrides={"optim": {"steps": 6}}, progress=False, print_summary=False)
    assert res2.summary["image_depth"]["points_from"] == "triangulated (cached)"


def test_nothing_to_triangulate_is_a_warning_and_training_goes_on_rgb_only(tmp_path):
    textured_plane_scene(tmp_path / "plane", n=4)
    _strip_depth(tmp_path / "plane")
    meta = json.loads((tmp_path / "plane" / "transforms.json").read_text())
    for fr in meta["frames"]:  # every camera at the same place: no baseline
        fr["transform_matrix"] = meta["frames"][0]["transform_matrix"]
    (tmp_path / "plane" / "transforms.json").write_text(json.dumps(meta))
    res = train(tmp_path / "plane", preset="fast", output_dir=tmp_path / "runs", overrides=TINY, progress=False,
                print_summary=False)
    info = res.summary["image_depth"]
    assert info["targets"] == 0 and res.summary["inputs"] == "RGB" and res.steps == 4
    assert any("no view pairs" in w for w in info["warnings"])
    cfg = yaml.safe_load((res.run.path / "config.yml").read_text())
    assert cfg["scene"]["image_depth"]["warnings"] == info["warnings"]


def test_unknown_image_depth_source_is_a_one_line_input_error(room):
    from lift3d.errors import InputError

    with pytest.raises(InputError, match="--image_depth.source"):
        image_depth_targets(load_scene(room), load_scene(room).split("train"), ImageDepthConfig(source="lidar"))


def test_planarity_prior_is_zero_on_planes_and_counts_only_triples_inside_one_valid_segment():
    from lift3d.model.losses import planar_segment_loss

    u, v = torch.meshgrid(torch.arange(6.0), torch.arange(6.0), indexing="ij")
    plane = (0.3 + 0.02 * u - 0.01 * v)[None]
    bowl = (0.3 + 0.01 * (u - 2.5) ** 2)[None]
    one, ok = torch.ones(1, 6, 6), torch.ones(1, 6, 6, dtype=torch.bool)
    assert float(planar_segment_loss(plane, one, ok)) < 1e-6
    assert float(planar_segment_loss(bowl, one, ok)) == pytest.approx(2 * 0.01 * 4 * 6 / (2 * 4 * 6))
    # Two planes meeting at a crease between two segments: no triple spans the crease.
    crease = torch.where(u < 3, 0.3 + 0.05 * u, 0.45 - 0.05 * (u - 3))[None]
    halves = (u >= 3).float()[None]
    assert float(planar_segment_loss(crease, halves, ok)) < 1e-6 < float(planar_segment_loss(crease, one, ok))
    assert float(planar_segment_loss(bowl, one, torch.zeros_like(ok))) == 0.0  # nothing valid: 0, not NaN


def test_plane_sweep_depths_few_views_confirmed_are_left_out_of_the_plane_fit_when_recorded(tmp_path):
    from lift3d.data.stereo import DenseDepth
    from lift3d.train.target_steps.plane_rules import dense_points

    gt = textured_plane_scene(tmp_path / "s", n=2)
    scene = load_scene(tmp_path / "s")
    depth = gt[0].astype(np.float32)
    support = np.full(depth.shape, 2, np.uint8)
    support[:, :20] = 1  # the part only one source view confirmed
    labels = {0: np.full(depth.shape, 7, np.int64)}
    recorded = DenseDepth(["f0"], [depth], [np.full_like(depth, 0.01)], support=[support])
    xyz, cls, cams = dense_points(scene, recorded, labels, min_support=2)
    assert len(xyz) == int((support >= 2).sum()) and np.all(cls == 7) and cams.shape == xyz.shape
    assert np.allclose(xyz[:, 2], 0.0, atol=1e-4)  # back on the floor z = 0 the depths came from
    assert len(dense_points(scene, recorded, labels, min_support=0)[0]) == depth.size
    unrecorded = DenseDepth(["f0"], [depth], [np.full_like(depth, 0.01)])
    assert len(dense_points(scene, unrecorded, labels, min_support=2)[0]) == depth.size


def test_plane_fit_takes_the_sweeps_depths_at_the_resolution_it_matched(tmp_path):
    from lift3d.data.stereo import DenseDepth
    from lift3d.train.target_steps.plane_rules import dense_points

    gt = textured_plane_scene(tmp_path / "s", n=2)
    scene = load_scene(tmp_path / "s")
    depth = gt[0].astype(np.float32)
    h, w = depth.shape
    labels = {0: np.full(depth.shape, 7, np.int64)}
    maps = DenseDepth(["f0"], [depth], [np.full_like(depth, 0.01)])
    every = dense_points(scene, maps, labels, min_support=0)[0]
    # a cap of half the longer side: every 2nd pixel of each row and column, still on the floor
    half = dense_points(scene, maps, labels, min_support=0, max_size=max(h, w) // 2)[0]
    assert len(half) == (h // 2) * (w // 2)  # the centre pixel of each 2 x 2 block
    assert np.allclose(half[:, 2], 0.0, atol=1e-4) and len(half) < len(every)
    assert len(dense_points(scene, maps, labels, min_support=0, max_size=max(h, w))[0]) == len(every)


def test_the_free_space_test_draws_at_most_max_sightlines_evenly():
    from lift3d.train.target_steps.plane_rules import FitPlanes

    cams = np.repeat(np.arange(10.0), 1000)[:, None] * np.ones(3)  # 10 cameras, 1000 sight lines each
    seen = cams + 1.0
    step = FitPlanes(max_sightlines=2000)
    c, p = step.drawn(cams, seen)
    assert len(c) == 2000 and np.allclose(p, c + 1.0)  # pairs stay pairs
    assert np.all(np.abs(np.bincount(c[:, 0].astype(int), minlength=10) - 200) < 60)  # every camera in proportion
    assert np.array_equal(step.drawn(cams, seen)[0], c)  # seeded
    assert len(FitPlanes(max_sightlines=0).drawn(cams, seen)[0]) == len(cams)
    assert len(FitPlanes(max_sightlines=20000).drawn(cams, seen)[0]) == len(cams)
