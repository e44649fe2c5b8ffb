"""Scene content of ``lift3d synth`` and how it is ray cast and shaded.

A synthetic scene is a set of triangle meshes, one per labelled object (a thing instance, or one piece of a
stuff class such as a wall), cast with Open3D's ``RaycastingScene``. Every triangle carries a material; the
colour of a surface point is

``albedo(x) * (ambient + hemisphere * n_z + sum_k w_k max(0, n . l_k))``

with ``albedo(x)`` a *solid* texture (a function of the world position ``x``, so it is the same in every
view) and the shading Lambertian with fixed directional lights: the colour of a point does not depend on the
viewing direction, which keeps the scenes learnable by a radiance field. Normals are turned towards the viewer
(two-sided surfaces); curved parts interpolate vertex normals so spheres and cylinders look round.

Textures are built from a few random plane waves ``sin(w . x + phi)`` per material (wavelengths of tens of
centimetres indoors, metres outdoors) squashed through ``tanh`` and used to blend two colours, plus an optional
soft grid (planks, façade windows). Nothing is finer than a few percent of the scene size, so a dense grid of
~128³ voxels can represent it.

Coordinates: metres, z up. Indoor rooms are centred on the origin with the floor at z = 0; the outdoor street
runs along +y with the road surface at z = 0.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lift3d.data.ply import read_labelled_ply
from lift3d.data.scene import Category
from lift3d.utils.geometry import vertex_normals

#: Number of plane waves per material texture.
N_WAVES = 5


# --------------------------------------------------------------------------------------------- meshes
@dataclass
class Mesh:
    """A triangle mesh with per-corner normals and a material per triangle.

    Attributes
    ----------
    vertices : np.ndarray
        ``[V, 3]`` float64 positions.
    triangles : np.ndarray
        ``[T, 3]`` int64 vertex indices.
    corner_normals : np.ndarray
        ``[T, 3, 3]`` float64 normal at each triangle corner (equal to the face normal for flat parts,
        averaged vertex normals for curved parts).
    material : np.ndarray
        ``[T]`` int64 material index (into a :class:`MaterialBank`).
    """

    vertices: np.ndarray
    triangles: np.ndarray
    corner_normals: np.ndarray
    material: np.ndarray

    def transformed(self, rotation: np.ndarray, translation: np.ndarray, scale: float = 1.0) -> "Mesh":
        """``x -> R (s x) + t``; normals rotate with ``R``."""
        rot = np.asarray(rotation, np.float64)
        return Mesh(self.vertices * scale @ rot.T + np.asarray(translation, np.float64), self.triangles.copy(),
                    self.corner_normals @ rot.T, self.material.copy())

    @property
    def bounds(self) -> np.ndarray:
        """``[2, 3]`` axis-aligned bounding box."""
        return np.stack([self.vertices.min(0), self.vertices.max(0)])


def _face_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    n = np.cross(b - a, c - a)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def make_mesh(vertices: np.ndarray, triangles: np.ndarray, material: int, smooth: bool) -> Mesh:
    """Build a :class:`Mesh` with one material; ``smooth`` interpolates area-weighted vertex normals."""
    vertices = np.asarray(vertices, np.float64)
    triangles = np.asarray(triangles, np.int64)
    face_n = _face_normals(vertices, triangles)
    if smooth:
        corner = vertex_normals(vertices, triangles)[triangles]
    else:
        corner = np.repeat(face_n[:, None, :], 3, axis=1)
    return Mesh(vertices, triangles, corner, np.full(len(triangles), material, np.int64))


def concat_meshes(meshes: list[Mesh]) -> Mesh:
    """One mesh holding all of ``meshes`` (materials are kept per triangle)."""
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
    return Mesh(
        np.concatenate([m.vertices for m in meshes]),
        np.concatenate([m.triangles + o for m, o in zip(meshes, offsets)]),
        np.concatenate([m.corner_normals for m in meshes]),
        np.concatenate([m.material for m in meshes]),
    )


def box_mesh(lo: np.ndarray, hi: np.ndarray, material: int) -> Mesh:
    """Axis-aligned box from corner ``lo`` to corner ``hi`` (flat faces)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    corners = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], np.float64)
    verts = lo + corners * (hi - lo)
    # Two triangles per face, wound counter-clockwise seen from outside.
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    tris = [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
    return make_mesh(verts, tris, material, smooth=False)


def quad_mesh(origin: np.ndarray, edge_u: np.ndarray, edge_v: np.ndarray, material: int) -> Mesh:
    """A flat parallelogram ``origin + s edge_u + t edge_v`` for ``s, t`` in [0, 1]."""
    o, u, v = (np.asarray(a, np.float64) for a in (origin, edge_u, edge_v))
    verts = np.stack([o, o + u, o + u + v, o + v])
    return make_mesh(verts, [(0, 1, 2), (0, 2, 3)], material, smooth=False)


def lathe_mesh(radii: np.ndarray, heights: np.ndarray, material: int, segments: int = 24,
               cap_bottom: bool = True, cap_top: bool = True) -> Mesh:
    """Surface of revolution about the z axis through the profile ``(radii[k], heights[k])``.

    The side is smooth-shaded; caps (flat discs closing a profile that ends at a non-zero radius) get their own
    vertices so their normals stay flat.
    """
    radii = np.asarray(radii, np.float64)
    heights = np.asarray(heights, np.float64)
    ang = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([np.cos(ang), np.sin(ang)], -1)
    n_prof = len(radii)
    verts = np.concatenate([np.column_stack([r * ring, np.full(segments, h)]) for r, h in zip(radii, heights)])
    tris = []
    for k in range(n_prof - 1):
        for j in range(segments):
            a, b = k * segments + j, k * segments + (j + 1) % segments
            c, d = a + segments, b + segments
            tris += [(a, b, d), (a, d, c)]
    tris_a = np.asarray(tris, np.int64)
    # Drop triangles that collapsed onto the axis (profile radius 0 at a pole).
    a, b, c = (verts[tris_a[:, k]] for k in range(3))
    keep = np.linalg.norm(np.cross(b - a, c - a), axis=1) > 1e-12
    side = make_mesh(verts, tris_a[keep], material, smooth=True)
    parts = [side]
    for cap, k, sign in ((cap_bottom, 0, -1.0), (cap_top, n_prof - 1, 1.0)):
        if cap and radii[k] > 1e-9:
            rim = np.column_stack([radii[k] * ring, np.full(segments, heights[k])])
            cverts = np.vstack([[0.0, 0.0, heights[k]], rim])
            ctris = [(0, 1 + (j + 1) % segments, 1 + j) if sign < 0 else (0, 1 + j, 1 + (j + 1) % segments)
                     for j in range(segments)]
            parts.append(make_mesh(cverts, ctris, material, smooth=False))
    return concat_meshes(parts)


def cylinder_mesh(radius: float, height: float, material: int, segments: int = 24) -> Mesh:
    """Closed cylinder standing on z = 0."""
    return lathe_mesh([radius, radius], [0.0, height], material, segments)


def sphere_mesh(radius: float, material: int, rings: int = 12, segments: int = 24) -> Mesh:
    """UV sphere centred on the origin."""
    theta = np.linspace(0, np.pi, rings + 1)
    return lathe_mesh(radius * np.sin(theta), -radius * np.cos(theta), material, segments,
                      cap_bottom=False, cap_top=False)


def rotation_z(yaw: float) -> np.ndarray:
    """Rotation about +z by ``yaw`` radians."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def example_mesh(name: str, material: int) -> Mesh:
    """A mesh shipped inside PyVista's ``examples`` folder (``airplane``, ``ant``, ``nut``), read from the
    installed package with plyfile (no download, and no PyVista import, which takes half a second)."""
    spec = importlib.util.find_spec("pyvista")
    if spec is None or not spec.submodule_search_locations:
        raise RuntimeError("pyvista is not installed: its example meshes are part of the synthetic scenes")
    path = Path(list(spec.submodule_search_locations)[0]) / "examples" / f"{name}.ply"
    ply = read_labelled_ply(path)
    return make_mesh(ply["xyz"].astype(np.float64), ply["faces"], material, smooth=True)


def fit_on_floor(mesh: Mesh, size: float, up_axis: int = 2) -> Mesh:
    """Rotate ``up_axis`` to +z, scale the largest horizontal extent to ``size`` and stand the mesh on z = 0
    centred on the z axis."""
    perm = {0: [1, 2, 0], 1: [2, 0, 1], 2: [0, 1, 2]}[up_axis]  # cyclic, so a proper rotation
    rot = np.eye(3)[perm]
    m = mesh.transformed(rot, np.zeros(3))
    lo, hi = m.bounds
    scale = size / max(hi[0] - lo[0], hi[1] - lo[1])
    centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    return m.transformed(np.eye(3), -centre * scale, scale)


# --------------------------------------------------------------------------------------------- materials
class MaterialBank:
    """Solid-texture parameters of every material in a scene, stored as arrays for vectorised shading.

    A material blends two colours ``c0, c1`` with ``s = 0.5 + 0.5 tanh(gain * sum_k a_k sin(w_k . x + p_k))``
    and then mixes in ``grid_color`` where a soft grid ``g(x) = sig(sharp sin(wa . x + pa)) *
    sig(sharp sin(wb . x + pb))`` is on, with weight ``grid_weight``.
    """

    def __init__(self, rng: np.random.Generator):
        self.rng = rng
        self.c0: list[np.ndarray] = []
        self.c1: list[np.ndarray] = []
        self.freq: list[np.ndarray] = []
        self.phase: list[np.ndarray] = []
        self.amp: list[np.ndarray] = []
        self.gain: list[float] = []
        self.grid_weight: list[float] = []
        self.grid_color: list[np.ndarray] = []
        self.grid_freq: list[np.ndarray] = []
        self.grid_phase: list[np.ndarray] = []
        self.grid_sharp: list[float] = []

    def __len__(self) -> int:
        return len(self.c0)

    def add(self, c0, c1, wavelength: float, *, gain: float = 1.2, flat_z: bool = False,
            stripe: tuple[np.ndarray, float, float] | None = None,
            grid: tuple[np.ndarray, np.ndarray, float, float, np.ndarray] | None = None) -> int:
        """Add a material and return its index.

        Parameters
        ----------
        c0, c1 : array-like
            Two RGB albedos in [0, 1] blended by the noise.
        wavelength : float
            Typical wavelength (metres) of the blotches; the waves use 0.8-1.6 times it.
        gain : float
            Contrast of the blend (higher: more two-tone).
        flat_z : bool
            Waves vary only horizontally (floors, roads: the pattern looks the same from any height).
        stripe : (direction, wavelength, amplitude), optional
            One dominant wave along ``direction`` (wood grain, planks, lane texture).
        grid : (dir_a, dir_b, period, weight, colour), optional
            A soft grid of cells ``period`` metres apart along the two directions (façade windows, tiles).
        """
        rng = self.rng
        dirs = rng.normal(size=(N_WAVES, 3))
        if flat_z:
            dirs[:, 2] = 0.0
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        lengths = wavelength * rng.uniform(0.8, 1.6, N_WAVES)
        freq = dirs * (2 * np.pi / lengths)[:, None]
        amp = rng.uniform(0.5, 1.0, N_WAVES)
        phase = rng.uniform(0, 2 * np.pi, N_WAVES)
        if stripe is not None:
            sdir, slen, samp = stripe
            sdir = np.asarray(sdir, np.float64) / np.linalg.norm(sdir)
            freq[0] = sdir * 2 * np.pi / slen
            amp[0] = samp
        amp = amp / np.sqrt(np.sum(amp**2))  # unit variance-ish, so gain means the same everywhere
        self.c0.append(np.asarray(c0, np.float64))
        self.c1.append(np.asarray(c1, np.float64))
        self.freq.append(freq)
        self.phase.append(phase)
        self.amp.append(amp)
        self.gain.append(gain)
        if grid is None:
            self.grid_weight.append(0.0)
            self.grid_color.append(np.zeros(3))
            self.grid_freq.append(np.zeros((2, 3)))
            self.grid_phase.append(np.zeros(2))
            self.grid_sharp.append(1.0)
        else:
            da, db, period, weight, colour = grid
            da = np.asarray(da, np.float64) / np.linalg.norm(da)
            db = np.asarray(db, np.float64) / np.linalg.norm(db)
            self.grid_weight.append(float(weight))
            self.grid_color.append(np.asarray(colour, np.float64))
            self.grid_freq.append(np.stack([da, db]) * 2 * np.pi / period)
            self.grid_phase.append(rng.uniform(0, 2 * np.pi, 2))
            self.grid_sharp.append(2.5)  # soft edges: a cell boundary spans ~1/5 of the period
        return len(self.c0) - 1

    def arrays(self) -> dict[str, np.ndarray]:
        """All parameters stacked along a leading material axis."""
        return {
            "c0": np.stack(self.c0), "c1": np.stack(self.c1), "freq": np.stack(self.freq),
            "phase": np.stack(self.phase), "amp": np.stack(self.amp), "gain": np.asarray(self.gain),
            "grid_weight": np.asarray(self.grid_weight), "grid_color": np.stack(self.grid_color),
            "grid_freq": np.stack(self.grid_freq), "grid_phase": np.stack(self.grid_phase),
            "grid_sharp": np.asarray(self.grid_sharp),
        }


def solid_texture(points: np.ndarray, material: np.ndarray, mats: dict[str, np.ndarray],
                  footprint: np.ndarray | None = None, wave_norm: np.ndarray | None = None,
                  grid_norm: np.ndarray | None = None) -> np.ndarray:
    """Albedo ``[N, 3]`` in [0, 1] of world ``points`` ``[N, 3]`` with material indices ``[N]``.

    With ``footprint`` (``[N]``, the standard deviation in metres of a pixel's footprint on the surface),
    each wave ``w`` is attenuated by ``exp(-(|w| footprint)^2 / 2)`` — the Gaussian-filtered wave — so far or
    grazing surfaces show their mean colour rather than aliasing. ``wave_norm`` ``[M, K]`` and ``grid_norm``
    ``[M]`` are the precomputed ``|w|`` (computed here when not given).
    """
    x = points
    take = lambda name, idx: np.take(mats[name], idx, axis=0)  # noqa: E731  (np.take: faster than [idx])
    arg = np.einsum("nkc,nc->nk", take("freq", material), x)
    arg += take("phase", material)
    amp = take("amp", material)
    if footprint is not None:
        wn = np.linalg.norm(mats["freq"], axis=2) if wave_norm is None else wave_norm
        amp = amp * np.exp(-0.5 * (np.take(wn, material, axis=0) * footprint[:, None]) ** 2)
    noise = np.einsum("nk,nk->n", amp, np.sin(arg))
    s = 0.5 + 0.5 * np.tanh(take("gain", material) * noise)
    c0 = take("c0", material)
    albedo = c0 + (take("c1", material) - c0) * s[:, None]
    gw = take("grid_weight", material)
    on = np.flatnonzero(gw > 0)
    if len(on):
        m = material[on]
        garg = np.einsum("nkc,nc->nk", take("grid_freq", m), x[on]) + take("grid_phase", m)
        cells = 1.0 / (1.0 + np.exp(-take("grid_sharp", m)[:, None] * np.sin(garg)))
        g = cells[:, 0] * cells[:, 1]
        if footprint is not None:
            gn = np.linalg.norm(mats["grid_freq"], axis=2).max(1) if grid_norm is None else grid_norm
            att = np.exp(-0.5 * (gn[m] * footprint[on]) ** 2)
            g = 0.25 + (g - 0.25) * att  # 0.25: the grid's mean over a cell
        g = (gw[on] * g)[:, None]
        albedo[on] = albedo[on] * (1.0 - g) + take("grid_color", m) * g
    return np.clip(albedo, 0.0, 1.0)


# --------------------------------------------------------------------------------------------- content
@dataclass
class SceneObject:
    """One labelled piece of the scene: a thing instance or a piece of a stuff class.

    ``segment_id`` is the scene-consistent GT panoptic id (stuff: the category id; things: 1000 + k).
    """

    segment_id: int
    category_id: int
    mesh: Mesh
    name: str = ""


@dataclass
class Lighting:
    """Lambertian lighting: ``ambient + hemisphere * n_z + sum_k weights[k] * max(0, n . directions[k])``."""

    ambient: float
    hemisphere: float
    directions: np.ndarray  # [L, 3] unit vectors towards the lights
    weights: np.ndarray  # [L]


@dataclass
class SceneContent:
    """Everything :func:`lift3d.synth.make.make_scene` needs to know about a synthetic scene's content."""

    kind: str
    categories: list[Category]
    objects: list[SceneObject]
    materials: MaterialBank
    lighting: Lighting
    #: plausible confusions of the simulated segmenter: category id -> similar category ids
    confusable: dict[int, list[int]]
    #: ``bounded`` (indoor; ``aabb`` is the room) or ``unbounded`` (outdoor; ``aabb`` bounds the content and
    #: the foreground box is set from the camera path by ``make_scene``)
    scene_box_type: str
    aabb: np.ndarray
    sky_category: int | None = None
    depth_unit_scale_factor: float = 1e-3
    #: free space for cameras (indoor): (x, y) centres and radii of object footprints
    footprints: list[tuple[np.ndarray, float]] = field(default_factory=list)
    extra: dict = field(default_factory=dict)

    @property
    def things(self) -> list[SceneObject]:
        cats = {c.id: c for c in self.categories}
        return [o for o in self.objects if cats[o.category_id].isthing]


def sky_color(directions: np.ndarray) -> np.ndarray:
    """A smooth, direction-only sky: pale near the horizon, deeper blue towards the zenith, with a soft glow
    around the sun. ``directions`` ``[N, 3]`` unit vectors → RGB ``[N, 3]`` in [0, 1]."""
    up = np.clip(directions[:, 2], 0.0, 1.0)[:, None]
    horizon = np.array([0.78, 0.85, 0.92])
    zenith = np.array([0.30, 0.50, 0.85])
    t = up ** 0.6
    col = horizon * (1 - t) + zenith * t
    sun = np.array([0.45, 0.75, 0.48])
    sun /= np.linalg.norm(sun)
    glow = np.exp((directions @ sun - 1.0) / 0.08)[:, None]  # ~exp(-angle² / 0.16): wide, no sharp sun disc
    col = col + 0.25 * glow * np.array([1.0, 0.9, 0.7])
    below = np.clip(-directions[:, 2], 0.0, 1.0)[:, None]  # under the horizon: a hazy grey-blue
    col = col * (1 - below) + np.array([0.62, 0.66, 0.70]) * below
    return np.clip(col, 0.0, 1.0)


# --------------------------------------------------------------------------------------------- indoor
INDOOR_CATEGORIES = [
    Category(1, "wall", False, (174, 199, 232)),
    Category(2, "floor", False, (152, 223, 138)),
    Category(3, "ceiling", False, (78, 71, 183)),
    Category(4, "rug", False, (255, 187, 120)),
    Category(5, "window", False, (197, 176, 213)),
    Category(6, "table", True, (255, 127, 14)),
    Category(7, "chair", True, (188, 189, 34)),
    Category(8, "cabinet", True, (31, 119, 180)),
    Category(9, "ball", True, (214, 39, 40)),
    Category(10, "lamp", True, (227, 119, 194)),
    Category(11, "plant", True, (44, 160, 44)),
    Category(12, "sculpture", True, (140, 86, 75)),
    Category(13, "toy_plane", True, (23, 190, 207)),
]

INDOOR_CONFUSABLE = {
    1: [5, 3], 2: [4, 1], 3: [1], 4: [2], 5: [1],
    6: [8, 7], 7: [6, 8], 8: [6, 7], 9: [10, 11, 12], 10: [11, 12], 11: [10, 9], 12: [13, 9, 11], 13: [12, 7],
}


def _hsv(h: float, s: float, v: float) -> np.ndarray:
    """HSV (all in [0, 1]) → RGB."""
    i = int(h * 6) % 6
    f = h * 6 - int(h * 6)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    return np.array([(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i])


def _two_tone(rng: np.random.Generator, hue: float, sat: float, val: float, spread: float = 0.18) -> tuple:
    """Two related colours around a hue (the two ends of a material's blend)."""
    h0 = (hue + rng.uniform(-0.03, 0.03)) % 1.0
    a = _hsv(h0, np.clip(sat + rng.uniform(-0.1, 0.1), 0, 1), np.clip(val + spread / 2, 0, 1))
    b = _hsv((h0 + rng.uniform(-0.04, 0.04)) % 1.0, np.clip(sat + rng.uniform(0.0, 0.15), 0, 1),
             np.clip(val - spread / 2, 0, 1))
    return a, b


# Furniture: each builder returns a mesh standing on z = 0, centred on the z axis, and the radius of its
# floor footprint (used to place objects without overlap).
def _table(rng, mat) -> tuple[Mesh, float]:
    w, d, h = rng.uniform(1.0, 1.4), rng.uniform(0.6, 0.85), rng.uniform(0.70, 0.78)
    top = box_mesh([-w / 2, -d / 2, h - 0.05], [w / 2, d / 2, h], mat)
    legs = [box_mesh([sx * (w / 2 - 0.05) - 0.04, sy * (d / 2 - 0.05) - 0.04, 0.0],
                     [sx * (w / 2 - 0.05) + 0.04, sy * (d / 2 - 0.05) + 0.04, h - 0.05], mat)
            for sx in (-1, 1) for sy in (-1, 1)]
    return concat_meshes([top] + legs), 0.5 * np.hypot(w, d)


def _chair(rng, mat) -> tuple[Mesh, float]:
    s, h = rng.uniform(0.42, 0.5), rng.uniform(0.43, 0.48)
    seat = box_mesh([-s / 2, -s / 2, h - 0.05], [s / 2, s / 2, h], mat)
    back = box_mesh([-s / 2, s / 2 - 0.05, h], [s / 2, s / 2, h + rng.uniform(0.4, 0.5)], mat)
    legs = [box_mesh([sx * (s / 2 - 0.03) - 0.025, sy * (s / 2 - 0.03) - 0.025, 0.0],
                     [sx * (s / 2 - 0.03) + 0.025, sy * (s / 2 - 0.03) + 0.025, h - 0.05], mat)
            for sx in (-1, 1) for sy in (-1, 1)]
    return concat_meshes([seat, back] + legs), s / np.sqrt(2)


def _cabinet(rng, mat) -> tuple[Mesh, float]:
    w, d, h = rng.uniform(0.6, 1.0), rng.uniform(0.4, 0.5), rng.uniform(0.9, 1.5)
    body = box_mesh([-w / 2, -d / 2, 0.0], [w / 2, d / 2, h], mat)
    top = box_mesh([-w / 2 - 0.02, -d / 2 - 0.02, h], [w / 2 + 0.02, d / 2 + 0.02, h + 0.03], mat)
    return concat_meshes([body, top]), 0.5 * np.hypot(w + 0.04, d + 0.04)


def _ball(rng, mat) -> tuple[Mesh, float]:
    r = rng.uniform(0.15, 0.28)
    return sphere_mesh(r, mat).transformed(np.eye(3), [0, 0, r]), r


def _lamp(rng, mat, mat_shade) -> tuple[Mesh, float]:
    h = rng.uniform(1.3, 1.6)
    base = cylinder_mesh(0.17, 0.04, mat)
    pole = cylinder_mesh(0.035, h, mat, segments=12)
    shade = lathe_mesh([0.24, 0.15], [0.0, 0.3], mat_shade).transformed(np.eye(3), [0, 0, h - 0.12])
    return concat_meshes([base, pole, shade]), 0.24


def _plant(rng, mat_pot, mat_leaves) -> tuple[Mesh, float]:
    pot_h = rng.uniform(0.28, 0.36)
    pot = lathe_mesh([0.13, 0.18], [0.0, pot_h], mat_pot)
    crowns = []
    for k in range(3):
        r = rng.uniform(0.18, 0.26)
        ang = 2 * np.pi * k / 3 + rng.uniform(-0.4, 0.4)
        off = np.array([0.1 * np.cos(ang), 0.1 * np.sin(ang), pot_h + 0.12 + r + 0.12 * k])
        crowns.append(sphere_mesh(r, mat_leaves).transformed(np.eye(3), off))
    return concat_meshes([pot] + crowns), 0.38


def _sculpture(rng, mat, which: str) -> tuple[Mesh, float]:
    if which == "nut":
        m = fit_on_floor(example_mesh("nut", mat), rng.uniform(0.45, 0.6), up_axis=1)
    else:
        m = fit_on_floor(example_mesh("ant", mat), rng.uniform(0.6, 0.8), up_axis=1)
    lo, hi = m.bounds
    return m, 0.5 * np.hypot(hi[0] - lo[0], hi[1] - lo[1])


def _toy_plane(rng, mat) -> tuple[Mesh, float]:
    m = fit_on_floor(example_mesh("airplane", mat), rng.uniform(0.9, 1.2), up_axis=2)
    lo, hi = m.bounds
    return m, 0.5 * np.hypot(hi[0] - lo[0], hi[1] - lo[1])


def build_indoor(rng: np.random.Generator) -> SceneContent:
    """A furnished room: walls, floor, ceiling, a rug and windows (stuff) and 8-15 objects of 8 thing classes,
    placed on the floor without overlapping.

    Parameters
    ----------
    rng : np.random.Generator
        The layout's random stream (the same stream gives the same room).
    """
    mats = MaterialBank(rng)
    width, depth, height = rng.uniform(5.5, 7.0), rng.uniform(4.5, 6.0), rng.uniform(2.7, 3.1)
    hx, hy = width / 2, depth / 2
    objects: list[SceneObject] = []

    # ---- stuff: one object per surface; surfaces overlap at the corners so no ray slips through a crack.
    pad = 0.05
    wall_hue = rng.uniform(0.05, 0.15)
    wall_mat = mats.add(*_two_tone(rng, wall_hue, 0.15, 0.85, 0.10), 1.2, gain=1.0)
    floor_mat = mats.add(*_two_tone(rng, rng.uniform(0.06, 0.1), 0.55, 0.55, 0.22), 0.9, gain=1.4, flat_z=True,
                         stripe=(np.array([1.0, 0.0, 0.0]), 0.45, 1.6))
    ceil_mat = mats.add(_hsv(0.12, 0.05, 0.92), _hsv(0.12, 0.08, 0.84), 1.5, gain=0.8)
    walls = [
        quad_mesh([-hx - pad, -hy, -pad], [width + 2 * pad, 0, 0], [0, 0, height + 2 * pad], wall_mat),
        quad_mesh([-hx - pad, hy, -pad], [width + 2 * pad, 0, 0], [0, 0, height + 2 * pad], wall_mat),
        quad_mesh([-hx, -hy - pad, -pad], [0, depth + 2 * pad, 0], [0, 0, height + 2 * pad], wall_mat),
        quad_mesh([hx, -hy - pad, -pad], [0, depth + 2 * pad, 0], [0, 0, height + 2 * pad], wall_mat),
    ]
    objects.append(SceneObject(1, 1, concat_meshes(walls), "wall"))
    objects.append(SceneObject(2, 2, quad_mesh([-hx - pad, -hy - pad, 0], [width + 2 * pad, 0, 0],
                                               [0, depth + 2 * pad, 0], floor_mat), "floor"))
    objects.append(SceneObject(3, 3, quad_mesh([-hx - pad, -hy - pad, height], [width + 2 * pad, 0, 0],
                                               [0, depth + 2 * pad, 0], ceil_mat), "ceiling"))
    rug_w, rug_d = rng.uniform(1.8, 2.8), rng.uniform(1.3, 2.0)
    rug_c = rng.uniform(-0.4, 0.4, 2)
    rug_mat = mats.add(*_two_tone(rng, rng.uniform(0.55, 1.0), 0.55, 0.6, 0.3), 0.7, gain=2.0, flat_z=True,
                       grid=(np.array([1.0, 1.0, 0]), np.array([1.0, -1.0, 0]), 0.6, 0.35, _hsv(0.13, 0.3, 0.9)))
    objects.append(SceneObject(4, 4, quad_mesh([rug_c[0] - rug_w / 2, rug_c[1] - rug_d / 2, 0.006],
                                               [rug_w, 0, 0], [0, rug_d, 0], rug_mat), "rug"))
    win_mat = mats.add(_hsv(0.58, 0.35, 0.95), _hsv(0.55, 0.5, 0.8), 1.0, gain=1.0,
                       grid=(np.array([1.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), 0.7, 0.3, (0.95, 0.95, 0.95)))
    windows = []
    for wall_side in rng.choice(4, size=2, replace=False):
        ww, wh, wz = rng.uniform(1.1, 1.6), rng.uniform(0.9, 1.2), rng.uniform(0.9, 1.1)
        if wall_side < 2:  # walls at y = -hy / +hy
            y = -hy + 0.01 if wall_side == 0 else hy - 0.01
            x0 = rng.uniform(-hx + 0.4, hx - 0.4 - ww)
            windows.append(quad_mesh([x0, y, wz], [ww, 0, 0], [0, 0, wh], win_mat))
        else:
            x = -hx + 0.01 if wall_side == 2 else hx - 0.01
            y0 = rng.uniform(-hy + 0.4, hy - 0.4 - ww)
            windows.append(quad_mesh([x, y0, wz], [0, ww, 0], [0, 0, wh], win_mat))
    objects.append(SceneObject(5, 5, concat_meshes(windows), "window"))

    # ---- things: how many of each class (9-17 drawn, every class at least once; crowded rooms drop some).
    counts = {
        "cabinet": int(rng.integers(1, 3)), "lamp": 1, "plant": int(rng.integers(1, 3)),
        "table": int(rng.integers(1, 3)), "chair": int(rng.integers(2, 4)), "ball": int(rng.integers(1, 4)),
        "sculpture": int(rng.integers(1, 3)), "toy_plane": 1,
    }
    cat_of = {c.name: c.id for c in INDOOR_CATEGORIES}
    along_wall = {"cabinet", "lamp", "plant"}  # these stand near walls; the rest in the middle of the room
    footprints: list[tuple[np.ndarray, float]] = []
    next_id = 1001
    sculpt_kinds = ["nut", "ant"]
    rng.shuffle(sculpt_kinds)
    for name in ["cabinet", "lamp", "plant", "table", "chair", "toy_plane", "sculpture", "ball"]:
        for k in range(counts[name]):
            hue = {"table": 0.08, "cabinet": 0.07, "chair": rng.uniform(0, 1), "ball": rng.uniform(0, 1),
                   "lamp": rng.uniform(0, 1), "plant": 0.05, "sculpture": rng.uniform(0, 1),
                   "toy_plane": rng.uniform(0, 1)}[name]
            if name in ("table", "cabinet"):  # wood: brown, grain along x
                mat = mats.add(*_two_tone(rng, hue, 0.6, 0.5, 0.25), 0.5, gain=1.5,
                               stripe=(np.array([1.0, 0.2, 0.0]), 0.45, 1.2))
            else:
                mat = mats.add(*_two_tone(rng, hue, 0.6, 0.7, 0.3), rng.uniform(0.45, 0.7), gain=1.3)
            if name == "table":
                mesh, radius = _table(rng, mat)
            elif name == "chair":
                mesh, radius = _chair(rng, mat)
            elif name == "cabinet":
                mesh, radius = _cabinet(rng, mat)
            elif name == "ball":
                mesh, radius = _ball(rng, mat)
            elif name == "lamp":
                shade = mats.add(*_two_tone(rng, 0.12, 0.25, 0.9, 0.1), 0.5, gain=1.0)
                mesh, radius = _lamp(rng, mat, shade)
            elif name == "plant":
                leaves = mats.add(*_two_tone(rng, rng.uniform(0.25, 0.38), 0.65, 0.5, 0.3), 0.45, gain=1.4)
                mesh, radius = _plant(rng, mat, leaves)
            elif name == "sculpture":
                mesh, radius = _sculpture(rng, mat, sculpt_kinds[k % 2])
            else:
                mesh, radius = _toy_plane(rng, mat)
            placed = _place(rng, radius, hx, hy, footprints, near_wall=name in along_wall)
            if placed is None:
                continue  # no room left: drop the object (the count check below keeps >= 8)
            centre, yaw = placed
            footprints.append((centre, radius))
            mesh = mesh.transformed(rotation_z(yaw), [centre[0], centre[1], 0.0])
            objects.append(SceneObject(next_id, cat_of[name], mesh, f"{name}_{k}"))
            next_id += 1
    n_things = next_id - 1001
    if n_things < 8:
        raise RuntimeError(f"could only place {n_things} objects in the room (need 8)")
    aabb = np.array([[-hx, -hy, 0.0], [hx, hy, height]])
    return SceneContent(
        kind="indoor", categories=list(INDOOR_CATEGORIES), objects=objects, materials=mats,
        lighting=Lighting(0.42, 0.10, np.array([_unit([0.35, 0.25, 1.0]), _unit([-0.6, -0.7, 0.35])]),
                          np.array([0.42, 0.22])),
        confusable=INDOOR_CONFUSABLE, scene_box_type="bounded", aabb=aabb, depth_unit_scale_factor=1e-3,
        footprints=footprints, extra={"room_size": [width, depth, height]},
    )


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def _place(rng, radius: float, hx: float, hy: float, footprints, near_wall: bool,
           gap: float = 0.12, tries: int = 300) -> tuple[np.ndarray, float] | None:
    """A free floor position (bounding circles do not overlap) and a yaw; None when none was found."""
    for _ in range(tries):
        if near_wall:
            side = rng.integers(4)
            along = rng.uniform(-1, 1)
            off = radius + 0.03
            if side == 0:
                c, yaw = np.array([along * (hx - off), -hy + off]), 0.0
            elif side == 1:
                c, yaw = np.array([along * (hx - off), hy - off]), np.pi
            elif side == 2:
                c, yaw = np.array([-hx + off, along * (hy - off)]), -np.pi / 2
            else:
                c, yaw = np.array([hx - off, along * (hy - off)]), np.pi / 2
        else:
            # The middle of the room: cameras circle around it.
            c = np.array([rng.uniform(-0.55, 0.55) * hx, rng.uniform(-0.55, 0.55) * hy])
            yaw = rng.uniform(0, 2 * np.pi)
        if abs(c[0]) > hx - radius - 0.02 or abs(c[1]) > hy - radius - 0.02:
            continue
        if all(np.linalg.norm(c - p) > radius + r + gap for p, r in footprints):
            return c, float(yaw)
    return None


# --------------------------------------------------------------------------------------------- outdoor
OUTDOOR_CATEGORIES = [
    Category(1, "road", False, (128, 64, 128)),
    Category(2, "sidewalk", False, (244, 35, 232)),
    Category(3, "building", False, (70, 70, 70)),
    Category(4, "terrain", False, (152, 251, 152)),
    Category(5, "sky", False, (70, 130, 180)),
    Category(6, "car", True, (0, 0, 142)),
    Category(7, "van", True, (0, 60, 100)),
    Category(8, "pedestrian", True, (220, 20, 60)),
    Category(9, "tree", True, (107, 142, 35)),
    Category(10, "streetlight", True, (250, 170, 30)),
]

OUTDOOR_CONFUSABLE = {
    1: [2], 2: [1, 4], 3: [5], 4: [2], 5: [3],
    6: [7], 7: [6], 8: [10], 9: [10], 10: [9, 8],
}

#: Street layout (metres): the road spans |x| < ROAD_HALF, then a grass strip, the sidewalk, the façades.
ROAD_HALF, GRASS_END, SIDEWALK_END = 4.0, 5.2, 8.5
STREET_START, STREET_END = -40.0, 520.0


def _car(rng, body_mat: int, glass_mat: int, tyre_mat: int, van: bool) -> Mesh:
    """A car (body + glass cabin) or a van (tall body + windscreen) on four wheels, along +y, on z = 0."""
    length = rng.uniform(4.6, 5.4) if van else rng.uniform(3.9, 4.6)
    width = rng.uniform(1.9, 2.1) if van else rng.uniform(1.7, 1.85)
    body_h = rng.uniform(1.5, 1.8) if van else rng.uniform(0.65, 0.8)
    parts = [box_mesh([-width / 2, -length / 2, 0.3], [width / 2, length / 2, 0.3 + body_h], body_mat)]
    if van:
        parts.append(box_mesh([-width / 2 + 0.05, length / 2 - 1.2, 0.9], [width / 2 - 0.05, length / 2 + 0.02,
                                                                            0.3 + body_h - 0.15], glass_mat))
    else:
        cab_l = length * rng.uniform(0.45, 0.55)
        y0 = -length / 2 + length * rng.uniform(0.2, 0.3)
        parts.append(box_mesh([-width / 2 + 0.1, y0, 0.3 + body_h], [width / 2 - 0.1, y0 + cab_l, 0.3 + body_h + 0.55],
                              glass_mat))
    rot_x = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # wheel axis along x
    for sx in (-1, 1):
        for sy in (-1, 1):
            # The rotated cylinder spans x in [0, 0.24]: shift it so the tyre is centred under the body's edge.
            wheel = cylinder_mesh(0.34, 0.24, tyre_mat, segments=16).transformed(
                rot_x, [sx * (width / 2 - 0.1) - 0.12, sy * (length / 2 - 0.8), 0.34])
            parts.append(wheel)
    return concat_meshes(parts)


def build_outdoor(rng: np.random.Generator) -> SceneContent:
    """An unbounded street along +y: road, grass strips, sidewalks and façades reaching hundreds of metres,
    with parked cars and vans, pedestrians, trees and streetlights; sky where nothing is hit.

    Parameters
    ----------
    rng : np.random.Generator
        The layout's random stream.
    """
    mats = MaterialBank(rng)
    objects: list[SceneObject] = []
    length = STREET_END - STREET_START
    road_mat = mats.add((0.36, 0.36, 0.38), (0.27, 0.27, 0.29), 3.0, gain=1.2, flat_z=True,
                        grid=(np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0]), 8.0, 0.0, (0.9, 0.9, 0.85)))
    objects.append(SceneObject(1, 1, quad_mesh([-ROAD_HALF - 0.05, STREET_START, 0.0], [2 * ROAD_HALF + 0.1, 0, 0],
                                               [0, length, 0], road_mat), "road"))
    walk_mat = mats.add((0.66, 0.63, 0.6), (0.55, 0.53, 0.5), 2.0, gain=1.0, flat_z=True,
                        grid=(np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), 1.6, 0.25, (0.75, 0.73, 0.7)))
    grass_mat = mats.add((0.33, 0.52, 0.2), (0.22, 0.4, 0.14), 1.5, gain=1.4, flat_z=True)
    walks, grass = [], []
    for side in (-1, 1):
        # Raised by 12 cm: the kerb is a box side visible from the road.
        lo_g = min(side * ROAD_HALF, side * GRASS_END)
        grass.append(box_mesh([lo_g, STREET_START, -0.5], [lo_g + GRASS_END - ROAD_HALF, STREET_END, 0.12], grass_mat))
        lo_w = min(side * GRASS_END, side * SIDEWALK_END)
        walks.append(box_mesh([lo_w, STREET_START, -0.5], [lo_w + SIDEWALK_END - GRASS_END, STREET_END, 0.12],
                              walk_mat))
    objects.append(SceneObject(2, 2, concat_meshes(walks), "sidewalk"))
    objects.append(SceneObject(4, 4, concat_meshes(grass), "terrain"))

    # ---- façades: boxes of random width and height on both sides, and one across the far end of the street.
    buildings = []
    for side in (-1, 1):
        y = STREET_START
        while y < STREET_END:
            w = rng.uniform(10.0, 24.0)
            h = rng.uniform(7.0, 22.0)
            d = rng.uniform(10.0, 16.0)
            hue = rng.choice([0.05, 0.08, 0.1, 0.55, 0.0])
            c0, c1 = _two_tone(rng, hue, rng.uniform(0.1, 0.35), rng.uniform(0.55, 0.8), 0.12)
            mat = mats.add(c0, c1, 4.0, gain=1.0,
                           grid=(np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), rng.uniform(2.8, 3.6),
                                 0.55, _hsv(0.58, 0.25, 0.35)))
            x_in = side * (SIDEWALK_END + rng.uniform(0.0, 0.6))
            lo = [min(x_in, x_in + side * d), y, -0.5]
            hi = [max(x_in, x_in + side * d), min(y + w, STREET_END), h]
            buildings.append(box_mesh(lo, hi, mat))
            y += w + (rng.uniform(2.0, 6.0) if rng.random() < 0.3 else 0.0)
    end_mat = mats.add((0.7, 0.62, 0.55), (0.6, 0.52, 0.47), 6.0, gain=1.0,
                       grid=(np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), 3.5, 0.5, _hsv(0.58, 0.25, 0.35)))
    buildings.append(box_mesh([-70.0, STREET_END, -0.5], [70.0, STREET_END + 12.0, 40.0], end_mat))
    objects.append(SceneObject(3, 3, concat_meshes(buildings), "building"))

    # ---- things.
    cat_of = {c.name: c.id for c in OUTDOOR_CATEGORIES}
    next_id = 1001
    tyre = mats.add((0.08, 0.08, 0.08), (0.14, 0.14, 0.14), 0.5, gain=1.0)
    glass = mats.add((0.2, 0.25, 0.3), (0.35, 0.4, 0.45), 1.5, gain=1.0)

    def add(name: str, mesh: Mesh) -> None:
        nonlocal next_id
        objects.append(SceneObject(next_id, cat_of[name], mesh, f"{name}_{next_id - 1000}"))
        next_id += 1

    # Parked cars along both kerbs, densely near the start of the street so they are seen up close.
    for side in (-1, 1):
        y = STREET_START + 30 + rng.uniform(0, 4)
        while y < 200.0:
            if rng.random() < (0.75 if y < 60 else 0.45):
                van = rng.random() < 0.25
                body = mats.add(*_two_tone(rng, rng.uniform(0, 1), rng.uniform(0.2, 0.8), rng.uniform(0.4, 0.85), 0.15),
                                1.2, gain=1.0)
                mesh = _car(rng, body, glass, tyre, van)
                x = side * (ROAD_HALF - 1.15)
                add("van" if van else "car", mesh.transformed(rotation_z(rng.uniform(-0.04, 0.04)), [x, y + 2.5, 0.0]))
                y += (5.6 if van else 5.0) + rng.uniform(0.3, 1.5)
            else:
                y += rng.uniform(4.0, 9.0)
    # Trees on the grass strips, streetlights on the sidewalk edge between them, pedestrians on the sidewalks.
    trunk_mat = mats.add((0.35, 0.25, 0.16), (0.25, 0.17, 0.1), 0.6, gain=1.0)
    pole_mat = mats.add((0.45, 0.47, 0.5), (0.35, 0.37, 0.4), 1.0, gain=1.0)
    for side in (-1, 1):
        tree_ys = np.arange(STREET_START + 35 + rng.uniform(0, 5), 320.0, 13.0)
        for y in tree_ys:
            y = y + rng.uniform(-1.5, 1.5)
            crown = mats.add(*_two_tone(rng, rng.uniform(0.22, 0.33), 0.6, 0.45, 0.2), 0.7, gain=1.0)
            h = rng.uniform(2.2, 3.0)
            r = rng.uniform(1.4, 2.0)
            tree = concat_meshes([cylinder_mesh(0.16, h + 0.5, trunk_mat, segments=12),
                                  sphere_mesh(r, crown).transformed(np.eye(3), [0, 0, h + r * 0.8])])
            add("tree", tree.transformed(np.eye(3), [side * (ROAD_HALF + GRASS_END) / 2, y, 0.12]))
        occupied = []  # (y, radius) along this sidewalk: streetlights and pedestrians do not overlap
        for y in tree_ys[1::2] + 6.5:  # half-way between two trees, so no pole grows through a crown
            h = rng.uniform(6.0, 7.0)
            arm = box_mesh([0.0, -0.08, h - 0.15], [1.6, 0.08, h], pole_mat)
            head = box_mesh([1.2, -0.22, h - 0.3], [1.9, 0.22, h - 0.1], pole_mat)
            light = concat_meshes([cylinder_mesh(0.15, h, pole_mat, segments=12), arm, head])
            yaw = 0.0 if side < 0 else np.pi  # the arm reaches over the road
            add("streetlight", light.transformed(rotation_z(yaw), [side * (GRASS_END + 0.4), y, 0.12]))
            occupied.append((np.array([side * (GRASS_END + 0.4), y]), 0.2))
        for _ in range(int(rng.integers(5, 9))):
            for _try in range(50):
                pos = np.array([side * rng.uniform(GRASS_END + 0.8, SIDEWALK_END - 0.4), rng.uniform(5.0, 90.0)])
                if all(np.linalg.norm(pos - q) > r + 0.5 for q, r in occupied):
                    break
            else:
                continue
            occupied.append((pos, 0.25))
            cloth = mats.add(*_two_tone(rng, rng.uniform(0, 1), 0.6, 0.6, 0.3), 0.6, gain=1.2)
            skin = mats.add(*_two_tone(rng, 0.07, 0.45, 0.75, 0.1), 0.5, gain=1.0)
            height = rng.uniform(1.55, 1.9)
            body = lathe_mesh([0.16, 0.22, 0.2, 0.12], [0.0, 0.9, height - 0.3, height - 0.22], cloth, segments=12)
            head = sphere_mesh(0.12, skin, rings=8, segments=12).transformed(np.eye(3), [0, 0, height - 0.12])
            add("pedestrian", concat_meshes([body, head]).transformed(np.eye(3), [pos[0], pos[1], 0.12]))
    return SceneContent(
        kind="outdoor", categories=list(OUTDOOR_CATEGORIES), objects=objects, materials=mats,
        lighting=Lighting(0.45, 0.12, np.array([_unit([0.45, 0.75, 0.48]), _unit([-0.5, -0.3, 0.3])]),
                          np.array([0.55, 0.12])),
        confusable=OUTDOOR_CONFUSABLE, scene_box_type="unbounded",
        aabb=np.array([[-SIDEWALK_END - 16, STREET_START, -0.5], [SIDEWALK_END + 16, STREET_END + 12, 40.0]]),
        sky_category=cat_of["sky"], depth_unit_scale_factor=1e-2,
    )


# --------------------------------------------------------------------------------------------- ray casting
@dataclass
class Hits:
    """What rays hit. Per-ray arrays cover all rays; per-hit arrays only the rays that hit something, in ray
    order (``index`` gives their ray numbers).

    Rays that hit nothing get segment/category 0, or the sky's id outdoors (the sky's segment id is its
    category id), and ``t = inf``.
    """

    hit: np.ndarray  # [N] bool
    t: np.ndarray  # [N] float64 distance along the (unit) ray, inf on a miss
    segment: np.ndarray  # [N] int64 GT panoptic segment id
    category: np.ndarray  # [N] int64 category id
    index: np.ndarray  # [H] int64 rays that hit
    points: np.ndarray  # [H, 3] world hit points
    normals: np.ndarray  # [H, 3] unit shading normals, facing the viewer
    material: np.ndarray  # [H] int64 material index
    cosine: np.ndarray  # [H] |cos| between ray and geometric normal (for texture filtering)


class RayCaster:
    """Casts rays into a :class:`SceneContent` with Open3D's ``RaycastingScene`` and shades them.

    Parameters
    ----------
    content : SceneContent
        The scene. Each object becomes one geometry of the ray-casting scene.
    """

    def __init__(self, content: SceneContent):
        import open3d as o3d

        self._o3d = o3d
        self.content = content
        self.scene = o3d.t.geometry.RaycastingScene()
        self.invalid_id = int(o3d.t.geometry.RaycastingScene.INVALID_ID)
        n_obj = len(content.objects)
        self.segment_of_geometry = np.zeros(n_obj, np.int64)
        self.category_of_geometry = np.zeros(n_obj, np.int64)
        tri_offset = np.zeros(n_obj, np.int64)
        corner_normals, tri_material = [], []
        offset = 0
        for k, obj in enumerate(content.objects):
            gid = self.scene.add_triangles(
                o3d.core.Tensor(obj.mesh.vertices.astype(np.float32)),
                o3d.core.Tensor(obj.mesh.triangles.astype(np.uint32)),
            )
            if gid != k:
                raise RuntimeError("Open3D did not number geometries in insertion order")
            self.segment_of_geometry[k] = obj.segment_id
            self.category_of_geometry[k] = obj.category_id
            tri_offset[k] = offset
            offset += len(obj.mesh.triangles)
            corner_normals.append(obj.mesh.corner_normals)
            tri_material.append(obj.mesh.material)
        self.tri_offset = tri_offset
        self.corner_normals = np.concatenate(corner_normals)
        self.tri_material = np.concatenate(tri_material)
        # Flat triangles (all corners share the face normal) skip the interpolation.
        cn = self.corner_normals
        self.tri_smooth = ~np.all(np.abs(cn[:, 1:] - cn[:, :1]) < 1e-9, axis=(1, 2))
        self.materials = content.materials.arrays()
        # |w| of every texture wave, for band-limiting (see shade).
        self.wave_norm = np.linalg.norm(self.materials["freq"], axis=2)
        self.grid_norm = np.linalg.norm(self.materials["grid_freq"], axis=2).max(axis=1)

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> Hits:
        """Cast rays (``[N, 3]`` origins, ``[N, 3]`` unit directions) and return what they hit."""
        o3d = self._o3d
        rays = np.concatenate([origins, directions], axis=1).astype(np.float32)
        ans = self.scene.cast_rays(o3d.core.Tensor(rays))
        geom = ans["geometry_ids"].numpy()
        hit = geom != self.invalid_id
        idx = np.flatnonzero(hit)
        n = len(geom)
        sky = self.content.sky_category or 0
        segment = np.full(n, sky, np.int64)
        category = np.full(n, sky, np.int64)
        t = np.full(n, np.inf)
        g = geom[idx].astype(np.int64)
        tri = self.tri_offset[g] + ans["primitive_ids"].numpy()[idx]
        segment[idx] = self.segment_of_geometry[g]
        category[idx] = self.category_of_geometry[g]
        th = ans["t_hit"].numpy()[idx].astype(np.float64)
        t[idx] = th
        d = directions[idx]
        points = origins[idx] + th[:, None] * d
        # Face the viewer: the geometric normal decides the side (robust at silhouettes).
        gn = ans["primitive_normals"].numpy()[idx].astype(np.float64)
        dot = np.einsum("ij,ij->i", gn, d)
        gn *= -np.sign(dot)[:, None]
        normals = gn
        smooth = np.flatnonzero(self.tri_smooth[tri])
        if len(smooth):
            # Barycentric interpolation of corner normals; Open3D/Embree's uv weight corners 1 and 2.
            uv = ans["primitive_uvs"].numpy()[idx[smooth]].astype(np.float64)
            cn = self.corner_normals[tri[smooth]]
            nrm = (1 - uv[:, :1] - uv[:, 1:]) * cn[:, 0] + uv[:, :1] * cn[:, 1] + uv[:, 1:] * cn[:, 2]
            nrm /= np.sqrt(np.maximum(np.einsum("ij,ij->i", nrm, nrm), 1e-24))[:, None]
            # Keep the smooth normal in the hemisphere of the (flipped) geometric one.
            nrm *= np.where(np.einsum("ij,ij->i", nrm, gn[smooth]) < 0, -1.0, 1.0)[:, None]
            normals = gn.copy()
            normals[smooth] = nrm
        return Hits(hit, t, segment, category, idx, points, normals, self.tri_material[tri], np.abs(dot))

    def shade(self, hits: Hits, directions: np.ndarray, pixel_angle: float) -> np.ndarray:
        """Lambertian colour ``[N, 3]`` in [0, 1]; misses get the sky (or black where there is none).

        ``pixel_angle`` (radians per pixel, ``1 / fx``) sets the footprint used to band-limit the textures:
        waves much finer than a pixel fade to their mean instead of aliasing.
        """
        rgb = np.zeros((len(hits.t), 3))
        if len(hits.index):
            footprint = 0.4 * hits.t[hits.index] * pixel_angle / np.maximum(hits.cosine, 0.25)
            albedo = solid_texture(hits.points, hits.material, self.materials, footprint=footprint,
                                   wave_norm=self.wave_norm, grid_norm=self.grid_norm)
            light = self.content.lighting
            n = hits.normals
            shade = light.ambient + light.hemisphere * n[:, 2]
            shade += np.maximum(n @ light.directions.T, 0.0) @ light.weights
            rgb[hits.index] = albedo * shade[:, None]
        if self.content.sky_category is not None and len(hits.index) < len(hits.t):
            miss = ~hits.hit
            rgb[miss] = sky_color(directions[miss])
        return np.clip(rgb, 0.0, 1.0)
