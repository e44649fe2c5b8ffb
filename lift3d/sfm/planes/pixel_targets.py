"""Pixel targets on the planes beyond each ray's first hit: segments a plane surrounds in a view (a window in a
wall) take its depth, and the other views' labels vote on whether a plane target is the plane's stuff."""

from __future__ import annotations

import numpy as np

from lift3d.sfm.planes.model import StuffPlanes, _beyond_hull, ray_plane_distance


def enclosed_segments(cameras, i: int, sem: np.ndarray, classes, planes: StuffPlanes, stride: int = 4,
                      min_share: float = 0.6, min_ring: int = 8, targeted: np.ndarray | None = None,
                      max_targeted: float = 0.5, margin: bool = False
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pixels of segments that one plane surrounds in view ``i``, on that plane: a window in a wall.

    A stuff class no plane holds (a window with a repeating pattern, which stereo matches wrongly, so no plane
    gathers half its points) gets no depth target, though its segment sits inside a wall whose pixels have one.
    Each connected segment of ``classes`` in ``sem`` is looked at on its own: the pixels just around it (its
    one-pixel ring, void left out) cast their rays at the planes, and when ``min_share`` of the ring meets one
    plane that holds the ring pixel's class, the segment's pixels (every ``stride``-th row and column) take
    the depth where their rays meet that plane, inside the hull of its points (no margin): sky above the
    top of a building's face is not in that face's hull.

    With ``targeted``, held classes can be enclosed too: a window in a second wall, when the plane that holds
    the window class is the first wall. Pixels that already have a target keep it, and a segment of which more
    than ``max_targeted`` of the kept pixels already have one is left alone (a floor segment that a wall's
    plane happens to surround is the floor plane's).

    Parameters
    ----------
    cameras : lift3d.data.cameras.Cameras
    i : int
        The view.
    sem : np.ndarray
        ``[H, W]`` its semantic labels (0 = void).
    classes : iterable of int
        Classes whose segments may be enclosed (stuff that no plane holds; any stuff with ``targeted``).
    planes : StuffPlanes
    stride : int
        Pixels of the segments kept: rows and columns ``stride // 2 + k · stride`` (as the plane targets).
    min_share : float
        Share of the ring that must meet the one plane.
    min_ring : int
        Fewest ring pixels (a smaller segment is noise).
    targeted : np.ndarray, optional
        ``bool [H, W]``: pixels that already have a target (they are not returned).
    max_targeted : float
        With ``targeted``: most share of a segment's kept pixels that may already have a target.
    margin : bool
        Pixels whose rays meet the plane within its margin count too (where :meth:`StuffPlanes.first_hit`
        meets it first). For a room, where no sky lies above a wall: a window high on a wall whose points stop
        below it.

    Returns
    -------
    rows, cols : np.ndarray
        ``int64 [N]`` pixels.
    t : np.ndarray
        ``[N]`` distance along each pixel's unit ray to the plane.
    plane : np.ndarray
        ``int64 [N]`` the plane.

    Examples
    --------
    A window (class 5) in the middle of a wall x = 3 (class 1) that a view from the origin looks at:

    >>> from lift3d.sfm.planes import fit_planes
    >>> from lift3d.data.cameras import Cameras, look_at
    >>> wall = np.c_[np.full(40, 3.0), np.random.default_rng(0).uniform(-2, 2, (40, 2))]
    >>> planes = fit_planes(wall, np.ones(40, int), [1], threshold=0.02)
    >>> cams = Cameras(look_at(np.zeros(3), np.array([1.0, 0, 0]))[None], fx=40.0, fy=40.0, cx=32.0, cy=32.0,
    ...                width=64, height=64)
    >>> sem = np.ones((64, 64), np.int64); sem[24:40, 24:40] = 5
    >>> r, c, t, k = enclosed_segments(cams, 0, sem, [5], planes, stride=4)
    >>> len(r), k.tolist() == [0] * len(r), bool(np.allclose(cams.rays(0, c, r)[1][:, 0] * t, 3.0))
    (16, True, True)
    """
    from scipy import ndimage

    sem = np.asarray(sem)
    empty = np.zeros(0, np.int64)
    out = []
    for cl in sorted(int(c) for c in classes):
        segments, n = ndimage.label(sem == cl)
        if n == 0:
            continue
        owner = ndimage.grey_dilation(segments, size=(3, 3))
        rr, cc = np.nonzero((owner > 0) & (segments == 0) & (sem > 0))
        if not len(rr):
            continue
        o, d = cameras.rays(i, cc, rr)
        _, hit = planes.first_hit(o, d)
        hit = np.where(planes.holds(hit, sem[rr, cc].astype(np.int64)), hit, -1)
        ring_owner = owner[rr, cc]
        ring_size = np.bincount(ring_owner, minlength=n + 1)
        for j in np.flatnonzero(ring_size >= min_ring):
            k = hit[(ring_owner == j) & (hit >= 0)]
            if not len(k):
                continue
            host = int(np.bincount(k).argmax())
            if (k == host).sum() < min_share * ring_size[j]:
                continue
            pr, pc = np.nonzero(segments[stride // 2::stride, stride // 2::stride] == j)
            pr, pc = pr * stride + stride // 2, pc * stride + stride // 2
            if targeted is not None and len(pr):
                done = targeted[pr, pc]
                if done.mean() > max_targeted:
                    continue
                pr, pc = pr[~done], pc[~done]
            if not len(pr):
                continue
            po, pd = cameras.rays(i, pc, pr)
            t, cos = ray_plane_distance(po, pd, planes.normal[host], planes.offset[host])
            with np.errstate(invalid="ignore"):
                ok = np.isfinite(t) & (t > 0) & (np.abs(cos) >= 0.1)
            _, beyond = _beyond_hull(po[ok] + t[ok, None] * pd[ok], planes.origin[host], planes.basis[host],
                                     planes.hull[host])
            inside = beyond <= 0
            if margin and not inside.all():
                inside |= planes.first_hit(po[ok], pd[ok])[1] == host
            ok[ok] = inside
            out.append((pr[ok], pc[ok], t[ok], np.full(int(ok.sum()), host, np.int64)))
    if not out:
        return empty, empty, np.zeros(0), empty
    return tuple(np.concatenate(a) for a in zip(*out))


def label_support(cameras, frames, labels: dict[int, np.ndarray], planes: StuffPlanes, points: np.ndarray,
                  plane: np.ndarray, own_frame: int, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """How many other views' 2D labels agree that plane points are the plane's stuff.

    A plane target comes from one view's label: a wardrobe that one view's segmenter calls wall gets the
    wall's depth behind it. The other views that look at that spot of the wall see the wardrobe in front of
    it and label it wardrobe. Each point is projected into every view of ``frames`` but ``own_frame``; a
    view votes when the point falls inside its image, in front of it, not behind another plane (from that
    camera the first plane met lies no nearer than the point, less ``tolerance``) and its label there is not
    void. The vote supports the point when that label is a class the point's plane holds.

    Parameters
    ----------
    cameras : lift3d.data.cameras.Cameras
    frames : np.ndarray
        The views that vote (training frames).
    labels : dict
        Frame index → ``[H, W]`` semantic pseudo-labels (0 = void).
    planes : StuffPlanes
    points : np.ndarray
        ``[N, 3]`` points on the planes (world units).
    plane : np.ndarray
        ``int64 [N]`` the plane of each point.
    own_frame : int
        The view the points came from (does not vote).
    tolerance : float
        How much nearer than the point another plane may be met and still not hide it (world units).

    Returns
    -------
    support, votes : np.ndarray
        ``int64 [N]`` supporting views and voting views.

    Examples
    --------
    A wall x = 2 that every view labels wall (class 1) on its left half and wardrobe (class 9) on its right:

    >>> from lift3d.sfm.planes import fit_planes
    >>> from lift3d.data.cameras import Cameras, look_at
    >>> rng = np.random.default_rng(0)
    >>> wall = np.c_[np.full(60, 2.0), rng.uniform(-2, 2, 60), rng.uniform(0, 3, 60)]
    >>> planes = fit_planes(wall, np.full(60, 1), [1], threshold=0.02)
    >>> eyes = [np.array([0.0, y, 1.5]) for y in (-0.5, 0.0, 0.5)]
    >>> c2w = np.stack([look_at(e, e + np.array([1.0, 0, 0])) for e in eyes])
    >>> cams = Cameras(c2w=c2w, fx=np.full(3, 50.0), fy=np.full(3, 50.0), cx=np.full(3, 50.0),
    ...                cy=np.full(3, 50.0), width=np.full(3, 100), height=np.full(3, 100))
    >>> sem = np.ones((100, 100), np.int64); sem[:, 50:] = 9
    >>> pts = np.array([[2.0, 1.0, 1.5], [2.0, -1.0, 1.5]])  # left of the views, right of the views
    >>> label_support(cams, [0, 1, 2], {i: sem for i in range(3)}, planes, pts, np.zeros(2, np.int64), 0, 0.05)
    (array([2, 0]), array([2, 2]))
    """
    points = np.asarray(points, np.float64)
    support = np.zeros(len(points), np.int64)
    votes = np.zeros(len(points), np.int64)
    plane = np.asarray(plane, np.int64)
    for j in frames:
        j = int(j)
        if j == int(own_frame) or j not in labels:
            continue
        sem = labels[j]
        h, w = sem.shape
        uv, z = cameras.project(j, points)
        with np.errstate(invalid="ignore"):
            k = np.flatnonzero((z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h))
        if not len(k):
            continue
        cls = sem[uv[k, 1].astype(np.int64), uv[k, 0].astype(np.int64)]
        k, cls = k[cls != 0], cls[cls != 0]
        if not len(k):
            continue
        center = cameras.centers[j]
        seg = points[k] - center
        dist = np.linalg.norm(seg, axis=1)
        t, _ = planes.first_hit(np.broadcast_to(center, seg.shape), seg / dist[:, None])
        open_ = t >= dist - tolerance
        k, cls = k[open_], cls[open_]
        votes[k] += 1
        support[k] += planes.holds(plane[k], cls)
    return support, votes
