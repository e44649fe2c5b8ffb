"""A trained run, loaded: labels at any 3D point and renders from any pose, in the world frame.

:func:`load_run` is the one loader every command uses (render, eval, export, plot, bench) and the public
``lift3d.load_run``::

    run = lift3d.load_run("outputs/room0/fast/2026-11-22_101500", device="cpu")   # newest checkpoint
    run.classes                                    # {category id: Category(id, name, isthing, color)}
    q = run.query_points(xyz)                      # world (N, 3) -> density, semantic, instance, ...
    out = run.render(c2w, K, width, height)        # OpenGL camera-to-world as in transforms.json
    out = run.render_rays(origins, directions)     # world frame, any number of rays

Everything takes and returns numpy arrays in the scene's world frame (the frame of its
``transforms.json``); large inputs are processed in chunks, so the memory needed beyond the inputs and
outputs does not grow with their size. See docs/api.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from lift3d.data.cameras import Cameras
from lift3d.data.categories import Category, as_class_table, default_category_color
from lift3d.data.scene import Scene, load_scene
from lift3d.errors import InputError
from lift3d.model.config import Config, config_from_dict
from lift3d.model.labels import LabelSpace
from lift3d.model.normalization import SceneNormalization
from lift3d.model.panoptic import PanopticModel
from lift3d.model.run_folder import RunFolder
from lift3d.render.images import render_frame
from lift3d.render.rays import RayGenerator
from lift3d.utils.device import resolve_device

#: Rendered opacity below which a ray (pixel) counts as hitting nothing: depth 0 (as ``lift3d render``).
EMPTY_OPACITY = 1e-4


@dataclass(repr=False)
class LoadedRun:
    """A trained run ready to query and render: model, configuration, normalisation, labels and its scene.

    Attributes
    ----------
    run : RunFolder
    cfg : Config
        The run's resolved configuration.
    model : PanopticModel
        In evaluation mode, on ``device``.
    norm : SceneNormalization
        World ↔ the field's normalised coordinates.
    labels : LabelSpace
        Semantic channel ↔ category id.
    step : int
        Training step of the checkpoint.
    device : torch.device
    """

    run: RunFolder
    cfg: Config
    model: PanopticModel
    norm: SceneNormalization
    labels: LabelSpace
    step: int
    device: torch.device

    def __repr__(self) -> str:
        return (f"LoadedRun({str(self.run.path)!r}, step={self.step}, classes={len(self.labels.semantic_ids)}, "
                f"device={self.device})")

    # ------------------------------------------------------------------ the scene
    def scene(self, data: str | Path | None = None) -> Scene:
        """The run's scene folder (or ``data``, when it moved since training)."""
        path = Path(data) if data else Path(self.cfg.scene.get("data", ""))
        if not path.is_dir():
            raise InputError(path, "the run's scene folder is gone (pass --data to point at it)")
        return load_scene(path)

    def rays(self, scene: Scene) -> RayGenerator:
        """Rays of the scene's cameras in the field's coordinates."""
        return RayGenerator(scene.cameras, self.norm.c2w_normalized(scene.cameras.c2w), self.device)

    # ------------------------------------------------------------------ classes
    @property
    def classes(self) -> dict[int, Category]:
        """The classes the run predicts: category id → ``Category(id, name, isthing, color)``.

        Names and colours come from the categories recorded at training (runs trained before that was
        recorded read them from the scene folder, or fall back to ``class_<id>``).
        """
        recorded = self.cfg.scene.get("categories")
        if recorded:
            known = {c.id: c for c in as_class_table(recorded, self.run.config_path)}
        else:
            try:
                known = {c.id: c for c in self.scene().categories}
            except InputError:
                known = {}
        return {cid: known.get(cid) or unnamed_category(cid, cid in self.labels.thing_ids)
                for cid in self.labels.semantic_ids}

    @property
    def channel_categories(self) -> np.ndarray:
        """``[U]`` category id of every semantic channel (column of ``semantic_probs``); 0 = void."""
        return self.model.channel_category.cpu().numpy().copy()

    # ------------------------------------------------------------------ queries
    def query_points(self, xyz, *, chunk: int = 32768) -> dict[str, np.ndarray]:
        """The field at world points, without rendering (what ``lift3d export`` labels its points with).

        Parameters
        ----------
        xyz : array_like
            ``[N, 3]`` points in the world frame.
        chunk : int
            Points per chunk.

        Returns
        -------
        dict of np.ndarray
            ``density`` ``[N]`` float32 (per world unit of length: a segment of length ``d`` has opacity
            ``1 - exp(-density d)``); ``semantic`` ``[N]`` int32 category id (void is never chosen);
            ``instance`` ``[N]`` int32 instance channel ``1..V`` on thing classes, 0 on stuff (the export
            splits and renumbers these, see docs/api.md); ``confidence`` ``[N]`` float32 probability of
            the chosen class; ``semantic_probs`` ``[N, U]`` float32, one column per semantic channel
            (:attr:`channel_categories`).
        """
        x = self.norm.to_normalized(_points(xyz, "xyz"))
        labels = self.model.query_labels(x, chunk=chunk, with_probs=True)
        return {"density": (labels.sigma * np.float32(self.norm.scale)).astype(np.float32),
                "semantic": labels.semantic, "instance": labels.channel, "confidence": labels.confidence,
                "semantic_probs": labels.semantic_probs}

    def render(self, c2w, K, width: int, height: int, *, chunk_size: int | None = None) -> dict[str, np.ndarray]:
        """Render one pinhole view, exactly as ``lift3d render`` renders a frame.

        Parameters
        ----------
        c2w : array_like
            ``[4, 4]`` (or ``[3, 4]``) camera-to-world in the world frame, OpenGL axes (x right, y up,
            looking down -z), as ``transform_matrix`` in transforms.json.
        K : array_like
            ``[3, 3]`` intrinsics: ``fx``, ``fy`` on the diagonal, ``cx``, ``cy`` in the last column
            (pixel ``(u, v)`` is sampled at its centre ``(u + 0.5, v + 0.5)``).
        width, height : int
            Image size in pixels.
        chunk_size : int, optional
            Rays rendered at once (default: the run's ``sampling.chunk_size``).

        Returns
        -------
        dict of np.ndarray
            ``rgb`` ``[H, W, 3]`` float32 in [0, 1]; ``depth`` ``[H, W]`` float32 z-depth (along the optical
            axis, world units; 0 where nothing is hit); ``semantic``, ``instance`` ``[H, W]`` int64 (as in
            :meth:`query_points`; they mean nothing where ``opacity`` is near 0); ``confidence``,
            ``opacity`` ``[H, W]`` float32.
        """
        m = np.asarray(c2w, np.float64)
        if m.shape == (3, 4):
            m = np.vstack([m, [0.0, 0.0, 0.0, 1.0]])
        k = np.asarray(K, np.float64)
        if m.shape != (4, 4) or k.shape != (3, 3):
            raise InputError("render", f"c2w must be 4x4 and K 3x3 (got {m.shape} and {k.shape})")
        if int(width) < 1 or int(height) < 1:
            raise InputError("render", f"the image size must be positive (got {width} x {height})")
        cams = Cameras(c2w=m[None], fx=k[0, 0], fy=k[1, 1], cx=k[0, 2], cy=k[1, 2], width=int(width),
                       height=int(height))
        rays = RayGenerator(cams, self.norm.c2w_normalized(cams.c2w), self.device)
        frame = render_frame(self.model, rays, 0, self.norm.scale, chunk_size=chunk_size)
        return {"rgb": frame.rgb, "depth": frame.depth, "semantic": frame.semantic, "instance": frame.instance,
                "confidence": frame.confidence, "opacity": frame.opacity}

    def render_rays(self, origins, directions, *, chunk_size: int | None = None) -> dict[str, np.ndarray]:
        """Render any number of rays given in the world frame.

        Parameters
        ----------
        origins, directions : array_like
            ``[N, 3]`` ray origins and directions (normalised here) in the world frame.
        chunk_size : int, optional
            Rays rendered at once (default: the run's ``sampling.chunk_size``); the results are gathered
            as labels, so memory beyond the outputs does not grow with ``N``.

        Returns
        -------
        dict of np.ndarray
            Per ray: ``rgb`` ``[N, 3]`` float32; ``depth`` ``[N]`` float32 distance along the ray to what it
            sees (world units; 0 where nothing is hit); ``semantic``, ``instance`` ``[N]`` int64 (as in
            :meth:`render`); ``confidence``, ``opacity`` ``[N]`` float32.
        """
        o = self.norm.to_normalized(_points(origins, "origins"))
        d = _points(directions, "directions")
        if len(d) != len(o):
            raise InputError("render_rays", f"{len(o)} origins but {len(d)} directions")
        length = np.linalg.norm(d, axis=1, keepdims=True)
        if not np.all(length > 0):
            raise InputError("render_rays", "directions must be non-zero")
        d = d / length  # the normalisation is a uniform scale: directions keep their meaning
        n = len(o)
        out = {"rgb": np.zeros((n, 3), np.float32), "depth": np.zeros(n, np.float32),
               "semantic": np.zeros(n, np.int64), "instance": np.zeros(n, np.int64),
               "confidence": np.zeros(n, np.float32), "opacity": np.zeros(n, np.float32)}
        step = chunk_size or self.cfg.sampling.chunk_size
        was_training = self.model.training
        self.model.eval()
        try:
            for s in range(0, n, step):
                e = min(n, s + step)
                ot = torch.as_tensor(o[s:e], dtype=torch.float32, device=self.device)
                dt = torch.as_tensor(d[s:e], dtype=torch.float32, device=self.device)
                r = self.model.render_chunked(ot, dt, chunk_size=step)
                opacity = r["opacity"]
                dist = r["depth"] / opacity.clamp_min(1e-6) / self.norm.scale
                out["rgb"][s:e] = r["rgb"].clamp(0, 1).cpu().numpy()
                out["depth"][s:e] = torch.where(opacity > EMPTY_OPACITY, dist, torch.zeros_like(dist)).cpu().numpy()
                out["opacity"][s:e] = opacity.cpu().numpy()
                if "semantic" in r:
                    category, instance, conf = self.model.panoptic_from_probs(r["semantic"], r.get("instance"))
                    out["semantic"][s:e] = category.cpu().numpy()
                    out["instance"][s:e] = instance.cpu().numpy()
                    out["confidence"][s:e] = conf.cpu().numpy()
        finally:
            if was_training:
                self.model.train()
        return out


def unnamed_category(cid: int, isthing: bool) -> Category:
    """The category of an id nothing names: ``class_<id>``, the default colour of that id."""
    return Category(int(cid), f"class_{int(cid)}", bool(isthing), default_category_color(int(cid)))


def _points(a, name: str) -> np.ndarray:
    x = np.asarray(a, np.float64)
    if x.ndim != 2 or x.shape[1] != 3:
        raise InputError(name, f"expected an (N, 3) array, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise InputError(name, "must be finite")
    return x


def model_from_state(state: dict, device: torch.device) -> tuple[Config, PanopticModel, SceneNormalization, LabelSpace]:
    """Rebuild the model of a checkpoint (its config may use the old flat ``field`` layout)."""
    cfg = config_from_dict(state["config"], "checkpoint")
    labels = LabelSpace.from_dict(state["labels"])
    norm = SceneNormalization.from_json(state["normalization"])
    model = PanopticModel(cfg, labels).to(device)
    model.load_state_dict(state["model"])
    model.eval()
    if not model.field.space.occupancy.built:  # checkpoints written before the occupancy grid existed
        model.update_occupancy(subdivide=2)
    return cfg, model, norm, labels


def load_run(path: str | Path, device: str = "auto") -> LoadedRun:
    """Load the newest readable checkpoint of a run folder (``lift3d.load_run``).

    Parameters
    ----------
    path : str or Path
        A run folder written by ``lift3d train``.
    device : str
        ``auto`` (CUDA when available), ``cpu`` or ``cuda[:N]``.

    Raises
    ------
    InputError
        No run folder, no readable checkpoint, or a checkpoint this lift3d cannot rebuild.
    """
    run = RunFolder.open(path)
    dev = resolve_device(device)
    state = run.load_latest_checkpoint(map_location=dev)
    try:
        cfg, model, norm, labels = model_from_state(state, dev)
    except (KeyError, RuntimeError) as exc:
        raise InputError(state.get("_path", run.checkpoint_dir), f"checkpoint does not match this lift3d ({exc})") from exc
    return LoadedRun(run, cfg, model, norm, labels, int(state["step"]), dev)
