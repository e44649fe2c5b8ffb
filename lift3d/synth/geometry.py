"""Scene content of ``lift3d synth`` and how it is ray cast and shaded.

A synthetic scene is a set of triangle meshes, one per labelled object (a thing instance, or one piece of a
stuff class such as a wall), cast with Open3D's ``RaycastingScene``. Every triangle carries a material; the
colour of a surface point is

``albedo(x) * (ambient + hemisphere * n_z + sum_k c_k max(0, n . l_k))``   (per RGB channel)

with ``albedo(x)`` a *solid* texture (a function of the world position ``x``, so it is the same in every
view) and the shading Lambertian with fixed directional lights of colour ``c_k`` (a colour temperature times
an intensity, drawn per scene; :class:`Lighting`): the colour of a point does not depend on the
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
from typing import Callable

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
    ``rests_on`` is the ``segment_id`` of the thing this one stands on (a cup on a table), 0 for the floor
    or ground. ``thin`` is the thickness (metres) of its thinnest part (legs, poles, wings), None when it
    has none or it is not known; ``yaw`` (radians) the turn about z from the frame it was built in, where it
    is axis-aligned (None: not known).
    """

    segment_id: int
    category_id: int
    mesh: Mesh
    name: str = ""
    rests_on: int = 0
    thin: float | None = None
    yaw: float | None = None


@dataclass
class Lighting:
    """Lambertian lighting of a surface with normal ``n`` (RGB, per channel):

    ``ambient + hemisphere * n_z + sum_k colors[k] * max(0, n . directions[k])``.
    """

    ambient: np.ndarray  # [3] RGB ambient level
    hemisphere: float  # extra light on upward-facing surfaces (sky / ceiling bounce)
    directions: np.ndarray  # [L, 3] unit vectors towards the lights
    colors: np.ndarray  # [L, 3] RGB intensity of each light (its colour temperature times its strength)

    def shade(self, normals: np.ndarray) -> np.ndarray:
        """``[N, 3]`` RGB irradiance factor of unit ``normals`` ``[N, 3]``."""
        out = self.ambient[None, :] + self.hemisphere * normals[:, 2:3]
        return out + np.maximum(normals @ self.directions.T, 0.0) @ self.colors


@dataclass
class RoomSpec:
    """What planning cameras in a room needs beyond its floor outline (rooms other than the original
    rectangle and L, and cluttered rooms; None keeps the original cameras).

    Attributes
    ----------
    ceiling_at : callable
        ``[N, 2]`` floor points -> ``[N]`` height of the ceiling above them.
    camera_region : np.ndarray
        ``[K, 2]`` polygon (counter-clockwise) the cameras stay in.
    camera_top : callable
        ``[N, 2]`` -> ``[N]`` the highest a camera may be there (the ceiling or a door's lintel less the
        clearance).
    obstacles : list of np.ndarray
        ``[M, 2]`` convex floor polygons no camera stands on (inner walls).
    clearance : float
        Every camera stays at least this far (metres) from the walls, floor and ceiling; ``orbit`` and ``walk``
        cameras also from everything else (``handheld`` passes close to furniture on purpose).
    cover_things : bool
        Turn some views towards the things seen in too few views (cluttered rooms, whose small things are
        the point; ``lift3d.synth.cameras.cover_things``).
    """

    ceiling_at: Callable[[np.ndarray], np.ndarray]
    camera_region: np.ndarray
    camera_top: Callable[[np.ndarray], np.ndarray]
    obstacles: list = field(default_factory=list)
    clearance: float = 0.5
    cover_things: bool = False


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
    #: indoor: the room's floor outline, ``[K, 2]`` (x, y) corners counter-clockwise (walls stand on its edges)
    room_polygon: np.ndarray | None = None
    #: what the seed chose (room shape and size, textures, lighting, objects, street layout): JSON-ready, written
    #: to ``transforms.json`` under ``lift3d_synth.scene``
    description: dict = field(default_factory=dict)
    #: indoor rooms of the new shapes and cluttered rooms: what camera planning needs (None: the original rooms)
    room: RoomSpec | None = None

    @property
    def things(self) -> list[SceneObject]:
        cats = {c.id: c for c in self.categories}
        return [o for o in self.objects if cats[o.category_id].isthing]

    @property
    def floor_things(self) -> list[SceneObject]:
        """Things standing on the floor (obstacles for a walking camera)."""
        return [o for o in self.things if o.rests_on == 0]


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


# --------------------------------------------------------------------------------------------- colours
def hsv(h: float, s: float, v: float) -> np.ndarray:
    """HSV (all in [0, 1]) → RGB."""
    i = int(h * 6) % 6
    f = h * 6 - int(h * 6)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    return np.array([(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i])


def two_tone(rng: np.random.Generator, hue: float, sat: float, val: float, spread: float = 0.18) -> tuple:
    """Two related colours around a hue (the two ends of a material's blend); ``spread`` is their brightness
    difference (0.01: near-uniform, 0.4: strongly two-tone)."""
    h0 = (hue + rng.uniform(-0.03, 0.03)) % 1.0
    a = hsv(h0, np.clip(sat + rng.uniform(-0.1, 0.1), 0, 1), np.clip(val + spread / 2, 0, 1))
    b = hsv((h0 + rng.uniform(-0.04, 0.04)) % 1.0, np.clip(sat + rng.uniform(0.0, 0.15), 0, 1),
            np.clip(val - spread / 2, 0, 1))
    return a, b


def kelvin_rgb(kelvin: float, white_balance: float = 0.5) -> np.ndarray:
    """RGB tint of a light of colour temperature ``kelvin`` (mean 1).

    Tanner Helland's fit of the black-body colour in sRGB, moved ``white_balance`` of the way towards white,
    as a camera's automatic white balance partly corrects a warm or cold light.

    Examples
    --------
    >>> np.round(kelvin_rgb(2700), 2).tolist(), np.round(kelvin_rgb(6500), 2).tolist()
    ([1.2, 0.99, 0.81], [1.0, 1.0, 0.99])
    """
    t = kelvin / 100.0
    r = 255.0 if t <= 66 else 329.698727446 * (t - 60) ** -0.1332047592
    g = 99.4708025861 * np.log(t) - 161.1195681661 if t <= 66 else 288.1221695283 * (t - 60) ** -0.0755148492
    b = 255.0 if t >= 66 else (0.0 if t <= 19 else 138.5177312231 * np.log(t - 10) - 305.0447927307)
    rgb = np.clip(np.array([r, g, b], np.float64), 0, 255) / 255.0
    rgb = white_balance + (1 - white_balance) * rgb
    return rgb / rgb.mean()


def unit(v) -> np.ndarray:
    """``v`` scaled to length 1."""
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


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

    def distance(self, points: np.ndarray) -> np.ndarray:
        """``[N]`` unsigned distance (metres) from ``points`` ``[N, 3]`` to the nearest surface."""
        o3d = self._o3d
        q = o3d.core.Tensor(np.asarray(points, np.float32).reshape(-1, 3))
        return self.scene.compute_distance(q).numpy().astype(np.float64)

    def closest_points(self, points: np.ndarray) -> np.ndarray:
        """``[N, 3]`` nearest surface point to each of ``points`` ``[N, 3]``."""
        o3d = self._o3d
        q = o3d.core.Tensor(np.asarray(points, np.float32).reshape(-1, 3))
        return self.scene.compute_closest_points(q)["points"].numpy().astype(np.float64)

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
            rgb[hits.index] = albedo * self.content.lighting.shade(hits.normals)
        if self.content.sky_category is not None and len(hits.index) < len(hits.t):
            miss = ~hits.hit
            rgb[miss] = sky_color(directions[miss])
        return np.clip(rgb, 0.0, 1.0)
