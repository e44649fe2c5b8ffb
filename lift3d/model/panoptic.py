"""The trained object: field + proposal grids + what the scene fixed (label space), and its loss."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor, nn

from lift3d.field.grids import DenseGrid
from lift3d.field.layers import ProposalGrid
from lift3d.field.registry import build_field
from lift3d.model.config import Config, load_config
from lift3d.model.labels import LabelSpace
from lift3d.model.loss_terms import LossInputs, RayBatch, compute_loss_terms, needs_labels
from lift3d.render.renderer import RenderOptions, RenderOutputs, render_rays, render_rays_chunked
from lift3d.utils.progress import progress_bar


@dataclass
class PointLabels:
    """Field values and labels at query points (numpy, one row per point)."""

    sigma: np.ndarray  # [N] float32 density (normalised units)
    rgb: np.ndarray  # [N, 3] uint8
    semantic: np.ndarray  # [N] int32 category id (never void)
    channel: np.ndarray  # [N] int32 raw instance channel 1..V on thing classes, 0 on stuff
    confidence: np.ndarray  # [N] float32 probability of the chosen class
    semantic_probs: np.ndarray | None = None  # [N, U] float32 per semantic channel (with_probs)


class PanopticModel(nn.Module):
    """A panoptic radiance field ready to render.

    Parameters
    ----------
    cfg : Config
        Fully resolved (sizes derived from the scene).
    labels : LabelSpace
        Semantic channel ↔ category id table.
    """

    def __init__(self, cfg: Config, labels: LabelSpace):
        super().__init__()
        self.cfg = cfg
        self.labels = labels
        self.field = build_field(cfg.field)
        self.proposals = nn.ModuleList(
            [ProposalGrid(r, cfg.field.density_bias) for r in cfg.sampling.proposal_resolutions]
        )
        self.bounded = cfg.field.contraction == "none"
        box = ((cfg.scene or {}).get("render_box") or {}).get("normalized") if self.bounded else None
        if box:  # the scene's own box (lift3d.train.trainer.resolve_config); older runs have none: the cube
            self.field.space.set_box(*box)
        # Channels beyond the label space (a user asked for a larger U) map to void and are never chosen.
        extra = max(0, cfg.field.num_semantic_classes - labels.num_channels)
        things = torch.cat([torch.as_tensor(labels.thing_channels()), torch.zeros(extra, dtype=torch.bool)])
        category = torch.cat([torch.as_tensor(labels.channel_to_category()), torch.zeros(extra, dtype=torch.long)])
        self.register_buffer("thing_channels", things, persistent=False)
        self.register_buffer("channel_category", category, persistent=False)

    @property
    def has_instances(self) -> bool:
        return self.field.has_instances

    @property
    def trains_labels(self) -> bool:
        """Training renders composite label logits (a label loss is on)."""
        return needs_labels(self.cfg.losses)

    def grid_parameters(self) -> list[nn.Parameter]:
        """Parameters of dense grids (higher learning rate, in-place sparse gradients): the field's, then
        the proposal grids'."""
        proposal = [p for m in self.proposals.modules() if isinstance(m, DenseGrid) for p in m.parameters()]
        return self.field.grid_parameters() + proposal

    def decoder_parameters(self) -> list[nn.Parameter]:
        grid_ids = {id(p) for p in self.grid_parameters()}
        return [p for p in self.parameters() if id(p) not in grid_ids]

    @torch.no_grad()
    def update_occupancy(self, generator: torch.Generator | None = None, subdivide: int = 1) -> None:
        """Measure the field's density once more into its occupancy grid (:mod:`lift3d.field.occupancy`);
        nothing when ``field.occupancy.resolution`` is 0. ``generator`` places the measurement in each cell
        (cell centres without one); ``subdivide`` measures ``subdivide³`` points per cell (see
        :meth:`~lift3d.field.occupancy.OccupancyGrid.update`)."""
        occ = self.cfg.field.occupancy
        if occ.resolution <= 0:
            return
        space = self.field.space
        # A cell the box's face cuts is measured inside the box (its outer part has no density, and a wall on the
        # face would read as empty space); cells farther out than one cell stay empty.
        cell = 2.0 * space.extent / occ.resolution
        space.occupancy.update(lambda x: self.field.geometry(space.clamp_to_box(x, cell))[0], resolution=occ.resolution,
                                          threshold=occ.threshold, decay=occ.decay, generator=generator,
                                          subdivide=subdivide)

    def render(self, origins: Tensor, dirs: Tensor, options: RenderOptions | None = None, *,
               generator: torch.Generator | None = None, depth_target: Tensor | None = None,
               depth_spread: Tensor | None = None) -> RenderOutputs:
        """Render a batch of normalised-space rays (with gradients); see :func:`render_rays` (default options: a
        render outside training, with labels)."""
        return render_rays(self.field, self.proposals, origins, dirs, self.cfg.sampling, options, bounded=self.bounded,
                           generator=generator, depth_target=depth_target, depth_spread=depth_spread)

    def forward(self, origins: Tensor, dirs: Tensor, options: RenderOptions | None = None, *,
                generator: torch.Generator | None = None, depth_target: Tensor | None = None,
                depth_spread: Tensor | None = None) -> RenderOutputs:
        """:meth:`render`, the entry point DistributedDataParallel wraps; default options: a training render."""
        return self.render(origins, dirs, RenderOptions(training=True) if options is None else options,
                           generator=generator, depth_target=depth_target, depth_spread=depth_spread)

    def get_loss_dict(self, outputs: RenderOutputs, batch: RayBatch, *, progress: float,
                      generator: torch.Generator | None = None, perceptual: nn.Module | None = None) -> dict[str, Tensor]:
        """The weighted loss terms of one training step (:mod:`lift3d.model.loss_terms`); their sum is the loss.

        Parameters
        ----------
        outputs : RenderOutputs
            This model's training render of ``batch``'s rays.
        batch : RayBatch
            Targets of the rays.
        progress : float
            Fraction of training done (terms that start late, e.g. L_seg, read it).
        generator : torch.Generator, optional
            Randomness of stochastic terms (L_tv samples grid nodes).
        perceptual : nn.Module, optional
            L_feat's frozen feature extractor (L_feat is off without it).
        """
        return compute_loss_terms(LossInputs(outputs, batch, self.cfg.losses, self.field, len(self.proposals) > 0,
                                             progress, generator, perceptual))

    def render_chunked(self, origins: Tensor, dirs: Tensor, *, with_labels: bool = True,
                       with_median_depth: bool = False, chunk_size: int | None = None,
                       progress: bool = False) -> dict[str, Tensor]:
        """Render any number of rays without gradients; label outputs are probabilities; see
        :func:`render_rays_chunked`."""
        return render_rays_chunked(self.field, self.proposals, origins, dirs, self.cfg.sampling, bounded=self.bounded,
                                   with_labels=with_labels, with_median_depth=with_median_depth,
                                   chunk_size=chunk_size, progress=progress)

    def panoptic_from_probs(self, sem_probs: Tensor, inst_probs: Tensor | None) -> tuple[Tensor, Tensor, Tensor]:
        """Pixel/point panoptic labels from probabilities (the paper's rule: u* = argmax U; v* = argmax V for things).

        Parameters
        ----------
        sem_probs : Tensor
            ``[N, U]`` semantic probabilities (channel 0 = void is never chosen).
        inst_probs : Tensor, optional
            ``[N, V]`` instance probabilities.

        Returns
        -------
        category : Tensor
            ``[N]`` int64 category ids.
        instance : Tensor
            ``[N]`` int64 instance ids ``1..V`` on thing classes, 0 on stuff.
        confidence : Tensor
            ``[N]`` probability of the chosen class.
        """
        p = torch.where(self.channel_category > 0, sem_probs, torch.full_like(sem_probs, -1.0))
        conf, chan = p.max(-1)
        category = self.channel_category[chan]
        if inst_probs is None:
            instance = torch.zeros_like(category)
        else:
            instance = torch.where(self.thing_channels[chan], inst_probs.argmax(-1) + 1, torch.zeros_like(chan))
        return category, instance, conf

    @torch.no_grad()
    def query_labels(self, x_normalized, view_dirs=None, *, chunk: int = 32768, with_probs: bool = False,
                     progress: bool = False, desc: str = "label points") -> PointLabels:
        """Run the density, colour, semantic and instance heads once per point, in chunks, without rendering.

        The one place labels at 3D points come from: the export labels its points and mesh vertices with
        it, and :meth:`lift3d.model.run.LoadedRun.query_points` answers with it.

        Parameters
        ----------
        x_normalized : array_like or Tensor
            ``[N, 3]`` points in normalised scene coordinates (uncontracted).
        view_dirs : array_like or Tensor, optional
            ``[N, 3]`` unit directions the colour is seen along (e.g. from a camera that sees the point).
            Default: looking down ``-z``.
        chunk : int
            Points per chunk; 32768 keeps every temporary under ~16 MiB (measured: the allocator, not the
            arithmetic, dominates larger chunks on CPU).
        with_probs : bool
            Also return the semantic probabilities of every channel (``semantic_probs``).
        progress : bool
            Show a progress bar.

        Returns
        -------
        PointLabels

        Examples
        --------
        >>> labels = _tiny_model().query_labels(torch.zeros(3, 3), with_probs=True)
        >>> labels.semantic.shape, labels.rgb.dtype, bool((labels.semantic > 0).all()), labels.semantic_probs.shape
        ((3,), dtype('uint8'), True, (3, 4))
        """
        device = next(self.parameters()).device
        x = torch.as_tensor(x_normalized, dtype=torch.float32)
        n = x.shape[0]
        if view_dirs is None:
            dirs = torch.tensor([[0.0, 0.0, -1.0]]).expand(n, 3)
        else:
            dirs = torch.as_tensor(view_dirs, dtype=torch.float32)
        out = PointLabels(
            sigma=np.empty(n, np.float32), rgb=np.empty((n, 3), np.uint8), semantic=np.empty(n, np.int32),
            channel=np.empty(n, np.int32), confidence=np.empty(n, np.float32),
            semantic_probs=np.empty((n, self.channel_category.numel()), np.float32) if with_probs else None,
        )
        field = self.field
        for s in progress_bar(range(0, n, chunk), desc=desc, disable=not progress, leave=False, unit="chunk"):
            xs = x[s:s + chunk].to(device)
            ds = torch.nn.functional.normalize(dirs[s:s + chunk].to(device), dim=-1)
            sigma, geo, u = field.geometry(xs)
            sem_logits, inst_logits = field.labels(u, geo)
            rgb = field.color(geo, ds)
            sem_probs = torch.softmax(sem_logits, -1)
            inst_probs = None if inst_logits is None else torch.softmax(inst_logits, -1)
            category, channel, conf = self.panoptic_from_probs(sem_probs, inst_probs)
            e = s + xs.shape[0]
            out.sigma[s:e] = sigma.cpu().numpy()
            out.rgb[s:e] = (rgb.clamp(0, 1) * 255.0 + 0.5).to(torch.uint8).cpu().numpy()
            out.semantic[s:e] = category.cpu().numpy()
            out.channel[s:e] = channel.cpu().numpy()
            out.confidence[s:e] = conf.cpu().numpy()
            if with_probs:
                out.semantic_probs[s:e] = sem_probs.cpu().numpy()
        return out


def count_parameters(model: nn.Module) -> int:
    return int(sum(p.numel() for p in model.parameters()))


def _tiny_model() -> PanopticModel:
    """A small untrained :class:`PanopticModel` for doctests and unit tests."""
    torch.manual_seed(0)
    cfg = load_config("fast", "indoor", None)
    cfg.field.grid.max_resolution, cfg.field.grid.min_resolution = 16, 8
    cfg.field.num_semantic_classes, cfg.field.num_instance_channels = 4, 3
    cfg.field.contraction = "none"
    labels = LabelSpace(semantic_ids=[1, 2, 3], thing_ids=[3])
    return PanopticModel(cfg, labels).eval()
