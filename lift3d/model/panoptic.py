"""The trained object: field + proposal grids + what the scene fixed (label space), and its loss."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from lift3d.field.grids import DenseGrid
from lift3d.field.layers import ProposalGrid
from lift3d.field.registry import build_field
from lift3d.model.config import Config
from lift3d.model.labels import LabelSpace
from lift3d.model.loss_terms import LossInputs, RayBatch, compute_loss_terms, needs_labels
from lift3d.render.renderer import RenderOutputs, render_rays, render_rays_chunked


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

    def render(self, origins: Tensor, dirs: Tensor, *, training: bool = False, with_labels: bool = True,
               generator: torch.Generator | None = None, proposal_anneal: float = 1.0,
               depth_target: Tensor | None = None) -> RenderOutputs:
        """Render a batch of normalised-space rays (with gradients); see :func:`render_rays`."""
        return render_rays(self.field, self.proposals, origins, dirs, self.cfg.sampling, bounded=self.bounded,
                           training=training, with_labels=with_labels, generator=generator,
                           proposal_anneal=proposal_anneal, depth_target=depth_target)

    def forward(self, origins: Tensor, dirs: Tensor, training: bool = True, with_labels: bool = True,
                generator: torch.Generator | None = None, proposal_anneal: float = 1.0,
                depth_target: Tensor | None = None) -> RenderOutputs:
        """Same as :meth:`render`; the entry point DistributedDataParallel wraps."""
        return self.render(origins, dirs, training=training, with_labels=with_labels, generator=generator,
                           proposal_anneal=proposal_anneal, depth_target=depth_target)

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
                       chunk_size: int | None = None, progress: bool = False) -> dict[str, Tensor]:
        """Render any number of rays without gradients; label outputs are probabilities."""
        return render_rays_chunked(self.field, self.proposals, origins, dirs, self.cfg.sampling, bounded=self.bounded,
                                   with_labels=with_labels, chunk_size=chunk_size, progress=progress)

    def panoptic_from_probs(self, sem_probs: Tensor, inst_probs: Tensor | None) -> tuple[Tensor, Tensor, Tensor]:
        """Pixel/point panoptic labels from probabilities (PAPER.md: u* = argmax U; v* = argmax V for things).

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

    def query_points(self, x: Tensor, chunk: int = 65536) -> dict[str, Tensor]:
        """Field values at normalised points (no rendering): ``sigma``, ``rgb`` (seen head-on along -z is
        not meaningful for view-dependent colour, so the mean over 6 axis directions is used), semantic and
        instance probabilities. Used by export."""
        out: dict[str, list[Tensor]] = {}
        dirs6 = torch.tensor([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                             dtype=x.dtype, device=x.device)
        with torch.no_grad():
            for s in range(0, x.shape[0], chunk):
                xs = x[s:s + chunk]
                sigma, geo, u = self.field.geometry(xs)
                rgb = torch.stack([self.field.color(geo, d.expand(len(xs), 3)) for d in dirs6]).mean(0)
                sem, inst = self.field.labels(u, geo)
                parts = {"sigma": sigma, "rgb": rgb, "semantic": torch.softmax(sem, -1)}
                if inst is not None:
                    parts["instance"] = torch.softmax(inst, -1)
                for k, v in parts.items():
                    out.setdefault(k, []).append(v)
        return {k: torch.cat(v) for k, v in out.items()}


def count_parameters(model: nn.Module) -> int:
    return int(sum(p.numel() for p in model.parameters()))
