"""Training data kept compact in memory, and the patch + random-ray batches of each step.

Per pixel the cache holds 3 bytes of colour, int16 semantic channel and per-frame instance id, int32
per-frame segment id, (when not all ones) a float16 confidence and (when depth supervision is on) a
float32 depth: ~13–17 bytes, not ``H·W·C`` floats.
Frames may differ in size (the pixels of all frames are concatenated).

Depth targets from the images (:mod:`lift3d.train.image_depth`: triangulated points, plane-sweep depth) are
kept as a list of (frame, sub-pixel position, depth, sigma), and every step draws a share of its rays from
them: sparse points cover about 1 % of the pixels, so random rays would rarely meet one.
"""

from __future__ import annotations

import numpy as np
import torch

from lift3d.data.scene import Scene
from lift3d.model.labels import LabelSpace
from lift3d.model.loss_terms import RayBatch
from lift3d.render.rays import RayGenerator
from lift3d.train.image_depth import DepthTargets
from lift3d.train.scene_sizes import ThingSegments
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
    targets : DepthTargets, optional
        Depth targets from the images (world units) for frames without a depth map.
    target_scale : float
        Normalised units per world unit (converts ``targets``).
    target_sigma_scale, target_min_sigma : float
        A target's standard deviation along its ray is ``max(min_sigma, sigma_scale · σ) / cos`` (normalised
        units; ``cos`` between the ray and the optical axis, as for its depth).
    """

    def __init__(self, scene: Scene, frames: np.ndarray, rays: RayGenerator, labels: LabelSpace | None = None,
                 progress: bool = True, depth_scale: float | None = None, targets: DepthTargets | None = None,
                 target_scale: float = 1.0, target_sigma_scale: float = 1.0, target_min_sigma: float = 0.0):
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
        with_depth = depth_scale is not None and any(scene.frames[int(i)].depth_path is not None for i in self.frames)
        depth = np.zeros(n, np.float32) if with_depth else None
        mask = None
        self.max_instances_per_frame = 0
        thing_parts = []
        thing_categories = set(scene.thing_ids)
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
            d = scene.depth(int(i)) if scene.has_depth else None
            if d is not None:
                d = d.reshape(-1)  # unknown depth is 0 already (read_depth)
                if depth is not None:
                    depth[a:b] = d * depth_scale
            thing_parts.append(_thing_segments(k, compact, cats[a:b], d, thing_categories,
                                               float(scene.cameras.fx[int(i)])))
            m = scene.mask(int(i))
            if m is not None:
                if mask is None:
                    mask = np.ones(n, bool)
                mask[a:b] = m.reshape(-1)
        self.used_category_ids = sorted(int(c) for c in np.unique(cats) if c > 0)
        self.labels = labels or LabelSpace(self.used_category_ids, [c for c in scene.thing_ids if c in self.used_category_ids])
        lut = self.labels.category_to_channel()
        cats = np.where(cats < len(lut), cats, 0)
        self.thing_segments = ThingSegments.concatenate(thing_parts)
        self.thing_segments.channel = lut[np.where(self.thing_segments.channel < len(lut), self.thing_segments.channel, 0)]
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
        self._set_targets(targets, target_scale, target_sigma_scale, target_min_sigma)
        self._index_segments(seg, lut[cats].astype(np.int64))

    def _set_targets(self, targets: DepthTargets | None, scale: float, sigma_scale: float, min_sigma: float) -> None:
        """Keep the targets sorted by training frame, in normalised units, with per-frame offsets."""
        dev = self.device
        self.min_sigma = float(min_sigma)
        local_of = {int(f): k for k, f in enumerate(self.frames)}
        if targets is None or len(targets) == 0:
            self.num_targets = 0
            self.target_offsets = torch.zeros(len(self) + 1, dtype=torch.long, device=dev)
            self.target_points = torch.zeros(len(self), dtype=torch.long, device=dev)
            return
        local = np.array([local_of.get(int(f), -1) for f in targets.frame], np.int64)
        keep = local >= 0
        dense = np.asarray(targets.dense, bool)[keep]
        # by frame, and within a frame the point targets before the dense ones (plane or plane-sweep depths)
        order = np.lexsort((dense, local[keep]))
        local, dense = local[keep][order], dense[order]
        u, v = targets.u[keep][order], targets.v[keep][order]
        w, h = self.widths.cpu().numpy()[local], self.heights.cpu().numpy()[local]
        col = np.clip(np.round(u).astype(np.int64), 0, w - 1)
        row = np.clip(np.round(v).astype(np.int64), 0, h - 1)
        self.num_targets = int(len(local))
        self.target_frame = torch.from_numpy(local).to(dev)
        self.target_flat = torch.from_numpy(self.offsets[local] + row * w + col).to(dev)
        self.target_u = torch.from_numpy(u.astype(np.float32)).to(dev)
        self.target_v = torch.from_numpy(v.astype(np.float32)).to(dev)
        self.target_z = torch.from_numpy((targets.z[keep][order] * scale).astype(np.float32)).to(dev)
        self.target_sigma = torch.from_numpy((targets.sigma[keep][order] * scale * sigma_scale).astype(np.float32)).to(dev)
        counts = np.bincount(local, minlength=len(self))
        self.target_offsets = torch.as_tensor(np.concatenate([[0], np.cumsum(counts)]), dtype=torch.long, device=dev)
        self.target_points = torch.as_tensor(np.bincount(local[~dense], minlength=len(self)), dtype=torch.long,
                                             device=dev)  # per frame, how many of its targets are points

    def _index_segments(self, seg: np.ndarray, channel: np.ndarray) -> None:
        """Pixels grouped by (frame, 2D segment) for :meth:`sample`'s segment rays: ``seg_pixels`` holds the
        labelled pixels sorted by group; group ``g`` is ``seg_pixels[seg_start[g] : seg_start[g] + seg_count[g]]``
        of frame ``seg_frame[g]``; a frame's groups are contiguous from ``frame_first_segment``."""
        n_frames = len(self.frames)
        # Every pixel of every training frame passes through here (56 M for 184 views of 640 x 480), so the
        # arrays are made one at a time and the sorted keys are cut into groups where they change (what
        # np.unique would do after sorting them again).
        labelled = np.flatnonzero(seg > 0)
        key = np.searchsorted(np.asarray(self.offsets), labelled, side="right") - 1  # the pixel's frame
        key <<= 20
        key |= seg[labelled]
        order = np.argsort(key, kind="stable")
        key = key[order]
        pixels = labelled[order]
        del labelled, order
        start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]]) if len(key) else np.zeros(0, np.int64)
        count = np.diff(np.r_[start, len(key)])
        frame = key[start] >> 20
        del key
        # A 2D panoptic segment has one category: the channel of its first pixel is the segment's.
        thing = self.labels.thing_channels()[channel[pixels[start]]] if len(start) else np.zeros(0, bool)
        dev = self.device
        self.seg_pixels = torch.as_tensor(pixels, device=dev)
        self.seg_start = torch.as_tensor(start, device=dev)
        self.seg_count = torch.as_tensor(count, device=dev)
        self.seg_is_thing = torch.as_tensor(thing, device=dev)
        self.frame_first_segment = torch.as_tensor(np.searchsorted(frame, np.arange(n_frames + 1)), device=dev)

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
               generator: torch.Generator, target_rays_per_image: int = 0, segments_per_image: int = 0,
               rays_per_segment: int = 0, thing_segment_weight: float = 1.0, point_share: float = 0.0) -> RayBatch:
        """Draw ``images_per_batch`` frames; from each a ``patch_size²`` patch, ``rays_per_image`` random
        pixels, ``segments_per_image × rays_per_segment`` segment rays (masked pixels other than the
        patch's are dropped) and ``target_rays_per_image`` rays through its depth targets from the images
        (drawn with replacement; none from a frame without targets). Those come last; with ``point_share``
        > 0 that share of them is drawn among the frame's point targets and the rest among its dense ones
        (plane or plane-sweep depths), else all uniformly among its targets.

        Segment rays are Panoptic Lifting's segment sampler: ``segments_per_image`` 2D segments of the frame
        are drawn (with replacement), every segment equally likely whatever its size so that small ones get
        rays too, thing segments ``thing_segment_weight`` times as likely; then ``rays_per_segment`` pixels
        uniformly inside each. L_seg then always has groups of at least ``rays_per_segment`` rays."""
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
        if segments_per_image > 0 and rays_per_segment > 0 and len(self.seg_start):
            su, sv, sf = self._segment_rays(local, segments_per_image, rays_per_segment, thing_segment_weight,
                                            generator)
            parts_u.append(su)
            parts_v.append(sv)
            parts_f.append(sf)
        u, v, f = torch.cat(parts_u), torch.cat(parts_v), torch.cat(parts_f)
        flat = self.offsets_t[f] + v * self.widths[f] + u
        n_patch = k * ps * ps
        if self.mask is not None:
            keep = self.mask[flat]
            keep[:n_patch] = True  # patches stay whole (L_feat needs the full patch)
            u, v, f, flat = u[keep], v[keep], f[keep], flat[keep]
        scene_frames = torch.as_tensor(self.frames, device=dev)
        origins, dirs, cos_axis = self.rays.rays(scene_frames[f], u, v)
        depth = None if self.depth is None else self.depth[flat] / cos_axis.clamp_min(1e-6)
        sigma = None
        if self.num_targets and target_rays_per_image > 0:
            first, count = self.target_offsets[local], self.target_offsets[local + 1] - self.target_offsets[local]
            r = torch.rand(k, target_rays_per_image, generator=generator, device=generator.device).to(dev)
            first, count = first[:, None].expand_as(r), count[:, None].expand_as(r)
            n_points = int(round(point_share * target_rays_per_image))
            if n_points > 0:
                # the first n_points draws among the frame's point targets, the rest among its dense ones
                # (either group empty: the whole frame's)
                pts = self.target_points[local][:, None].expand_as(r)
                is_pt = torch.arange(target_rays_per_image, device=dev)[None, :] < n_points
                both = (pts > 0) & (pts < count)
                first = torch.where(both & ~is_pt, first + pts, first)
                count = torch.where(both, torch.where(is_pt, pts, count - pts), count)
            pick = first + (r * count.float()).long().clamp_max((count - 1).clamp_min(0))
            pick = pick[count > 0]
            t_flat = self.target_flat[pick]
            if self.mask is not None:
                pick, t_flat = pick[self.mask[t_flat]], t_flat[self.mask[t_flat]]
            t_f = self.target_frame[pick]
            t_o, t_d, t_cos = self.rays.rays(scene_frames[t_f], self.target_u[pick], self.target_v[pick])
            cos = t_cos.clamp_min(1e-6)
            t_sigma = (self.target_sigma[pick] / cos).clamp_min(self.min_sigma)
            n_plain = len(flat)
            origins, dirs = torch.cat([origins, t_o]), torch.cat([dirs, t_d])
            depth = torch.cat([depth if depth is not None else origins.new_zeros(n_plain), self.target_z[pick] / cos])
            sigma = torch.cat([origins.new_zeros(n_plain), t_sigma])
            flat, f = torch.cat([flat, t_flat]), torch.cat([f, t_f])
            cos_axis = torch.cat([cos_axis, t_cos])
        return RayBatch(
            origins=origins,
            dirs=dirs,
            rgb=self.rgb[flat].float() / 255.0,
            semantic=self.semantic[flat].long(),
            instance=self.instance[flat].long(),
            segment=self.segment[flat].long(),
            confidence=None if self.confidence is None else self.confidence[flat].float(),
            image=f,
            depth=depth,
            n_patch_rays=n_patch,
            patch_size=ps,
            depth_sigma=sigma,
            cos=cos_axis,
        )

    def _segment_rays(self, local: torch.Tensor, k_segments: int, m_rays: int, thing_weight: float,
                      generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Pixel columns, rows and frame slots of the segment rays of frames ``local`` (see :meth:`sample`);
        frames without a labelled pixel get none."""
        dev = self.device
        first = self.frame_first_segment[local]
        n_seg = self.frame_first_segment[local + 1] - first  # [k]
        has = n_seg > 0
        local, first, n_seg = local[has], first[has], n_seg[has]
        if len(local) == 0:
            empty = torch.zeros(0, dtype=torch.long, device=dev)
            return empty, empty, empty
        width = int(n_seg.max())
        slot = torch.arange(width, device=dev)
        group = (first[:, None] + slot[None, :]).clamp(max=len(self.seg_start) - 1)
        weight = torch.where(self.seg_is_thing[group], float(thing_weight), 1.0) * (slot[None, :] < n_seg[:, None])
        # draws on the generator's device (the training device; see Trainer), results on the batch's
        gdev = generator.device
        pick = torch.multinomial(weight.float().to(gdev), k_segments, replacement=True, generator=generator).to(dev)
        chosen = group.gather(1, pick).reshape(-1)  # [k * K]
        r = torch.rand(len(chosen), m_rays, device=gdev, generator=generator).to(dev)
        within = (r * self.seg_count[chosen][:, None].float()).long().clamp_max(self.seg_count[chosen][:, None] - 1)
        flat = self.seg_pixels[self.seg_start[chosen][:, None] + within].reshape(-1)
        f = local.repeat_interleave(k_segments * m_rays)
        rel = flat - self.offsets_t[f]
        w = self.widths[f]
        return rel % w, rel // w, f


def _thing_segments(slot: int, instance: np.ndarray, category: np.ndarray, depth: np.ndarray | None,
                    thing_categories: set[int], focal: float) -> ThingSegments:
    """The thing segments of one frame (flattened per-pixel compact instance ids, category ids and depth in
    world units, 0 = unknown) as :class:`ThingSegments` rows; ``channel`` holds the *category* until the
    label space is known."""
    ids, first, counts = np.unique(instance, return_index=True, return_counts=True)
    keep = (ids > 0) & np.isin(category[first], list(thing_categories))
    ids, first, counts = ids[keep], first[keep], counts[keep]
    med = np.zeros(len(ids))
    if depth is not None and len(ids):
        order = np.argsort(instance, kind="stable")
        starts = np.searchsorted(instance[order], ids)
        for j, (s, n) in enumerate(zip(starts, counts)):
            d = depth[order[s:s + n]]
            d = d[d > 0]
            med[j] = float(np.median(d)) if len(d) else 0.0
    n = len(ids)
    return ThingSegments(frame=np.full(n, slot, np.int64), channel=category[first].astype(np.int64),
                         pixels=counts.astype(np.int64), depth=med, focal=np.full(n, focal),
                         image_pixels=np.full(n, len(instance), np.int64))
