"""Training data kept compact in memory, and the patch + random-ray batches of each step.

Per pixel the cache holds 3 bytes of colour, int16 semantic channel and per-frame instance id, int32
per-frame segment id, (when not all ones) a float16 confidence and (when depth supervision is on) a
float32 depth: ~13–17 bytes, not ``H·W·C`` floats.
Frames may differ in size (the pixels of all frames are concatenated).
"""

from __future__ import annotations

import numpy as np
import torch

from lift3d.data.scene import Scene
from lift3d.model.labels import LabelSpace
from lift3d.model.loss_terms import RayBatch
from lift3d.render.rays import RayGenerator
from lift3d.utils.progress import progress_bar


class TrainingData:
    """Pixels and pseudo-labels of the training frames.

    Parameters
    ----------
    scene : Scene
    frames : np.ndarray
        Indices of the training frames.
    rays : RayGenerator
        Ray generator over *all* scene frames (normalised coordinates).
    labels : LabelSpace, optional
        The semantic channels; derived from the labels when None.
    depth_scale : float, optional
        Load the frames' depth maps (``depth_file_path``), converted to normalised units with this scale
        (normalised units per world unit); None = no depth.
    """

    def __init__(self, scene: Scene, frames: np.ndarray, rays: RayGenerator, labels: LabelSpace | None = None,
                 progress: bool = True, depth_scale: float | None = None):
        self.frames = np.asarray(frames, np.int64)
        self.rays = rays
        self.device = rays.device
        widths = scene.cameras.width[self.frames]
        heights = scene.cameras.height[self.frames]
        sizes = widths * heights
        self.offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        n = int(self.offsets[-1])
        rgb = np.empty((n, 3), np.uint8)
        cats = np.empty(n, np.int32)
        inst = np.empty(n, np.int16)
        seg = np.empty(n, np.int32)
        conf = np.empty(n, np.float16)
        depth = np.zeros(n, np.float32) if depth_scale is not None and scene.has_depth else None
        mask = None
        self.max_instances_per_frame = 0
        for k, i in enumerate(progress_bar(self.frames, desc="load frames", disable=not progress)):
            a, b = self.offsets[k], self.offsets[k + 1]
            rgb[a:b] = scene.image(int(i)).reshape(-1, 3)
            lab = scene.pseudo_labels(int(i))
            cats[a:b] = lab.semantic.reshape(-1)
            # Per-frame compact ids: 2D ids are arbitrary per frame anyway.
            ids = lab.instance.reshape(-1)
            uniq, inv = np.unique(ids, return_inverse=True)
            compact = inv.astype(np.int32) + (0 if uniq[0] == 0 else 1)
            inst[a:b] = compact
            self.max_instances_per_frame = max(self.max_instances_per_frame, int(compact.max(initial=0)))
            _, sinv = np.unique(lab.segment.reshape(-1), return_inverse=True)
            seg[a:b] = np.where(lab.segment.reshape(-1) > 0, sinv + 1, 0)
            conf[a:b] = lab.confidence.reshape(-1)
            if depth is not None:
                d = scene.depth(int(i))
                if d is not None:
                    depth[a:b] = np.where(np.isfinite(d) & (d > 0), d, 0).reshape(-1) * depth_scale
            m = scene.mask(int(i))
            if m is not None:
                if mask is None:
                    mask = np.ones(n, bool)
                mask[a:b] = m.reshape(-1)
        self.used_category_ids = sorted(int(c) for c in np.unique(cats) if c > 0)
        self.labels = labels or LabelSpace(self.used_category_ids, [c for c in scene.thing_ids if c in self.used_category_ids])
        lut = self.labels.category_to_channel()
        cats = np.where(cats < len(lut), cats, 0)
        dev = self.device
        self.rgb = torch.from_numpy(rgb).to(dev)
        self.semantic = torch.from_numpy(lut[cats].astype(np.int16)).to(dev)
        self.instance = torch.from_numpy(inst).to(dev)
        self.segment = torch.from_numpy(seg).to(dev)
        self.confidence = None if bool(np.all(conf == 1)) else torch.from_numpy(conf).to(dev)
        self.mask = None if mask is None else torch.from_numpy(mask).to(dev)
        self.depth = None if depth is None or not depth.any() else torch.from_numpy(depth).to(dev)
        self.widths = torch.as_tensor(widths, device=dev)
        self.heights = torch.as_tensor(heights, device=dev)
        self.offsets_t = torch.as_tensor(self.offsets, device=dev)

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def num_pixels(self) -> int:
        return int(self.offsets[-1])

    def semantic_pixel_fractions(self) -> np.ndarray:
        """Fraction of labelled pixels per channel (for reports)."""
        counts = torch.bincount(self.semantic.long(), minlength=self.labels.num_channels).double()
        return (counts / counts[1:].sum().clamp_min(1)).cpu().numpy()

    def sample(self, images_per_batch: int, rays_per_image: int, patch_size: int,
               generator: torch.Generator) -> RayBatch:
        """Draw ``images_per_batch`` frames; from each a ``patch_size²`` patch and ``rays_per_image`` random
        pixels (masked pixels are redrawn once and then dropped)."""
        dev = self.device
        k = min(images_per_batch, len(self))
        # Draws come from the generator's device (the training device) and stay there.
        local = torch.randperm(len(self), generator=generator, device=generator.device)[:k].to(dev)
        w, h = self.widths[local], self.heights[local]
        ps = int(min(patch_size, int(w.min()), int(h.min()))) if patch_size > 0 else 0
        parts_u, parts_v, parts_f = [], [], []
        if ps > 0:
            x0 = (torch.rand(k, generator=generator, device=generator.device).to(dev) * (w - ps + 1).float()).long()
            y0 = (torch.rand(k, generator=generator, device=generator.device).to(dev) * (h - ps + 1).float()).long()
            ar = torch.arange(ps, device=dev)
            pu = (x0[:, None, None] + ar[None, None, :]).expand(k, ps, ps)
            pv = (y0[:, None, None] + ar[None, :, None]).expand(k, ps, ps)
            parts_u.append(pu.reshape(-1))
            parts_v.append(pv.reshape(-1))
            parts_f.append(local[:, None].expand(k, ps * ps).reshape(-1))
        if rays_per_image > 0:
            r = torch.rand(k, rays_per_image, generator=generator, device=generator.device).to(dev)
            pix = (r * (w * h)[:, None].float()).long()
            parts_u.append((pix % w[:, None]).reshape(-1))
            parts_v.append((pix // w[:, None]).reshape(-1))
            parts_f.append(local[:, None].expand(k, rays_per_image).reshape(-1))
        u, v, f = torch.cat(parts_u), torch.cat(parts_v), torch.cat(parts_f)
        flat = self.offsets_t[f] + v * self.widths[f] + u
        n_patch = k * ps * ps
        if self.mask is not None:
            keep = self.mask[flat]
            keep[:n_patch] = True  # patches stay whole (L_feat needs the full patch)
            u, v, f, flat = u[keep], v[keep], f[keep], flat[keep]
        scene_frame = torch.as_tensor(self.frames, device=dev)[f]
        origins, dirs, cos_axis = self.rays.rays(scene_frame, u, v)
        return RayBatch(
            origins=origins,
            dirs=dirs,
            rgb=self.rgb[flat].float() / 255.0,
            semantic=self.semantic[flat].long(),
            instance=self.instance[flat].long(),
            segment=self.segment[flat].long(),
            confidence=None if self.confidence is None else self.confidence[flat].float(),
            image=f,
            depth=None if self.depth is None else self.depth[flat] / cos_axis.clamp_min(1e-6),
            n_patch_rays=n_patch,
            patch_size=ps,
        )
