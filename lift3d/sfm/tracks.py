"""Tracks: which keypoints in different views see the same 3D point (union-find over (view, keypoint)).

Pairwise matches are joined into tracks as connected components of the match graph. A wrong match can chain
two 3D points into one component, which then holds two keypoints of the same view (a *conflict*); such a
component would be dropped whole by triangulation. Conflicting components are therefore rebuilt with a
union-find that adds their matches best first (lowest descriptor ratio) and refuses any union that would put
two keypoints of one view into one track, so one wrong match costs one observation instead of a point.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


def build_tracks(edges: np.ndarray, quality: np.ndarray, node_view: np.ndarray) -> tuple[np.ndarray, int]:
    """Track label of every node.

    Parameters
    ----------
    edges : np.ndarray
        ``int64 [E, 2]`` matched node pairs (a node is one keypoint of one view).
    quality : np.ndarray
        ``[E]`` lower is better (e.g. the ratio-test ratio); conflicts are resolved in this order.
    node_view : np.ndarray
        ``[N]`` the view of each node.

    Returns
    -------
    labels : np.ndarray
        ``int64 [N]`` track id per node (unmatched nodes get their own id).
    conflicts : int
        Number of components that had to be split.

    Examples
    --------
    Node 0 (view 0) matches node 1 (view 1) and node 2 (view 2); node 2 also matches node 3 (view 0),
    a worse match that would put two keypoints of view 0 into one track:

    >>> import numpy as np
    >>> labels, n = build_tracks(np.array([[0, 1], [0, 2], [3, 2]]), np.array([0.1, 0.2, 0.5]),
    ...                          np.array([0, 1, 2, 0]))
    >>> bool(labels[0] == labels[1] == labels[2] != labels[3]), n
    (True, 1)
    """
    n = len(node_view)
    if len(edges) == 0:
        return np.arange(n, dtype=np.int64), 0
    adj = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, label = connected_components(adj, directed=False)
    label = label.astype(np.int64)
    # Components with two nodes in one view.
    key = np.unique(label * (int(node_view.max()) + 1) + node_view)
    comp_of_key = key // (int(node_view.max()) + 1)
    nodes_per_comp = np.bincount(label, minlength=label.max() + 1)
    views_per_comp = np.bincount(comp_of_key, minlength=label.max() + 1)
    bad = np.flatnonzero(nodes_per_comp > views_per_comp)
    if len(bad) == 0:
        return label, 0
    in_bad = np.zeros(label.max() + 1, bool)
    in_bad[bad] = True
    sel = np.flatnonzero(in_bad[label[edges[:, 0]]])
    sel = sel[np.argsort(quality[sel], kind="stable")]
    parent: dict[int, int] = {}
    views: dict[int, set] = {}

    def find(x: int) -> int:
        root = x
        while parent.get(root, root) != root:
            root = parent[root]
        while parent.get(x, x) != root:  # path compression
            parent[x], x = root, parent[x]
        return root

    for a, b in edges[sel].tolist():
        ra, rb = find(a), find(b)
        if ra == rb:
            continue
        va = views.get(ra, {int(node_view[ra])})
        vb = views.get(rb, {int(node_view[rb])})
        if va & vb:
            continue  # would put two keypoints of one view into one track
        if len(va) < len(vb):
            ra, rb, va, vb = rb, ra, vb, va
        parent[rb] = ra
        va |= vb
        views[ra] = va
        views.pop(rb, None)
    nodes = np.flatnonzero(in_bad[label])
    roots = np.array([find(int(x)) for x in nodes], np.int64)
    # New ids past the existing ones, so split pieces never collide with untouched components.
    label = label.copy()
    label[nodes] = label.max() + 1 + roots
    return label, len(bad)
