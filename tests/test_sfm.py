"""Geometry from the images (lift3d.sfm): triangulation, the epipolar check, filters, plane sweep, storage."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from lift3d.cli.main import main as cli_main
from lift3d.data.cameras import Cameras, look_at
from lift3d.data.scene import Category, FramePseudoLabels, SceneWriter, Segment, load_scene
from lift3d.data.stereo import DenseDepth, SparsePoints, read_sparse_points, write_mvs_depth, write_sparse_points
from lift3d.errors import InputError
from lift3d.sfm import SfmConfig, TrackConfig, plane_sweep_scene, triangulate_scene
from lift3d.sfm.config import MatchConfig
from lift3d.sfm.geometry import fundamental, intrinsics, project, world_to_camera
from lift3d.sfm.matching import match_pair
from lift3d.sfm.triangulation import triangulate_tracks

F = 80.0
SIZE = 64


def ring_cameras(n=6, radius=2.0, height=0.3, target=(0.0, 0.0, 0.0)):
    """OpenGL cameras on an arc around ``target``, all looking at it."""
    c2w = []
    for k in range(n):
        a = np.radians(-40 + 80 * k / max(n - 1, 1))
        eye = np.array([radius * np.sin(a), -radius * np.cos(a), height])
        c2w.append(look_at(eye, np.asarray(target, float)))
    return Cameras(c2w=np.stack(c2w), fx=F, fy=F, cx=SIZE / 2, cy=SIZE / 2, width=SIZE, height=SIZE)


def observe(cams, xyz, noise=0.0, seed=0):
    """Every point seen by every camera: view, ideal pixel and track arrays."""
    r, t = world_to_camera(cams)
    k = intrinsics(cams)
    n_v, n_p = len(cams), len(xyz)
    view = np.tile(np.arange(n_v), n_p)
    track = np.repeat(np.arange(n_p), n_v)
    p, z, _ = project(r, t, k, view, xyz[track])
    p = p + np.random.default_rng(seed).normal(0, noise, p.shape) if noise else p
    return r, t, k, view, p, track, z


# ------------------------------------------------------------------------------------------ triangulation
def test_triangulation_recovers_points_without_noise():
    cams = ring_cameras()
    xyz = np.random.default_rng(1).uniform(-0.4, 0.4, (50, 3))
    r, t, k, view, p, track, _ = observe(cams, xyz)
    out = triangulate_tracks(r, t, k, view, p, track, TrackConfig())
    assert sum(out.dropped.values()) == 0
    np.testing.assert_allclose(out.xyz, xyz, atol=1e-7)
    np.testing.assert_allclose(out.error, 0.0, atol=1e-6)
    assert np.all(np.bincount(out.obs_point) == len(cams))


def test_triangulation_with_pixel_noise_is_within_its_sigma():
    cams = ring_cameras()
    xyz = np.random.default_rng(2).uniform(-0.4, 0.4, (400, 3))
    r, t, k, view, p, track, z_true = observe(cams, xyz, noise=0.5, seed=3)
    out = triangulate_tracks(r, t, k, view, p, track, TrackConfig(sigma_floor=0.5))
    assert len(out.xyz) == len(xyz)
    err = np.linalg.norm(out.xyz - xyz, axis=1)
    # 0.5 px at 2 m with f = 80 is 1.25 cm across one ray; six rays over 80 degrees pin the point about that well.
    assert np.median(err) < 0.02
    dz = np.abs(out.obs_depth - z_true[out.obs_index])
    within = np.mean(dz < 2 * out.obs_sigma)
    assert 0.85 < within <= 1.0  # a calibrated Gaussian gives 0.95
    assert 0.3 < np.median(out.error) < 0.8


def test_points_behind_outside_short_inconsistent_and_flat_are_dropped_and_counted():
    cams = ring_cameras()
    r, t, k = *world_to_camera(cams), intrinsics(cams)
    good = np.array([[0.1, 0.0, 0.1], [-0.2, 0.1, 0.0], [0.0, -0.1, 0.2]])
    behind = np.array([[0.0, -6.0, 0.0]])  # behind every camera (they look towards +y from y < 0)
    outside = np.array([[0.0, 0.0, 1.2]])  # in front of the cameras, above the box
    rows = []
    for kind, pts in (("good", good), ("behind", behind), ("outside", outside)):
        for x in pts:
            v = np.arange(len(cams))
            p, _, _ = project(r, t, k, v, np.repeat(x[None], len(v), 0))
            rows.append((kind, v, p))
    # A two-view track, and a track whose observations are of different points (no consistent 3D point).
    v2 = np.array([0, 1])
    rows.append(("short", v2, project(r, t, k, v2, np.repeat(good[:1], 2, 0))[0]))
    v4 = np.arange(4)
    mixed = np.stack([good[0], good[1], good[2], good[0] + [0.3, 0.0, 0.2]])
    rows.append(("inconsistent", v4, project(r, t, k, v4, mixed)[0]))
    view = np.concatenate([v for _, v, _ in rows])
    p = np.concatenate([q for _, _, q in rows])
    track = np.concatenate([np.full(len(v), i) for i, (_, v, _) in enumerate(rows)])
    aabb = np.array([[-1.0, -1.0, -0.5], [1.0, 1.0, 0.5]])
    out = triangulate_tracks(r, t, k, view, p, track, TrackConfig(box_margin=0.05), aabb=aabb)
    assert out.dropped == {"short track": 1, "behind camera": 1, "large error": 1, "small angle": 0,
                           "outside box": 1}
    np.testing.assert_allclose(np.sort(out.xyz, axis=0), np.sort(good, axis=0), atol=1e-6)
    # Unbounded scenes keep points outside their (foreground) box.
    out = triangulate_tracks(r, t, k, view, p, track, TrackConfig(), aabb=aabb, bounded=False)
    assert out.dropped["outside box"] == 0 and len(out.xyz) == 4


def test_tiny_baseline_is_dropped_as_small_angle():
    eye = np.array([0.0, -3.0, 0.0])
    c2w = [look_at(eye + [0.002 * k, 0, 0], np.zeros(3)) for k in range(4)]
    cams = Cameras(c2w=np.stack(c2w), fx=F, fy=F, cx=SIZE / 2, cy=SIZE / 2, width=SIZE, height=SIZE)
    r, t, k, view, p, track, _ = observe(cams, np.array([[0.1, 0.0, 0.05], [0.0, 0.2, -0.1]]))
    out = triangulate_tracks(r, t, k, view, p, track, TrackConfig(min_triangulation_angle=1.0))
    assert out.dropped["small angle"] == 2 and len(out.xyz) == 0


# ------------------------------------------------------------------------------------------ matching
def test_epipolar_check_rejects_matches_that_break_the_known_geometry():
    cams = ring_cameras(n=2)
    r, t, k = *world_to_camera(cams), intrinsics(cams)
    xyz = np.random.default_rng(4).uniform(-0.3, 0.3, (30, 3))
    pi, _, _ = project(r, t, k, np.zeros(30, int), xyz)
    pj, _, _ = project(r, t, k, np.ones(30, int), xyz)
    desc = np.random.default_rng(5).normal(size=(30, 128)).astype(np.float32)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    # Swap the positions of the highest and the lowest keypoint in view j (far apart across the nearly
    # horizontal epipolar lines): their descriptors still match perfectly, their geometry does not.
    a, b = int(np.argmin(pj[:, 1])), int(np.argmax(pj[:, 1]))
    pj_wrong = pj.copy()
    pj_wrong[[a, b]] = pj[[b, a]]
    f = fundamental(r, t, k, 0, 1)
    for guided in (False, True):
        m, _ = match_pair(desc, desc, pi, pj, f, MatchConfig(guided=guided))
        assert sorted(map(tuple, m.tolist())) == [(c, c) for c in range(30)]
        m, _ = match_pair(desc, desc, pi, pj_wrong, f, MatchConfig(guided=guided, max_epipolar_error=1.0))
        pairs = set(map(tuple, m.tolist()))
        assert pairs == {(c, c) for c in range(30)} - {(a, a), (b, b)}


# ------------------------------------------------------------------------------------------ scenes
def textured_plane_scene(root, n=4, k1=0.0, c2w=None):
    """Cameras above a textured floor z = 0 (rendered exactly by ray casting onto the plane); ``k1`` != 0
    makes them OPENCV cameras with that radial distortion. ``c2w``: other camera poses (default: four on a
    short arc, all looking at one spot)."""
    rng = np.random.default_rng(6)
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (512, 512)).astype(np.float32), (0, 0), 2.0)
    tex = cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX)
    if c2w is None:
        c2w = [look_at(np.array([-0.45 + 0.3 * k, -1.2, 1.6]), np.array([0.0, 0.3, 0.0])) for k in range(n)]
    n = len(c2w)
    model = "OPENCV" if k1 else "PINHOLE"
    cams = Cameras(c2w=np.stack(c2w), fx=F, fy=F, cx=SIZE / 2, cy=SIZE / 2, width=SIZE, height=SIZE,
                   camera_model=model, distortion=[k1, 0, 0, 0, 0])
    cats = [Category(1, "floor", False)]
    depths = []
    with SceneWriter(root, cats, camera_model=model) as w:
        for i in range(n):
            v, u = np.mgrid[0:SIZE, 0:SIZE]
            o, d = cams.rays(i, u.ravel(), v.ravel())
            s = -o[:, 2] / d[:, 2]
            x = o + d * s[:, None]
            mx = ((x[:, 0] + 2.0) / 4.0 * 512 - 0.5).reshape(SIZE, SIZE).astype(np.float32)
            my = ((x[:, 1] + 2.0) / 4.0 * 512 - 0.5).reshape(SIZE, SIZE).astype(np.float32)
            grey = cv2.remap(tex, mx, my, cv2.INTER_LINEAR)
            img = np.repeat(np.clip(grey, 0, 255).astype(np.uint8)[..., None], 3, axis=2)
            z = (s * (d @ cams.forward[i])).reshape(SIZE, SIZE)
            depths.append(z)
            w.add_frame(f"f{i}", img, c2w[i], (F, F, SIZE / 2, SIZE / 2),
                        labels=FramePseudoLabels(np.ones((SIZE, SIZE), np.int64), [Segment(1, 1)]), depth=z,
                        distortion={"k1": k1} if k1 else None)
        w.set_scene_box("bounded", np.array([[-2.0, -2.0, -0.3], [2.0, 2.0, 2.0]]))
        w.set_splits([f"images/f{i}.png" for i in range(n)])
    return depths


@pytest.mark.parametrize("k1", [0.0, -0.3])
def test_plane_sweep_recovers_a_textured_plane(tmp_path, k1):
    depths = textured_plane_scene(tmp_path / "plane", k1=k1)
    scene = load_scene(tmp_path / "plane")
    cfg = SfmConfig()
    cfg.dense.consistent_views = 1
    dense = plane_sweep_scene(scene, config=cfg)
    assert len(dense) == 4
    for d, s, gt in zip(dense.depth, dense.sigma, depths):
        valid = d > 0
        assert valid.mean() > 0.5
        rel = np.abs(d[valid] - gt[valid]) / gt[valid]
        assert np.median(rel) < 0.01 and np.mean(rel < 0.03) > 0.9
        assert np.all(s[valid] > 0) and np.all(s[~valid] == 0)


@pytest.mark.parametrize("fewer", [True, False])
def test_plane_sweep_gives_depth_where_only_one_source_view_sees_the_point(tmp_path, fewer):
    # Cameras side by side looking the same way: the first view's left part holds floor that only the second
    # view also sees (the end of a walk). Asking two sources there leaves it without depth.
    c2w = [look_at(np.array([-0.9 + 0.5 * k, -1.2, 1.6]), np.array([-0.9 + 0.5 * k, 0.3, 0.0])) for k in range(4)]
    depths = textured_plane_scene(tmp_path / "walk", c2w=c2w)
    scene = load_scene(tmp_path / "walk")
    cfg = SfmConfig()
    cfg.dense.fewer_where_fewer_see = fewer
    dense = plane_sweep_scene(scene, config=cfg)
    cams = scene.cameras
    # pixels of view 0 whose floor point lies in view 1's image but not in view 2's or view 3's
    v, u = np.mgrid[0:SIZE, 0:SIZE]
    x = cams.unproject(0, u.ravel() + 0.5, v.ravel() + 0.5, depths[0].ravel())
    seen_by = [((uv >= 0) & (uv < SIZE)).all(1) & (z > 0) for uv, z in (cams.project(j, x) for j in (1, 2, 3))]
    only_one = (seen_by[0] & ~seen_by[1] & ~seen_by[2]).reshape(SIZE, SIZE)
    only_one[:, :4] = only_one[:, -4:] = False  # a ZNCC window needs the image around the pixel
    assert only_one.sum() > 200
    d = dense.depth[0]
    if not fewer:
        assert np.mean(d[only_one] > 0) < 0.05
        return
    got = only_one & (d > 0)
    assert got.sum() > 0.5 * only_one.sum()
    rel = np.abs(d[got] - depths[0][got]) / depths[0][got]
    assert np.median(rel) < 0.01 and np.mean(rel < 0.03) > 0.9
    # where two sources see the point, two still have to agree: depth as good as before
    two = (seen_by[0] & seen_by[1]).reshape(SIZE, SIZE) & (d > 0)
    assert np.mean(np.abs(d[two] - depths[0][two]) / depths[0][two] < 0.03) > 0.9
    # the support says which is which: one source confirmed the first, two or more the second
    n = dense.support[0]
    assert np.all(n[got] == 1) and np.mean(n[two] >= 2) > 0.9 and np.all(n[d == 0] == 0)


@pytest.mark.parametrize("best_k", [2, 3])
def test_the_fewer_sources_rule_swept_beside_the_full_rule_equals_it_swept_alone(tmp_path, best_k):
    # Swept together, the fewer-sources rule's winner is taken over from the full rule's wherever every plane's
    # point is in at least best_k sources' images, and the two means come from one running sum; swept alone, it
    # takes the winner of its whole cost volume. Same maps, on the walk whose ends only one source sees.
    from lift3d.sfm.mvs import intrinsics, sweep_view, world_to_camera, _grey

    c2w = [look_at(np.array([-0.9 + 0.5 * k, -1.2, 1.6]), np.array([-0.9 + 0.5 * k, 0.3, 0.0])) for k in range(4)]
    textured_plane_scene(tmp_path / "walk", c2w=c2w)
    scene = load_scene(tmp_path / "walk")
    cams = scene.cameras
    dc = SfmConfig().dense
    dc.best_k = best_k
    r, t = world_to_camera(cams)
    ks = intrinsics(cams)
    greys = [_grey(scene.image(i), (SIZE, SIZE)) for i in range(4)]
    rel = [(r[n] @ r[0].T, t[n] - r[n] @ r[0].T @ t[0]) for n in (1, 2, 3)]
    args = (greys[0], greys[1:], ks[0], list(ks[1:]), rel, 0.5, 6.0, dc, [np.array([0.0, 0, 1]), r[0] @ [0, 0, 1.0]])
    full, together = sweep_view(*args, rules=(False, True))
    (alone,) = sweep_view(*args, rules=(True,))
    (full_alone,) = sweep_view(*args, rules=(False,))
    assert (together[0] > 0).sum() > (full[0] > 0).sum() > 100  # the rule adds depth at the walk's end
    for a, b in zip(together + full, alone + full_alone):
        np.testing.assert_array_equal(a, b)


def test_triangulation_with_distorted_cameras(tmp_path):
    depths = textured_plane_scene(tmp_path / "plane", k1=-0.3)
    scene = load_scene(tmp_path / "plane")
    assert scene.cameras.has_distortion
    sp = triangulate_scene(scene)
    assert len(sp) > 50 and np.median(sp.error) < 0.5
    for k in range(len(scene)):
        obs = sp.frame_observations(k)
        uv, z = scene.cameras.project(k, sp.xyz[obs["point"]])  # distortion applied
        # 0.08 px with undistorted keypoints; treating them as pinhole pixels leaves ~0.5 px.
        assert np.median(np.linalg.norm(uv - obs["uv"], axis=1)) < 0.25
        c = obs["uv"].astype(int)
        assert np.median(np.abs(obs["depth"] - depths[k][c[:, 1], c[:, 0]]) / obs["depth"]) < 0.01


def test_triangulate_scene_on_a_textured_plane_and_the_cli_round_trip(tmp_path, capsys):
    depths = textured_plane_scene(tmp_path / "plane")
    scene = load_scene(tmp_path / "plane")
    sp = triangulate_scene(scene)
    assert len(sp) > 50 and sp.info["warnings"] == []
    rel = []
    for k in range(len(scene)):
        obs = sp.frame_observations(k)
        c = obs["uv"].astype(int)
        rel.append(np.abs(obs["depth"] - depths[k][c[:, 1], c[:, 0]]) / obs["depth"])
    assert np.median(np.concatenate(rel)) < 0.01
    rc = cli_main(["triangulate", "--data", str(tmp_path / "plane"), "--dense", "--quiet",
                   "--dense.consistent-views", "1"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "points, median reprojection error" in out and "dropped: short track" in out and "dense:" in out
    scene = load_scene(tmp_path / "plane")
    scene.validate()
    loaded = scene.sparse_points()
    assert len(loaded) > 50 and loaded.frame_names == [f.name for f in scene.frames]
    d, s = scene.mvs_depth(1)
    assert (d > 0).mean() > 0.5 and np.all(s[d > 0] > 0)
    meta = json.loads((tmp_path / "plane" / "transforms.json").read_text())
    assert meta["sparse_points"]["source"] == "lift3d triangulate"
    assert meta["frames"][0]["mvs_depth_file_path"] == "mvs/depth/f0.png"


def test_orb_features_and_a_detached_output_folder(tmp_path, capsys):
    textured_plane_scene(tmp_path / "plane")
    before = (tmp_path / "plane" / "transforms.json").read_text()
    rc = cli_main(["triangulate", "--data", str(tmp_path / "plane"), "--out", str(tmp_path / "elsewhere"),
                   "--features.detector", "orb", "--quiet"])
    assert rc == 0
    assert (tmp_path / "plane" / "transforms.json").read_text() == before  # the scene is left alone
    record = json.loads((tmp_path / "elsewhere" / "triangulation.json").read_text())
    entry = record["sparse_points"]
    assert entry["count"] > 20 and entry["settings"] == {"features": {"detector": "orb"}}
    sp = read_sparse_points(tmp_path / "elsewhere" / entry["points"], tmp_path / "elsewhere" / entry["observations"])
    assert len(sp) == entry["count"] and np.median(sp.error) < 1.0


def test_degenerate_baseline_is_a_warning_not_a_crash(tmp_path, capsys):
    textured_plane_scene(tmp_path / "plane")
    meta = json.loads((tmp_path / "plane" / "transforms.json").read_text())
    for fr in meta["frames"]:  # every camera at the same place: rotation only
        fr["transform_matrix"] = meta["frames"][0]["transform_matrix"]
    (tmp_path / "plane" / "transforms.json").write_text(json.dumps(meta))
    rc = cli_main(["triangulate", "--data", str(tmp_path / "plane"), "--dense", "--quiet"])
    assert rc == 0
    captured = capsys.readouterr()
    assert "sparse: no points" in captured.out
    assert "warning: no view pairs" in captured.err and "warning: only 0 points" in captured.err
    assert load_scene(tmp_path / "plane").sparse_points() is not None


# ------------------------------------------------------------------------------------------ storage
def small_sparse(names):
    return SparsePoints(
        xyz=np.array([[0.0, 0.1, 0.2], [1.0, 1.5, -0.5]]), rgb=np.array([[1, 2, 3], [250, 128, 0]], np.uint8),
        error=np.array([0.3, 0.7], np.float32), track_length=np.array([2, 1], np.int32), frame_names=names,
        obs_frame=np.array([1, 0, 1], np.int32), obs_point=np.array([0, 0, 1], np.int32),
        obs_uv=np.array([[10.5, 3.25], [1.0, 2.0], [30.0, 31.0]], np.float32),
        obs_depth=np.array([1.5, 2.0, 2.5], np.float32), obs_sigma=np.array([0.01, 0.02, 0.03], np.float32),
        info={"source": "test"})


def test_sparse_points_and_mvs_depth_round_trip(tmp_path):
    textured_plane_scene(tmp_path / "s", n=2)
    # Names in another order than the scene's: the reader maps them to scene frame indices.
    write_sparse_points(tmp_path / "s", small_sparse(["f1", "f0"]))
    scene = load_scene(tmp_path / "s")
    sp = scene.sparse_points()
    np.testing.assert_allclose(sp.xyz, [[0.0, 0.1, 0.2], [1.0, 1.5, -0.5]], atol=1e-7)
    assert sp.rgb.tolist() == [[1, 2, 3], [250, 128, 0]] and sp.track_length.tolist() == [2, 1]
    assert sp.frame_names == ["f0", "f1"] and sp.obs_frame.tolist() == [0, 1, 0]
    np.testing.assert_allclose(sp.frame_observations(0)["uv"], [[10.5, 3.25], [30.0, 31.0]])
    assert sp.frame_observations(1)["sigma"].tolist() == pytest.approx([0.02])
    depth = np.full((SIZE, SIZE), 2.0, np.float32)
    depth[:10] = 0
    sigma = np.where(depth > 0, 0.0002, 0).astype(np.float32)  # below one unit (1 mm): stored as 1 mm
    write_mvs_depth(tmp_path / "s", DenseDepth(["f1"], [depth], [sigma]), 1e-3)
    scene = load_scene(tmp_path / "s")
    assert scene.mvs_depth(0) is None
    d, s = scene.mvs_depth(1)
    np.testing.assert_allclose(d, depth, atol=5e-4)
    assert np.all(s[depth > 0] == pytest.approx(1e-3)) and np.all(s[depth == 0] == 0)
    assert scene.mvs_support(1) is None  # not recorded
    scene.validate()
    # with how many views confirmed each depth; 0 where there is none
    support = np.where(np.arange(SIZE)[None, :] < 20, 1, 3).astype(np.uint8) * (depth > 0)
    write_mvs_depth(tmp_path / "s", DenseDepth(["f1"], [depth], [sigma], support=[support]), 1e-3)
    scene = load_scene(tmp_path / "s")
    assert np.array_equal(scene.mvs_support(1), support) and scene.mvs_support(0) is None
    scene.validate()
    # written again without it: the frame no longer refers to the old map
    write_mvs_depth(tmp_path / "s", DenseDepth(["f1"], [depth], [sigma]), 1e-3)
    assert load_scene(tmp_path / "s").mvs_support(1) is None


@pytest.mark.parametrize("corrupt,problem", [
    (lambda a: a.pop("sigma"), "arrays ['sigma'] are missing"),
    (lambda a: a.__setitem__("point", np.array([0, 0, 5], np.int32)), "point indices must lie in [0, 2)"),
    (lambda a: a.__setitem__("frame_names", np.array(["f1", "nope"])), "frames ['nope'] are not in transforms.json"),
    (lambda a: a.__setitem__("depth", np.array([1.5, -2.0, 2.5], np.float32)), "depth and sigma must be positive"),
    (lambda a: a.__setitem__("uv", np.zeros((2, 2), np.float32)), "one entry per observation"),
    (lambda a: a.__setitem__("point", np.array([0, 1, 1], np.int32)), "track_length does not match"),
])
def test_bad_sparse_files_are_one_line_errors_naming_the_file(tmp_path, corrupt, problem):
    textured_plane_scene(tmp_path / "s", n=2)
    write_sparse_points(tmp_path / "s", small_sparse(["f1", "f0"]))
    path = tmp_path / "s" / "sparse" / "observations.npz"
    arrays = dict(np.load(path))
    corrupt(arrays)
    np.savez(path, **arrays)
    with pytest.raises(InputError) as err:
        load_scene(tmp_path / "s").sparse_points()
    assert problem in err.value.problem
    where = "points3D.ply" if "track_length" in problem else "observations.npz"
    assert err.value.where.endswith(where) and "\n" not in str(err.value)


def test_bad_sparse_entries_and_files(tmp_path):
    textured_plane_scene(tmp_path / "s", n=2)
    write_sparse_points(tmp_path / "s", small_sparse(["f1", "f0"]))
    (tmp_path / "s" / "sparse" / "observations.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="not a readable .npz file"):
        load_scene(tmp_path / "s").sparse_points()
    (tmp_path / "s" / "sparse" / "points3D.ply").unlink()
    with pytest.raises(InputError) as err:
        load_scene(tmp_path / "s")
    assert err.value.where.endswith("points3D.ply") and "file not found" in err.value.problem
    meta = json.loads((tmp_path / "s" / "transforms.json").read_text())
    meta["sparse_points"] = {"points": 3}
    (tmp_path / "s" / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match="sparse_points: needs 'points' and 'observations'"):
        load_scene(tmp_path / "s")


def test_bad_settings_name_the_flag(tmp_path, capsys):
    textured_plane_scene(tmp_path / "s", n=2)
    rc = cli_main(["triangulate", "--data", str(tmp_path / "s"), "--dense.window", "4"])
    assert rc == 2
    assert "--dense.window: must be an odd number >= 3" in capsys.readouterr().err
    rc = cli_main(["triangulate", "--data", str(tmp_path / "s"), "--features.detector", "surf"])
    assert rc == 2
    assert "--features.detector" in capsys.readouterr().err
