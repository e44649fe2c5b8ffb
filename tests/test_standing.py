"""Upright faces of things standing on the floor (lift3d.sfm.standing): boxes get faces where they stand, an
overhang gets none, and stereo depths that disagree with a face refute it."""

import numpy as np

from lift3d.data.cameras import Cameras, look_at
from lift3d.sfm.standing import StandingFaces, StandingSettings, standing_faces, stereo_agreement

WALL, FLOOR, BOX, SLAB = 1, 2, 6, 7
UP = np.array([0.0, 0.0, 1.0])
ROOM = (np.array([-3.0, -3.0, 0.0]), np.array([3.0, 3.0, 2.6]))
BOX_LO, BOX_HI = np.array([-0.5, 1.0, 0.0]), np.array([0.3, 1.6, 1.2])     # a plain cabinet on the floor
SLAB_LO, SLAB_HI = np.array([-1.3, -1.2, 0.7]), np.array([-0.3, -0.5, 0.75])  # a table top, its legs unseen


def _slab_hit(o, d, lo, hi):
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = (lo - o) / d, (hi - o) / d
    t_in, t_out = np.nanmax(np.minimum(a, b), 1), np.nanmin(np.maximum(a, b), 1)
    return np.where((t_in < t_out) & (t_out > 0) & (t_in > 0), t_in, np.inf)


def _room(size=64, f=56.0, with_slab=False):
    """Eight views from a ring 2.4 m around the room's middle, 1.5 m up, all looking at the cabinet or the slab;
    exact labels and z-depth by ray casting (the room's inside, the cabinet, the slab)."""
    angles = np.radians(np.arange(-150, 180, 45))
    eyes = np.c_[2.4 * np.cos(angles), 2.4 * np.sin(angles) - 0.3, np.full(len(angles), 1.5)]
    target = np.array([-0.1, 1.3, 0.5])
    c2w = []
    for e in eyes:
        look = target if not with_slab or e[1] > -0.3 else np.array([-0.8, -0.85, 0.5])
        c2w.append(look_at(e, look))
    cams = Cameras(np.stack(c2w), fx=f, fy=f, cx=size / 2, cy=size / 2, width=size, height=size)
    labels, depth = {}, {}
    v, u = np.mgrid[0:size, 0:size]
    for i in range(len(eyes)):
        o, d = cams.rays(i, u.ravel().astype(float), v.ravel().astype(float))
        with np.errstate(divide="ignore", invalid="ignore"):
            a, b = (ROOM[0] - o) / d, (ROOM[1] - o) / d
        t_room = np.nanmin(np.maximum(a, b), 1)  # inside the room: where the ray leaves it
        x = o + t_room[:, None] * d
        sem = np.where(x[:, 2] < 1e-6, FLOOR, WALL)
        t = t_room
        for lo, hi, cls in [(BOX_LO, BOX_HI, BOX)] + ([(SLAB_LO, SLAB_HI, SLAB)] if with_slab else []):
            tb = _slab_hit(o, d, lo, hi)
            sem = np.where(tb < t, cls, sem)
            t = np.minimum(t, tb)
        labels[i] = sem.reshape(size, size)
        depth[i] = (t * (d @ cams.c2w_opencv[i][:3, 2])).reshape(size, size)
    return cams, labels, depth


def _faces(cams, labels):
    return standing_faces(cams, sorted(labels), labels, UP, 0.0, [FLOOR], [BOX, SLAB], [WALL, FLOOR],
                          threshold=0.06, step=0.03, max_height=2.5)


def test_a_plain_box_on_the_floor_gets_faces_along_its_sides_and_its_pixels_their_depth():
    cams, labels, depth = _room()
    faces = _faces(cams, labels)
    assert len(faces) >= 2 and (faces.classes == BOX).all()
    # every face stands on a side of the cabinet, and rises about as high as it
    for s, e, h in zip(faces.start, faces.end, faces.height):
        mid = 0.5 * (s + e)
        to_side = np.min(np.abs(np.r_[mid[:2] - BOX_LO[:2], mid[:2] - BOX_HI[:2]]))
        assert to_side < 0.06 and abs(h - BOX_HI[2]) < 0.1
    # its pixels in every view take the depth of the face they see, the views that see no foot too; pixels of
    # its top (a third to a half in the two near views) get nothing. 64-pixel views: a foot is 5-8 cm per pixel.
    hit = good = total = 0
    for i, sem in labels.items():
        r, c = np.nonzero(sem == BOX)
        o, d = cams.rays(i, c.astype(float), r.astype(float))
        t, k = faces.first_hit(o, d, sem[r, c])
        ok = k >= 0
        z = t[ok] * (d[ok] @ cams.c2w_opencv[i][:3, 2])
        total += len(r)
        hit += int(ok.sum())
        good += int((np.abs(z - depth[i][r[ok], c[ok]]) < 0.05).sum())
    assert hit > 0.45 * total and good > 0.85 * hit


def test_an_edge_over_the_floor_makes_no_face():
    # A table top seen above the floor under it: the ray through that boundary meets the floor behind the
    # edge, at a different spot for each view, and the other views see the floor through the line above it.
    cams, labels, _ = _room(with_slab=True)
    assert any((sem == SLAB).sum() > 50 for sem in labels.values())
    faces = _faces(cams, labels)
    assert (faces.classes == BOX).sum() >= 2 and not (faces.classes == SLAB).any()
    # each view alone, uncarved, would put faces under it
    alone = standing_faces(cams, sorted(labels), labels, UP, 0.0, [FLOOR], [BOX, SLAB], [WALL, FLOOR],
                           threshold=0.06, step=0.03, max_height=2.5,
                           settings=StandingSettings(min_views=1, min_carve_views=10 ** 6))
    assert (alone.classes == SLAB).sum() >= 3


def test_stereo_depths_off_a_face_refute_it_and_depths_on_it_agree():
    cams, labels, depth = _room()
    faces = _faces(cams, labels)
    views = sorted(labels)
    met, agreeing = stereo_agreement(faces, cams, views, labels, [depth[i] for i in views], tolerance=0.05)
    assert (met > 0).all() and (agreeing > 0.75 * met).all()
    # a plant's leaves: stereo puts its depths 30 cm in front of the face from the pot's foot
    nearer = [np.where(labels[i] == BOX, depth[i] - 0.3, depth[i]) for i in views]
    met, agreeing = stereo_agreement(faces, cams, views, labels, nearer, tolerance=0.05)
    assert (met > 0).all() and (agreeing < 0.1 * met).all()
    # no stereo depth at all (a plain box): nothing met, nothing refuted
    met, agreeing = stereo_agreement(faces, cams, views, labels, [np.zeros_like(depth[i]) for i in views], 0.05)
    assert not met.any() and not agreeing.any()


def test_a_ray_meets_only_faces_of_its_own_class_inside_them():
    faces = StandingFaces(start=np.array([[-1.0, 2.0, 0.0]]), end=np.array([[1.0, 2.0, 0.0]]),
                          height=np.array([1.0]), classes=np.array([BOX]), rms=np.array([0.01]),
                          views=np.array([5]), facing=np.array([[0.0, -1.0, 0.0]]), up=UP)
    o = np.zeros((4, 3)) + [0.0, 0.0, 0.5]
    d = np.array([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.6, 0.8], [0.0, -1.0, 0.0]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t, k = faces.first_hit(o, d, np.array([BOX, WALL, BOX, BOX]))
    # straight ahead: met at 2 m; another class: not; above the face's top: not; behind the camera: not
    assert k.tolist() == [0, -1, -1, -1] and abs(t[0] - 2.0) < 1e-9
    assert len(faces.subset(np.array([False]))) == 0


def test_the_training_summary_says_what_the_faces_gave():
    from lift3d.train.trainer import image_depth_lines

    info = {"source": "planes", "points": 10, "targets": 1000,
            "planes": {"planes": 4, "targets": 900, "standing": 120, "standing_faces": 3}}
    assert "(120 on 3 upright faces of things on the floor)" in image_depth_lines(info)[0]
    info["planes"]["standing"] = 0
    assert "upright faces" not in image_depth_lines(info)[0]
