"""Mask2Former panoptic segmentation through Hugging Face ``transformers`` (the optional ``label`` extra).

:func:`load_mask2former` finds the weights (a local folder or the Hugging Face cache; never a download when
``HF_HUB_OFFLINE`` is set) and :class:`Mask2FormerLabeler` turns images into panoptic labels in the scene's
vocabulary:

1. the image processor resizes and normalises a batch; the model predicts, per query, class logits over
   the model's classes plus "no object", and a mask;
2. the class probabilities are mapped onto the target vocabulary *before* any decision
   (:meth:`~lift3d.label.classes.ClassMapping.map_probabilities`): merged source classes add up, and the
   probability of classes that become void is gathered in an extra "unmapped" class;
3. the image processor's ``post_process_panoptic_segmentation`` assigns pixels to queries in that target
   space; segments of the "unmapped" class become void;
4. the same query outputs give the per-pixel maps of :mod:`lift3d.label.tta` (class probabilities, mask
   probability of the winning query), which score the segments, fuse stuff, decide classes under TTA and
   give the per-pixel confidence.

``transformers`` is imported only inside these functions, so ``lift3d`` works without it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from lift3d.data.scene import Segment
from lift3d.errors import InputError
from lift3d.label.classes import ClassMapping, load_class_mapping, sources_from_labels
from lift3d.label.tta import Augmentation, PassMaps, mean_confidence, mean_probabilities, pixel_confidence, \
    relabel_segments, run_tta

#: The checkpoint the docs and error messages point to.
DEFAULT_MODEL = "facebook/mask2former-swin-large-coco-panoptic"

# transformers' panoptic post-processing first resamples every mask to this fixed size and only then to the
# requested output size. The per-pixel maps follow the same two steps so that their winning query is the
# one the post-processing assigned the pixel to (otherwise boundaries would disagree by a pixel or two).
_HF_POSTPROCESS_SIZE = (384, 384)

_TRUTHY = {"1", "on", "yes", "true"}


def import_transformers() -> Any:
    """``transformers``, or a one-line :class:`InputError` naming the extra that provides it."""
    try:
        import transformers
    except ImportError as exc:
        raise InputError("--model", "Mask2Former labelling needs the optional dependency 'transformers': "
                                    "pip install 'lift3d[label]'") from exc
    return transformers


def hub_offline() -> bool:
    """Whether ``HF_HUB_OFFLINE`` forbids network access (read now, not at import)."""
    return os.environ.get("HF_HUB_OFFLINE", "").strip().lower() in _TRUTHY


def _looks_like_path(name: str) -> bool:
    # Hub ids are "name" or "owner/name"; anything else the user typed is meant as a folder.
    return name.startswith((".", "/", "~")) or name.count("/") > 1 or "\\" in name or os.path.isabs(name)


def _not_found(name: str, exc: BaseException | None, hub: bool, local_only: bool) -> InputError:
    if hub and local_only:
        reason = "not in the Hugging Face cache, and HF_HUB_OFFLINE forbids downloading"
    else:
        # transformers' messages run to several sentences; the first says what went wrong.
        first = " ".join(str(exc).split()).split(". ")[0] if exc is not None else "missing files"
        reason = first if len(first) <= 160 else first[:157] + "..."
    repo = name if hub else DEFAULT_MODEL
    return InputError(
        name,
        f"Mask2Former weights not found ({reason}). On a machine with network run "
        f"`huggingface-cli download {repo}` and copy its Hugging Face cache (~/.cache/huggingface) here, or pass "
        f"--model DIR (a folder with config.json, model.safetensors and preprocessor_config.json)",
    )


@dataclass
class _Source:
    name: str  # what the user gave
    source: str  # what from_pretrained gets
    local: bool
    kwargs: dict


def _resolve(name_or_path: str | Path, cache_dir: str | Path | None) -> _Source:
    name = str(name_or_path)
    path = Path(name).expanduser()
    local = path.is_dir()
    if not local and (_looks_like_path(name) or path.exists()):
        raise InputError(name, "model folder not found" if not path.exists() else
                         "not a folder (expected a save_pretrained folder or a Hugging Face hub id)")
    kwargs: dict[str, Any] = {"local_files_only": local or hub_offline()}
    if cache_dir is not None:
        kwargs["cache_dir"] = str(cache_dir)
    return _Source(name, str(path) if local else name, local, kwargs)


def _load_errors() -> tuple[type[BaseException], ...]:
    errors: tuple[type[BaseException], ...] = (OSError, ValueError)
    try:
        from huggingface_hub.errors import HfHubHTTPError

        errors = errors + (HfHubHTTPError,)
    except ImportError:  # older huggingface_hub: its errors derive from OSError/ValueError anyway
        pass
    return errors


def load_mask2former_config(name_or_path: str | Path, *, cache_dir: str | Path | None = None) -> Any:
    """Only the model's configuration (classes, architecture): a few kB, read before the weights so that
    vocabulary problems are reported without loading hundreds of MB.

    Parameters and errors as :func:`load_mask2former`.
    """
    transformers = import_transformers()
    src = _resolve(name_or_path, cache_dir)
    try:
        config = transformers.AutoConfig.from_pretrained(src.source, **src.kwargs)
    except _load_errors() as exc:
        raise _not_found(src.name, exc, not src.local, src.kwargs["local_files_only"]) from exc
    if getattr(config, "model_type", None) != "mask2former":
        raise InputError(src.name, f"is a {getattr(config, 'model_type', 'unknown')!r} checkpoint, not Mask2Former")
    return config


def load_mask2former(name_or_path: str | Path, *, device: torch.device | str = "cpu",
                     cache_dir: str | Path | None = None, config: Any = None) -> tuple[Any, Any]:
    """Load a Mask2Former panoptic model and its image processor without downloading anything unasked.

    Parameters
    ----------
    name_or_path : str or Path
        A local folder (``save_pretrained`` layout) or a Hugging Face hub id such as
        ``facebook/mask2former-swin-large-coco-panoptic``, looked up in the Hugging Face cache.
    device : torch.device or str
        Where the model runs.
    cache_dir : str or Path, optional
        Hugging Face cache to search instead of the default one.
    config : optional
        The configuration from :func:`load_mask2former_config` (read again when not given).

    Returns
    -------
    (model, processor)
        ``Mask2FormerForUniversalSegmentation`` in eval mode on ``device`` and its image processor.

    Raises
    ------
    InputError
        transformers missing, folder missing, weights not found (saying how to get them) or not a
        Mask2Former checkpoint.

    Notes
    -----
    A local folder is always read with ``local_files_only=True``; a hub id too when ``HF_HUB_OFFLINE`` is
    set. Otherwise transformers may fetch a hub id that is not cached yet, as ``from_pretrained`` does.
    """
    transformers = import_transformers()
    if config is None:
        config = load_mask2former_config(name_or_path, cache_dir=cache_dir)
    src = _resolve(name_or_path, cache_dir)
    try:
        model = transformers.Mask2FormerForUniversalSegmentation.from_pretrained(src.source, config=config,
                                                                                 **src.kwargs)
        processor = transformers.AutoImageProcessor.from_pretrained(src.source, **src.kwargs)
    except _load_errors() as exc:
        raise _not_found(src.name, exc, not src.local, src.kwargs["local_files_only"]) from exc
    if not hasattr(processor, "post_process_panoptic_segmentation"):
        raise InputError(src.name, f"its image processor ({type(processor).__name__}) has no panoptic post-processing")
    return model.eval().to(device), processor


def _size_value(size: Any, key: str) -> int | None:
    value = getattr(size, key, None)
    if value is None and isinstance(size, dict):
        value = size.get(key)
    return int(value) if value else None


@dataclass
class QueryOutput:
    """Raw model output for one image (padding already cropped away)."""

    class_logits: Tensor  # [Q, S + 1]
    mask_logits: Tensor  # [Q, h, w] at the model's mask resolution


@dataclass
class FramePrediction:
    """Panoptic labels of one image in the target vocabulary (category ids of ``mapping.categories``)."""

    panoptic: np.ndarray  # int64 [H, W], 0 = void
    segments: list[Segment]
    confidence: np.ndarray  # float32 [H, W] in [0, 1]
    probabilities: np.ndarray | None = None  # float32 [H, W, K + 1] (void first), when asked for
    confidence_tta: np.ndarray | None = None  # float32 [H, W]: C̄ (score × mask, averaged over passes)
    confidence_notta: np.ndarray | None = None  # float32 [H, W]: the same for the identity pass only


class Mask2FormerLabeler:
    """Mask2Former panoptic predictions mapped onto a target vocabulary, optionally with TTA.

    Parameters
    ----------
    model, processor
        From :func:`load_mask2former` (or built in code, e.g. a small random model for tests).
    mapping : ClassMapping, optional
        Source → target classes. Default: the model's classes as they are (COCO panoptic models only).
    threshold : float
        Queries whose best class probability is not above this are dropped (Mask2Former's panoptic
        ``object_mask_threshold``; 0.8 in its COCO configs).
    overlap_threshold : float
        A query keeps its segment only when it wins more than this fraction of its own mask.
    mask_threshold : float
        Mask probability that counts as "inside" a query's mask for the overlap test.
    shortest_edge : int, optional
        Inference resolution (shortest image side after resizing) instead of the processor's own; smaller
        is faster on CPU. TTA scales multiply it.
    """

    def __init__(self, model: Any, processor: Any, mapping: ClassMapping | None = None, *, threshold: float = 0.8,
                 overlap_threshold: float = 0.8, mask_threshold: float = 0.5, shortest_edge: int | None = None):
        self.model = model
        self.processor = processor
        sources = sources_from_labels(model.config.id2label)
        self.mapping = mapping if mapping is not None else load_class_mapping(None, sources)
        if [s.name for s in self.mapping.sources] != [s.name for s in sources]:
            raise ValueError("the class mapping was built for another source vocabulary than the model's")
        if not 0.0 <= threshold < 1.0:
            raise InputError("--threshold", f"must lie in [0, 1) (got {threshold})")
        if not 0.0 < overlap_threshold <= 1.0:
            raise InputError("--overlap-threshold", f"must lie in (0, 1] (got {overlap_threshold})")
        self.threshold = float(threshold)
        self.overlap_threshold = float(overlap_threshold)
        self.mask_threshold = float(mask_threshold)
        self.device = next(model.parameters()).device
        self._base_size = self._processor_size(shortest_edge)

    # ------------------------------------------------------------------ sizes
    def _processor_size(self, shortest_edge: int | None) -> dict[str, int] | None:
        size = getattr(self.processor, "size", None)
        short, long_ = _size_value(size, "shortest_edge"), _size_value(size, "longest_edge")
        height, width = _size_value(size, "height"), _size_value(size, "width")
        if shortest_edge is not None:
            if shortest_edge < 64:
                raise InputError("--shortest-edge", f"must be at least 64 pixels (got {shortest_edge})")
            ratio = (long_ / short) if short and long_ else 1333 / 800
            return {"shortest_edge": int(shortest_edge), "longest_edge": int(round(shortest_edge * ratio))}
        if short:
            return {"shortest_edge": short, **({"longest_edge": long_} if long_ else {})}
        if height and width:
            return {"height": height, "width": width}
        return None  # the processor's own rule; TTA scales then cannot change the resolution

    def _size_for(self, scale: float) -> dict[str, int] | None:
        if self._base_size is None or scale == 1.0:
            return self._base_size
        # Never below 64 px: the coarsest feature map (stride 32) must keep more than one pixel per side,
        # or the pixel decoder's group norms have a single value per group.
        return {k: max(64, int(round(v * scale))) for k, v in self._base_size.items()}

    # ------------------------------------------------------------------ model
    @torch.inference_mode()
    def forward(self, images: Sequence[np.ndarray], scale: float = 1.0) -> list[QueryOutput]:
        """Run the model on a batch of ``uint8 [H, W, 3]`` RGB images at ``scale`` × the base resolution."""
        size = self._size_for(scale)
        kwargs: dict[str, Any] = {"return_tensors": "pt"}
        if size is not None:
            kwargs["size"] = size
        inputs = self.processor(images=list(images), **kwargs)
        pixel_values = inputs["pixel_values"].to(self.device)
        pixel_mask = inputs.get("pixel_mask")
        out = self.model(pixel_values=pixel_values)
        hp, wp = pixel_values.shape[-2:]
        results = []
        for b in range(len(images)):
            masks = out.masks_queries_logits[b]
            if pixel_mask is not None:
                # Images of different sizes are padded to a common one at the bottom/right: keep only the
                # part of the masks that covers the image, so resizing to the image maps pixel to pixel.
                valid = pixel_mask[b].bool()
                vh, vw = int(valid.any(1).sum()), int(valid.any(0).sum())
                mh, mw = masks.shape[-2:]
                masks = masks[:, : max(1, round(vh * mh / hp)), : max(1, round(vw * mw / wp))]
            results.append(QueryOutput(out.class_queries_logits[b].float(), masks.float()))
        return results

    def target_probabilities(self, class_logits: Tensor) -> Tensor:
        """``[Q, K + 2]``: target classes, "unmapped", "no object" (see :meth:`ClassMapping.map_probabilities`)."""
        return self.mapping.map_probabilities(class_logits.softmax(-1))

    # ------------------------------------------------------------------ per-pixel maps
    def pass_maps(self, q: QueryOutput, size: tuple[int, int]) -> PassMaps:
        """The pass's :class:`PassMaps` on an ``size = (H, W)`` grid (the classes are target index + 1)."""
        probs = self.target_probabilities(q.class_logits)
        k = self.mapping.num_targets
        scores, labels = probs.max(-1)
        keep = (labels != k + 1) & (scores > self.threshold)  # same rule as the post-processing
        masks = F.interpolate(q.mask_logits[None], size=_HF_POSTPROCESS_SIZE, mode="bilinear",
                              align_corners=False)[0].sigmoid()[keep]
        h, w = size
        # Void first: "no object" plus unmapped, then the K target classes.
        folded = torch.cat([probs[keep][:, k:].sum(-1, keepdim=True), probs[keep][:, :k]], dim=-1)
        cls = torch.where(labels[keep] == k, torch.zeros_like(labels[keep]), labels[keep] + 1)
        if masks.shape[0] == 0:
            return PassMaps(folded.cpu(), cls.cpu(), scores[keep].cpu(), torch.full((h, w), -1, dtype=torch.long),
                            torch.zeros(h, w))
        masks = F.interpolate(masks[None], size=(h, w), mode="bilinear", align_corners=False)[0]
        winner = (masks * scores[keep].view(-1, 1, 1)).argmax(0)
        mask_prob = masks.gather(0, winner[None])[0]
        return PassMaps(folded.cpu(), cls.cpu(), scores[keep].cpu(), winner.cpu(), mask_prob.cpu())

    # ------------------------------------------------------------------ panoptic
    def panoptic_segments(self, q: QueryOutput, size: tuple[int, int]) -> tuple[Tensor, dict[int, int]]:
        """The image processor's panoptic post-processing, in the target vocabulary.

        Returns the segment map (``long [H, W]``, 0 = void) and ``{segment id: class}`` with classes as
        target index + 1; segments of the "unmapped" class are already void. Nothing is fused yet.
        """
        from transformers.models.mask2former.modeling_mask2former import Mask2FormerForUniversalSegmentationOutput

        probs = self.target_probabilities(q.class_logits)
        k = self.mapping.num_targets
        # log-probabilities: the post-processing's softmax turns them back into exactly these probabilities.
        logits = probs.clamp_min(1e-12).log()
        outputs = Mask2FormerForUniversalSegmentationOutput(class_queries_logits=logits[None],
                                                            masks_queries_logits=q.mask_logits[None])
        # label_ids_to_fuse stays empty: transformers' fusion bookkeeping can give two different segments the
        # same id once a fused class reappears after a new segment; stuff is fused afterwards instead.
        res = self.processor.post_process_panoptic_segmentation(
            outputs, threshold=self.threshold, mask_threshold=self.mask_threshold,
            overlap_mask_area_threshold=self.overlap_threshold, label_ids_to_fuse=set(), target_sizes=[size])[0]
        seg = torch.as_tensor(res["segmentation"]).long().cpu().clamp_min(0)  # -1 = nothing found
        classes: dict[int, int] = {}
        for info in res["segments_info"]:
            sid, label = int(info["id"]), int(info["label_id"])
            if label >= k:  # the "unmapped" class: what the vocabulary leaves out is void
                seg[seg == sid] = 0
            else:
                classes[sid] = label + 1
        return seg, classes

    # ------------------------------------------------------------------ everything
    def predict(self, images: Sequence[np.ndarray], augs: Sequence[Augmentation] = (Augmentation(),),
                keep_probabilities: bool = False) -> list[FramePrediction]:
        """Panoptic labels of a batch of images.

        Parameters
        ----------
        images : sequence of np.ndarray
            ``uint8 [H, W, 3]`` RGB.
        augs : sequence of Augmentation
            The passes; the first must be the identity (its segments become the labels).
        keep_probabilities : bool
            Also return the averaged class probabilities and confidences (:class:`FramePrediction`).
        """
        if not augs or not augs[0].is_identity:
            raise ValueError("the first pass must be the identity (x1, no flip)")
        sizes = [im.shape[:2] for im in images]
        identity: list[QueryOutput] = []

        def predict_pass(batch: list[np.ndarray], aug: Augmentation) -> list[PassMaps]:
            outputs = self.forward(batch, aug.scale)
            if aug.is_identity:
                identity.extend(outputs)
            return [self.pass_maps(q, s) for q, s in zip(outputs, sizes)]

        all_passes = run_tta(images, predict_pass, augs)
        stuff = {t + 1 for t in self.mapping.stuff_targets}
        cats = self.mapping.categories
        results = []
        for q, size, passes in zip(identity, sizes, all_passes):
            seg, classes = self.panoptic_segments(q, tuple(size))
            seg, labelled = relabel_segments(seg, classes, passes, stuff)
            lut = torch.zeros(int(seg.max()) + 1 if seg.numel() else 1, dtype=torch.long)
            for s in labelled:
                lut[s.id] = s.cls
            semantic = lut[seg]
            confidence = pixel_confidence(passes, semantic)
            segments = [Segment(s.id, cats[s.cls - 1].id, s.score) for s in labelled]
            pred = FramePrediction(seg.numpy().astype(np.int64), segments, confidence.numpy().astype(np.float32))
            if keep_probabilities:
                pred.probabilities = mean_probabilities(passes).permute(1, 2, 0).numpy().astype(np.float32)
                pred.confidence_tta = mean_confidence(passes).numpy().astype(np.float32)
                pred.confidence_notta = passes[0].confidence().numpy().astype(np.float32)
            results.append(pred)
        return results
